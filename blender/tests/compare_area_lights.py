"""Blender's area lights as tilefarm's `type = "area"` lights (issue 50), against Cycles
4.2 (PyPI's bpy; CPU, no denoising, a one-pixel box filter, no clamping, the same
bounces, Filter Glossy 0).

First, the export alone: a square, a rectangle, a disk and an ellipse, scaled and
turned, written as `[[light]] type = "area"` with Blender's shape, size, matrix (its
scale included), power and colour; `visible` from the object's camera visibility (off
for a new light, as Blender makes it); what does not map (a spread under 180°, shadows
off, rays a light is hidden from, a portal, a Z scaled to 0, a sheared frame) each a
line of the warning.

Then a rectangle (turned about its normal, scaled 1.2 × 0.8) and a disk (scaled 0.75),
each low over a floor in front of a wall, tilted towards the camera (which sees their
emitting side), beside a white and a rough metal sphere, no other light, black world,
6 bounces. Both renderers render it twice (seeds 1 and 2, the same spp; tilefarm's
first with its variance layer):
- channel means within 2 % of Cycles', and 8 × 8 blocks within their noise (a light
  turned or flipped, or emitting from its other side, fails here);
- noise: tilefarm's relative MSE between its two seeds at most Cycles' between its own
  (Cycles samples rectangles by solid angle as tilefarm does, disks by area as tilefarm
  does). The same with direct light alone (no bounces), over everything but the
  spheres, is reported (`relmse_seeds_direct_floor`), not held: it is 1e-5 and moves by
  tens of percent from one seed pair to the next;
- with a point light in front of it too (4 × spp: the wall's indirect light is noisy):
  channel means within 2 %; unseen, the pixels the light covers (its shape projected,
  eroded by a pixel) show what is behind it, within 5 % of Cycles' (a bright polygon
  would be hundreds of times brighter); no shadow, the wall behind it, where the point
  light throws the area light's shadow (its pixels eroded, those next to the light's
  left out), lit as in Cycles, within 3 %;
- with the object's camera visibility on (spp / 4): both show the light where it is,
  within 5 % of each other, and tilefarm's visible light (an emissive surface, which
  blocks) darkens that wall where Cycles' does not (the shadow check can fail).

Prints one JSON line of figures; exits non-zero on a failure.

    python blender/tests/compare_area_lights.py COORDINATOR_EXE WORK_DIR [SPP]
"""

import json
import math
import os
import subprocess
import sys
import time
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

import bpy  # noqa: E402
import mathutils  # noqa: E402
import numpy as np  # noqa: E402
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402

import compare_cycles as cc  # noqa: E402
from export_testing import expect  # noqa: E402
from tilefarm_blender.export import export_scene  # noqa: E402

W, H = 96, 72
BOUNCES = 6
# The area lights' place and tilt (towards the camera and down), and the point light of
# the shadow check, in front of the light: the wall behind (around SHADOW_AT) is in the
# area light's shadow from that point.
LIGHT_AT = (0.0, 0.3, 0.8)
LIGHT_AIM = (0.0, -1.0, -0.35)
WALL_Y = 3.0
SHADOW_AT = (0.0, WALL_Y, 0.6)
POINT_AT = tuple(a - 0.7 * (b - a) for a, b in zip(LIGHT_AT, SHADOW_AT))
CAMERA_AT, CAMERA_LOOK = (0.0, -4.0, 2.0), (0.0, 0.5, 0.5)
SHAPES = {
    # shape, size, size_y, object scale, roll about the normal (degrees), power W, colour
    "rectangle": ("RECTANGLE", 1.0, 0.5, (1.2, 0.8, 1.0), 25.0, 60.0, (1.0, 0.85, 0.7)),
    "disk": ("DISK", 0.8, 0.8, (0.75, 0.75, 0.75), 0.0, 40.0, (0.7, 0.85, 1.0)),
}


# Export ------------------------------------------------------------------------------


