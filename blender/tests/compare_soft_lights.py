"""Blender's point and spot Radius and sun Angle as tilefarm's `radius` and `angle`
(issue 50, soft shadows), against Cycles 4.2 (PyPI's bpy; CPU, no denoising, a
one-pixel box filter, no clamping, the same bounces).

First, the export alone: a point light's and a spot's Radius (`shadow_soft_size`) are
written as `radius` (metres), a sun's Angle (radians in bpy) as `angle` (degrees), none
when zero (the hard lights); Soft Falloff off (Cycles' sphere) is one line of the
warning, and nothing says "hard shadows" any more.

Then four scenes, each a white floor under a thin plate raised above it whose straight
edge (along Y) throws a shadow edge that a camera straight above sees across the image
(image x is floor x, image up floor +Y), the plate itself out of view, black world:
- `point`: a point light of radius 0.3 m, 2.5 m up, beside the plate (0.5 m up);
- `spot`: a spot of radius 0.2 m there, its cone's blend crossing the image's top rows;
- `sun`: a sun of Angle 10°, 35° from the zenith;
- `sun_default`: Blender's default sun Angle, 0.526°, over a plate 4 m up (a penumbra of
  a few centimetres: the camera sees 24 cm of floor).
Both renderers render each twice (seeds 1 and 2, the same spp; tilefarm's first with
its variance layer):
- channel means within 2 % of Cycles', and 8 × 8 blocks within their noise (as
  compare_area_lights.py);
- the penumbra: the profile across the shadow edge (each column's mean over a band of
  rows, divided by the unshadowed direct light's fall-off, normalised between the
  umbra's and the lit side's ends), and its width from 10 % to 90 %, in metres on the
  floor. tilefarm's within PENUMBRA_TOLERANCE of Cycles' (see there); the same export
  with half the radius or angle must fail that.
- for `point`, Cycles with Soft Falloff off (a sphere light) is rendered too and its
  means reported (what the export's warning for it says).

Prints one JSON line of figures; exits non-zero on a failure.

    python blender/tests/compare_soft_lights.py COORDINATOR_EXE WORK_DIR [SPP [CASE,CASE…]]
"""

import json
import math
import os
import re
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

import compare_cycles as cc  # noqa: E402
from export_testing import expect  # noqa: E402
from tilefarm_blender.export import export_scene  # noqa: E402

W = 128  # pixels across; each case has its own height
BOUNCES = 6
CAMERA_HEIGHT = 1.5
COLOR = (1.0, 0.9, 0.75)
# The 10 %–90 % penumbra widths may differ by this much (relative). Both renderers see
# the floor through the same pixels and box filter, and the width is measured the same
# way in both, so what is left is noise and the light's model: each renderer's two seeds
# give widths 0.1–0.25 % apart at 256 spp, so 3 % is over ten times the noise, and a
# radius or angle off by more than about 3 % fails (the width is proportional to it:
# half the size gives half the width, which the script checks fails).
PENUMBRA_TOLERANCE = 0.03

# kind: the light's type, its place (or, for a sun, its angle from the zenith, travelling
# towards +X), where it aims (a spot), its Radius or Angle, power or strength, spot size
# and blend; the plate's height; the floor width the camera sees (W pixels) and the
# image's height in pixels; the profile's band of floor y (metres), if not all of it.
CASES = {
    "point": dict(type="POINT", at=(-1.0, 0.0, 2.5), size=0.3, energy=300.0, plate=0.5, field=0.6, height=64),
    # The spot's blend (12.6° to 14.5° from its axis) crosses the image's upper half,
    # widened by the disk's own 4°, as Cycles attenuates each sampled direction; the
    # profile's band, y < −0.1, is at full intensity (spot_cone_check).
    "spot": dict(type="SPOT", at=(-1.0, 0.0, 2.5), aim=(0.25, -0.4, 0.0), size=0.2, energy=600.0,
                 spot_size=math.radians(29.0), spot_blend=0.244, plate=0.5, field=0.6, height=128,
                 band=(-1.0, -0.1)),
    "sun": dict(type="SUN", zenith=35.0, size=math.radians(10.0), energy=3.0, plate=0.5, field=0.6, height=64),
    "sun_default": dict(type="SUN", zenith=35.0, size=None, energy=3.0, plate=4.0, field=0.24, height=64),
}


# Export ------------------------------------------------------------------------------


def lamp(scene, name, kind, at=(0, 0, 3), aim=None, **props):
    ob = bpy.data.objects.new(name, bpy.data.lights.new(name, kind))
    scene.collection.objects.link(ob)
    ob.location = at
    if aim is not None:
        ob.rotation_euler = (mathutils.Vector(aim) - mathutils.Vector(at)).to_track_quat("-Z", "Y").to_euler()
    for k, v in props.items():
        setattr(ob.data, k, v)
    return ob


