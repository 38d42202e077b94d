"""The Principled mapping against Cycles (issue 49): scenes of Principled cases built
in `bpy`, rendered by Cycles twice (seeds 1 and 2: the noise floor) and by tilefarm
(CPU, no denoising, a one-pixel box filter, no clamping, Filter Glossy 0, the same
bounces), compared object by object (Cycles' object index pass, eroded by a pixel, is
each object's mask): every channel mean within 2 % of Cycles' (of the brightest
channel's mean at least, so a red object's near-black green is not divided by almost
nothing; or, where Cycles' two seeds differ by more than a third of that, within three
times their difference: a small sharp highlight is noisy in both), and the relative MSE against Cycles within twice Cycles' own against its
second seed. The cases in KNOWN_GAPS are held to the looser bounds written there, with
the reason. An export or a tilefarm render that fails is a failed case. Prints one JSON
line of figures; exits non-zero on a failure.

    python blender/tests/compare_principled.py COORDINATOR_EXE WORK_DIR [SPP [SCENES [TILEFARM_SPP]]]

SCENES: `all` or a comma-separated list (`maps,layers`). TILEFARM_SPP (default SPP):
CI renders tilefarm at four times Cycles' samples (tests/tests/blender.rs), so that the
relative MSE measures a difference between the two rather than tilefarm's own noise.
"""

import json
import math
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

import bpy  # noqa: E402
import numpy as np  # noqa: E402
import OpenEXR  # noqa: E402

import compare_cycles as cc  # noqa: E402
from export_testing import save_image  # noqa: E402
from tilefarm_blender.export import export_scene  # noqa: E402

W, H = 160, 96
RED = (0.8, 0.05, 0.04, 1.0)
GOLD = (1.0, 0.78, 0.34, 1.0)


def grid(n=64):
    v, u = (np.mgrid[0:n, 0:n] + 0.5) / n
    return u, v


def images(work):
    """Smooth patterns (8-bit sRGB texels interpolate differently in Cycles and tilefarm
    where neighbours differ much): a colour, a height field and its tangent-space
    normals, a roughness field and an alpha pattern."""
    u, v = grid()
    one = np.ones_like(u)
    color = np.stack([0.15 + 0.8 * u, 0.1 + 0.85 * v * v, 0.4 + 0.3 * np.sin(2 * math.pi * u) * v, one], -1)
    height = 0.5 + 0.5 * np.sin(4 * math.pi * u) * np.sin(4 * math.pi * v)
    k = 2.0 * math.pi  # the height's slope per unit of u and v, at strength 1
    nx = -k * np.cos(4 * math.pi * u) * np.sin(4 * math.pi * v)
    ny = -k * np.sin(4 * math.pi * u) * np.cos(4 * math.pi * v)
    nz = np.ones_like(u) * 4.0
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    normal = np.stack([0.5 + 0.5 * nx / norm, 0.5 + 0.5 * ny / norm, 0.5 + 0.5 * nz / norm, one], -1)
    rough = 0.15 + 0.7 * (0.5 + 0.5 * np.sin(2 * math.pi * u))
    alpha = np.clip(0.5 + 2.0 * np.sin(2 * math.pi * 3 * u) * np.sin(2 * math.pi * 2 * v), 0.0, 1.0)
    return {
        "color": save_image(work, "color", color),
        "height": save_image(work, "height", np.stack([height, height, height, one], -1), "Non-Color"),
        "normal": save_image(work, "normal", normal, "Non-Color"),
        "rough": save_image(work, "rough", np.stack([rough, rough, rough, one], -1), "Non-Color"),
        "cutout": save_image(work, "cutout", np.concatenate([color[..., :3], alpha[..., None]], -1)),
    }


def principled(name, **inputs):
    """A material of the default Principled BSDF with `inputs` (socket names with
    underscores for spaces) set."""
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    p = m.node_tree.nodes["Principled BSDF"]
    for key, value in inputs.items():
        p.inputs[key.replace("_", " ")].default_value = value
    return m


