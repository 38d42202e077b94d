#!/usr/bin/env python3
"""What Principled materials and normal maps cost against a Lambertian twin (issue 49,
item 5): the same scene — a floor and twelve UV spheres (2,048 triangles each, texture
coordinates, smooth normals) under a sun and a grey sky — rendered with

- `lambert`: every surface a plain MTL `Kd` (the eight-lane route's diffuse lanes);
- `principled`: every surface a Principled dielectric (roughness 0.3, the defaults);
- `principled+normal`: the same with a tangent-space normal map (a sine bump field).

Each scene is rendered by `coordinator render` (one process, both cores, no workers) in
alternated rounds; prints the median render seconds of each (loading excluded) and its
ratio to `lambert`.

    python3 bench/principled_cost.py target/release/coordinator [SPP [ROUNDS]]
"""

import math
import re
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import zlib

SPHERES = [(x, y) for y in (0.0, 1.3, 2.6) for x in (-2.4, -1.2, 0.0, 1.2)]


def png(path, w, h, pixel):
    """An 8-bit RGB PNG of pixel(x, y) -> (r, g, b) in 0..1 (stdlib only)."""
    rows = b"".join(
        b"\x00" + bytes(int(round(255 * max(0.0, min(1.0, c)))) for x in range(w) for c in pixel(x, y))
        for y in range(h)
    )

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))


def normal_texel(x, y, n=128):
    """The tangent-space normal of a bump field with slopes up to 1 (45°)."""
    u, v = (x + 0.5) / n, 1.0 - (y + 0.5) / n
    nx = -math.cos(4 * math.pi * u) * math.sin(4 * math.pi * v)
    ny = -math.sin(4 * math.pi * u) * math.cos(4 * math.pi * v)
    length = math.sqrt(nx * nx + ny * ny + 1.0)
    return (0.5 + 0.5 * nx / length, 0.5 + 0.5 * ny / length, 0.5 + 0.5 / length)


def uv_sphere(segments=64, rings=32):
    """OBJ text of a unit UV sphere: positions, normals, texture coordinates, quads."""
    out = ["mtllib m.mtl", "usemtl m"]
    for r in range(rings + 1):
        theta = math.pi * r / rings
        for s in range(segments + 1):
            phi = 2 * math.pi * s / segments
            p = (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))
            out.append("v %.6f %.6f %.6f" % p)
            out.append("vn %.6f %.6f %.6f" % p)
            out.append("vt %.6f %.6f" % (s / segments, 1.0 - r / rings))
    row = segments + 1
    for r in range(rings):
        for s in range(segments):
            a, b = r * row + s + 1, r * row + s + 2
            c, d = b + row, a + row
            out.append("f %d/%d/%d %d/%d/%d %d/%d/%d %d/%d/%d" % (a, a, a, d, d, d, c, c, c, b, b, b))
    return "\n".join(out) + "\n"


FLOOR = """mtllib m.mtl
usemtl m
v -8 -4 0
v 8 -4 0
v 8 8 0
v -8 8 0
vt 0 0
vt 8 0
vt 8 6
vt 0 6
vn 0 0 1
f 1/1/1 2/2/1 3/3/1 4/4/1
"""


def write_scene(folder, kind):
    os.makedirs(folder, exist_ok=True)
    png(os.path.join(folder, "normal.png"), 128, 128, normal_texel)
    with open(os.path.join(folder, "m.mtl"), "w") as f:
        f.write("newmtl m\nKd 0.8 0.05 0.04\n")
    with open(os.path.join(folder, "floor.obj"), "w") as f:
        f.write(FLOOR)
    sphere = uv_sphere()
    text = [
        "[camera]\nposition = [0, -7, 2.4]\nlook_at = [0, 1.2, 0.8]\nup = [0, 0, 1]\nfov = 40\n"
        "width = 320\nheight = 192\n",
        "[render]\nmax_depth = 8\nseed = 1\n",
        "[background]\nradiance = [0.3, 0.3, 0.3]\n",
        "[[light]]\ntype = \"directional\"\ndirection = [0.3, 0.5, -0.8]\nirradiance = [3, 3, 3]\n",
        "[[mesh]]\nobj = \"floor.obj\"\n",
    ]
    for k, (x, y) in enumerate(SPHERES):
        # One file per copy: a file placed once is stored flat, as a scene's own meshes are.
        with open(os.path.join(folder, f"sphere{k}.obj"), "w") as f:
            f.write(sphere)
        text.append(f"[[mesh]]\nobj = \"sphere{k}.obj\"\nscale = 0.55\ntranslate = [{x}, {y}, 0.6]\n")
    if kind != "lambert":
        table = "[materials.m]\nbase_color = [0.8, 0.05, 0.04]\nroughness = 0.3\n"
        if kind == "principled+normal":
            table += 'normal_map = { file = "normal.png", colorspace = "non-color" }\n'
        text.append(table)
    path = os.path.join(folder, "scene.toml")
    with open(path, "w") as f:
        f.write("".join(text))
    return path


def render(coordinator, scene, spp, out):
    """The render's own time (its summary line's \"rendered … in Xs\"), without loading."""
    cmd = [coordinator, "render", scene, "--spp", str(spp), "--local-workers", "0", "-o", out]
    run = subprocess.run(cmd, check=True, capture_output=True, text=True)
    found = re.search(r"rendered .* in ([0-9.]+)s:", run.stderr + run.stdout)
    if not found:
        sys.exit(f"no render time in the output of {' '.join(cmd)}:\n{run.stderr}")
    return float(found.group(1))


def main():
    coordinator = sys.argv[1]
    spp = int(sys.argv[2]) if len(sys.argv) > 2 else 32
    rounds = int(sys.argv[3]) if len(sys.argv) > 3 else 3
    kinds = ["lambert", "principled", "principled+normal"]
    with tempfile.TemporaryDirectory() as work:
        scenes = {k: write_scene(os.path.join(work, k.replace("+", "_")), k) for k in kinds}
        times = {k: [] for k in kinds}
        for _ in range(rounds):
            for k in kinds:
                times[k].append(render(coordinator, scenes[k], spp, os.path.join(work, "out.exr")))
    base = statistics.median(times["lambert"])
    print(f"{len(SPHERES)} UV spheres + floor, 320x192, {spp} spp, {rounds} alternated rounds (median s, ratio):")
    for k in kinds:
        m = statistics.median(times[k])
        print(f"  {k:18s} {m:7.2f} s  {m / base:5.2f}x   (all: {', '.join(f'{t:.2f}' for t in times[k])})")


if __name__ == "__main__":
    main()