def export_checks(work):
    """Points, spots and suns with and without a size as written, and the warning's
    lines: returns what was checked."""
    scene = cc.fresh()
    cc.cycles_settings(scene, 16, 1)
    cc.quad("floor", [(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)], cc.principled("white", (0.7, 0.7, 0.7)))
    cc.camera(scene, (0, -5, 2), (0, 0, 0.5))
    # As an artist adds them (Add › Light): Blender's defaults.
    added = {}
    for kind in ("POINT", "SUN"):
        bpy.ops.object.light_add(type=kind, location=(0, 0, 3))
        added[kind] = bpy.context.object
        added[kind].name = f"added_{kind.lower()}"
    lamp(scene, "point", "POINT", (1, 0, 2), shadow_soft_size=0.3, energy=100.0)
    lamp(scene, "hard", "POINT", (-1, 0, 2), shadow_soft_size=0.0)
    lamp(scene, "sphere", "POINT", (0, 1, 2), shadow_soft_size=0.25, use_soft_falloff=False)
    lamp(scene, "hard_sphere", "POINT", (0, -1, 2), shadow_soft_size=0.0, use_soft_falloff=False)
    lamp(scene, "spot", "SPOT", (2, 0, 2), aim=(2, 0, 0), shadow_soft_size=0.2, spot_size=math.radians(50),
         spot_blend=0.25)
    lamp(scene, "sun", "SUN", angle=math.radians(10.0))
    lamp(scene, "hard_sun", "SUN", angle=0.0)
    lamp(scene, "wide_sun", "SUN", angle=math.pi)
    folder = os.path.join(work, "export")
    report = export_scene(folder, scene)
    with open(os.path.join(folder, "scene.toml"), encoding="utf-8") as f:
        text = f.read()
    # Each light's table, by the `# NAME` comment the exporter writes under [[light]].
    by_name = {}
    for chunk in text.split("[[light]]")[1:]:
        name = chunk.split("\n")[1].lstrip("# ").strip()
        by_name[name] = tomllib.loads(chunk.split("\n[")[0])
    lights = tomllib.loads(text)["light"]
    assert len(lights) == len(by_name) == 10, f"{len(lights)} lights written: {sorted(by_name)}"
    default_point = added["POINT"].data
    want = {
        "point": ("point", "radius", 0.3),
        "hard": ("point", "radius", None),
        "sphere": ("point", "radius", 0.25),
        "hard_sphere": ("point", "radius", None),
        "spot": ("spot", "radius", 0.2),
        "sun": ("directional", "angle", 10.0),
        "hard_sun": ("directional", "angle", None),
        "wide_sun": ("directional", "angle", 179.99),
        # As Add › Light makes them in bpy 4.2: a point light's Radius (0 there; the
        # startup scene's Light has 0.1 m, below) and a sun's Angle (0.526°).
        "added_point": ("point", "radius", default_point.shadow_soft_size or None),
        "added_sun": ("directional", "angle", math.degrees(added["SUN"].data.angle)),
    }
    for name, (kind, key, value) in want.items():
        light = by_name[name]
        assert light["type"] == kind, f"{name}: type {light['type']}, expected {kind}"
        if value is None:
            assert key not in light, f"{name}: {key} written for a hard light: {light}"
        else:
            expect(f"{name}.{key}", light.get(key), value, 1e-6)
    expect("added_sun.angle (Blender's default)", by_name["added_sun"]["angle"], 0.526, 1e-3)
    # The spot keeps its cone: half the spot size, the blend's full-intensity angle.
    expect("spot.cone_angle", by_name["spot"]["cone_angle"], 25.0, 1e-6)
    cos_half = math.cos(math.radians(25.0))
    full = math.degrees(math.acos(cos_half + (1.0 - cos_half) * 0.25))
    expect("spot.falloff_start", by_name["spot"]["falloff_start"], full, 1e-5)
    expect("point.intensity", by_name["point"]["intensity"], [100.0 / (4.0 * math.pi)] * 3, 1e-6)
    lines = report.warnings
    assert not [w for w in lines if "hard shadows" in w], f"a size still reported as hard shadows: {lines}"
    soft_off = [w for w in lines if "Soft Falloff off" in w]
    assert len(soft_off) == 1 and soft_off[0].startswith("light sphere: "), \
        f"Soft Falloff off: one line, for the light with a radius: {lines}"
    assert any(w.startswith("light wide_sun: ") and "179.99" in w for w in lines), f"wide_sun: {lines}"
    quiet = [w for w in lines if w.split(":")[0] not in {"light sphere", "light wide_sun"}]
    assert not quiet, f"warnings about lights that map exactly: {quiet}"
    checked = {"lights": len(lights), "warnings": lines, "added_point_radius": default_point.shadow_soft_size}

    # Blender's startup scene (the cube): its Light, a 1,000 W point light of Radius
    # 0.1 m with Soft Falloff, exports with that radius and nothing to report.
    bpy.ops.wm.read_factory_settings()
    folder = os.path.join(work, "startup")
    report = export_scene(folder, bpy.context.scene)
    with open(os.path.join(folder, "scene.toml"), "rb") as f:
        (light,) = tomllib.load(f)["light"]
    assert light["type"] == "point", light
    expect("the startup scene's Light: radius", light.get("radius"), 0.1, 1e-6)
    expect("the startup scene's Light: intensity", light["intensity"], [1000.0 / (4.0 * math.pi)] * 3, 1e-6)
    assert not [w for w in report.warnings if w.startswith("light")], report.warnings
    checked["startup_light"] = light
    return checked


