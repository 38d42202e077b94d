#!/usr/bin/env python3
"""Generate tilefarm's bundled test scenes (OBJ + MTL + scene.toml).

Usage:  python3 scenes/tools/gen_scenes.py [--check-only]

Standard library only.  Output is deterministic (fixed float formatting with
'{:.6g}', fixed vertex order), so re-running it reproduces the committed files
byte for byte.  Every face that is written is checked:

* its winding (Newell normal) must point the way the scene needs it:
  into the room for walls/floors/ceilings, outward for solids, downward for
  ceiling lights, towards the camera side for the glossy plates;
* closed solids (boxes, the lathed cup) must be watertight and consistently
  wound (every directed edge used once, its reverse used once) with a positive
  signed volume (= outward normals);
* the camera must see the scene: the corners of the scene's bounding box are
  projected with the renderer's camera convention (right = forward x up,
  row 0 at the top) and the projected centre of the interesting objects must
  land inside the frame.

Scenes (all under scenes/<name>/):
  cornell-box  the measured Cornell box (Cornell Program of Computer Graphics)
  cube         a few boxes on a floor, ceiling quad light + point light
  cup          a lathed ceramic cup on a table, spot light + area light
  room         a room with a table, ceiling area light + point light
  veach-mis    Veach's multiple importance sampling test scene
  glass        mirror + glass sphere in a Cornell-style box (caustic)
"""

import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.dirname(HERE)

# --------------------------------------------------------------------------
# small vector helpers