def area(scene, name, shape, size, size_y=None, at=(0, 0, 1), rotation=(0, 0, 0), scale=(1, 1, 1), energy=10.0,
         color=(1, 1, 1)):
    ob = bpy.data.objects.new(name, bpy.data.lights.new(name, "AREA"))
    scene.collection.objects.link(ob)
    ob.data.shape, ob.data.size, ob.data.energy, ob.data.color = shape, size, energy, color
    if size_y is not None:
        ob.data.size_y = size_y
    ob.location, ob.rotation_euler, ob.scale = at, rotation, scale
    return ob


def export_checks(work):
    """The four shapes (and a portal, a flattened and a sheared light) as written, and
    the warning's lines: returns what was checked."""
    scene = cc.fresh()
    cc.quad("floor", [(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)], cc.principled("white", (0.7, 0.7, 0.7)))
    cc.camera(scene, (0, -5, 2), (0, 0, 0.5))
    # As an artist adds one (Add › Light › Area): not visible to the camera.
    bpy.ops.object.light_add(type="AREA", location=(0, 0, 3))
    added = bpy.context.object
    added.name = "added"
    assert not added.visible_camera, "Blender's new area light is visible to the camera (expected not)"
    area(scene, "square", "SQUARE", 0.5, at=(1, 2, 3), rotation=(0.3, -0.2, 0.5), scale=(2, 2, 2), energy=25.0,
         color=(1, 0.5, 0.25))
    area(scene, "rectangle", "RECTANGLE", 1.5, 0.4, at=(-1, 0.5, 2), rotation=(math.radians(90), 0, 0),
         scale=(1, 3, 1), energy=100.0)
    disk = area(scene, "disk", "DISK", 0.8, at=(0, -1, 2.5), energy=50.0)
    disk.visible_camera = True
    disk.data.spread = math.radians(60)
    ellipse = area(scene, "ellipse", "ELLIPSE", 1.0, 0.25, at=(2, 0, 1), rotation=(0, math.radians(-90), 0), energy=7.0)
    ellipse.data.use_shadow = False
    ellipse.visible_glossy = False
    portal = area(scene, "portal", "RECTANGLE", 2.0, 1.0, at=(0, 3, 1))
    portal.data.cycles.is_portal = True
    area(scene, "flat", "SQUARE", 1.0, at=(0, 0, 2), scale=(1, 1, 0))
    # Under a turned parent scaled along one axis: a sheared frame, its y made square.
    parent = bpy.data.objects.new("parent", None)
    scene.collection.objects.link(parent)
    parent.rotation_euler, parent.scale = (0, 0, 0.7), (1, 3, 1)
    area(scene, "sheared", "SQUARE", 1.0, at=(0, 0, 2), rotation=(0, 0, 0.5)).parent = parent
    folder = os.path.join(work, "export")
    report = export_scene(folder, scene)
    with open(os.path.join(folder, "scene.toml"), "rb") as f:
        written = tomllib.load(f)
    lights = written.get("light", [])
    assert all(light["type"] == "area" for light in lights), lights
    assert not [n for n in os.listdir(folder) if n.startswith("light-")], "an area light written as a mesh"
    by_matrix = {}
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for name in ("added", "square", "rectangle", "disk", "ellipse"):
        m = bpy.data.objects[name].evaluated_get(depsgraph).matrix_world
        rows = [[float(m[r][c]) for c in range(4)] for r in range(4)]
        found = [light for light in lights if np.allclose(light["matrix"], rows, atol=1e-6)]
        assert len(found) == 1, f"{name}: {len(found)} lights with its matrix {rows} in {lights}"
        by_matrix[name] = found[0]
    want = {
        "added": ("rectangle", 1.0, 10.0, [1, 1, 1], False),  # Blender's default: a 1 m square, 10 W
        "square": ("rectangle", 0.5, 25.0, [1, 0.5, 0.25], False),
        "rectangle": ("rectangle", [1.5, 0.4], 100.0, [1, 1, 1], False),
        "disk": ("disk", 0.8, 50.0, [1, 1, 1], True),
        "ellipse": ("ellipse", [1.0, 0.25], 7.0, [1, 1, 1], False),
    }
    for name, (shape, size, power, color, visible) in want.items():
        light = by_matrix[name]
        assert light["shape"] == shape, f"{name}: shape {light['shape']}, expected {shape}"
        expect(f"{name}.size", light["size"], size)
        expect(f"{name}.power", light["power"], power)
        expect(f"{name}.color", light["color"], color)
        assert light["visible"] is visible, f"{name}: visible {light['visible']}"
    assert len(lights) == 6, f"the portal or the flat light was written: {lights}"
    sheared = [light for light in lights if light not in by_matrix.values()][0]
    x, y = np.array(sheared["matrix"])[:3, 0], np.array(sheared["matrix"])[:3, 1]
    assert abs(x @ y) < 1e-5 * np.linalg.norm(x) * np.linalg.norm(y), f"sheared: {sheared['matrix']}"
    lines = report.warnings
    for name, words in [("disk", "visible to the camera"), ("disk", "spread 60°"), ("ellipse", "shadows off"),
                        ("ellipse", "off for glossy rays"), ("portal", "a portal"), ("flat", "scaled to nothing"),
                        ("sheared", "a sheared shape")]:
        assert any(w.startswith(f"light {name}: ") and words in w for w in lines), f"{name}: no '{words}' in {lines}"
    quiet = [w for w in lines if w.split(":")[0] in {"light added", "light square", "light rectangle"}]
    assert not quiet, f"warnings about lights that map exactly: {quiet}"
    return {"lights": len(lights), "warnings": lines}