# Renders -----------------------------------------------------------------------------


def shadow_edge(case):
    """Where the plate's edge (x = 0, at the plate's height) throws its shadow on the
    floor (from the light's centre): x in metres."""
    h = case["plate"]
    if case["type"] == "SUN":
        return h * math.tan(math.radians(case["zenith"]))
    lx, _, lz = case["at"]
    return lx + (0.0 - lx) * lz / (lz - h)


def build(kind, soft_falloff=True):
    """The floor, the plate (a thin box over x < 0 at the case's height), the light, and
    a camera straight above the shadow's edge seeing `field` metres of floor across."""
    case = CASES[kind]
    scene = cc.fresh()
    white = cc.principled("white", (0.7, 0.7, 0.7))
    edge = shadow_edge(case)
    cc.quad("floor", [(edge - 6, -6, 0), (edge + 6, -6, 0), (edge + 6, 6, 0), (edge - 6, 6, 0)], white)
    h, thick = case["plate"], 0.02
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(-2.0, 0.0, h + thick / 2), scale=(4.0, 6.0, thick))
    bpy.context.object.name = "plate"
    bpy.context.object.data.materials.append(cc.principled("grey", (0.5, 0.5, 0.5)))
    if case["type"] == "SUN":
        z = math.radians(case["zenith"])
        travel = mathutils.Vector((math.sin(z), 0.0, -math.cos(z)))
        light = lamp(scene, "sun", "SUN", (0, 0, 5), energy=case["energy"], color=COLOR)
        light.rotation_euler = travel.to_track_quat("-Z", "Y").to_euler()
        if case["size"] is not None:
            light.data.angle = case["size"]
    else:
        aim = case.get("aim", (edge, 0.0, 0.0))
        light = lamp(scene, kind, case["type"], case["at"], aim=aim, energy=case["energy"], color=COLOR,
                     shadow_soft_size=case["size"], use_soft_falloff=soft_falloff)
        if case["type"] == "SPOT":
            light.data.spot_size, light.data.spot_blend = case["spot_size"], case["spot_blend"]
    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    scene.world = world
    cam = cc.camera(scene, (edge, 0.0, CAMERA_HEIGHT), (edge, 0.0, 0.0))
    cam.rotation_euler = (0.0, 0.0, 0.0)  # straight down, +Y up: image x is floor x
    cam.data.sensor_fit = "HORIZONTAL"
    cam.data.lens = cam.data.sensor_width * CAMERA_HEIGHT / case["field"]
    settings(scene, case, 16, 1)
    bpy.context.view_layer.update()
    return scene, light


def settings(scene, case, spp, seed):
    cc.cycles_settings(scene, spp, seed)
    c = scene.cycles
    c.max_bounces = c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = BOUNCES
    c.blur_glossy = 0.0
    scene.render.resolution_x, scene.render.resolution_y = W, case["height"]


def floor_points(case):
    """Each pixel's centre on the floor: x, y (rows top to bottom), and its width in
    metres."""
    h, px = case["height"], case["field"] / W
    x = shadow_edge(case) + (np.arange(W) + 0.5 - W / 2) * px
    y = (h / 2 - np.arange(h) - 0.5) * px
    return np.broadcast_to(x, (h, W)), np.broadcast_to(y[:, None], (h, W)), px


def band(case):
    """The rows of the profile: those whose floor y is in the case's band."""
    _, y, _ = floor_points(case)
    lo, hi = case.get("band", (-math.inf, math.inf))
    return (y[:, 0] >= lo) & (y[:, 0] <= hi)


