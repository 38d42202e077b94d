"""The world's environment map against Cycles: a grey sphere on a grey floor lit only
by a small synthetic HDRI (a dim blue constant and one bright warm spot, the image
written as OpenEXR), through a Mapping node that turns it about Z, rendered by Cycles
and by tilefarm from the export (`map`, `strength`, `rotate`, `up = "z"`). The spot's
direction decides where the sphere is lit and where its shadow falls: the channel means
must agree within 2 % and 8×8-pixel blocks within their noise (as compare_cycles.py
holds its scenes). The map is 512 × 256: Cycles' rows are pixels (row i at
(i + ½)/H), tilefarm's, as Mitsuba's, samples from pole to pole (i/(H − 1)), which
stretches a map over the sphere by H/(H − 1) in elevation; at 128 × 64 that alone
makes tilefarm's image 2.3 % brighter here (0.6 % at 512 × 256). As a control, the same export with `rotate` off by 90° must fail
the block check, so the check sees the orientation. Last, a Nishita Sky Texture (its
sky a constant, its sun a directional light in the export) is held to looser bounds.
Prints one JSON line of figures; exits non-zero on a failure.

    python blender/tests/compare_world.py COORDINATOR_EXE WORK_DIR [SPP]
"""

import json
import math
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

import bpy  # noqa: E402
import numpy as np  # noqa: E402
import OpenEXR  # noqa: E402

import compare_cycles as cc  # noqa: E402
from tilefarm_blender.export import export_scene  # noqa: E402

MAP_W, MAP_H = 512, 256
SPOT = (0.3, math.radians(35.0))  # the spot's u in the image and its elevation
CASES = [
    # (name, Mapping type or None, Z rotation in degrees, strength)
    ("point-30", "POINT", 30.0, 1.5),
    ("texture-minus-45", "TEXTURE", -45.0, 0.7),
]


def hdri(work):
    """The HDRI as a float OpenEXR file (rows top to bottom), loaded into Blender: a
    Gaussian spot (σ 6°) at SPOT in Blender's equirectangular mapping, on 0.05 × blue."""
    x, y = np.meshgrid((np.arange(MAP_W) + 0.5) / MAP_W, (np.arange(MAP_H) + 0.5) / MAP_H)
    # Blender: u = 1/2 − atan2(d_y, d_x)/2π, v (from the top) = 1/2 − elevation/π.
    azimuth, elevation = (0.5 - x) * 2 * math.pi, (0.5 - y) * math.pi
    d = np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], -1)
    sa, se = (0.5 - SPOT[0]) * 2 * math.pi, SPOT[1]
    spot = np.array([math.cos(se) * math.cos(sa), math.cos(se) * math.sin(sa), math.sin(se)])
    angle = np.arccos(np.clip(d @ spot, -1.0, 1.0))
    glow = 150.0 * np.exp(-0.5 * (angle / math.radians(6.0)) ** 2)
    px = np.stack([0.03 + glow, 0.04 + 0.8 * glow, 0.06 + 0.55 * glow], -1).astype(np.float32)
    path = os.path.join(work, "spot.exr")
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"RGB": px}).write(path)
    return bpy.data.images.load(path)


def stage(work, spp):
    scene = cc.fresh()
    cc.cycles_settings(scene, spp, seed=1)
    scene.render.resolution_x, scene.render.resolution_y = 96, 64
    grey = cc.principled("grey", (0.5, 0.5, 0.5))
    cc.quad("floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], grey)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0.0, 0.3, 0.6), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(grey)
    cc.camera(scene, (0.0, -4.0, 2.6), (0.0, 0.4, 0.35))
    return scene


def environment_world(scene, image, kind, degrees, strength):
    world = bpy.data.worlds.new("hdri")
    scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = image
    nt.links.new(env.outputs["Color"], nt.nodes["Background"].inputs["Color"])
    nt.nodes["Background"].inputs["Strength"].default_value = strength
    if kind is not None:
        mp = nt.nodes.new("ShaderNodeMapping")
        mp.vector_type = kind
        mp.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(degrees))
        nt.links.new(nt.nodes.new("ShaderNodeTexCoord").outputs["Generated"], mp.inputs["Vector"])
        nt.links.new(mp.outputs["Vector"], env.inputs["Vector"])


def sky_world(scene):
    world = bpy.data.worlds.new("sky")
    scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    sky = nt.nodes.new("ShaderNodeTexSky")
    sky.sun_elevation, sky.sun_rotation = math.radians(35.0), math.radians(-50.0)
    nt.links.new(sky.outputs["Color"], nt.nodes["Background"].inputs["Color"])
    nt.nodes["Background"].inputs["Strength"].default_value = 0.05