# Renders -----------------------------------------------------------------------------


def room(kind, point=False):
    """The floor and wall, a white and a rough metal sphere, and the area light of
    SHAPES[kind] (unseen by the camera, as Blender makes it); with `point`, a point
    light in front of it too, whose rays through it go on to the wall."""
    scene = cc.fresh()
    white = cc.principled("white", (0.7, 0.7, 0.7))
    cc.quad("floor", [(-4, -3, 0), (4, -3, 0), (4, WALL_Y, 0), (-4, WALL_Y, 0)], white)
    y = WALL_Y
    cc.quad("wall", [(-4, y, 0), (4, y, 0), (4, y, 3), (-4, y, 3)], cc.principled("wall", (0.4, 0.5, 0.6)))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(-1.0, -0.7, 0.35), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(white)
    metal = bpy.data.materials.new("metal")
    metal.use_nodes = True
    p = metal.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (0.9, 0.8, 0.6, 1.0)
    p.inputs["Metallic"].default_value = 1.0
    p.inputs["Roughness"].default_value = 0.3
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(1.0, -0.8, 0.35), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(metal)
    shape, size, size_y, scale, roll, power, color = SHAPES[kind]
    light = area(scene, "area", shape, size, size_y, at=LIGHT_AT, scale=scale, energy=power, color=color)
    turn = mathutils.Vector(LIGHT_AIM).to_track_quat("-Z", "Y") @ mathutils.Quaternion((0, 0, 1), math.radians(roll))
    light.rotation_euler = turn.to_euler()
    if point:
        ob = bpy.data.objects.new("point", bpy.data.lights.new("point", "POINT"))
        scene.collection.objects.link(ob)
        ob.location, ob.data.energy, ob.data.shadow_soft_size = POINT_AT, 150.0, 0.0
    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    scene.world = world
    cc.camera(scene, CAMERA_AT, CAMERA_LOOK)
    settings(scene, 16, 1)
    bpy.context.view_layer.update()
    return scene, light