def linked(m, image, output, *sockets, via=None):
    """Links an Image Texture of `image` (its `output`) into the Principled `sockets`,
    or into `via`'s input 0 (whose output goes to the first socket)."""
    nt = m.node_tree
    p = nt.nodes["Principled BSDF"]
    t = nt.nodes.new("ShaderNodeTexImage")
    t.image = image
    if via is None:
        for s in sockets:
            nt.links.new(t.outputs[output], p.inputs[s])
    else:
        node = nt.nodes.new(via[0])
        for k, v in via[1].items():
            node.inputs[k].default_value = v
        nt.links.new(t.outputs[output], node.inputs[via[2]])
        nt.links.new(node.outputs[0], p.inputs[sockets[0]])
    return m


def mix_shader(name):
    """0.6 of a rough red Principled and 0.4 of a Glossy gold."""
    m = principled(name, Base_Color=RED, Roughness=0.5)
    nt = m.node_tree
    glossy = nt.nodes.new("ShaderNodeBsdfAnisotropic")
    glossy.inputs["Color"].default_value = GOLD
    glossy.inputs["Roughness"].default_value = 0.25
    mix = nt.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.4
    nt.links.new(nt.nodes["Principled BSDF"].outputs[0], mix.inputs[1])
    nt.links.new(glossy.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
    return m


def dielectric(img):
    return [(f"red_rough_{r}", principled(f"red{r}", Base_Color=RED, Roughness=r)) for r in (0.0, 0.2, 0.5, 0.8)]


def metal(img):
    textured = linked(principled("goldtex", Metallic=1.0, Roughness=0.3), img["color"], "Color", "Base Color")
    return [("gold_rough_0.0", principled("gold0", Base_Color=GOLD, Metallic=1.0, Roughness=0.0)),
            ("gold_rough_0.3", principled("gold3", Base_Color=GOLD, Metallic=1.0, Roughness=0.3)),
            ("gold_textured", textured),
            # Blender's default tangent is radial about the object's Z; on a UV sphere that
            # is the UV map's tangent, which tilefarm uses.
            ("gold_anisotropic", principled("goldaniso", Base_Color=GOLD, Metallic=1.0, Roughness=0.4,
                                            Anisotropic=0.8, Anisotropic_Rotation=0.1))]


def maps(img):
    normal = linked(principled("nmap", Base_Color=RED, Roughness=0.3), img["normal"], "Color", "Normal",
                    via=("ShaderNodeNormalMap", {"Strength": 1.0}, "Color"))
    bump = linked(principled("bump", Base_Color=RED, Roughness=0.3), img["height"], "Color", "Normal",
                  via=("ShaderNodeBump", {"Strength": 1.0, "Distance": 0.2}, "Height"))
    rough = linked(principled("roughtex", Base_Color=GOLD, Metallic=1.0), img["rough"], "Color", "Roughness")
    cutout = linked(principled("cutout", Roughness=0.5), img["cutout"], "Color", "Base Color")
    linked(cutout, img["cutout"], "Alpha", "Alpha")
    # A coat over a normal-mapped base: Blender's coat keeps its own (unlinked) Coat Normal.
    coated = linked(principled("coatnmap", Base_Color=RED, Roughness=0.6, Coat_Weight=1.0, Coat_Roughness=0.1),
                    img["normal"], "Color", "Normal", via=("ShaderNodeNormalMap", {"Strength": 1.0}, "Color"))
    return [("normal_mapped", normal), ("bump_mapped", bump), ("roughness_textured", rough),
            ("alpha_textured", cutout), ("coat_over_normal_map", coated)]


def layers(img):
    return [
        ("coat", principled("coat", Base_Color=RED, Roughness=0.6, Coat_Weight=1.0, Coat_Roughness=0.05)),
        ("sheen", principled("sheen", Base_Color=(0.05, 0.05, 0.2, 1.0), Sheen_Weight=1.0, Sheen_Roughness=0.3,
                             Sheen_Tint=(1.0, 0.8, 0.6, 1.0))),
        ("specular_tint", principled("spectint", Base_Color=(0.05, 0.05, 0.05, 1.0), Roughness=0.2,
                                     Specular_Tint=(1.0, 0.1, 0.1, 1.0))),
        ("rough_glass", principled("glass", Base_Color=(1.0, 1.0, 1.0, 1.0), Transmission_Weight=1.0, Roughness=0.3)),
        ("mix_shader", mix_shader("mix")),
    ]


# Cases where tilefarm and Cycles 4.2 are known to differ, and why: (relative MSE as a
# multiple of Cycles' floor, channel-mean difference) they are held to instead, so that
# they still fail when they get worse. README.md's Blender table says the same.
FIREFLIES = ("rare bright paths through the neighbouring rough glass sphere, which Cycles does not show at "
             "equal samples (the means agree; Mitsuba 3's path tracer, the same estimator, has the same tails "
             "through rough glass: how Cycles avoids them is not known yet)")
KNOWN_GAPS = {
    "maps/bump_mapped": (12.0, 0.03, "Cycles 4.2 differentiates the height over a pixel's footprint (forward "
                         "differences along ray differentials); tilefarm takes the bilinear height's own derivative"),
    "layers/floor": (6.0, 0.02, FIREFLIES),
    "layers/sheen": (8.0, 0.02, FIREFLIES),
    "layers/specular_tint": (30.0, 0.02, FIREFLIES),
}

# Each scene's objects, in a row left to right, as (case name, material).
SCENES = {"dielectric": dielectric, "metal": metal, "maps": maps, "layers": layers}


def build(objects):
    """A floor of the default Principled BSDF (`floor`), the objects as spheres in a
    row, a sun and a grey sky. Object indices: 1 the floor, then 2, 3, …"""
    scene = bpy.context.scene
    floor = cc.quad("floor", [(-8, -4, 0), (8, -4, 0), (8, 8, 0), (-8, 8, 0)], principled("floor"))
    floor.pass_index = 1
    n = len(objects)
    for k, (case, material) in enumerate(objects):
        x = (k - (n - 1) / 2) * 1.25
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.55, location=(x, 0.0, 0.6), segments=64, ring_count=32)
        bpy.ops.object.shade_smooth()
        ob = bpy.context.object
        ob.name = case
        ob.data.materials.append(material)
        ob.pass_index = k + 2
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    scene.collection.objects.link(sun)
    sun.data.energy, sun.data.angle = 3.0, 0.0
    sun.rotation_euler = (math.radians(40), 0.0, math.radians(-30))
    world = bpy.data.worlds.new("sky")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.3, 0.3, 0.3, 1.0)
    scene.world = world
    cc.camera(scene, (0.0, -7.0, 2.4), (0.0, 0.0, 0.5))
    return ["floor"] + [case for case, _ in objects]


