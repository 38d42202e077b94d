"""tilefarm's environment map against Mitsuba 3's `envmap` (PyPI `mitsuba`, `scalar_rgb`).

The script writes a latitude-longitude radiance map (EXR, 256 × 128, through
`mi.Bitmap`): a sky from blue at the zenith to a lighter blue-white at the horizon, a
little brighter towards one azimuth, dim brown below the horizon, and a sun of 3 × 2
texels, 1,260 times the luminance of the sky beside it, at azimuth −130° and elevation
40° (off every axis, behind the sphere to the left, so that a turned or mirrored map
moves the sun, its highlights and the floor's shadow). Each case is one
sphere over a diffuse floor (a 100 × 100 quad, from the same OBJ file in both renderers)
lit only by that map: a tilefarm scene (`[background] map`, `rotate`) and a Mitsuba scene
dict (`envmap`, `to_world = rotate([0, 1, 0], rotate)`). The camera sees the sky above
the horizon, the floor, the sun's shadow of the sphere on it and the sphere. Y is up.
Both renders: 96 × 64, the same spp (1,024; case c 4,096), a one-pixel box filter,
`max_depth` 8, Mitsuba's `path` integrator and `independent` sampler; about 35 s for all
four cases on one core.

Checks, per case, as `compare_materials.py` makes them (its statistics are imported
from it): each channel's image mean within 1 %, and every 8 × 8-pixel block within its
noise: z = (tilefarm − Mitsuba) / sqrt(var_t + var_m) per block and channel, var_t from
tilefarm's variance layer (`--aovs`), var_m from Mitsuba's spread over PASSES passes;
|z| under the Bonferroni bound for the case's blocks × channels at a family-wise
false-alarm rate of ALPHA, and the rms of z under its chi-square bound. The noise floor
is the same figures for Mitsuba's first half of passes against its second half.

Cases (`--cases`, default all):
  a  a diffuse sphere
  b  white GGX metal, roughness 0.5 (tilefarm Principled, metallic 1, distribution ggx;
     Mitsuba roughconductor, material none, alpha = 0.25)
  c  a mirror sphere (tilefarm `illum 3`, `Ks 1 1 1`; Mitsuba conductor, material none)
  d  case a with the map turned: tilefarm `rotate = 90`, Mitsuba
     `to_world = rotate([0, 1, 0], 90)` (the sun then stands in front, to the left, and
     the shadow falls behind the sphere, to the right; turned the other way it would
     fall in front, to the left)

`--probe` renders, instead, a mirror sphere under a map that is black but for one
bright texel (the sun's), with both renderers, and prints where the highlight is in each
image (for finding an orientation mismatch).

What the bounds catch, measured by giving tilefarm's scene a fault against the same
Mitsuba render (1,024 spp): the sky seen directly above the horizon is exact but for
pixel jitter, so any turn, mirror or scale of the map shows there first — a turn of
1° (case c: |z| 1,032), 3° (a: 3,097), strength 1.02 (a: 9,002, means +2 %), the map's
columns reversed (a: 55,454) or shifted a row (c: 1,695), `rotate = -90` for 90 (d:
175,764, means −13 %); and in the lit part, roughness 0.55 for 0.5 (b: |z| 22.7, rms z
3.3, means −0.5 %).

Prints one JSON line of figures; exits non-zero naming the failed cases.

    python tests/mitsuba/compare_envmap.py COORDINATOR_EXE WORK_DIR [--cases a,b] [--spp N]
        [--print-scenes] [--probe]
"""

import argparse
import json
import math
import os
import pprint
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import compare_materials as cm  # noqa: E402  (also sets Mitsuba's variant, scalar_rgb)
from compare_materials import mi  # noqa: E402

W, H = 96, 64
MAX_DEPTH = 8
SPP = 1024  # case c: SPP × its spp_factor
PASSES = cm.PASSES  # Mitsuba renders spp / PASSES samples PASSES times, with different seeds
MEAN_TOLERANCE = 0.01

# --------------------------------------------------------------------------------------
# The map. Mitsuba's envmap (and tilefarm's, README "Environment maps") looks a unit
# direction d (map frame, +Y up) up at u = 1/2 − atan2(d.x, d.z)/2π, v = acos(d.y)/π:
# column u·W − 1/2, row v·(H − 1), bilinearly; row 0 is the zenith.
# --------------------------------------------------------------------------------------

