"""The exporter from a shell (see `__main__.py`)."""

import argparse
import sys


def main(argv):
    parser = argparse.ArgumentParser(prog="python -m tilefarm_blender",
                                     description="Export a Blender scene as a tilefarm scene folder.")
    parser.add_argument("out", help="the folder to write (scene.toml, OBJs, materials.mtl, textures)")
    parser.add_argument("--blend", help="the .blend file to open first (default: the scene loaded now)")
    parser.add_argument("--frame", type=int, help="the frame to export (default: the current one)")
    parser.add_argument("--frames", metavar="A-B",
                        help="export frames A to B, one scene file each (scene.0001.toml, …), sharing what does "
                             "not change; submit them with coordinator submit 'OUT/scene.####.toml' --frames A-B")
    args = parser.parse_args(argv)
    frames = None
    if args.frames:
        try:
            first, last = (int(x) for x in args.frames.split("-", 1))
        except ValueError:
            print(f"error: --frames {args.frames}: give a range such as 1-250", file=sys.stderr)
            return 2
        frames = (first, last)
    import bpy

    from .export import export_animation, export_scene

    if args.blend:
        try:
            bpy.ops.wm.open_mainfile(filepath=args.blend)
        except RuntimeError as e:
            print(f"error: {args.blend}: {e}", file=sys.stderr)
            return 1
    try:
        if frames:
            report = export_animation(args.out, *frames)
        else:
            report = export_scene(args.out, frame=args.frame)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    summary = report.summary()
    if summary:
        print(summary, file=sys.stderr)
    what = f"frames {frames[0]}-{frames[1]}" if frames else "scene.toml"
    print(f"wrote {what} in {args.out}: {report.meshes} mesh(es) in {report.mesh_files} file(s), "
          f"{report.triangles} triangles, in {report.seconds:.2f} s")
    return 0


def run_from_blender():
    """`blender -b FILE.blend --python-expr "import tilefarm_blender.cli as c; c.run_from_blender()" -- OUT_DIR`:
    exports the opened file (the arguments after `--` are this command's) and exits."""
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    sys.exit(main(argv))