def settings(scene, spp, seed, bounces=BOUNCES):
    cc.cycles_settings(scene, spp, seed)
    c = scene.cycles
    c.max_bounces = c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = bounces
    scene.cycles.blur_glossy = 0.0
    scene.render.resolution_x, scene.render.resolution_y = W, H


def shape_points(light, n=200):
    """Points filling the light's shape, in world space."""
    d = light.data
    sx, sy = d.size, d.size_y if d.shape in {"RECTANGLE", "ELLIPSE"} else d.size
    u, v = (np.mgrid[0:n, 0:n] + 0.5) / n - 0.5
    keep = np.ones_like(u, bool) if d.shape in {"SQUARE", "RECTANGLE"} else (u * u + v * v <= 0.25)
    m = light.matrix_world
    return [m @ mathutils.Vector((float(a) * sx, float(b) * sy, 0.0)) for a, b in zip(u[keep], v[keep])]


def pixel_mask(scene, points, grow=False):
    """The pixels (rows top to bottom) the world points land in, eroded by a pixel (or,
    with `grow`, dilated by one)."""
    mask = np.zeros((H, W), bool)
    for q in points:
        c = world_to_camera_view(scene, scene.camera, q)
        x, y = int(c.x * W), int((1.0 - c.y) * H)
        if c.z > 0 and 0 <= x < W and 0 <= y < H:
            mask[y, x] = True
    out = mask.copy()
    for a, b in [(np.s_[1:, :], np.s_[:-1, :]), (np.s_[:-1, :], np.s_[1:, :]),
                 (np.s_[:, 1:], np.s_[:, :-1]), (np.s_[:, :-1], np.s_[:, 1:])]:
        if grow:
            out[a] |= mask[b]
        else:
            out[a] &= mask[b]
    return out


def sphere_mask(scene):
    """The spheres' pixels, grown by three."""
    points = [ob.matrix_world @ v.co for ob in scene.objects if ob.name.startswith("Sphere") for v in ob.data.vertices]
    mask = pixel_mask(scene, points, grow=True)
    for _ in range(2):
        grown = mask.copy()
        grown[1:] |= mask[:-1]
        grown[:-1] |= mask[1:]
        grown[:, 1:] |= mask[:, :-1]
        grown[:, :-1] |= mask[:, 1:]
        mask = grown
    return mask


def shadow_points(light, n=200):
    """Points of the wall (y = WALL_Y) the area light would shadow from the point light:
    the rays from POINT_AT through its shape, continued to the wall."""
    p = mathutils.Vector(POINT_AT)
    out = []
    for q in shape_points(light, n):
        w = p + (q - p) * ((WALL_Y - p.y) / (q.y - p.y))
        if 0.0 < w.z < 3.0:
            out.append(w)
    return out


def render_cycles(scene, spp, seed, path, bounces=BOUNCES):
    settings(scene, spp, seed, bounces)
    t = time.perf_counter()
    cc.cycles(scene, path)
    return cc.pixels(path), time.perf_counter() - t


def render_tilefarm(coordinator, folder, path, spp, seed):
    t = time.perf_counter()
    cmd = [coordinator, "render", os.path.join(folder, "scene.toml"), "-q", "--spp", str(spp), "--seed", str(seed),
           "--aovs", "--local-workers", "0", "--tile", "16", "-o", path]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    if run.returncode != 0:
        raise SystemExit(f"tilefarm render failed: {run.stderr}")
    return cc.pixels(path), time.perf_counter() - t


def relmse(a, b, ref):
    """The relative MSE between two renders, over a common reference's squares."""
    return float(np.mean((a - b) ** 2 / (ref * ref + 1e-2)))