def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def mul(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def length(a):
    return math.sqrt(dot(a, a))


def normalize(a):
    n = length(a)
    return (a[0] / n, a[1] / n, a[2] / n)


def centroid(pts):
    n = float(len(pts))
    return (sum(p[0] for p in pts) / n, sum(p[1] for p in pts) / n, sum(p[2] for p in pts) / n)


def newell(pts):
    """Area-weighted normal of a polygon (Newell's method); CCW => right-hand rule."""
    nx = ny = nz = 0.0
    for i in range(len(pts)):
        a = pts[i]
        b = pts[(i + 1) % len(pts)]
        nx += (a[1] - b[1]) * (a[2] + b[2])
        ny += (a[2] - b[2]) * (a[0] + b[0])
        nz += (a[0] - b[0]) * (a[1] + b[1])
    return (nx, ny, nz)


def rot_y(p, deg):
    """Right-handed rotation about +y (x towards -z for positive angles)."""
    c = math.cos(math.radians(deg))
    s = math.sin(math.radians(deg))
    return (c * p[0] + s * p[2], p[1], -s * p[0] + c * p[2])


# --------------------------------------------------------------------------
# number formatting


def fnum(x):
    """Fixed OBJ/MTL float format: 6 significant digits, no negative zero."""
    if abs(x) < 5e-10:
        x = 0.0
    s = "{:.6g}".format(x)
    if s == "-0":
        s = "0"
    return s


def tnum(x):
    """TOML float: like fnum but always a float literal."""
    s = fnum(x)
    if not any(c in s for c in ".en"):
        s += ".0"
    return s


def tvec(v):
    return "[" + ", ".join(tnum(c) for c in v) + "]"


def mvec(v):
    return " ".join(fnum(c) for c in v)


# --------------------------------------------------------------------------
# OBJ writer with built-in checks


class CheckError(Exception):
    pass


class Obj:
    def __init__(self, name, mtllib, header):
        self.name = name
        self.mtllib = mtllib
        self.header = header
        self.verts = []  # formatted (x, y, z) strings
        self.vindex = {}
        self.body = []
        self.faces = []  # (group, [vertex indices (0-based)])
        self.group_name = None
        self.ntris = 0

    def vert(self, p):
        key = tuple(fnum(c) for c in p)
        idx = self.vindex.get(key)
        if idx is None:
            idx = len(self.verts)
            self.verts.append(key)
            self.vindex[key] = idx
        return idx

    def group(self, name, mtl, smooth=False):
        self.group_name = name
        self.body.append("")
        self.body.append("g " + name)
        self.body.append("usemtl " + mtl)
        self.body.append("s 1" if smooth else "s off")

    def face(self, pts):
        idx = [self.vert(p) for p in pts]
        if len(set(idx)) != len(idx):
            raise CheckError("%s/%s: degenerate face %r" % (self.name, self.group_name, pts))
        self.body.append("f " + " ".join(str(i + 1) for i in idx))
        self.faces.append((self.group_name, idx))
        self.ntris += len(idx) - 2

    # -- geometry access (uses the *written*, rounded coordinates) --
    def pos(self, i):
        return tuple(float(c) for c in self.verts[i])

    def face_pts(self, f):
        return [self.pos(i) for i in f[1]]

    def group_faces(self, group):
        out = [f for f in self.faces if f[0] == group]
        if not out:
            raise CheckError("%s: no faces in group %s" % (self.name, group))
        return out

    def bbox(self):
        ps = [self.pos(i) for i in range(len(self.verts))]
        return (tuple(min(p[k] for p in ps) for k in range(3)), tuple(max(p[k] for p in ps) for k in range(3)))

    def text(self):
        out = ["# " + line if line else "#" for line in self.header]
        out.append("# generated by scenes/tools/gen_scenes.py -- edit the generator, not this file")
        out.append("mtllib " + self.mtllib)
        out.append("")
        for v in self.verts:
            out.append("v " + " ".join(v))
        out.extend(self.body)
        return "\n".join(out) + "\n"

    # -- checks --
    def check_faces(self, group, pred, what):
        """pred(normal_unit, face_centre) -> bool for every face of the group."""
        for f in self.group_faces(group):
            pts = self.face_pts(f)
            n = newell(pts)
            if length(n) == 0.0:
                raise CheckError("%s/%s: zero-area face" % (self.name, group))
            if not pred(normalize(n), centroid(pts)):
                raise CheckError("%s/%s: face %s fails check: %s (normal %r)" % (
                    self.name, group, [i + 1 for i in f[1]], what, normalize(n)))

    def check_into(self, group, inside_point):
        self.check_faces(group, lambda n, c: dot(n, sub(inside_point, c)) > 0.0,
                         "normal must point towards %r" % (inside_point,))

    def check_dir(self, group, direction, min_cos=0.99):
        d = normalize(direction)
        self.check_faces(group, lambda n, c: dot(n, d) >= min_cos,
                         "normal must be along %r" % (direction,))

    def check_planar(self, group, rel_tol=1e-3):
        """Returns the largest out-of-plane deviation (relative to face size)."""
        worst = 0.0
        for f in self.group_faces(group):
            pts = self.face_pts(f)
            if len(pts) <= 3:
                continue
            n = normalize(newell(pts))
            c = centroid(pts)
            size = max(length(sub(p, c)) for p in pts)
            dev = max(abs(dot(sub(p, c), n)) for p in pts) / size
            worst = max(worst, dev)
        if worst > rel_tol:
            raise CheckError("%s/%s: non-planar quad (rel. deviation %.3g)" % (self.name, group, worst))
        return worst

    def check_closed_outward(self, groups, label):
        """Watertight, consistently wound, positive volume (outward normals)."""
        faces = [f for g in groups for f in self.group_faces(g)]
        edges = {}
        for f in faces:
            idx = f[1]
            for k in range(len(idx)):
                e = (idx[k], idx[(k + 1) % len(idx)])
                edges[e] = edges.get(e, 0) + 1
        for e, cnt in edges.items():
            if cnt != 1:
                raise CheckError("%s/%s: directed edge %r used %d times (inconsistent winding)" % (
                    self.name, label, e, cnt))
            if (e[1], e[0]) not in edges:
                raise CheckError("%s/%s: open edge %r (not watertight)" % (self.name, label, e))
        vol = 0.0
        for f in faces:
            pts = self.face_pts(f)
            for k in range(1, len(pts) - 1):  # fan triangulation, like the loader
                vol += dot(pts[0], cross(pts[k], pts[k + 1])) / 6.0
        if vol <= 0.0:
            raise CheckError("%s/%s: signed volume %.6g <= 0 (normals point inward)" % (self.name, label, vol))
        return vol


class Mtl:
    def __init__(self, header):
        self.header = header
        self.lines = []

    def material(self, name, kd=(0, 0, 0), ks=None, ns=None, ke=None, illum=None, ni=None, d=None, tf=None,
                 comment=None):
        self.lines.append("")
        if comment:
            self.lines.append("# " + comment)
        self.lines.append("newmtl " + name)
        self.lines.append("Kd " + mvec(kd))
        if ks is not None:
            self.lines.append("Ks " + mvec(ks))
        if ns is not None:
            self.lines.append("Ns " + fnum(ns))
        if ke is not None:
            self.lines.append("Ke " + mvec(ke))
        if ni is not None:
            self.lines.append("Ni " + fnum(ni))
        if d is not None:
            self.lines.append("d " + fnum(d))
        if tf is not None:
            self.lines.append("Tf " + mvec(tf))
        if illum is not None:
            self.lines.append("illum %d" % illum)

    def text(self):
        out = ["# " + line if line else "#" for line in self.header]
        out.append("# generated by scenes/tools/gen_scenes.py -- edit the generator, not this file")
        out.extend(self.lines)
        return "\n".join(out) + "\n"


# --------------------------------------------------------------------------
# scene.toml writer


class Toml:
    def __init__(self, header):
        self.lines = ["# " + line if line else "#" for line in header]
        self.lines.append("# generated by scenes/tools/gen_scenes.py -- edit the generator, not this file")

    def table(self, name, fields, array=False, comment=None):
        self.lines.append("")
        if comment:
            for c in comment if isinstance(comment, list) else [comment]:
                self.lines.append("# " + c)
        self.lines.append(("[[%s]]" if array else "[%s]") % name)
        width = max(len(k) for k, _ in fields)
        for k, v in fields:
            if isinstance(v, bool):
                s = "true" if v else "false"
            elif isinstance(v, int):
                s = str(v)
            elif isinstance(v, float):
                s = tnum(v)
            elif isinstance(v, str):
                s = '"%s"' % v
            else:
                s = tvec(v)
            self.lines.append("%s = %s" % (k.ljust(width), s))

    def text(self):
        return "\n".join(self.lines) + "\n"


# --------------------------------------------------------------------------
# camera check (same convention as the renderer)


class Camera:
    def __init__(self, position, look_at, up, fov, width, height):
        self.position = position
        self.look_at = look_at
        self.up_hint = up
        self.fov = fov
        self.width = width
        self.height = height
        self.forward = normalize(sub(look_at, position))
        self.right = normalize(cross(self.forward, up))
        self.up = cross(self.right, self.forward)

    def project(self, p):
        """-> (column, row, depth); row 0 at the top.  depth <= 0 means behind."""
        d = sub(p, self.position)
        z = dot(d, self.forward)
        if z <= 1e-9:
            return (None, None, z)
        t = math.tan(math.radians(self.fov) / 2.0)
        aspect = self.width / float(self.height)
        sx = dot(d, self.right) / z / (t * aspect)
        sy = dot(d, self.up) / z / t
        return ((sx + 1.0) / 2.0 * self.width, (1.0 - sy) / 2.0 * self.height, z)

    def fields(self):
        return [("position", self.position), ("look_at", self.look_at), ("up", self.up_hint),
                ("fov", float(self.fov)), ("width", self.width), ("height", self.height)]

    def check_visible(self, name, label, p, margin=0.0):
        c, r, z = self.project(p)
        if c is None:
            raise CheckError("%s: %s %r is behind the camera" % (name, label, p))
        m = margin
        if not (-m * self.width <= c <= (1 + m) * self.width and -m * self.height <= r <= (1 + m) * self.height):
            raise CheckError("%s: %s %r projects outside the frame at (%.1f, %.1f)" % (name, label, p, c, r))
        return (c, r)


def box_corners(lo, hi):
    return [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]


def report_framing(name, cam, lo, hi, log):
    """Project the bounding-box corners; report how much of the frame they span."""
    cs = []
    for p in box_corners(lo, hi):
        c, r, z = cam.project(p)
        cs.append((c, r, z))
    front = [x for x in cs if x[0] is not None]
    if front:
        cols = [x[0] for x in front]
        rows = [x[1] for x in front]
        log.append("  %s: bbox %s..%s, %d/8 corners in front of the camera, projected columns %.0f..%.0f, "
                   "rows %.0f..%.0f of %dx%d" % (name, [fnum(c) for c in lo], [fnum(c) for c in hi], len(front),
                                                 min(cols), max(cols), min(rows), max(rows), cam.width, cam.height))
    else:
        raise CheckError("%s: whole bounding box is behind the camera" % name)


# --------------------------------------------------------------------------
# geometry builders


def box_quads(lo, hi, rotate_y=0.0, pivot=None, translate=(0.0, 0.0, 0.0)):
    """Six outward-facing, CCW (seen from outside) quads of a box [lo, hi],
    optionally rotated about the vertical axis through `pivot`, then translated."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    quads = [
        [(x0, y1, z0), (x0, y1, z1), (x1, y1, z1), (x1, y1, z0)],  # +y top
        [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)],  # -y bottom
        [(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)],  # +x
        [(x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)],  # -x
        [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)],  # +z
        [(x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0)],  # -z
    ]
    if pivot is None:
        pivot = ((x0 + x1) / 2.0, 0.0, (z0 + z1) / 2.0)
    out = []
    for q in quads:
        qq = []
        for p in q:
            p = add(rot_y(sub(p, pivot), rotate_y), pivot)
            qq.append(add(p, translate))
        out.append(qq)
    return out


def write(path, text, written):
    full = os.path.join(SCENES, path)
    os.makedirs(os.path.dirname(full), exist_ok=True)
    written.append((path, text))


# ==========================================================================
# 1. Cornell box
# Published data: http://www.graphics.cornell.edu/online/box/data.html
# (Cornell Program of Computer Graphics; units mm).  Vertex order as published.

CBOX_FLOOR = [(552.8, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 559.2), (549.6, 0.0, 559.2)]
CBOX_CEILING = [(556.0, 548.8, 0.0), (556.0, 548.8, 559.2), (0.0, 548.8, 559.2), (0.0, 548.8, 0.0)]
CBOX_BACK = [(549.6, 0.0, 559.2), (0.0, 0.0, 559.2), (0.0, 548.8, 559.2), (556.0, 548.8, 559.2)]
CBOX_RIGHT_GREEN = [(0.0, 0.0, 559.2), (0.0, 0.0, 0.0), (0.0, 548.8, 0.0), (0.0, 548.8, 559.2)]
CBOX_LEFT_RED = [(552.8, 0.0, 0.0), (549.6, 0.0, 559.2), (556.0, 548.8, 559.2), (556.0, 548.8, 0.0)]
CBOX_LIGHT_Y = 548.8
CBOX_LIGHT = [(343.0, 548.8, 227.0), (343.0, 548.8, 332.0), (213.0, 548.8, 332.0), (213.0, 548.8, 227.0)]
CBOX_SHORT = [
    [(130.0, 165.0, 65.0), (82.0, 165.0, 225.0), (240.0, 165.0, 272.0), (290.0, 165.0, 114.0)],
    [(290.0, 0.0, 114.0), (290.0, 165.0, 114.0), (240.0, 165.0, 272.0), (240.0, 0.0, 272.0)],
    [(130.0, 0.0, 65.0), (130.0, 165.0, 65.0), (290.0, 165.0, 114.0), (290.0, 0.0, 114.0)],
    [(82.0, 0.0, 225.0), (82.0, 165.0, 225.0), (130.0, 165.0, 65.0), (130.0, 0.0, 65.0)],
    [(240.0, 0.0, 272.0), (240.0, 165.0, 272.0), (82.0, 165.0, 225.0), (82.0, 0.0, 225.0)],
]
CBOX_TALL = [
    [(423.0, 330.0, 247.0), (265.0, 330.0, 296.0), (314.0, 330.0, 456.0), (472.0, 330.0, 406.0)],
    [(423.0, 0.0, 247.0), (423.0, 330.0, 247.0), (472.0, 330.0, 406.0), (472.0, 0.0, 406.0)],
    [(472.0, 0.0, 406.0), (472.0, 330.0, 406.0), (314.0, 330.0, 456.0), (314.0, 0.0, 456.0)],
    [(314.0, 0.0, 456.0), (314.0, 330.0, 456.0), (265.0, 330.0, 296.0), (265.0, 0.0, 296.0)],
    [(265.0, 0.0, 296.0), (265.0, 330.0, 296.0), (423.0, 330.0, 247.0), (423.0, 0.0, 247.0)],
]
CBOX_CENTRE = (278.0, 274.4, 279.6)
CBOX_WHITE = (0.725, 0.71, 0.68)
CBOX_RED = (0.63, 0.065, 0.05)
CBOX_GREEN = (0.14, 0.45, 0.091)
CBOX_KE = (17.0, 12.0, 4.0)
CBOX_LIGHT_KD = (0.78, 0.78, 0.78)
CBOX_CAMERA = Camera((278.0, 273.0, -800.0), (278.0, 273.0, 0.0), (0.0, 1.0, 0.0),
                     round(math.degrees(2.0 * math.atan(12.5 / 35.0)), 1), 512, 512)


def cbox_walls(obj):
    """Floor, ceiling, back, green (x = 0) and red (x ~ 555) walls of the Cornell box."""
    for name, quad, mtl in (("floor", CBOX_FLOOR, "white"), ("ceiling", CBOX_CEILING, "white"),
                            ("back_wall", CBOX_BACK, "white"), ("right_wall_green", CBOX_RIGHT_GREEN, "green"),
                            ("left_wall_red", CBOX_LEFT_RED, "red")):
        obj.group(name, mtl)
        obj.face(quad)
    return ["floor", "ceiling", "back_wall", "right_wall_green", "left_wall_red"]


def cbox_materials(mtl):
    mtl.material("white", kd=CBOX_WHITE, comment="reflectances as in the Mitsuba/pbrt Cornell box conversions")
    mtl.material("red", kd=CBOX_RED)
    mtl.material("green", kd=CBOX_GREEN)


def check_cbox_left_right(name, cam, log):
    """Red wall (x ~ 555) must be on the left of the image, green (x = 0) on the right."""
    red_c, _ = cam.check_visible(name, "red wall centre", centroid(CBOX_LEFT_RED), margin=0.5)
    green_c, _ = cam.check_visible(name, "green wall centre", centroid(CBOX_RIGHT_GREEN), margin=0.5)
    if not red_c < cam.width / 2.0 < green_c:
        raise CheckError("%s: red wall should be left (col %.0f) and green right (col %.0f)" % (name, red_c, green_c))
    log.append("  %s: camera right = forward x up = %r; red wall centre at column %.0f (left), "
               "green at %.0f (right)" % (name, tuple(fnum(c) for c in cam.right), red_c, green_c))


def gen_cornell_box(written, log):
    name = "cornell-box"
    light_y = 548.7  # a hair below the ceiling (548.8) so the light is not coplanar with it
    header = ["Cornell box, measured geometry from the Cornell Program of Computer Graphics",
              "http://www.graphics.cornell.edu/online/box/data.html (units: mm, vertex order as published).",
              "Light quad lowered from y = 548.8 to 548.7 so it does not coincide with the ceiling."]
    obj = Obj(name, "cbox.mtl", header)
    walls = cbox_walls(obj)
    obj.group("short_block", "white")
    for q in CBOX_SHORT:
        obj.face(q)
    obj.group("tall_block", "white")
    for q in CBOX_TALL:
        obj.face(q)
    obj.group("light", "light")
    obj.face([(x, light_y, z) for (x, _, z) in CBOX_LIGHT])

    # checks
    for g in walls:
        obj.check_into(g, CBOX_CENTRE)
    for g in ("floor", "ceiling", "back_wall", "right_wall_green"):
        obj.check_planar(g, 1e-9)
    dev = obj.check_planar("left_wall_red", 1e-2)  # published red wall is slightly non-planar
    obj.check_dir("light", (0.0, -1.0, 0.0), 0.999999)
    # the blocks are open at the bottom (they stand on the floor): check each side
    # faces away from its block's centre, the top faces up.
    for g, quads in (("short_block", CBOX_SHORT), ("tall_block", CBOX_TALL)):
        c = centroid([p for q in quads for p in q])
        obj.check_faces(g, lambda n, fc, c=c: dot(n, sub(fc, c)) > 0.0, "outward from the block")
    cam = CBOX_CAMERA
    check_cbox_left_right(name, cam, log)
    for p in CBOX_LIGHT:
        cam.check_visible(name, "light corner", p)
    lo, hi = obj.bbox()
    report_framing(name, cam, lo, hi, log)
    log.append("  %s: walls face into the box, blocks outward, light faces -y; red wall non-planarity %.2g "
               "(published data); %d triangles" % (name, dev, obj.ntris))

    mtl = Mtl(["Cornell box materials.  RGB reflectances as used by the Mitsuba / pbrt Cornell box",
               "conversions (e.g. Bitterli's rendering resources); light radiance (17, 12, 4)."])
    cbox_materials(mtl)
    mtl.material("light", kd=CBOX_LIGHT_KD, ke=CBOX_KE, comment="area light: emits from its front (downward) face")

    toml = Toml([
        "Cornell box -- the measured scene of the Cornell Program of Computer Graphics",
        "(http://www.graphics.cornell.edu/online/box/data.html).  Geometry in mm, exact published vertices.",
        "Camera as published: position (278, 273, -800), looking along +z, up +y, focal length 0.035 m",
        "on a 0.025 x 0.025 m film: vertical fov = 2 atan(12.5 / 35) = 39.3 degrees.",
        "camera right = forward x up = (0,0,1) x (0,1,0) = (-1,0,0): the red wall (x ~ 555) is on the left",
        "of the image, the green wall (x = 0) on the right, as in the published photographs.",
        "Materials: Mitsuba/pbrt conversion reflectances, light Ke = (17, 12, 4) (see cbox.mtl).",
    ])
    toml.table("camera", cam.fields())
    toml.table("render", [("spp", 64), ("max_depth", 8), ("seed", 0)])
    toml.table("mesh", [("obj", "cbox.obj")], array=True)
    write(name + "/cbox.obj", obj.text(), written)
    write(name + "/cbox.mtl", mtl.text(), written)
    write(name + "/scene.toml", toml.text(), written)


# ==========================================================================
# 2. cube: a few boxes on a floor


def gen_cube(written, log):
    name = "cube"
    header = ["cube scene: boxes on a floor (units: metres), a ceiling quad light; one box rotated, one glossy."]
    obj = Obj(name, "cube.mtl", header)
    obj.group("floor", "floor")
    obj.face([(-6.0, 0.0, -6.0), (-6.0, 0.0, 6.0), (6.0, 0.0, 6.0), (6.0, 0.0, -6.0)])
    boxes = [
        # name, material, lo, hi, rotate_y
        ("box_red", "red", (-1.8, 0.0, -0.2), (-0.8, 1.0, 0.8), 0.0),
        ("box_white_top", "white", (-1.55, 1.0, 0.05), (-1.05, 1.5, 0.55), 0.0),
        ("box_glossy_blue", "glossy_blue", (0.05, 0.0, 0.45), (0.95, 1.6, 1.35), 30.0),
        ("box_yellow", "yellow", (1.35, 0.0, -0.9), (1.95, 0.6, -0.3), 0.0),
    ]
    for bname, mat, lo, hi, ry in boxes:
        obj.group(bname, mat)
        for q in box_quads(lo, hi, rotate_y=ry):
            obj.face(q)
    light_c = (0.0, 4.0, 0.3)
    hs = 0.6
    obj.group("ceiling_light", "light")
    # CCW seen from below => normal -y
    obj.face([(light_c[0] - hs, light_c[1], light_c[2] - hs), (light_c[0] + hs, light_c[1], light_c[2] - hs),
              (light_c[0] + hs, light_c[1], light_c[2] + hs), (light_c[0] - hs, light_c[1], light_c[2] + hs)])

    obj.check_dir("floor", (0.0, 1.0, 0.0))
    obj.check_dir("ceiling_light", (0.0, -1.0, 0.0))
    for bname, _, _, _, _ in boxes:
        obj.check_closed_outward([bname], bname)
        obj.check_planar(bname, 1e-5)

    mtl = Mtl(["cube scene materials"])
    mtl.material("floor", kd=(0.55, 0.55, 0.55))
    mtl.material("red", kd=(0.65, 0.12, 0.1))
    mtl.material("white", kd=(0.75, 0.75, 0.75))
    mtl.material("glossy_blue", kd=(0.1, 0.18, 0.45), ks=(0.4, 0.4, 0.4), ns=200,
                 comment="diffuse blue under a normalised Blinn-Phong lobe (Ns 200)")
    mtl.material("yellow", kd=(0.7, 0.6, 0.2))
    mtl.material("light", kd=(0.0, 0.0, 0.0), ke=(20.0, 19.0, 17.0),
                 comment="1.2 m x 1.2 m quad at 4 m, facing down: ~1.8 W/m^2 on the floor below")

    cam = Camera((0.6, 2.6, -6.0), (0.1, 0.6, 0.3), (0.0, 1.0, 0.0), 40.0, 640, 480)
    for bname, _, lo, hi, _ in boxes:
        cam.check_visible(name, bname, ((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2))
    report_framing(name, cam, (-1.8, 0.0, -0.9), (1.95, 1.6, 1.35), log)
    log.append("  %s: floor +y, light -y, %d boxes closed & outward; %d triangles" % (name, len(boxes), obj.ntris))

    toml = Toml([
        "cube -- a few boxes on a floor (units: metres): a red box with a small white box on it, a",
        "glossy blue box (Ks 0.4, Ns 200) rotated 30 degrees about y, a small yellow box.",
        "Lit by a 1.2 m square ceiling quad light (Ke 20, 4 m up, no ceiling around it) and a point light.",
        "Camera slightly above, looking down at the boxes.  camera right = forward x up ~ -x, so the",
        "red box (x < 0) is on the right of the image.  Numbers are this repository's own choice.",
    ])
    toml.table("camera", cam.fields())
    toml.table("render", [("spp", 64), ("max_depth", 8), ("seed", 0)])
    toml.table("mesh", [("obj", "cube.obj")], array=True)
    toml.table("light", [("type", "point"), ("position", (-3.0, 3.5, -2.5)), ("intensity", (10.0, 10.0, 10.0))],
               array=True, comment="fill from the front right (image right): ~0.6 W/m^2 at the red box")
    toml.table("background", [("radiance", (0.02, 0.025, 0.03))])
    write(name + "/cube.obj", obj.text(), written)
    write(name + "/cube.mtl", mtl.text(), written)
    write(name + "/scene.toml", toml.text(), written)


# ==========================================================================
# 3. cup: a lathed cup


CUP_H = 9.5  # cm, rim height
CUP_W = 0.3  # wall thickness
CUP_B = 0.6  # bottom thickness
CUP_SEGMENTS = 48


def cup_r_outer(y):
    return 3.1 + 1.1 * (y / CUP_H) + 0.15 * math.sin(math.pi * y / CUP_H)


def cup_profile():
    """Closed profile (r, y) of the cup, counter-clockwise around the material in the
    (r, y) half-plane: out along the base, up the outside, over the rounded rim, down the
    inside, in along the inner bottom.  Returns [(r, y, smooth_flag_of_segment_to_next)]."""
    pts = []
    f_o = 0.4  # foot fillet radius
    r_foot = cup_r_outer(f_o)
    # base disc: pole then ring (flat => not smooth)
    pts.append((0.0, 0.0, False))
    # foot fillet: quarter circle centred (r_foot - f_o, f_o) from -90 to 0 degrees
    n = 4
    for k in range(n):
        a = math.radians(-90.0 + 90.0 * k / n)
        pts.append((r_foot - f_o + f_o * math.cos(a), f_o + f_o * math.sin(a), True))
    # outer wall from y = f_o to CUP_H
    n = 14
    for k in range(n):
        y = f_o + (CUP_H - f_o) * k / n
        pts.append((cup_r_outer(y), y, True))
    # rim: half circle centred (r_outer(H) - w/2, H), from 0 to 180 degrees (over the top)
    rc = cup_r_outer(CUP_H) - CUP_W / 2.0
    n = 8
    for k in range(n):
        a = math.radians(180.0 * k / n)
        pts.append((rc + CUP_W / 2.0 * math.cos(a), CUP_H + CUP_W / 2.0 * math.sin(a), True))
    # inner wall from H down to CUP_B + f_i
    f_i = 0.5
    n = 14
    for k in range(n):
        y = CUP_H + (CUP_B + f_i - CUP_H) * k / n
        pts.append((cup_r_outer(y) - CUP_W, y, True))
    # inner fillet: centre (r_i - f_i, b + f_i), from 0 to -90 degrees
    ri = cup_r_outer(CUP_B + f_i) - CUP_W
    n = 4
    for k in range(n):
        a = math.radians(-90.0 * k / n)
        pts.append((ri - f_i + f_i * math.cos(a), CUP_B + f_i + f_i * math.sin(a), True))
    # end of fillet = ring of the inner bottom disc; the disc itself is flat
    pts.append((ri - f_i, CUP_B, False))
    pts.append((0.0, CUP_B, False))
    return pts


def gen_cup(written, log):
    name = "cup"
    header = ["cup: surface of revolution (units: cm), base at y = 0, axis = y.  Closed, watertight,",
              "outward normals; curved parts in smoothing group 1 (no vn: the loader smooths them)."]
    obj = Obj(name, "cup.mtl", header)
    prof = cup_profile()
    nseg = CUP_SEGMENTS

    def ring(r, y, j):
        a = 2.0 * math.pi * (j % nseg) / nseg
        return (r * math.cos(a), y, r * math.sin(a))

    # the first segment (pole -> foot fillet) and the last one (inner fillet -> pole) are the
    # flat base and inner bottom discs: "s off"; everything in between is curved: "s 1"
    last = len(prof) - 2
    runs = [("cup_base", False, [0]), ("cup_body", True, list(range(1, last))), ("cup_inner_bottom", False, [last])]
    groups = []
    for gname, smooth, segs in runs:
        groups.append(gname)
        obj.group(gname, "ceramic", smooth=smooth)
        for k in segs:
            (r0, y0, _), (r1, y1, _) = prof[k], prof[k + 1]
            for j in range(nseg):
                if r0 == 0.0:
                    obj.face([ring(0.0, y0, 0), ring(r1, y1, j), ring(r1, y1, j + 1)])
                elif r1 == 0.0:
                    obj.face([ring(r0, y0, j), ring(0.0, y1, 0), ring(r0, y0, j + 1)])
                else:
                    obj.face([ring(r0, y0, j), ring(r1, y1, j), ring(r1, y1, j + 1), ring(r0, y0, j + 1)])
    vol = obj.check_closed_outward(groups, "cup")
    # expected volume of the ceramic (Pappus / shoelace in the r-y plane): V = 2 pi * sum(...)
    area_moment = 0.0
    for k in range(len(prof)):
        (r0, y0, _), (r1, y1, _) = prof[k], prof[(k + 1) % len(prof)]
        # integral of r dA over the profile polygon = (1/6) sum (r0 + r1)(r0 y1 - r1 y0)
        area_moment += (r0 + r1) * (r0 * y1 - r1 * y0) / 6.0
    expected = 2.0 * math.pi * area_moment
    if not 0.9 * expected < vol < 1.01 * expected:
        raise CheckError("cup: mesh volume %.4g vs revolved profile %.4g" % (vol, expected))
    obj.check_dir("cup_base", (0.0, -1.0, 0.0), 0.999)
    obj.check_dir("cup_inner_bottom", (0.0, 1.0, 0.0), 0.999)
    # the outer wall at mid height faces away from the axis, the inner wall towards it
    for f in obj.group_faces("cup_body"):
        pts = obj.face_pts(f)
        c = centroid(pts)
        n = normalize(newell(pts))
        radial = normalize((c[0], 0.0, c[2]))
        rr = math.hypot(c[0], c[2])
        if 2.0 < c[1] < CUP_H - 0.5:
            outer = rr > cup_r_outer(c[1]) - CUP_W / 2.0
            if (dot(n, radial) > 0.0) != outer:
                raise CheckError("cup: wall face at %r points the wrong way" % (c,))
    lo, hi = obj.bbox()
    log.append("  %s: cup closed, watertight, outward (volume %.1f cm^3 vs %.1f from the profile), "
               "%d vertices, %d triangles" % (name, vol, expected, len(obj.verts), obj.ntris))

    table = Obj(name, "cup.mtl", ["table top and backdrop for the cup scene (units: cm)"])
    table.group("table", "table")
    table.face([(-45.0, 0.0, -30.0), (-45.0, 0.0, 30.0), (45.0, 0.0, 30.0), (45.0, 0.0, -30.0)])
    table.group("backdrop", "backdrop")
    table.face([(-80.0, -10.0, 30.0), (-80.0, 70.0, 30.0), (80.0, 70.0, 30.0), (80.0, -10.0, 30.0)])
    area_c = (12.0, 55.0, 8.0)
    hs = 12.0
    table.group("area_light", "light")
    table.face([(area_c[0] - hs, area_c[1], area_c[2] - hs), (area_c[0] + hs, area_c[1], area_c[2] - hs),
                (area_c[0] + hs, area_c[1], area_c[2] + hs), (area_c[0] - hs, area_c[1], area_c[2] + hs)])
    table.check_dir("table", (0.0, 1.0, 0.0))
    table.check_dir("backdrop", (0.0, 0.0, -1.0))
    table.check_dir("area_light", (0.0, -1.0, 0.0))

    mtl = Mtl(["cup scene materials"])
    mtl.material("ceramic", kd=(0.7, 0.7, 0.7), ks=(0.04, 0.04, 0.04), ns=300,
                 comment="glossy white ceramic: diffuse 0.7 under a weak sharp Blinn-Phong lobe")
    mtl.material("table", kd=(0.42, 0.29, 0.18), ks=(0.03, 0.03, 0.03), ns=40, comment="light wood")
    mtl.material("backdrop", kd=(0.5, 0.52, 0.55))
    mtl.material("light", kd=(0.0, 0.0, 0.0), ke=(6.0, 6.0, 6.0),
                 comment="24 cm square at 55 cm: ~1 W/m^2 on the table")

    cup_pos = (0.0, 0.01, 2.0)  # lifted 0.1 mm so the cup base does not coincide with the table
    spot_pos = (-30.0, 40.0, -25.0)
    spot_target = (0.0, 4.0, 2.0)
    spot_dir = normalize(sub(spot_target, spot_pos))
    d2 = dot(sub(spot_target, spot_pos), sub(spot_target, spot_pos))
    spot_i = 2500.0  # W/sr; at ~57 cm: ~0.8 W/m^2 (units of the scene are cm: I / d^2 with d in cm)

    cam = Camera((0.0, 16.0, -38.0), (0.0, 4.5, 2.0), (0.0, 1.0, 0.0), 30.0, 640, 480)
    cam.check_visible(name, "cup rim centre", add(cup_pos, (0.0, CUP_H, 0.0)))
    for p in box_corners(add(lo, cup_pos), add(hi, cup_pos)):
        cam.check_visible(name, "cup bbox corner", p)
    report_framing(name, cam, add(lo, cup_pos), add(hi, cup_pos), log)
    # the spot must light the cup (inside the cone)
    cone = math.degrees(math.acos(dot(spot_dir, normalize(sub(add(cup_pos, (0, 5, 0)), spot_pos)))))
    if cone > 15.0:
        raise CheckError("cup: cup is %.1f degrees off the spot axis" % cone)
    log.append("  %s: table +y, backdrop -z, area light -y; spot axis %.1f deg from the cup centre, "
               "distance %.0f cm" % (name, cone, math.sqrt(d2)))

    toml = Toml([
        "cup -- a lathed ceramic cup (no handle) on a table (units: cm).  The cup is a closed surface of",
        "revolution with 0.3 cm walls, a rounded rim and filleted foot/inner bottom, generated by",
        "scenes/tools/gen_scenes.py (48 segments, ~4.3k triangles, smoothing group 1, no vn).",
        "Material: Kd 0.7, Ks 0.04, Ns 300 (glossy white ceramic).  Lights: a spot light from the front",
        "left and a 24 cm square area light above.  Camera looks slightly down at the cup.",
    ])
    toml.table("camera", cam.fields())
    toml.table("render", [("spp", 64), ("max_depth", 8), ("seed", 0)])
    toml.table("mesh", [("obj", "cup.obj"), ("translate", cup_pos)], array=True)
    toml.table("mesh", [("obj", "table.obj")], array=True)
    toml.table("light", [("type", "spot"), ("position", spot_pos), ("direction", spot_dir),
                         ("intensity", (spot_i, spot_i * 0.95, spot_i * 0.85)), ("cone_angle", 25.0),
                         ("falloff_start", 15.0)],
               array=True, comment="warm spot aimed at the cup; scene units are cm, so I / d^2 ~ 0.8 at 57 cm")
    toml.table("background", [("radiance", (0.01, 0.01, 0.01))])
    write(name + "/cup.obj", obj.text(), written)
    write(name + "/table.obj", table.text(), written)
    write(name + "/cup.mtl", mtl.text(), written)
    write(name + "/scene.toml", toml.text(), written)


# ==========================================================================
# 4. room


def gen_room(written, log):
    name = "room"
    X0, X1, Y0, Y1, Z0, Z1 = -3.0, 3.0, 0.0, 2.8, -2.5, 2.5
    centre = ((X0 + X1) / 2, (Y0 + Y1) / 2, (Z0 + Z1) / 2)
    obj = Obj(name, "room.mtl", ["room: 6 m x 2.8 m x 5 m room with a table (units: metres)"])
    walls = [
        ("floor", "floor", [(X0, Y0, Z0), (X1, Y0, Z0), (X1, Y0, Z1), (X0, Y0, Z1)]),
        ("ceiling", "ceiling", [(X0, Y1, Z0), (X0, Y1, Z1), (X1, Y1, Z1), (X1, Y1, Z0)]),
        ("back_wall", "wall_accent", [(X0, Y0, Z1), (X1, Y0, Z1), (X1, Y1, Z1), (X0, Y1, Z1)]),
        ("front_wall", "wall", [(X0, Y0, Z0), (X0, Y1, Z0), (X1, Y1, Z0), (X1, Y0, Z0)]),
        ("wall_xpos", "wall", [(X1, Y0, Z0), (X1, Y1, Z0), (X1, Y1, Z1), (X1, Y0, Z1)]),
        ("wall_xneg", "wall", [(X0, Y0, Z0), (X0, Y0, Z1), (X0, Y1, Z1), (X0, Y1, Z0)]),
    ]
    # the quads above are listed counter-clockwise as seen from OUTSIDE the room; reverse them so
    # they are counter-clockwise seen from inside (normals into the room), then verify.
    walls = [(g, m, list(reversed(q))) for g, m, q in walls]
    for g, m, q in walls:
        n = newell(q)
        if dot(n, sub(centre, centroid(q))) < 0.0:
            raise CheckError("room: wall %s wound the wrong way" % g)
        obj.group(g, m)
        obj.face(q)
    # table: top 1.6 x 0.9 x 0.05 with its top surface at 0.75 m, four 0.06 m legs
    tc = (0.0, 0.0, 0.6)
    top_lo = (tc[0] - 0.8, 0.70, tc[2] - 0.45)
    top_hi = (tc[0] + 0.8, 0.75, tc[2] + 0.45)
    obj.group("table_top", "wood")
    for q in box_quads(top_lo, top_hi):
        obj.face(q)
    legs = []
    for sx in (-1, 1):
        for sz in (-1, 1):
            cx = tc[0] + sx * (0.8 - 0.08)
            cz = tc[2] + sz * (0.45 - 0.08)
            legs.append((cx, cz))
    for i, (cx, cz) in enumerate(legs):
        g = "table_leg_%d" % (i + 1)
        obj.group(g, "wood")
        for q in box_quads((cx - 0.03, 0.0, cz - 0.03), (cx + 0.03, 0.70, cz + 0.03)):
            obj.face(q)
    light_c = (tc[0], Y1 - 0.01, tc[2])
    obj.group("ceiling_light", "light")
    hx, hz = 0.5, 0.3
    obj.face([(light_c[0] - hx, light_c[1], light_c[2] - hz), (light_c[0] + hx, light_c[1], light_c[2] - hz),
              (light_c[0] + hx, light_c[1], light_c[2] + hz), (light_c[0] - hx, light_c[1], light_c[2] + hz)])

    for g, _, _ in walls:
        obj.check_into(g, centre)
        obj.check_planar(g, 1e-9)
    obj.check_closed_outward(["table_top"], "table_top")
    for i in range(4):
        obj.check_closed_outward(["table_leg_%d" % (i + 1)], "leg")
    obj.check_dir("ceiling_light", (0.0, -1.0, 0.0))

    mtl = Mtl(["room materials"])
    mtl.material("floor", kd=(0.5, 0.42, 0.32), ks=(0.1, 0.1, 0.1), ns=100, comment="glossy floor (Ks 0.1, Ns 100)")
    mtl.material("ceiling", kd=(0.8, 0.8, 0.8))
    mtl.material("wall", kd=(0.72, 0.7, 0.65))
    mtl.material("wall_accent", kd=(0.45, 0.55, 0.65))
    mtl.material("wood", kd=(0.4, 0.24, 0.12), comment="wood-ish brown")
    mtl.material("light", kd=(0.0, 0.0, 0.0), ke=(9.0, 8.5, 7.5),
                 comment="1.0 x 0.6 m ceiling panel, 2.05 m above the table top: ~1.2 W/m^2 direct")

    sphere_c = (0.35, 0.75 + 0.12, 0.45)
    cam = Camera((2.3, 1.6, -2.2), (-0.2, 0.8, 0.8), (0.0, 1.0, 0.0), 60.0, 640, 480)
    cam.check_visible(name, "table centre", (tc[0], 0.75, tc[2]))
    cam.check_visible(name, "sphere", sphere_c)
    report_framing(name, cam, (X0, Y0, Z0), (X1, Y1, Z1), log)
    report_framing(name + " table", cam, (-0.8, 0.0, 0.15), (0.8, 0.75, 1.05), log)
    log.append("  %s: 6 walls face into the room, table parts closed & outward, light -y; %d triangles"
               % (name, obj.ntris))

    toml = Toml([
        "room -- a closed 6 m x 2.8 m x 5 m room (floor, ceiling, four walls; units: metres) with a",
        "wooden table (1.6 x 0.9 m top at 0.75 m on four legs) and a small glossy sphere on it.",
        "Lit by a 1.0 x 0.6 m ceiling panel above the table and a dim point light in a corner.",
        "Floor: Kd (0.5, 0.42, 0.32) + Ks 0.1, Ns 100.  Numbers are this repository's own choice.",
    ])
    toml.table("camera", cam.fields())
    toml.table("render", [("spp", 64), ("max_depth", 8), ("seed", 0)])
    toml.table("mesh", [("obj", "room.obj")], array=True)
    toml.table("sphere", [("center", sphere_c), ("radius", 0.12), ("kd", (0.15, 0.3, 0.6)),
                          ("ks", (0.3, 0.3, 0.3)), ("ns", 300.0)], array=True)
    toml.table("light", [("type", "point"), ("position", (-2.4, 2.3, 2.0)), ("intensity", (1.5, 1.3, 1.0))],
               array=True, comment="warm corner light")
    write(name + "/room.obj", obj.text(), written)
    write(name + "/room.mtl", mtl.text(), written)
    write(name + "/scene.toml", toml.text(), written)


# ==========================================================================
# 5. Veach MIS


def gen_veach_mis(written, log):
    name = "veach-mis"
    cam_pos = (0.0, 2.0, 15.0)
    cam_target = (0.0, -2.0, 2.5)
    # Mitsuba / Nori versions use a 42 degree *horizontal* fov at 768 x 512; our fov is vertical.
    vfov = round(math.degrees(2.0 * math.atan(math.tan(math.radians(21.0)) / 1.5)), 2)
    cam = Camera(cam_pos, cam_target, (0.0, 1.0, 0.0), vfov, 768, 512)
    # sphere lights as in Veach's thesis / Mitsuba's veach_mis: x = -3.75 .. 3.75, radius x3 each
    radii = [0.1 / 3.0, 0.1, 0.3, 0.9]
    xs = [-3.75, -1.25, 1.25, 3.75]
    light_y, light_z = 0.0, 0.0
    # equal power: P = 4 pi^2 r^2 L  =>  L = P / (4 pi^2 r^2); P chosen so that L(r = 0.1) = 100
    power = 4.0 * math.pi ** 2 * 0.1 ** 2 * 100.0
    colours = [(1.0, 1.0, 1.0)] * 4
    # plates: 8 units long (x), stacked from front-low to back-high.  Plate centres are placed at
    # equally spaced elevation angles below the light row as seen from the camera (so the plates
    # fill the lower part of the frame without overlapping), at depths z from 2.5 (front) to -1
    # (back, behind the light row).  Each plate is tilted so that it mirrors the centre of the
    # light row into the camera at its centre (normal = half vector), and is made as wide as
    # 80 % of its share of the frame height.
    # Veach's plates are smoother still (Mitsuba: roughness 0.1 .. 0.005 ~ Blinn-Phong Ns 200 .. 80000);
    # keeping within the renderer's Ns range (0-1000), an exponent ladder of ~x3.3 per plate keeps the
    # highlights of every plate visible.
    exps = [30.0, 100.0, 300.0, 1000.0]  # front/bottom = roughest .. back/top = sharpest
    light_centre = (0.0, light_y, light_z)
    elevs = [-27.5, -23.0, -18.5, -14.0]
    zs = [2.5, 1.3, 0.1, -1.1]
    step = math.radians(4.5)
    obj = Obj(name, "veach-mis.mtl", ["Veach MIS scene: four glossy plates + dark floor and back wall"])
    plate_frames = []
    for i, (el, z, ns) in enumerate(zip(elevs, zs, exps)):
        y = cam_pos[1] + (cam_pos[2] - z) * math.tan(math.radians(el))
        c = (0.0, round(y, 3), z)
        h = normalize(add(normalize(sub(cam_pos, c)), normalize(sub(light_centre, c))))
        dist = length(sub(cam_pos, c))
        cos_view = dot(h, normalize(sub(cam_pos, c)))
        width = round(0.8 * step * dist / cos_view, 3)
        # plate spans x; its other in-plane axis t is perpendicular to x and h
        t = normalize(cross(h, (1.0, 0.0, 0.0)))  # lies in the y-z plane
        ex = (4.0, 0.0, 0.0)
        et = mul(t, width / 2.0)
        quad = [sub(sub(c, ex), et), add(sub(c, et), ex), add(add(c, ex), et), add(sub(c, ex), et)]
        if dot(newell(quad), h) < 0.0:
            quad.reverse()
        g = "plate%d" % (i + 1)
        obj.group(g, "plate%d" % (i + 1))
        obj.face(quad)
        plate_frames.append((g, h, c, width))
        tilt = math.degrees(math.acos(h[1]))
        log.append("  %s: %s centre %r, width %.3f, normal (%.3f, %.3f, %.3f) = %.1f deg from +y, "
                   "seen %.1f deg off its normal, Ns %g" % (name, g, c, width, h[0], h[1], h[2], tilt,
                                                           math.degrees(math.acos(cos_view)), ns))
    obj.group("floor", "dark")
    obj.face([(-12.0, -6.0, -3.0), (-12.0, -6.0, 20.0), (12.0, -6.0, 20.0), (12.0, -6.0, -3.0)])
    obj.group("back_wall", "dark")
    obj.face([(-12.0, -6.0, -3.0), (12.0, -6.0, -3.0), (12.0, 8.0, -3.0), (-12.0, 8.0, -3.0)])

    for g, h, c, _ in plate_frames:
        obj.check_dir(g, h, 0.999999)
        obj.check_into(g, cam_pos)  # the camera sees the front of every plate
        obj.check_into(g, light_centre)  # ... and so do the lights
        cam.check_visible(name, g + " centre", c)
    obj.check_dir("floor", (0.0, 1.0, 0.0))
    obj.check_dir("back_wall", (0.0, 0.0, 1.0))
    # plates must not overlap in the image: the projected vertical extents must be disjoint
    spans = []
    for g, h, c, w in plate_frames:
        t = normalize(cross(h, (1.0, 0.0, 0.0)))
        rows_ = [cam.project(add(add(c, mul(t, s_ * w / 2.0)), (xx, 0.0, 0.0)))[1]
                 for s_ in (-1.0, 1.0) for xx in (-4.0, 0.0, 4.0)]
        spans.append((min(rows_), max(rows_), g))
    spans.sort()
    for a, b in zip(spans, spans[1:]):
        if a[1] >= b[0]:
            raise CheckError("veach-mis: plates %s and %s overlap in the image" % (a[2], b[2]))
    log.append("  %s: plate image rows %s" % (name, ", ".join("%s %.0f-%.0f" % (g, a, b) for a, b, g in spans)))
    rows = []
    for x, r in zip(xs, radii):
        col, row = cam.check_visible(name, "light r=%g" % r, (x, light_y, light_z))
        rows.append((col, row))
    if not all(rows[i][0] < rows[i + 1][0] for i in range(3)):
        raise CheckError("veach-mis: lights should go from small (left) to large (right)")
    log.append("  %s: vertical fov %.2f (= 42 deg horizontal); light columns %s (small radius on the left)" % (
        name, vfov, [int(c) for c, _ in rows]))
    

    mtl = Mtl(["Veach MIS materials: plates = black diffuse + grey normalised Blinn-Phong lobe,",
               "exponents increasing from the front (rough) plate to the back (sharp) plate."])
    for i, ns in enumerate(exps):
        mtl.material("plate%d" % (i + 1), kd=(0.0, 0.0, 0.0), ks=(0.35, 0.35, 0.35), ns=ns)
    mtl.material("dark", kd=(0.1, 0.1, 0.1))

    toml = Toml([
        "veach-mis -- the multiple importance sampling test scene of Eric Veach's thesis (fig. 9.2), laid out",
        "like Mitsuba's / Nori's veach_mis: camera (0, 2, 15) -> (0, -2, 2.5), 768 x 512, 42 degree",
        "horizontal fov (= %.2f vertical).  Four 8-unit long plates, each tilted so that it mirrors the" % vfov,
        "centre of the light row into the camera, Blinn-Phong Ns = 30, 100, 300, 1000 (front to back),",
        "Ks 0.35, Kd 0.  Four sphere lights at x = -3.75, -1.25, 1.25, 3.75 with radii 1/30, 0.1, 0.3, 0.9",
        "and EQUAL POWER: L_i = P / (4 pi^2 r_i^2), P = 4 pi^2 (0.1)^2 100 (so L = 100 at r = 0.1, as Mitsuba).",
        "Fill light: sphere r = 0.5 at (10, 10, 4), L = 800 (as Mitsuba).  Floor and back wall Kd 0.1.",
    ])
    toml.table("camera", cam.fields())
    toml.table("render", [("spp", 64), ("max_depth", 8), ("seed", 0)])
    toml.table("mesh", [("obj", "veach-mis.obj")], array=True)
    for x, r, col in zip(xs, radii, colours):
        rr = float(fnum(r))  # the radius as written, so power is equal for the file's numbers
        L = power / (4.0 * math.pi ** 2 * rr * rr)
        toml.table("sphere", [("center", (x, light_y, light_z)), ("radius", rr), ("ke", mul(col, L))],
                   array=True, comment="light, radius %s: L = P / (4 pi^2 r^2) = %s" % (fnum(rr), fnum(L)))
    toml.table("sphere", [("center", (10.0, 10.0, 4.0)), ("radius", 0.5), ("ke", (800.0, 800.0, 800.0))],
               array=True, comment="fill light (Mitsuba veach_mis)")
    write(name + "/veach-mis.obj", obj.text(), written)
    write(name + "/veach-mis.mtl", mtl.text(), written)
    write(name + "/scene.toml", toml.text(), written)


# ==========================================================================
# 6. glass: mirror and glass spheres in a Cornell-style box


def gen_glass(written, log):
    name = "glass"
    obj = Obj(name, "glass.mtl", ["Cornell box walls (published geometry, mm) without the blocks,",
                                  "with a small 80 x 80 mm light towards the back of the ceiling."])
    walls = cbox_walls(obj)
    lc = (278.0, 548.7, 400.0)
    hs = 40.0
    obj.group("light", "light")
    obj.face([(lc[0] + hs, lc[1], lc[2] - hs), (lc[0] + hs, lc[1], lc[2] + hs),
              (lc[0] - hs, lc[1], lc[2] + hs), (lc[0] - hs, lc[1], lc[2] - hs)])
    for g in walls:
        obj.check_into(g, CBOX_CENTRE)
    obj.check_dir("light", (0.0, -1.0, 0.0), 0.999999)
    area_cbox = 130.0 * 105.0
    area = (2 * hs) ** 2
    ke = mul(CBOX_KE, area_cbox / area)

    mtl = Mtl(["glass scene materials: Cornell box reflectances; the light has the Cornell box light's",
               "power (Ke (17, 12, 4) x 13650 / 6400 mm^2) on an 80 x 80 mm quad."])
    cbox_materials(mtl)
    mtl.material("light", kd=CBOX_LIGHT_KD, ke=ke)

    cam = CBOX_CAMERA
    glass_c, glass_r = (185.0, 100.0, 200.0), 100.0
    mirror_c, mirror_r = (380.0, 100.0, 370.0), 100.0
    check_cbox_left_right(name, cam, log)
    gcol, _ = cam.check_visible(name, "glass sphere", glass_c)
    mcol, _ = cam.check_visible(name, "mirror sphere", mirror_c)
    # caustic: the glass sphere focuses the light roughly along light -> sphere centre; its
    # paraxial focus lies n R / (2 (n - 1)) = 1.5 R beyond the centre.  Check the spot lands on the
    # floor in front of the sphere's contact point (visible to the camera, not hidden behind it).
    d = normalize(sub(glass_c, lc))
    t_floor = (0.0 - lc[1]) / d[1]
    hit = add(lc, mul(d, t_floor))
    if not hit[2] < glass_c[2] - 20.0:
        raise CheckError("glass: caustic centre %r would be hidden behind the sphere" % (hit,))
    # is the floor point visible from the camera past the sphere?  (segment-sphere test)
    o = cam.position
    v = sub(hit, o)
    tt = max(0.0, min(1.0, dot(sub(glass_c, o), v) / dot(v, v)))
    closest = add(o, mul(v, tt))
    if length(sub(closest, glass_c)) < glass_r:
        raise CheckError("glass: caustic centre %r occluded by the glass sphere itself" % (hit,))
    log.append("  %s: glass sphere image column %.0f (right), mirror %.0f (left); caustic centre ~(%.0f, 0, %.0f), "
               "in front of the sphere's contact point and visible" % (name, gcol, mcol, hit[0], hit[2]))

    toml = Toml([
        "glass -- a mirror sphere (illum 3, Ks 0.95) and a glass sphere (illum 7, Ni 1.5, Tf 1) on the floor of",
        "the Cornell box (published walls, no blocks; camera as in cornell-box), lit by a small 80 x 80 mm",
        "ceiling light towards the back, so the glass sphere focuses a caustic onto the floor in front of",
        "itself.  The light keeps the Cornell box light's power.  max_depth 12 for the paths through glass.",
    ])
    toml.table("camera", cam.fields())
    toml.table("render", [("spp", 64), ("max_depth", 12), ("seed", 0)])
    toml.table("mesh", [("obj", "glass.obj")], array=True)
    toml.table("sphere", [("center", mirror_c), ("radius", mirror_r), ("ks", (0.95, 0.95, 0.95)), ("illum", 3)],
               array=True, comment="mirror")
    toml.table("sphere", [("center", glass_c), ("radius", glass_r), ("ks", (1.0, 1.0, 1.0)), ("ni", 1.5),
                          ("tf", (1.0, 1.0, 1.0)), ("illum", 7)], array=True, comment="clear glass, IOR 1.5")
    write(name + "/glass.obj", obj.text(), written)
    write(name + "/glass.mtl", mtl.text(), written)
    write(name + "/scene.toml", toml.text(), written)


# ==========================================================================


def main():
    check_only = "--check-only" in sys.argv[1:]
    written = []
    log = []
    for gen in (gen_cornell_box, gen_cube, gen_cup, gen_room, gen_veach_mis, gen_glass):
        gen(written, log)
    print("checks passed:")
    for line in log:
        print(line)
    changed = 0
    for path, text in written:
        full = os.path.join(SCENES, path)
        old = None
        if os.path.exists(full):
            with open(full, "r", encoding="utf-8", newline="") as f:
                old = f.read()
        if old != text:
            changed += 1
            if check_only:
                print("DIFFERS: scenes/" + path)
            else:
                with open(full, "w", encoding="utf-8", newline="\n") as f:
                    f.write(text)
                print("wrote scenes/" + path)
    if check_only and changed:
        sys.exit(1)
    print("%d files, %d changed" % (len(written), changed))


if __name__ == "__main__":
    try:
        main()
    except CheckError as e:
        print("CHECK FAILED: " + str(e), file=sys.stderr)
        sys.exit(2)