def measure(cy, tf_path):
    """Channel means' relative differences and the 8×8 blocks' z-scores (compare_cycles.py)."""
    tf = cc.pixels(tf_path)
    var = cc.layer(tf_path, "variance")
    means_cy, means_tf = cy.reshape(-1, 3).mean(0), tf.reshape(-1, 3).mean(0)
    rel = np.abs(means_tf - means_cy) / means_cy
    n = 8
    z = (cc.blocks(tf, n) - cc.blocks(cy, n)) / np.sqrt(2.0 * cc.blocks(var, n) / (n * n) + 1e-12)
    # Where the light comes from: the image's left and right halves, as ratios.
    half = cy.shape[1] // 2
    return {
        "means_cycles": means_cy.round(5).tolist(),
        "means_tilefarm": means_tf.round(5).tolist(),
        "mean_rel_diff": rel.round(5).tolist(),
        "left_right_cycles": round(float(cy[:, :half].mean() / cy[:, half:].mean()), 4),
        "left_right_tilefarm": round(float(tf[:, :half].mean() / tf[:, half:].mean()), 4),
        "block_z_rms": round(float(np.sqrt(np.mean(z * z))), 3),
        "blocks_over_4": int((np.abs(z) > 4).sum()),
        "blocks": int(z.size),
    }


def blocks_agree(f):
    return f["block_z_rms"] <= 2.0 and f["blocks_over_4"] <= max(1, f["blocks"] // 50)


def render_both(coordinator, work, name, scene, spp):
    folder = os.path.join(work, name)
    report = export_scene(folder, scene)
    cy_path, tf_path = os.path.join(work, f"{name}-cycles.exr"), os.path.join(work, f"{name}-tilefarm.exr")
    cc.cycles(scene, cy_path)
    cc.tilefarm(coordinator, folder, tf_path, spp)
    return folder, report, cc.pixels(cy_path), tf_path


def main():
    coordinator, work = sys.argv[1], sys.argv[2]
    spp = int(sys.argv[3]) if len(sys.argv) > 3 else 256
    os.makedirs(work, exist_ok=True)
    figures, failed = {}, []
    for name, kind, degrees, strength in CASES:
        scene = stage(work, spp)
        environment_world(scene, hdri(work), kind, degrees, strength)
        folder, report, cy, tf_path = render_both(coordinator, work, name, scene, spp)
        with open(os.path.join(folder, "scene.toml"), encoding="utf-8") as f:
            text = f.read()
        rotate = float(re.search(r"^rotate = (\S+)$", text, re.M).group(1))
        f = measure(cy, tf_path)
        f.update(rotate=rotate, warnings=report.warnings)
        if report.warnings:
            failed.append(f"{name}: the export warned: {report.warnings}")
        if not (np.array(f["mean_rel_diff"]) < 0.02).all():
            failed.append(f"{name}: channel means differ by {f['mean_rel_diff']} (more than 2 %)")
        if not blocks_agree(f):
            failed.append(f"{name}: blocks differ beyond their noise: rms z {f['block_z_rms']}, "
                          f"{f['blocks_over_4']} of {f['blocks']} over 4")
        # The control: the map turned a quarter further must not pass.
        with open(os.path.join(folder, "scene.toml"), "w", encoding="utf-8") as out:
            out.write(text.replace(f"rotate = {rotate:.9g}", f"rotate = {rotate + 90.0:.9g}"))
        control = os.path.join(work, f"{name}-turned.exr")
        cc.tilefarm(coordinator, folder, control, spp)
        c = measure(cy, control)
        f["control_turned_90"] = {k: c[k] for k in ("mean_rel_diff", "left_right_tilefarm", "block_z_rms",
                                                    "blocks_over_4")}
        if blocks_agree(c):
            failed.append(f"{name}: the map turned by 90° passes the block check too (it cannot see orientation)")
        figures[name] = f
    # A Nishita sky: a constant and a directional sun, so only roughly Cycles' image.
    scene = stage(work, spp)
    sky_world(scene)
    _, report, cy, tf_path = render_both(coordinator, work, "nishita", scene, spp)
    f = measure(cy, tf_path)
    f["warnings"] = report.warnings
    figures["nishita"] = {k: f[k] for k in ("means_cycles", "means_tilefarm", "mean_rel_diff", "left_right_cycles",
                                            "left_right_tilefarm", "warnings")}
    if not (np.array(f["mean_rel_diff"]) < 0.05).all():
        failed.append(f"nishita: channel means differ by {f['mean_rel_diff']} (more than 5 %)")
    if abs(math.log(f["left_right_tilefarm"] / f["left_right_cycles"])) > 0.1:
        failed.append(f"nishita: the halves' ratio {f['left_right_tilefarm']} against Cycles' "
                      f"{f['left_right_cycles']} (the sun on another side?)")
    print(json.dumps(figures))
    if failed:
        print("FAILED: " + "; ".join(failed), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # bpy 4.2 can crash at interpreter shutdown (see compare_cycles.py)