def compare(coordinator, work, spp, kind):
    figures, failed = {}, []
    path = lambda what: os.path.join(work, f"{kind}-{what}.exr")  # noqa: E731
    scene, light = room(kind)
    folder = os.path.join(work, kind)
    report = export_scene(folder, scene)
    figures["warnings"] = report.warnings
    light_mask = pixel_mask(scene, shape_points(light))
    shape, size, size_y, scale, _, power, color = SHAPES[kind]
    scale_xy = scale[0] * scale[1]
    light_area = size * size_y * scale_xy * (math.pi / 4.0 if shape in {"DISK", "ELLIPSE"} else 1.0)
    radiance = np.array(color) * power / (math.pi * light_area)
    cy1, t_cy = render_cycles(scene, spp, 1, path("cycles1"))
    cy2, _ = render_cycles(scene, spp, 2, path("cycles2"))
    tf1, t_tf = render_tilefarm(coordinator, folder, path("tilefarm1"), spp, 1)
    tf2, _ = render_tilefarm(coordinator, folder, path("tilefarm2"), spp, 2)
    var = cc.layer(path("tilefarm1"), "variance")
    figures["seconds"] = {"cycles": round(t_cy, 2), "tilefarm": round(t_tf, 2)}

    # Means, and blocks within their noise.
    cc.means_and_blocks(kind, cy1, cy2, tf1, tf2, var, figures, failed)

    # Noise: each renderer's two seeds against each other, over one reference.
    ref = (cy1 + cy2 + tf1 + tf2) / 4
    figures["relmse_seeds_cycles"] = round(relmse(cy1, cy2, ref), 6)
    figures["relmse_seeds_tilefarm"] = round(relmse(tf1, tf2, ref), 6)
    figures["noise_ratio"] = round(figures["relmse_seeds_tilefarm"] / figures["relmse_seeds_cycles"], 3)
    if figures["relmse_seeds_tilefarm"] > figures["relmse_seeds_cycles"]:
        failed.append(f"{kind}: tilefarm is noisier than Cycles at {spp} spp: seed-to-seed relMSE "
                      f"{figures['relmse_seeds_tilefarm']:.4g} over Cycles' {figures['relmse_seeds_cycles']:.4g}")
    # Direct light alone (no bounces): the light's sampling and MIS by themselves, on the
    # floor (the spheres left out: the metal one's highlight of the light is a few pixels
    # whose noise is the pixel's footprint as much as the light's). Reported, not held:
    # it is a small number (1e-5) that moves by tens of percent from seed pair to pair.
    settings(scene, 16, 1, bounces=0)
    direct = os.path.join(work, f"{kind}-direct")
    export_scene(direct, scene)
    d_cy = [render_cycles(scene, spp, s, path(f"cycles-direct{s}"), bounces=0)[0] for s in (1, 2)]
    d_tf = [render_tilefarm(coordinator, direct, path(f"tilefarm-direct{s}"), spp, s)[0] for s in (1, 2)]
    floor = ~sphere_mask(scene)
    d_ref = (sum(d_cy) + sum(d_tf))[floor] / 4
    figures["relmse_seeds_direct_floor"] = {"cycles": round(relmse(d_cy[0][floor], d_cy[1][floor], d_ref), 8),
                                            "tilefarm": round(relmse(d_tf[0][floor], d_tf[1][floor], d_ref), 8)}

    # With a point light in front of it too: unseen by the camera (where the light is,
    # what is behind it) and casting no shadow (on the wall behind it, where the point
    # light throws its shadow).
    scene, light = room(kind, point=True)
    behind_mask = pixel_mask(scene, shadow_points(light)) & ~pixel_mask(scene, shape_points(light), grow=True)
    lit_folder = os.path.join(work, f"{kind}-point")
    export_scene(lit_folder, scene)
    # Four times the samples: the wall's indirect light (from the floor under the point
    # light) is noisy, and the check asks 3 %.
    cys, _ = render_cycles(scene, 4 * spp, 1, path("cycles-point"))
    tfs, _ = render_tilefarm(coordinator, lit_folder, path("tilefarm-point"), 4 * spp, 1)
    figures["point_means_ratio"] = (tfs.reshape(-1, 3).mean(0) / cys.reshape(-1, 3).mean(0)).round(4).tolist()
    if not (np.abs(tfs.reshape(-1, 3).mean(0) / cys.reshape(-1, 3).mean(0) - 1.0) < 0.02).all():
        failed.append(f"{kind}: with the point light, channel means differ: {figures['point_means_ratio']}")
    figures["radiance"] = radiance.round(3).tolist()
    figures["light_pixels"] = int(light_mask.sum())
    figures["behind_pixels"] = int(behind_mask.sum())
    under = {"cycles": float(cys[light_mask].mean()), "tilefarm": float(tfs[light_mask].mean())}
    behind = {"cycles": float(cys[behind_mask].mean()), "tilefarm": float(tfs[behind_mask].mean())}

    # The same with the object's Ray Visibility › Camera on: both show the light, and
    # tilefarm's visible light (an emissive surface) blocks the point light, Cycles' not.
    light.visible_camera = True
    visible_folder = os.path.join(work, f"{kind}-point-visible")
    export_scene(visible_folder, scene)
    cyv, _ = render_cycles(scene, spp // 4, 1, path("cycles-point-visible"))
    tfv, _ = render_tilefarm(coordinator, visible_folder, path("tilefarm-point-visible"), spp // 4, 1)
    under.update(cycles_visible=float(cyv[light_mask].mean()), tilefarm_visible=float(tfv[light_mask].mean()))
    behind.update(cycles_visible=float(cyv[behind_mask].mean()), tilefarm_visible=float(tfv[behind_mask].mean()))
    figures["under_light"] = {k: round(v, 5) for k, v in under.items()}
    figures["behind_light"] = {k: round(v, 5) for k, v in behind.items()}
    if light_mask.sum() < 20 or abs(under["tilefarm"] / under["cycles"] - 1.0) > 0.05 \
            or under["tilefarm"] > 0.05 * radiance.mean():
        failed.append(f"{kind}: where the light is, tilefarm shows {under['tilefarm']:.4g}, Cycles "
                      f"{under['cycles']:.4g} (its radiance {radiance.mean():.4g}; {light_mask.sum()} pixels)")
    if abs(under["tilefarm_visible"] / under["cycles_visible"] - 1.0) > 0.05 \
            or under["cycles_visible"] < 0.5 * radiance.mean():
        failed.append(f"{kind}: the visible light shows {under['tilefarm_visible']:.4g} in tilefarm, "
                      f"{under['cycles_visible']:.4g} in Cycles (its radiance {radiance.mean():.4g})")
    if behind_mask.sum() < 20 or abs(behind["tilefarm"] / behind["cycles"] - 1.0) > 0.03:
        failed.append(f"{kind}: the wall behind the light is {behind['tilefarm']:.4g} in tilefarm, "
                      f"{behind['cycles']:.4g} in Cycles ({behind_mask.sum()} pixels)")
    if not behind["tilefarm_visible"] < 0.7 * behind["cycles"]:
        failed.append(f"{kind}: the shadow check cannot fail: tilefarm's visible (blocking) light leaves the wall "
                      f"behind it at {behind['tilefarm_visible']:.4g} (Cycles, unblocked: {behind['cycles']:.4g})")
    return figures, failed


def main():
    coordinator, work = sys.argv[1], sys.argv[2]
    spp = int(sys.argv[3]) if len(sys.argv) > 3 else 256
    os.makedirs(work, exist_ok=True)
    started = time.perf_counter()
    figures, failed = {"spp": spp, "size": [W, H]}, []
    try:
        figures["export"] = export_checks(work)
    except AssertionError as e:
        failed.append(f"export: {e}")
    for kind in SHAPES:
        figures[kind], problems = compare(coordinator, work, spp, kind)
        failed += problems
    figures["seconds"] = round(time.perf_counter() - started, 1)
    print(json.dumps(figures))
    for why in failed:
        print(f"FAILED {why}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # bpy 4.2 can crash at interpreter shutdown (see compare_cycles.py)