def unshadowed(case, light_at):
    """The direct light's fall-off over the floor without the plate (up to a constant):
    1 for a sun; the facing disk's cos θ / (d² + r²) for a point light or spot at
    `light_at`."""
    x, y, _ = floor_points(case)
    if case["type"] == "SUN":
        return np.ones_like(x)
    lx, ly, lz = light_at
    d2 = (x - lx) ** 2 + (y - ly) ** 2 + lz * lz
    return (lz / np.sqrt(d2)) / (d2 + case["size"] ** 2)


def spot_cone_check(case, light):
    """The spot's attenuation is full over the profile's rows (their angle from the axis,
    plus the disk's angular radius, inside the blend's full angle), and the cone's edge
    is in the image (some pixel's centre direction beyond it): the angles, degrees."""
    x, y, _ = floor_points(case)
    p = np.stack([x, y, np.zeros_like(x)], -1)
    at = np.array(light.matrix_world.translation)
    axis = -np.array(light.matrix_world.to_3x3().col[2])
    d = p - at
    dist = np.linalg.norm(d, axis=-1)
    angle = np.degrees(np.arccos(np.clip((d @ axis) / dist, -1, 1)))
    widened = angle + np.degrees(np.arctan(case["size"] / dist))
    half = math.degrees(case["spot_size"]) / 2
    cos_half = math.cos(math.radians(half))
    full = math.degrees(math.acos(cos_half + (1 - cos_half) * case["spot_blend"]))
    return {"profile_rows_max_deg": round(float(widened[band(case)].max()), 2), "full_deg": round(full, 2),
            "image_max_deg": round(float(angle.max()), 2), "cone_deg": round(half, 2)}


def penumbra(img, case, light_at):
    """The profile across the shadow edge and its 10 %–90 % width in metres."""
    lum = img.mean(-1) / unshadowed(case, light_at)
    prof = lum[band(case)].mean(0)
    k = 6
    lo, hi = prof[:k].mean(), prof[-k:].mean()
    f = (prof - lo) / (hi - lo)

    def crossing(level):
        i = int(np.argmax(f >= level))
        if i == 0:
            return float("nan")
        return i - 1 + (level - f[i - 1]) / (f[i] - f[i - 1])

    px = case["field"] / W
    x10, x90 = crossing(0.1), crossing(0.9)
    return {"width_m": (x90 - x10) * px, "x10_m": x10 * px, "x90_m": x90 * px, "contrast": hi / max(lo, 1e-9),
            "profile": f}


def render_cycles(scene, case, spp, seed, path):
    settings(scene, case, spp, seed)
    t = time.perf_counter()
    cc.cycles(scene, path)
    return cc.pixels(path), time.perf_counter() - t


def render_tilefarm(coordinator, folder, path, spp, seed, toml="scene.toml"):
    t = time.perf_counter()
    cmd = [coordinator, "render", os.path.join(folder, toml), "-q", "--spp", str(spp), "--seed", str(seed),
           "--aovs", "--local-workers", "0", "--tile", "16", "-o", path]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    if run.returncode != 0:
        raise SystemExit(f"tilefarm render failed: {run.stderr}")
    return cc.pixels(path), time.perf_counter() - t


def halved(folder, kind):
    """The export's scene.toml with the light's radius or angle halved, beside it."""
    with open(os.path.join(folder, "scene.toml"), encoding="utf-8") as f:
        text = f.read()
    key = "angle" if CASES[kind]["type"] == "SUN" else "radius"
    out, n = re.subn(rf"^{key} = (\S+)$", lambda m: f"{key} = {float(m.group(1)) / 2:.9g}", text, flags=re.M)
    assert n == 1, f"{kind}: {n} {key} lines in the export"
    with open(os.path.join(folder, "half.toml"), "w", encoding="utf-8") as f:
        f.write(out)
    return "half.toml"


