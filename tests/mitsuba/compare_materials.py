"""tilefarm's materials against Mitsuba 3 (PyPI `mitsuba`, variant `scalar_rgb`).

Each case is one sphere on a stage built twice from the same numbers: a tilefarm scene
(TOML + OBJ/MTL, an inline sphere) and a Mitsuba scene dict (`load_dict`, the same OBJ
files). The stage has structure for reflection and refraction to show, and no textures:
a two-coloured checkered floor, a striped back wall, a one-sided emissive panel (an area
light in both), a constant environment (`[background] radiance` = Mitsuba's `constant`
emitter) and, but for case b, a point light (W/sr in both). Y is up. Both renders:
64 × 64, the same spp, a one-pixel box filter, the same `max_depth` (tilefarm's follows
Mitsuba's `path` integrator), Mitsuba's `independent` sampler.

Checks, per case: each channel's image mean within 1 %, and every 8 × 8-pixel block's
mean within its noise: z = (tilefarm − Mitsuba) / sqrt(var_t + var_m) per block and
channel, where var_t comes from tilefarm's variance layer (`--aovs`) and var_m from
Mitsuba's spread over PASSES independent passes; |z| must stay under the Bonferroni
bound for the case's blocks × channels at a family-wise false-alarm rate of ALPHA, and
the rms of z under its chi-square bound at the same rate. The noise floor is the same
figures for Mitsuba's first half of passes against its second half (what noise alone
gives, at half the samples on each side).

Cases (`--cases`, default all):
  a  a diffuse sphere (tilefarm's Lambertian `kd`; the stage is Lambertian too)
  b  white GGX metal, roughness 0.1   (tilefarm Principled, metallic 1, distribution ggx;
  c  white GGX metal, roughness 0.3    Mitsuba roughconductor, material none, alpha = r²)
  d  rough glass, IOR 1.5, roughness 0.5 (Principled transmission 1 / roughdielectric)

Mitsuba writes its images synchronously: its default asynchronous EXR writer was seen to
hang the next EXR read in the same process (3.9.1).
Prints one JSON line of figures; exits non-zero naming the failed cases.

    python tests/mitsuba/compare_materials.py COORDINATOR_EXE WORK_DIR [--cases a,b] [--spp N]
        [--print-scenes]
"""

import argparse
import json
import math
import os
import pprint
import subprocess
import sys
import time
from statistics import NormalDist

import numpy as np

import mitsuba as mi

mi.set_variant("scalar_rgb")

W = H = 64
MAX_DEPTH = 8
SPP = 512
PASSES = 8  # Mitsuba renders spp / PASSES samples PASSES times, with different seeds
BLOCK = 8
MEAN_TOLERANCE = 0.01
ALPHA = 1e-3  # family-wise false-alarm rate of each case's block test

# --------------------------------------------------------------------------------------
# The stage, Y up. Numbers only; both renderers' scenes are written from them.
# --------------------------------------------------------------------------------------

CAMERA = {"position": [0.0, 1.5, 4.2], "look_at": [0.0, 0.75, 0.0], "up": [0.0, 1.0, 0.0], "fov": 38.0}
SPHERE = {"center": [0.0, 0.9, 0.0], "radius": 0.85}
POINT_LIGHT = {"position": [2.0, 4.0, 3.0], "intensity": [18.0, 16.0, 13.0]}
BACKGROUND = [0.25, 0.3, 0.4]
# Lambertian stage materials (MTL name -> Kd), and the emissive panel's radiance.
STAGE_KD = {
    "FloorCream": [0.75, 0.7, 0.6],
    "FloorBlue": [0.1, 0.2, 0.45],
    "WallRed": [0.7, 0.12, 0.08],
    "WallWhite": [0.8, 0.8, 0.8],
}
PANEL_KE = [6.0, 6.0, 7.0]


def quad(a, b, c, d):
    """Two triangles of the quad a b c d, counter-clockwise seen from its front (both
    renderers' front face), as lists of corners."""
    return [(a, b, c), (a, c, d)]


