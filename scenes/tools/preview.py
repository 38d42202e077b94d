#!/usr/bin/env python3
"""Quick geometry preview of a tilefarm scene.toml (standard library only).

Usage:  python3 scenes/tools/preview.py scenes/<name>/scene.toml out.png [--scale 0.5]

Reads the scene the way the renderer is specified to (TOML camera, [[mesh]] OBJ/MTL with
scale/rotate_y/translate, [[sphere]]s) and z-buffer rasterises it with the same camera
convention (right = normalize(forward x up), row 0 at the top).  It is not a renderer:

* front faces are shaded by |cos| to the eye, tinted with Kd (+Ks), emitters drawn yellow-white,
  mirror/glass materials drawn cyan;
* BACK faces (the counter-clockwise side facing away from the eye) are drawn MAGENTA, so wrongly
  wound walls or inside-out solids are obvious;
* point/spot lights are marked with a small white cross.
"""

import math
import os
import struct
import sys
import tomllib
import zlib


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def normalize(a):
    n = math.sqrt(dot(a, a))
    return (a[0] / n, a[1] / n, a[2] / n)


def load_mtl(path):
    mats = {}
    cur = None
    with open(path) as f:
        for line in f:
            t = line.split()
            if not t or t[0].startswith("#"):
                continue
            if t[0] == "newmtl":
                cur = mats.setdefault(t[1], {})
            elif cur is not None and t[0] in ("Kd", "Ks", "Ke", "Tf"):
                cur[t[0].lower()] = tuple(float(x) for x in t[1:4])
            elif cur is not None and t[0] in ("Ns", "Ni", "d"):
                cur[t[0].lower()] = float(t[1])
            elif cur is not None and t[0] == "illum":
                cur["illum"] = int(t[1])
    return mats


def load_obj(path):
    verts = []
    tris = []  # (p0, p1, p2, material dict)
    mats = {}
    cur = {}
    base = os.path.dirname(path)
    with open(path) as f:
        for line in f:
            t = line.split()
            if not t or t[0].startswith("#"):
                continue
            if t[0] == "v":
                verts.append(tuple(float(x) for x in t[1:4]))
            elif t[0] == "mtllib":
                mats.update(load_mtl(os.path.join(base, t[1])))
            elif t[0] == "usemtl":
                cur = mats.get(t[1], {})
            elif t[0] == "f":
                idx = []
                for s in t[1:]:
                    i = int(s.split("/")[0])
                    idx.append(i - 1 if i > 0 else len(verts) + i)
                for k in range(1, len(idx) - 1):  # fan, like the loader
                    tris.append((verts[idx[0]], verts[idx[k]], verts[idx[k + 1]], cur))
    return tris


def transform(p, m):
    s = m.get("scale", 1.0)
    if isinstance(s, (int, float)):
        s = (s, s, s)
    p = (p[0] * s[0], p[1] * s[1], p[2] * s[2])
    a = math.radians(m.get("rotate_y", 0.0))
    c, sn = math.cos(a), math.sin(a)
    p = (c * p[0] + sn * p[2], p[1], -sn * p[0] + c * p[2])
    t = m.get("translate", (0.0, 0.0, 0.0))
    return (p[0] + t[0], p[1] + t[1], p[2] + t[2])


def sphere_tris(c, r, mat, nu=48, nv=24):
    def pt(i, j):
        th = math.pi * j / nv
        ph = 2 * math.pi * i / nu
        return (c[0] + r * math.sin(th) * math.cos(ph), c[1] + r * math.cos(th), c[2] - r * math.sin(th) * math.sin(ph))

    out = []
    for j in range(nv):
        for i in range(nu):
            a, b, cc, d = pt(i, j), pt(i, j + 1), pt(i + 1, j + 1), pt(i + 1, j)
            if j != 0:
                out.append((a, b, d, mat))
            if j != nv - 1:
                out.append((b, cc, d, mat))
    return out


def colour_of(mat, n_dot_v):
    ke = mat.get("ke", (0, 0, 0))
    if max(ke) > 0:
        m = max(ke)
        return tuple(min(1.0, 0.6 + 0.4 * k / m) for k in ke)
    illum = mat.get("illum", 2)
    if illum in (3, 4, 5, 6, 7) or (mat.get("d", 1.0) < 1.0):
        base = (0.3, 0.9, 0.9)
    else:
        kd = mat.get("kd", (0.5, 0.5, 0.5) if not mat else (0, 0, 0))
        ks = mat.get("ks", (0, 0, 0))
        base = tuple(min(1.0, kd[i] + ks[i]) for i in range(3))
        if max(base) < 0.15:
            base = tuple(b + 0.15 for b in base)
    s = 0.25 + 0.75 * n_dot_v
    return tuple(min(1.0, b * s) for b in base)


def write_png(path, w, h, rows):
    raw = b"".join(b"\x00" + bytes(r) for r in rows)
    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