def cycles(scene, spp, seed, path):
    cc.cycles_settings(scene, spp, seed)
    # Filter Glossy (default 1) blurs glossy bounces after diffuse ones: a bias tilefarm
    # does not have (the comparisons ran with 0).
    scene.cycles.blur_glossy = 0.0
    scene.render.resolution_x, scene.render.resolution_y = W, H
    scene.view_layers[0].use_pass_object_index = True
    scene.render.filepath = path
    scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    scene.render.image_settings.color_depth = "32"
    bpy.ops.render.render(write_still=True)
    channels = OpenEXR.File(path).channels()
    rgb = np.asarray(channels["ViewLayer.Combined"].pixels, np.float64)[..., :3]
    return rgb, np.asarray(channels["ViewLayer.IndexOB.X"].pixels)


def tilefarm(coordinator, folder, out, spp):
    """tilefarm's image, or the error (a failed case, not the end of the run)."""
    cmd = [coordinator, "render", os.path.join(folder, "scene.toml"), "-q", "--spp", str(spp), "--local-workers", "0",
           "--tile", "16", "-o", out]
    try:
        run = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    except (OSError, subprocess.TimeoutExpired) as e:
        return None, str(e)
    if run.returncode != 0:
        return None, (run.stderr.strip() or f"exit code {run.returncode}")[-600:]
    return cc.pixels(out), None


def masks(index, count):
    """Each object's pixels, less those next to another object's (edges differ by
    how each renderer filters them)."""
    out = []
    for k in range(1, count + 1):
        m = index == k
        inner = m.copy()
        inner[1:, :] &= m[:-1, :]
        inner[:-1, :] &= m[1:, :]
        inner[:, 1:] &= m[:, :-1]
        inner[:, :-1] &= m[:, 1:]
        out.append(inner)
    return out


def relmse(a, ref):
    return float(np.mean((a - ref) ** 2 / (ref * ref + 1e-2)))