def stage_geometry():
    """Material name -> triangles: the floor (y = 0, facing +Y) in 1 × 1 checks, the back
    wall (z = −2.5, facing +Z) in 0.5-wide vertical stripes, and the panel (y = 3, facing
    −Y) up to the left of the sphere, where the metal sphere reflects it."""
    tris = {name: [] for name in list(STAGE_KD) + ["Panel"]}
    for i, x in enumerate(range(-4, 4)):
        for j, z in enumerate(np.arange(-2.5, 3.5, 1.0)):
            name = "FloorCream" if (i + j) % 2 == 0 else "FloorBlue"
            z = float(z)
            tris[name] += quad((x, 0.0, z + 1), (x + 1, 0.0, z + 1), (x + 1, 0.0, z), (x, 0.0, z))
    for k in range(16):
        x = -4.0 + 0.5 * k
        name = "WallRed" if k % 2 == 0 else "WallWhite"
        tris[name] += quad((x, 0.0, -2.5), (x + 0.5, 0.0, -2.5), (x + 0.5, 3.0, -2.5), (x, 3.0, -2.5))
    tris["Panel"] += quad((-2.2, 3.0, -0.5), (-1.2, 3.0, -0.5), (-1.2, 3.0, 0.5), (-2.2, 3.0, 0.5))
    return tris


def check_facing(tris, want):
    for a, b, c in tris:
        n = np.cross(np.subtract(b, a), np.subtract(c, a))
        assert np.dot(n, want) > 0, f"a triangle faces {n}, not {want}"


# --------------------------------------------------------------------------------------
# The cases: the sphere's material in each renderer.
# --------------------------------------------------------------------------------------


def metal(r, point_light):
    return {
        "title": f"white GGX metal, roughness {r}",
        "point_light": point_light,
        "tilefarm_sphere": {"material": "White"},
        "tilefarm_materials": {
            "White": {"base_color": [1.0, 1.0, 1.0], "metallic": 1.0, "roughness": r, "distribution": "ggx"}
        },
        "mitsuba_bsdf": {
            "type": "roughconductor",
            "material": "none",
            "distribution": "ggx",
            "alpha": round(r * r, 6),
            "sample_visible": True,
        },
    }


CASES = {
    "a": {
        "title": "diffuse sphere",
        "point_light": True,
        "tilefarm_sphere": {"kd": [0.6, 0.5, 0.4]},
        "tilefarm_materials": {},
        "mitsuba_bsdf": {
            "type": "twosided",
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.5, 0.4]}},
        },
    },
    # A point light's highlight on metal this smooth is a spot far smaller than a pixel
    # holding a third of the image's light: with Mitsuba's independent sampler the image
    # mean's standard error was over 1 % at 512 spp. The panel's reflection tests the
    # sharp lobe instead, through both light sampling and BSDF sampling.
    "b": metal(0.1, point_light=False),
    "c": metal(0.3, point_light=True),
    "d": {
        "title": "rough glass, IOR 1.5, roughness 0.5",
        "point_light": True,
        "tilefarm_sphere": {"material": "Glass"},
        "tilefarm_materials": {
            "Glass": {
                "base_color": [1.0, 1.0, 1.0],
                "transmission": 1.0,
                "ior": 1.5,
                "roughness": 0.5,
                "distribution": "ggx",
            }
        },
        "mitsuba_bsdf": {
            "type": "roughdielectric",
            "int_ior": 1.5,
            "ext_ior": 1.0,
            "distribution": "ggx",
            "alpha": 0.25,
            "sample_visible": True,
        },
    },
}


# --------------------------------------------------------------------------------------
# Writing the two scenes
# --------------------------------------------------------------------------------------


def toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return repr(float(v)) if isinstance(v, float) else str(v)


def toml_table(header, d):
    return [f"[{header}]"] + [f"{k} = {toml_value(v)}" for k, v in d.items()] + [""]