def main():
    scene_path = sys.argv[1]
    out = sys.argv[2]
    scale = 0.5
    if "--scale" in sys.argv:
        scale = float(sys.argv[sys.argv.index("--scale") + 1])
    with open(scene_path, "rb") as f:
        sc = tomllib.load(f)
    base = os.path.dirname(scene_path)
    cam = sc["camera"]
    W = max(1, int(cam["width"] * scale))
    H = max(1, int(cam["height"] * scale))
    eye = tuple(cam["position"])
    fwd = normalize(sub(tuple(cam["look_at"]), eye))
    right = normalize(cross(fwd, tuple(cam["up"])))
    up = cross(right, fwd)
    tanh = math.tan(math.radians(cam["fov"]) / 2)
    aspect = cam["width"] / cam["height"]

    tris = []
    for m in sc.get("mesh", []):
        for (a, b, c, mat) in load_obj(os.path.join(base, m["obj"])):
            tris.append((transform(a, m), transform(b, m), transform(c, m), mat))
    for s in sc.get("sphere", []):
        mat = {k: (tuple(v) if isinstance(v, list) else v) for k, v in s.items() if k not in ("center", "radius")}
        tris.extend(sphere_tris(tuple(s["center"]), s["radius"], mat))

    near = 1e-4 * max(1.0, max(abs(x) for x in eye))
    bg = sc.get("background", {}).get("radiance", (0, 0, 0))
    bgc = tuple(int(255 * min(1.0, 0.1 + v)) for v in bg) if max(bg) > 0 else (20, 20, 30)
    img = [[list(bgc) for _ in range(W)] for _ in range(H)]
    zbuf = [[float("inf")] * W for _ in range(H)]
    back_pixels = 0

    def to_cam(p):
        d = sub(p, eye)
        return (dot(d, right), dot(d, up), dot(d, fwd))

    for (a, b, c, mat) in tris:
        n = cross(sub(b, a), sub(c, a))
        if dot(n, n) == 0:
            continue
        n = normalize(n)
        cen = ((a[0] + b[0] + c[0]) / 3, (a[1] + b[1] + c[1]) / 3, (a[2] + b[2] + c[2]) / 3)
        v = normalize(sub(eye, cen))
        ndv = dot(n, v)
        col = (1.0, 0.0, 1.0) if ndv < 0 else colour_of(mat, ndv)
        rgb = [int(255 * x) for x in col]
        # clip polygon against the near plane in camera space
        poly = [to_cam(p) for p in (a, b, c)]
        clipped = []
        for i in range(len(poly)):
            p, q = poly[i], poly[(i + 1) % len(poly)]
            pin, qin = p[2] > near, q[2] > near
            if pin:
                clipped.append(p)
            if pin != qin:
                t = (near - p[2]) / (q[2] - p[2])
                clipped.append(tuple(p[k] + t * (q[k] - p[k]) for k in range(3)))
        if len(clipped) < 3:
            continue
        sp = []
        for (x, y, z) in clipped:
            sx = (x / z / (tanh * aspect) + 1) / 2 * W
            sy = (1 - y / z / tanh) / 2 * H
            sp.append((sx, sy, 1.0 / z))
        for k in range(1, len(sp) - 1):
            p0, p1, p2 = sp[0], sp[k], sp[k + 1]
            area = (p1[0] - p0[0]) * (p2[1] - p0[1]) - (p2[0] - p0[0]) * (p1[1] - p0[1])
            if area == 0:
                continue
            x0 = max(0, int(math.floor(min(p0[0], p1[0], p2[0]))))
            x1 = min(W - 1, int(math.ceil(max(p0[0], p1[0], p2[0]))))
            y0 = max(0, int(math.floor(min(p0[1], p1[1], p2[1]))))
            y1 = min(H - 1, int(math.ceil(max(p0[1], p1[1], p2[1]))))
            for py in range(y0, y1 + 1):
                yc = py + 0.5
                for px in range(x0, x1 + 1):
                    xc = px + 0.5
                    w0 = ((p1[0] - xc) * (p2[1] - yc) - (p2[0] - xc) * (p1[1] - yc)) / area
                    w1 = ((p2[0] - xc) * (p0[1] - yc) - (p0[0] - xc) * (p2[1] - yc)) / area
                    w2 = 1 - w0 - w1
                    if w0 < 0 or w1 < 0 or w2 < 0:
                        continue
                    iz = w0 * p0[2] + w1 * p1[2] + w2 * p2[2]
                    z = 1.0 / iz
                    if z < zbuf[py][px]:
                        zbuf[py][px] = z
                        img[py][px] = rgb
    for L in sc.get("light", []):
        if "position" in L:
            x, y, z = to_cam(tuple(L["position"]))
            if z > near:
                sx = int((x / z / (tanh * aspect) + 1) / 2 * W)
                sy = int((1 - y / z / tanh) / 2 * H)
                for d in range(-4, 5):
                    for (u, w) in ((sx + d, sy), (sx, sy + d)):
                        if 0 <= u < W and 0 <= w < H:
                            img[w][u] = [255, 255, 255]
    for row in img:
        for p in row:
            if p == [255, 0, 255]:
                back_pixels += 1
    write_png(out, W, H, [[c for p in row for c in p] for row in img])
    print("%s: %dx%d, %d triangles, %d back-face pixels" % (scene_path, W, H, len(tris), back_pixels))


if __name__ == "__main__":
    main()