MAP_W, MAP_H = 256, 128
ZENITH = np.array([0.30, 0.50, 1.00])
HORIZON = np.array([0.85, 0.92, 1.05])
GROUND = np.array([0.12, 0.085, 0.05])
SUN_AZIMUTH = -130.0  # degrees, from +Z towards +X
SUN_ELEVATION = 40.0
SUN = np.array([700.0, 630.0, 520.0])  # radiance of its texels (figures: sun_to_sky)
SUN_TEXELS = (3, 2)  # columns × rows


def direction(azimuth, elevation):
    a, e = math.radians(azimuth), math.radians(elevation)
    return np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])


def texel_of(d):
    """The (column, row) position, continuous, that the lookup gives direction d."""
    d = np.asarray(d, dtype=np.float64) / np.linalg.norm(d)
    u = (0.5 - math.atan2(d[0], d[2]) / (2 * math.pi)) % 1.0
    v = math.acos(max(-1.0, min(1.0, d[1]))) / math.pi
    return u * MAP_W - 0.5, v * (MAP_H - 1)


def sun_texels():
    """The sun's texels (row, column): a SUN_TEXELS block around the sun's direction."""
    col, row = texel_of(direction(SUN_AZIMUTH, SUN_ELEVATION))
    c0 = int(round(col - (SUN_TEXELS[0] - 1) / 2))
    r0 = int(round(row - (SUN_TEXELS[1] - 1) / 2))
    return [(r, c % MAP_W) for r in range(r0, r0 + SUN_TEXELS[1]) for c in range(c0, c0 + SUN_TEXELS[0])]


def sky_map():
    rows = np.arange(MAP_H)
    elevation = math.pi / 2 - math.pi * rows / (MAP_H - 1)
    img = np.zeros((MAP_H, MAP_W, 3))
    for i, e in enumerate(elevation):
        if e >= 0:
            t = (1 - math.sin(e)) ** 2  # 0 at the zenith, 1 at the horizon
            img[i, :] = (1 - t) * ZENITH + t * HORIZON
        else:
            img[i, :] = GROUND * (1 - 0.3 * math.sin(-e))
    # A little azimuthal structure, so that a turn shows in the sky as well.
    cols = (np.arange(MAP_W) + 0.5) / MAP_W
    img *= (1 + 0.15 * np.cos(2 * math.pi * (cols - 0.2)))[None, :, None]
    for r, c in sun_texels():
        img[r, c] = SUN
    return img.astype(np.float32)


def luminance(c):
    return 0.2126 * c[..., 0] + 0.7152 * c[..., 1] + 0.0722 * c[..., 2]


def sun_to_sky():
    """The sun's luminance over the mean luminance of the sky texels beside it."""
    img = sky_map()
    rows = sorted({r for r, _ in sun_texels()})
    cols = sorted({c for _, c in sun_texels()})
    beside = [img[r, (c + k) % MAP_W] for r in rows for c in (cols[0], cols[-1]) for k in (-3, 3)]
    return float(luminance(SUN) / luminance(np.array(beside)).mean())


def probe_map():
    """Black but for one bright texel, the sun's first."""
    img = np.zeros((MAP_H, MAP_W, 3), dtype=np.float32)
    r, c = sun_texels()[0]
    img[r, c] = SUN
    return img


def write_map(path, img):
    # Bitmap.write is synchronous (see compare_materials.py on the asynchronous writer).
    mi.Bitmap(img).write(path)


# --------------------------------------------------------------------------------------
# The stage
# --------------------------------------------------------------------------------------

CAMERA = {"position": [0.0, 1.6, 5.0], "look_at": [0.3, 0.7, 0.0], "up": [0.0, 1.0, 0.0], "fov": 40.0}
SPHERE = {"center": [0.0, 0.7, 0.0], "radius": 0.7}
FLOOR_KD = [0.5, 0.48, 0.45]
FLOOR_HALF = 50.0


def write_floor(folder):
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, "floor.mtl"), "w") as f:
        f.write("newmtl Floor\nKd " + " ".join(map(str, FLOOR_KD)) + "\n")
    s = FLOOR_HALF
    tris = cm.quad((-s, 0.0, s), (s, 0.0, s), (s, 0.0, -s), (-s, 0.0, -s))
    cm.check_facing(tris, [0, 1, 0])
    lines = ["mtllib floor.mtl", "usemtl Floor"]
    for tri in tris:
        lines += ["v " + " ".join(f"{c:g}" for c in p) for p in tri]
    lines += [f"f {3 * k + 1} {3 * k + 2} {3 * k + 3}" for k in range(len(tris))]
    with open(os.path.join(folder, "floor.obj"), "w") as f:
        f.write("\n".join(lines) + "\n")
    return "floor.obj"