def write_stage(folder):
    """The stage's OBJ files (one per material, so that Mitsuba, which takes one BSDF per
    shape, loads the same files) and their MTL. Returns the OBJ names by material."""
    os.makedirs(folder, exist_ok=True)
    mtl = []
    for name, kd in STAGE_KD.items():
        mtl += [f"newmtl {name}", "Kd " + " ".join(map(str, kd)), ""]
    mtl += ["newmtl Panel", "Kd 0 0 0", "Ke " + " ".join(map(str, PANEL_KE)), ""]
    with open(os.path.join(folder, "stage.mtl"), "w") as f:
        f.write("\n".join(mtl))
    objs = {}
    for name, tris in stage_geometry().items():
        check_facing(tris, [0, -1, 0] if name == "Panel" else [0, 0, 1] if name.startswith("Wall") else [0, 1, 0])
        lines = ["mtllib stage.mtl", f"usemtl {name}"]
        for tri in tris:
            lines += ["v " + " ".join(f"{c:g}" for c in p) for p in tri]
        lines += [f"f {3 * k + 1} {3 * k + 2} {3 * k + 3}" for k in range(len(tris))]
        objs[name] = f"{name.lower()}.obj"
        with open(os.path.join(folder, objs[name]), "w") as f:
            f.write("\n".join(lines) + "\n")
    return objs


def tilefarm_scene(case, spp, objs):
    lines = toml_table("camera", {**CAMERA, "width": W, "height": H})
    lines += toml_table("render", {"spp": spp, "max_depth": MAX_DEPTH, "seed": 0})
    for obj in objs.values():
        lines += ["[[mesh]]", f"obj = {toml_value(obj)}", ""]
    lines += ["[[sphere]]"] + [f"{k} = {toml_value(v)}" for k, v in {**SPHERE, **case["tilefarm_sphere"]}.items()]
    lines += [""]
    if case["point_light"]:
        lines += ["[[light]]", 'type = "point"']
        lines += [f"{k} = {toml_value(v)}" for k, v in POINT_LIGHT.items()] + [""]
    lines += toml_table("background", {"radiance": BACKGROUND})
    for name, m in case["tilefarm_materials"].items():
        lines += toml_table(f"materials.{name}", m)
    return "\n".join(lines)


def rgb(v):
    return {"type": "rgb", "value": list(v)}