def compare(coordinator, work, spp, kind):
    case = CASES[kind]
    figures, failed = {}, []
    path = lambda what: os.path.join(work, f"{kind}-{what}.exr")  # noqa: E731
    scene, light = build(kind)
    at = tuple(light.matrix_world.translation)
    folder = os.path.join(work, kind)
    report = export_scene(folder, scene)
    figures["warnings"] = report.warnings
    with open(os.path.join(folder, "scene.toml"), "rb") as f:
        figures["light"] = {k: v for k, v in tomllib.load(f)["light"][0].items() if k in {"radius", "angle", "type"}}
    if case["type"] == "SPOT":
        figures["cone"] = cone = spot_cone_check(case, light)
        if not (cone["profile_rows_max_deg"] < cone["full_deg"] and cone["image_max_deg"] > cone["cone_deg"]):
            failed.append(f"{kind}: the scene is not as meant (the profile's rows at full intensity, the cone's "
                          f"edge in the image): {cone}")
    cy1, t_cy = render_cycles(scene, case, spp, 1, path("cycles1"))
    cy2, _ = render_cycles(scene, case, spp, 2, path("cycles2"))
    tf1, t_tf = render_tilefarm(coordinator, folder, path("tilefarm1"), spp, 1)
    tf2, _ = render_tilefarm(coordinator, folder, path("tilefarm2"), spp, 2)
    var = cc.layer(path("tilefarm1"), "variance")
    figures["seconds"] = {"cycles": round(t_cy, 2), "tilefarm": round(t_tf, 2)}

    means_cy, _ = cc.means_and_blocks(kind, cy1, cy2, tf1, tf2, var, figures, failed)

    # The penumbra, each seed alone and both together.
    p = {name: penumbra(img, case, at) for name, img in
         [("cycles", (cy1 + cy2) / 2), ("tilefarm", (tf1 + tf2) / 2), ("cycles1", cy1), ("cycles2", cy2),
          ("tilefarm1", tf1), ("tilefarm2", tf2)]}
    half_toml = halved(folder, kind)
    tfh, _ = render_tilefarm(coordinator, folder, path("tilefarm-half"), spp, 1, half_toml)
    p["tilefarm_half"] = penumbra(tfh, case, at)
    mm = lambda v: round(1000.0 * v, 2)  # noqa: E731
    w_cy, w_tf, w_half = p["cycles"]["width_m"], p["tilefarm"]["width_m"], p["tilefarm_half"]["width_m"]
    figures["penumbra_mm"] = {
        "cycles": mm(w_cy), "tilefarm": mm(w_tf), "tilefarm_half_size": mm(w_half),
        "cycles_seeds": [mm(p["cycles1"]["width_m"]), mm(p["cycles2"]["width_m"])],
        "tilefarm_seeds": [mm(p["tilefarm1"]["width_m"]), mm(p["tilefarm2"]["width_m"])],
        "x10_x90_cycles": [mm(p["cycles"]["x10_m"]), mm(p["cycles"]["x90_m"])],
        "x10_x90_tilefarm": [mm(p["tilefarm"]["x10_m"]), mm(p["tilefarm"]["x90_m"])],
        "pixel": mm(case["field"] / W),
    }
    figures["penumbra_ratio"] = round(w_tf / w_cy, 4)
    figures["penumbra_ratio_half_size"] = round(w_half / w_cy, 4)
    figures["contrast"] = round(p["cycles"]["contrast"], 1)
    if not abs(w_tf / w_cy - 1.0) <= PENUMBRA_TOLERANCE:
        failed.append(f"{kind}: the penumbra is {mm(w_tf)} mm wide (10–90 %) in tilefarm, {mm(w_cy)} mm in Cycles")
    if not abs(w_half / w_cy - 1.0) > PENUMBRA_TOLERANCE:
        failed.append(f"{kind}: the penumbra check cannot fail: half the size gives {mm(w_half)} mm against "
                      f"Cycles' {mm(w_cy)} mm")
    edge = np.abs(p["tilefarm"]["profile"] - p["cycles"]["profile"]).max()
    figures["profile_max_diff"] = round(float(edge), 4)

    if case["type"] == "POINT":
        # Soft Falloff off: Cycles' sphere light (the export's warning), reported.
        sphere_scene, _ = build(kind, soft_falloff=False)
        cys, _ = render_cycles(sphere_scene, case, spp, 1, path("cycles-sphere"))
        figures["cycles_sphere_over_disk_means"] = (cys.reshape(-1, 3).mean(0) / means_cy).round(4).tolist()
        figures["penumbra_mm"]["cycles_sphere"] = mm(penumbra(cys, case, at)["width_m"])
    return figures, failed


def main():
    coordinator, work = sys.argv[1], sys.argv[2]
    spp = int(sys.argv[3]) if len(sys.argv) > 3 else 256
    kinds = sys.argv[4].split(",") if len(sys.argv) > 4 else list(CASES)
    os.makedirs(work, exist_ok=True)
    started = time.perf_counter()
    figures, failed = {"spp": spp, "width": W, "penumbra_tolerance": PENUMBRA_TOLERANCE}, []
    try:
        figures["export"] = export_checks(work)
    except AssertionError as e:
        failed.append(f"export: {e}")
    for kind in kinds:
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