DIFFUSE = {
    "tilefarm_sphere": {"kd": [0.6, 0.5, 0.4]},
    "tilefarm_materials": {},
    "mitsuba_bsdf": {
        "type": "twosided",
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.5, 0.4]}},
    },
}

MIRROR = {
    "tilefarm_sphere": {"ks": [1.0, 1.0, 1.0], "illum": 3},
    "tilefarm_materials": {},
    "mitsuba_bsdf": {"type": "conductor", "material": "none"},
}

CASES = {
    "a": {"title": "diffuse sphere", "rotate": 0.0, **DIFFUSE},
    "b": {
        "title": "white GGX metal, roughness 0.5",
        "rotate": 0.0,
        "tilefarm_sphere": {"material": "Metal"},
        "tilefarm_materials": {
            "Metal": {"base_color": [1.0, 1.0, 1.0], "metallic": 1.0, "roughness": 0.5, "distribution": "ggx"}
        },
        "mitsuba_bsdf": {
            "type": "roughconductor",
            "material": "none",
            "distribution": "ggx",
            "alpha": 0.25,
            "sample_visible": True,
        },
    },
    # The sun's reflection in the mirror is a fraction of a pixel about a thousand times
    # brighter than the rest: the four pixels it lies across hold nine tenths of the
    # image mean's variance, whose standard error was 0.3 % at 1,024 spp. 4 × the spp
    # brings it to 0.13 %, seven of them inside the 1 % bound.
    "c": {"title": "mirror sphere", "rotate": 0.0, "spp_factor": 4, **MIRROR},
    "d": {"title": "diffuse sphere, map turned 90 degrees", "rotate": 90.0, **DIFFUSE},
}


def tilefarm_scene(case, spp, floor_obj, map_file):
    lines = cm.toml_table("camera", {**CAMERA, "width": W, "height": H})
    lines += cm.toml_table("render", {"spp": spp, "max_depth": MAX_DEPTH, "seed": 0})
    lines += ["[[mesh]]", f"obj = {cm.toml_value(floor_obj)}", ""]
    lines += ["[[sphere]]"]
    lines += [f"{k} = {cm.toml_value(v)}" for k, v in {**SPHERE, **case["tilefarm_sphere"]}.items()] + [""]
    lines += cm.toml_table("background", {"map": map_file, "strength": 1.0, "rotate": case["rotate"], "up": "y"})
    for name, m in case["tilefarm_materials"].items():
        lines += cm.toml_table(f"materials.{name}", m)
    return "\n".join(lines)


def envmap_to_world(rotate):
    return mi.ScalarTransform4f().rotate([0.0, 1.0, 0.0], rotate)


def mitsuba_scene(case, spp, folder, floor_obj, map_file):
    film = {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}, "pixel_format": "rgb"}
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": MAX_DEPTH},
        "sensor": {
            "type": "perspective",
            "fov_axis": "y",
            "fov": CAMERA["fov"],
            "to_world": mi.ScalarTransform4f().look_at(
                origin=CAMERA["position"], target=CAMERA["look_at"], up=CAMERA["up"]
            ),
            "film": film,
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "floor": {
            "type": "obj",
            "filename": os.path.join(folder, floor_obj),
            "face_normals": True,
            "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": cm.rgb(FLOOR_KD)}},
        },
        "sphere": {"type": "sphere", "center": SPHERE["center"], "radius": SPHERE["radius"],
                   "bsdf": case["mitsuba_bsdf"]},
        "environment": {
            "type": "envmap",
            "filename": os.path.join(folder, map_file),
            "scale": 1.0,
            "to_world": envmap_to_world(case["rotate"]),
        },
    }


# --------------------------------------------------------------------------------------


