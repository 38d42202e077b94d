#!/usr/bin/env python3
"""A large scene for load and memory measurements: the bundled Cornell box with a
displaced sphere of about N triangles inside it (a UV sphere whose radius is perturbed
by a few sines, so that the kd-tree has real work to do), written as an OBJ beside a
copy of the box.

    bench/make_big_scene.py OUT_DIR [--triangles 1310720]
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
    args = ap.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    for f in ["cbox.obj", "cbox.mtl"]:
        shutil.copy(ROOT / "scenes/cornell-box" / f, out / f)
    # rings × segments quads, two triangles each.
    segments = max(8, int(math.sqrt(args.triangles)))
    rings = max(4, args.triangles // (2 * segments))
    centre, radius = (278.0, 160.0, 279.5), 140.0
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
                f.write(f"f {a} {c} {b}\nf {b} {c} {d}\n")
    (out / "sphere.mtl").write_text("newmtl sphere\nKd 0.6 0.6 0.6\n")
    text = (ROOT / "scenes/cornell-box/scene.toml").read_text()
    (out / "scene.toml").write_text(text + '\n[[mesh]]\nobj = "sphere.obj"\n')
    print(f"{out / 'scene.toml'}: the Cornell box and a sphere of {2 * rings * segments} triangles")


if __name__ == "__main__":
    main()