def figures(mask, cy1, cy2, tf):
    means_cy = cy1[mask].mean(0)
    floor = np.maximum(means_cy, 0.05 * means_cy.max() + 1e-6)
    out = {"pixels": int(mask.sum()), "means_cycles": means_cy.round(5).tolist(),
           "means_cycles_seed2": cy2[mask].mean(0).round(5).tolist(),
           "relmse_floor": round(relmse(cy2[mask], cy1[mask]), 6)}
    out["cycles_seeds_mean_diff"] = (np.abs(cy2[mask].mean(0) - means_cy) / floor).round(5).tolist()
    if tf is None:
        return out
    means_tf = tf[mask].mean(0)
    out["means_tilefarm"] = means_tf.round(5).tolist()
    out["mean_rel_diff"] = (np.abs(means_tf - means_cy) / floor).round(5).tolist()
    out["relmse"] = round(relmse(tf[mask], cy1[mask]), 6)
    return out


def run_scene(coordinator, work, spp, name, img, tilefarm_spp):
    cc.fresh()
    scene = bpy.context.scene
    # The images live in bpy.data, which fresh() emptied: load them again.
    img = {k: bpy.data.images.load(v) for k, v in img.items()}
    for k in ("height", "normal", "rough"):
        img[k].colorspace_settings.name = "Non-Color"
    cases = build(SCENES[name](img))
    folder = os.path.join(work, name)
    cc.cycles_settings(scene, spp, seed=1)
    scene.render.resolution_x, scene.render.resolution_y = W, H
    results, error = {}, None
    try:
        report = export_scene(folder, scene)
        warnings = report.warnings
    except Exception as e:  # an export that fails fails every case of its scene
        error, warnings = f"export: {e}", []
    cy1, index = cycles(scene, spp, 1, os.path.join(work, f"{name}-cycles1.exr"))
    cy2, _ = cycles(scene, spp, 2, os.path.join(work, f"{name}-cycles2.exr"))
    tf = None
    if error is None:
        tf, error = tilefarm(coordinator, folder, os.path.join(work, f"{name}-tilefarm.exr"), tilefarm_spp)
    for case, mask in zip(cases, masks(index, len(cases))):
        key = f"{name}/{case}"
        f = figures(mask, cy1, cy2, tf)
        times, means, why = KNOWN_GAPS.get(key, (2.0, 0.02, None))
        if why is not None:
            f["known_gap"] = why
        if error is not None:
            f["error"] = error
        elif not all(d <= max(means, 3.0 * s) for d, s in zip(f["mean_rel_diff"], f["cycles_seeds_mean_diff"])):
            f["error"] = (f"channel means differ by {f['mean_rel_diff']} (more than {means:.0%}, and more than three "
                          f"times Cycles' own seed-to-seed {f['cycles_seeds_mean_diff']})")
        elif f["relmse"] > times * f["relmse_floor"]:
            f["error"] = f"relMSE {f['relmse']:.3g} over {times:g} times Cycles' noise floor {f['relmse_floor']:.3g}"
        results[key] = f
    return results, warnings


def main():
    coordinator, work = sys.argv[1], sys.argv[2]
    spp = int(sys.argv[3]) if len(sys.argv) > 3 else 256
    os.makedirs(work, exist_ok=True)
    started = time.perf_counter()
    cc.fresh()
    files = {k: bpy.path.abspath(i.filepath_raw) for k, i in images(work).items()}
    results, warnings = {}, {}
    only = sys.argv[4].split(",") if len(sys.argv) > 4 and sys.argv[4] != "all" else list(SCENES)
    tilefarm_spp = int(sys.argv[5]) if len(sys.argv) > 5 else spp
    for name in only:
        r, warnings[name] = run_scene(coordinator, work, spp, name, files, tilefarm_spp)
        results.update(r)
    failed = {k: f["error"] for k, f in results.items() if "error" in f}
    print(json.dumps({"spp": spp, "tilefarm_spp": tilefarm_spp, "size": [W, H], "cases": results, "warnings": warnings,
                      "passed": len(results) - len(failed), "failed": len(failed),
                      "seconds": round(time.perf_counter() - started, 1)}))
    for k, why in failed.items():
        print(f"FAILED {k}: {why}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # bpy 4.2 can crash at interpreter shutdown (see compare_cycles.py)