def prepare_case(key, work, spp, print_scenes):
    """Writes the case's map and two scenes and renders Mitsuba's: (scene path, Mitsuba
    passes, seconds)."""
    case = CASES[key]
    folder = os.path.join(work, f"case-{key}")
    floor_obj = write_floor(folder)
    write_map(os.path.join(folder, "sky.exr"), sky_map())
    scene_path = os.path.join(folder, "scene.toml")
    with open(scene_path, "w") as f:
        f.write(tilefarm_scene(case, spp, floor_obj, "sky.exr"))
    scene_dict = mitsuba_scene(case, spp, folder, floor_obj, "sky.exr")
    if print_scenes:
        with open(scene_path) as f:
            print(f"===== case {key}: {case['title']} =====\n--- {scene_path}\n{f.read()}")
        print(f"--- {folder}/sky.exr: {MAP_W} x {MAP_H}, sun texels (row, column) {sun_texels()}")
        print(f"--- Mitsuba {mi.__version__} scene dict (mi.load_dict)")
        shown = dict(scene_dict, sensor=dict(scene_dict["sensor"], to_world=(
            f"mi.ScalarTransform4f().look_at(origin={CAMERA['position']}, target={CAMERA['look_at']}, "
            f"up={CAMERA['up']})")), environment=dict(scene_dict["environment"], to_world=(
                f"mi.ScalarTransform4f().rotate([0, 1, 0], {case['rotate']})")))
        pprint.pprint(shown, width=110, sort_dicts=False)
        sys.stdout.flush()
    stack, mi_s = cm.render_mitsuba(scene_dict, spp, PASSES)
    return scene_path, stack, mi_s


def run_case(key, exe, work, spp, prepared):
    """tilefarm's render of a prepared case, compared with Mitsuba's: (figures, failures)."""
    case = CASES[key]
    folder = os.path.join(work, f"case-{key}")
    scene_path, stack, mi_s = prepared
    figures = {"title": case["title"]}
    try:
        tf, tf_var, tf_s = cm.render_tilefarm(exe, scene_path, spp, os.path.join(folder, "tilefarm.exr"))
    except cm.TilefarmFailed as e:
        return figures, [f"case {key} ({case['title']}): {e}"]
    mi_img, mi_var = cm.passes_estimate(stack)
    mi.util.write_bitmap(os.path.join(folder, "mitsuba.exr"), mi_img.astype(np.float32), write_async=False)

    cmp = cm.compare(tf, tf_var, mi_img, mi_var)
    half = PASSES // 2
    noise = cm.compare(*cm.passes_estimate(stack[:half]), *cm.passes_estimate(stack[half:]))
    z_max_bound, z_rms_bound = cm.z_bounds(cmp["blocks"])
    ratio = (np.array(cmp["means"][0]) / np.array(cmp["means"][1])).round(5).tolist()
    figures.update({
        "rotate": case["rotate"],
        "spp": spp,
        "tilefarm_s": round(tf_s, 2),
        "mitsuba_s": round(mi_s, 2),
        "means_tilefarm": cmp["means"][0],
        "means_mitsuba": cmp["means"][1],
        "means_ratio": ratio,
        "mean_rel_diff": cmp["mean_rel_diff"],
        "mean_rel_se": cmp["mean_rel_se"],
        "block_z_rms": cmp["block_z_rms"],
        "block_z_max": cmp["block_z_max"],
        "worst_block": cmp["worst_block"],
        "bounds": {"mean_rel": MEAN_TOLERANCE, "z_max": round(z_max_bound, 3), "z_rms": round(z_rms_bound, 3)},
        "noise_floor": {k: noise[k] for k in ("mean_rel_diff", "mean_rel_se", "block_z_rms", "block_z_max")},
    })
    name = f"case {key} ({case['title']})"
    failed = []
    rel = np.array(cmp["mean_rel_diff"])
    if not (rel < MEAN_TOLERANCE).all():
        failed.append(f"{name}: channel means differ by {rel.tolist()} (more than {MEAN_TOLERANCE:.0%}); "
                      f"tilefarm {cmp['means'][0]}, Mitsuba {cmp['means'][1]}")
    if cmp["block_z_max"] > z_max_bound:
        w = cmp["worst_block"]
        failed.append(f"{name}: an 8x8 block differs beyond its noise: |z| {cmp['block_z_max']} > "
                      f"{z_max_bound:.2f} at block row {w['row']}, column {w['col']}, channel {w['channel']} "
                      f"(pixels from y {w['row'] * cm.BLOCK}, x {w['col'] * cm.BLOCK})")
    if cmp["block_z_rms"] > z_rms_bound:
        failed.append(f"{name}: the blocks differ beyond their noise overall: rms z {cmp['block_z_rms']} > "
                      f"{z_rms_bound:.2f}")
    return figures, failed


