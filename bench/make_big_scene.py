#!/usr/bin/env python3
"""A large scene for load and memory measurements: the bundled Cornell box with a
displaced sphere of about N triangles inside it (a UV sphere whose radius is perturbed
by a few sines, so that the kd-tree has real work to do), written as an OBJ beside a
copy of the box.

With --copies K, the sphere is placed K times instead, small, in a grid filling the box,
each copy turned about its own axis: one OBJ and an `instance` list, so tilefarm stores
it once. With --flatten as well, each copy gets an OBJ file of its own (the same text),
so the copies are stored triangle by triangle: the same image, for comparison.

    bench/make_big_scene.py OUT_DIR [--triangles 1310720] [--copies K [--flatten]]
    coordinator render OUT_DIR/scene.toml --spp 64 ...
"""
import argparse
import math
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--triangles", type=int, default=1_310_720)
    ap.add_argument("--copies", type=int, default=0, help="place the sphere this many times (instances)")
    ap.add_argument("--flatten", action="store_true", help="with --copies: one OBJ file per copy")
    args = ap.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    for f in ["cbox.obj", "cbox.mtl"]:
        shutil.copy(ROOT / "scenes/cornell-box" / f, out / f)
    # rings × segments quads, two triangles each, counter-clockwise seen from outside
    # (front faces out, as OBJ expects).
    segments = max(8, int(math.sqrt(args.triangles)))
    rings = max(4, args.triangles // (2 * segments))
    centre, radius = ((0.0, 0.0, 0.0), 1.0) if args.copies else ((278.0, 160.0, 279.5), 140.0)
    with open(out / "sphere.obj", "w") as f:
        f.write("mtllib sphere.mtl\nusemtl sphere\n")
        for i in range(rings + 1):
            th = math.pi * i / rings
            for j in range(segments):
                ph = 2 * math.pi * j / segments
                r = radius * (1 + 0.03 * math.sin(13 * th) * math.sin(17 * ph) + 0.01 * math.sin(71 * ph + 5 * th))
                x = centre[0] + r * math.sin(th) * math.cos(ph)
                y = centre[1] + r * math.cos(th)
                z = centre[2] + r * math.sin(th) * math.sin(ph)
                f.write(f"v {x:.4f} {y:.4f} {z:.4f}\n")
        for i in range(rings):
            for j in range(segments):
                a = i * segments + j + 1
                b = i * segments + (j + 1) % segments + 1
                c, d = a + segments, b + segments
                f.write(f"f {a} {b} {c}\nf {b} {d} {c}\n")
    (out / "sphere.mtl").write_text("newmtl sphere\nKd 0.6 0.6 0.6\n")
    text = (ROOT / "scenes/cornell-box/scene.toml").read_text()
    n = 2 * rings * segments
    if not args.copies:
        (out / "scene.toml").write_text(text + '\n[[mesh]]\nobj = "sphere.obj"\n')
        print(f"{out / 'scene.toml'}: the Cornell box and a sphere of {n} triangles")
        return
    (out / "scene.toml").write_text(text + copies_text(args.copies, args.flatten, out))
    how = "stored triangle by triangle" if args.flatten else "instanced"
    print(f"{out / 'scene.toml'}: the Cornell box and {args.copies} copies ({how}) of a sphere of {n} triangles")


def copies_text(k, flatten, out):
    """K copies of sphere.obj in a grid filling the box's lower half, each turned about
    its own tilted axis."""
    side = math.ceil(k ** (1 / 3))
    cell = 500.0 / side
    placements = []
    for i in range(k):
        x, y, z = i % side, (i // side) % side, i // (side * side)
        t = (30 + (x + 0.5) * cell, 10 + (y + 0.5) * cell * 0.6, 30 + (z + 0.5) * cell)
        axis = (math.sin(i), 1.0, math.cos(1.7 * i))
        placements.append(
            f"translate = [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}], scale = {0.35 * cell:.3f}, "
            f"rotate = {{ axis = [{axis[0]:.3f}, {axis[1]:.3f}, {axis[2]:.3f}], degrees = {(37 * i) % 360} }}"
        )
    if not flatten:
        return '\n[[mesh]]\nobj = "sphere.obj"\ninstance = [\n' + "".join(f"  {{ {p} }},\n" for p in placements) + "]\n"
    text = ""
    for i, p in enumerate(placements):
        shutil.copy(out / "sphere.obj", out / f"sphere{i}.obj")
        text += f'\n[[mesh]]\nobj = "sphere{i}.obj"\n' + p.replace(", rotate", "\nrotate").replace(", scale", "\nscale") + "\n"
    return text


if __name__ == "__main__":
    main()