def mitsuba_scene(case, spp, folder, objs):
    """The scene dict for `mi.load_dict`. tilefarm's Lambertian surfaces shade both
    sides, Mitsuba's `diffuse` one: the stage's are wrapped in `twosided`."""
    film = {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}, "pixel_format": "rgb"}
    d = {
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
    }
    for name, obj in objs.items():
        shape = {"type": "obj", "filename": os.path.join(folder, obj), "face_normals": True}
        if name == "Panel":
            shape["bsdf"] = {"type": "diffuse", "reflectance": rgb([0.0, 0.0, 0.0])}
            shape["emitter"] = {"type": "area", "radiance": rgb(PANEL_KE)}
        else:
            shape["bsdf"] = {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": rgb(STAGE_KD[name])}}
        d[name.lower()] = shape
    d["sphere"] = {"type": "sphere", "center": SPHERE["center"], "radius": SPHERE["radius"],
                   "bsdf": case["mitsuba_bsdf"]}
    if case["point_light"]:
        d["point"] = {"type": "point", "position": POINT_LIGHT["position"],
                      "intensity": rgb(POINT_LIGHT["intensity"])}
    d["environment"] = {"type": "constant", "radiance": rgb(BACKGROUND)}
    return d


# --------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------


class TilefarmFailed(Exception):
    """`coordinator render` exited non-zero (the message has its command and stderr)."""


def exr_channels(path, names):
    """Channels of an EXR by name, as one float64 array (rows top to bottom, the named
    channels last, in the order given)."""
    bitmap = mi.Bitmap(path)
    struct = bitmap.struct_()
    have = [struct[i].name for i in range(bitmap.channel_count())]
    missing = [n for n in names if n not in have]
    if missing:
        raise SystemExit(f"{path} has no channel {', '.join(missing)} (it has {', '.join(have)})")
    pixels = np.array(bitmap, dtype=np.float64)
    return pixels[..., [have.index(n) for n in names]]


def render_tilefarm(exe, scene_path, spp, out):
    cmd = [exe, "render", scene_path, "-q", "--spp", str(spp), "--aovs", "--local-workers", "0",
           "--tile", "16", "--no-scene-cache", "-o", out]
    t = time.perf_counter()
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    seconds = time.perf_counter() - t
    if run.returncode != 0:
        raise TilefarmFailed(f"`{' '.join(cmd)}` exited {run.returncode}: {run.stderr.strip()}")
    px = exr_channels(out, ["R", "G", "B", "variance.R", "variance.G", "variance.B"])
    return px[..., :3], px[..., 3:], seconds


def render_mitsuba(scene_dict, spp, passes):
    """`passes` independent renders of spp / passes samples each: (passes, H, W, 3)."""
    scene = mi.load_dict(scene_dict)
    t = time.perf_counter()
    images = [np.array(mi.render(scene, spp=spp // passes, seed=k), dtype=np.float64)[..., :3]
              for k in range(passes)]
    return np.stack(images), time.perf_counter() - t


# --------------------------------------------------------------------------------------
# Statistics
# --------------------------------------------------------------------------------------


def blocks(a, n=BLOCK):
    h, w = a.shape[:2]
    return a[: h // n * n, : w // n * n].reshape(h // n, n, w // n, n, -1).mean(axis=(1, 3))


def passes_estimate(stack):
    """The mean of independent passes and the variance of that mean, per pixel."""
    return stack.mean(0), stack.var(0, ddof=1) / stack.shape[0]


def z_bounds(tests):
    """Bonferroni: the |z| that a normal variable exceeds with probability ALPHA / tests
    (two-sided); and the rms of `tests` standard normals that is exceeded with probability
    ALPHA (chi-square, Wilson-Hilferty)."""
    z_max = NormalDist().inv_cdf(1 - ALPHA / (2 * tests))
    z_a = NormalDist().inv_cdf(1 - ALPHA)
    k = tests
    chi2 = k * (1 - 2 / (9 * k) + z_a * math.sqrt(2 / (9 * k))) ** 3
    return z_max, math.sqrt(chi2 / k)


def compare(img_a, var_a, img_b, var_b):
    """Figures for two independent estimates of the same image, each with its per-pixel
    variance of the mean."""
    n = img_a.shape[0] * img_a.shape[1]
    mean_a, mean_b = img_a.reshape(-1, 3).mean(0), img_b.reshape(-1, 3).mean(0)
    se = np.sqrt(var_a.reshape(-1, 3).sum(0) + var_b.reshape(-1, 3).sum(0)) / n
    # A block's mean has the summed variance of its pixels over its pixel count squared.
    # A block whose pixels are all exact in both (the environment seen directly) has no
    # noise at all: a floor of 1e-6 relative keeps float rounding from being a failure.
    var_block = (blocks(var_a) + blocks(var_b)) / (BLOCK * BLOCK)
    diff = blocks(img_a) - blocks(img_b)
    floor = 1e-6 * np.abs(blocks(img_b)) + 1e-9
    z = diff / np.sqrt(var_block + floor * floor)
    worst = np.unravel_index(np.argmax(np.abs(z)), z.shape)
    return {
        "means": [mean_a.round(5).tolist(), mean_b.round(5).tolist()],
        "mean_rel_diff": (np.abs(mean_a - mean_b) / mean_b).round(5).tolist(),
        "mean_rel_se": (se / mean_b).round(5).tolist(),
        "block_z_rms": round(float(np.sqrt(np.mean(z * z))), 3),
        "block_z_max": round(float(np.abs(z).max()), 3),
        "worst_block": {"row": int(worst[0]), "col": int(worst[1]), "channel": "RGB"[worst[2]]},
        "blocks": int(z.size),
    }


# --------------------------------------------------------------------------------------


def prepare_case(key, work, spp, print_scenes):
    """Writes the case's two scenes and renders Mitsuba's: (scene path, Mitsuba passes, seconds)."""
    case = CASES[key]
    folder = os.path.join(work, f"case-{key}")
    objs = write_stage(folder)
    scene_path = os.path.join(folder, "scene.toml")
    with open(scene_path, "w") as f:
        f.write(tilefarm_scene(case, spp, objs))
    scene_dict = mitsuba_scene(case, spp, folder, objs)
    if print_scenes:
        with open(scene_path) as f:
            print(f"===== case {key}: {case['title']} =====\n--- {scene_path}\n{f.read()}")
        with open(os.path.join(folder, "stage.mtl")) as f:
            print(f"--- {folder}/stage.mtl\n{f.read()}")
        for obj in objs.values():
            with open(os.path.join(folder, obj)) as f:
                print(f"--- {folder}/{obj}: {sum(line.startswith('f ') for line in f)} triangles")
        print(f"--- Mitsuba {mi.__version__} scene dict (mi.load_dict)")
        shown = dict(scene_dict, sensor=dict(scene_dict["sensor"], to_world=(
            f"mi.ScalarTransform4f().look_at(origin={CAMERA['position']}, target={CAMERA['look_at']}, "
            f"up={CAMERA['up']})")))
        pprint.pprint(shown, width=110, sort_dicts=False)
        sys.stdout.flush()
    stack, mi_s = render_mitsuba(scene_dict, spp, PASSES)
    return scene_path, stack, mi_s


def run_case(key, exe, work, spp, prepared):
    """tilefarm's render of a prepared case, compared with Mitsuba's: (figures, failures)."""
    case = CASES[key]
    folder = os.path.join(work, f"case-{key}")
    scene_path, stack, mi_s = prepared
    figures = {"title": case["title"]}
    failed = []
    try:
        tf, tf_var, tf_s = render_tilefarm(exe, scene_path, spp, os.path.join(folder, "tilefarm.exr"))
    except TilefarmFailed as e:
        return figures, failed + [f"case {key} ({case['title']}): {e}"]
    mi_img, mi_var = passes_estimate(stack)
    mi.util.write_bitmap(os.path.join(folder, "mitsuba.exr"), mi_img.astype(np.float32), write_async=False)

    cmp = compare(tf, tf_var, mi_img, mi_var)
    half = PASSES // 2
    noise = compare(*passes_estimate(stack[:half]), *passes_estimate(stack[half:]))
    z_max_bound, z_rms_bound = z_bounds(cmp["blocks"])
    figures.update({
        "spp": spp,
        "tilefarm_s": round(tf_s, 2),
        "mitsuba_s": round(mi_s, 2),
        "means_tilefarm": cmp["means"][0],
        "means_mitsuba": cmp["means"][1],
        "mean_rel_diff": cmp["mean_rel_diff"],
        "mean_rel_se": cmp["mean_rel_se"],
        "block_z_rms": cmp["block_z_rms"],
        "block_z_max": cmp["block_z_max"],
        "worst_block": cmp["worst_block"],
        "bounds": {"mean_rel": MEAN_TOLERANCE, "z_max": round(z_max_bound, 3), "z_rms": round(z_rms_bound, 3)},
        "noise_floor": {k: noise[k] for k in ("mean_rel_diff", "mean_rel_se", "block_z_rms", "block_z_max")},
    })
    name = f"case {key} ({case['title']})"
    rel = np.array(cmp["mean_rel_diff"])
    if not (rel < MEAN_TOLERANCE).all():
        failed.append(f"{name}: channel means differ by {rel.tolist()} (more than {MEAN_TOLERANCE:.0%}); "
                      f"tilefarm {cmp['means'][0]}, Mitsuba {cmp['means'][1]}")
    if cmp["block_z_max"] > z_max_bound:
        w = cmp["worst_block"]
        failed.append(f"{name}: an 8x8 block differs beyond its noise: |z| {cmp['block_z_max']} > "
                      f"{z_max_bound:.2f} at block row {w['row']}, column {w['col']}, channel {w['channel']} "
                      f"(pixels from y {w['row'] * BLOCK}, x {w['col'] * BLOCK})")
    if cmp["block_z_rms"] > z_rms_bound:
        failed.append(f"{name}: the blocks differ beyond their noise overall: rms z {cmp['block_z_rms']} > "
                      f"{z_rms_bound:.2f}")
    return figures, failed


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("coordinator", help="the coordinator executable")
    ap.add_argument("work", help="a folder for the scenes and images")
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated, of " + ",".join(CASES))
    ap.add_argument("--spp", type=int, default=SPP, help=f"samples per pixel (a multiple of {PASSES})")
    ap.add_argument("--print-scenes", action="store_true", help="print each case's two scenes")
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
    start = time.perf_counter()
    figures = {"mitsuba": mi.__version__, "variant": mi.variant(), "size": [W, H], "max_depth": MAX_DEPTH}
    failed = []
    prepared = {key: prepare_case(key, args.work, args.spp, args.print_scenes) for key in cases}
    for key in cases:
        t = time.perf_counter()
        figures[key], problems = run_case(key, args.coordinator, args.work, args.spp, prepared[key])
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