def highlight(img):
    """Where an image's highlight is: its brightest pixel (row, column), that pixel's
    value (channel sum) and the centroid (row, column, pixel centres) of the pixels
    brighter than a fifth of it."""
    s = img.sum(-1)
    r, c = np.unravel_index(np.argmax(s), s.shape)
    w = np.where(s > 0.2 * s[r, c], s, 0.0)
    rows, cols = np.indices(s.shape) + 0.5
    centroid = [round(float((w * rows).sum() / w.sum()), 2), round(float((w * cols).sum() / w.sum()), 2)]
    return {"brightest": [int(r), int(c)], "value": round(float(s[r, c]), 3), "centroid": centroid}


def probe(exe, work, spp):
    """The orientation probe (module docstring): where each renderer shows the one
    bright texel's reflection in a mirror sphere, unturned and turned 90°."""
    out = {"texel": {"row_col": list(sun_texels()[0])}}
    for rotate in (0.0, 90.0):
        case = {**CASES["c"], "rotate": rotate}
        folder = os.path.join(work, f"probe-{rotate:g}")
        floor_obj = write_floor(folder)
        write_map(os.path.join(folder, "one.exr"), probe_map())
        scene_path = os.path.join(folder, "scene.toml")
        with open(scene_path, "w") as f:
            f.write(tilefarm_scene(case, spp, floor_obj, "one.exr"))
        stack, _ = cm.render_mitsuba(mitsuba_scene(case, spp, folder, floor_obj, "one.exr"), spp, PASSES)
        tf, _, _ = cm.render_tilefarm(exe, scene_path, spp, os.path.join(folder, "tilefarm.exr"))
        mi_img = stack.mean(0)
        mi.util.write_bitmap(os.path.join(folder, "mitsuba.exr"), mi_img.astype(np.float32), write_async=False)
        out[f"rotate {rotate:g}"] = {
            "tilefarm": highlight(tf),
            "mitsuba": highlight(mi_img),
            "means_tilefarm": tf.reshape(-1, 3).mean(0).round(5).tolist(),
            "means_mitsuba": mi_img.reshape(-1, 3).mean(0).round(5).tolist(),
        }
    print(json.dumps(out))
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("coordinator", help="the coordinator executable")
    ap.add_argument("work", help="a folder for the scenes and images")
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated, of " + ",".join(CASES))
    ap.add_argument("--spp", type=int, default=SPP, help=f"samples per pixel (a multiple of {PASSES})")
    ap.add_argument("--print-scenes", action="store_true", help="print each case's two scenes")
    ap.add_argument("--probe", action="store_true", help="locate a single bright texel in both renderers")
    args = ap.parse_args()
    cases = [c for c in args.cases.split(",") if c]
    unknown = [c for c in cases if c not in CASES]
    if unknown or not cases:
        ap.error(f"unknown cases {unknown}: the cases are {', '.join(CASES)}")
    if args.spp % PASSES or args.spp < 2 * PASSES:
        ap.error(f"--spp must be a multiple of {PASSES}, at least {2 * PASSES}")
    if not os.access(args.coordinator, os.X_OK):
        ap.error(f"{args.coordinator} is not an executable")
    os.makedirs(args.work, exist_ok=True)
    if args.probe:
        return probe(args.coordinator, args.work, args.spp)
    start = time.perf_counter()
    figures = {"mitsuba": mi.__version__, "variant": mi.variant(), "size": [W, H], "max_depth": MAX_DEPTH,
               "map": [MAP_W, MAP_H], "sun_texels": sun_texels(), "sun_to_sky": round(sun_to_sky(), 1)}
    failed = []
    spp = {key: args.spp * CASES[key].get("spp_factor", 1) for key in cases}
    prepared = {key: prepare_case(key, args.work, spp[key], args.print_scenes) for key in cases}
    for key in cases:
        t = time.perf_counter()
        figures[key], problems = run_case(key, args.coordinator, args.work, spp[key], prepared[key])
        figures[key]["case_s"] = round(time.perf_counter() - t + prepared[key][2], 2)
        failed += problems
    figures["seconds"] = round(time.perf_counter() - start, 2)
    print(json.dumps(figures))
    if failed:
        print("FAILED: " + "\nFAILED: ".join(failed), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
