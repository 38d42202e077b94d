"""Exports scenes built in `bpy` (PyPI's, no .blend file) with tilefarm_blender, renders
them with tilefarm and with Cycles (CPU, the same spp, no denoising, a one-pixel box
filter, no clamping, the same bounces), and compares: per-channel image means within
2 %, and 8×8-pixel blocks within their noise (tilefarm's variance layer, for both). A
second check renders a scene with a bright object to the camera's right and finds it on
the image's right. A third exports a saved .blend with `python -m tilefarm_blender` and
with the add-on's operator (the same files), and, given a farm in TILEFARM_COORDINATOR,
renders it there with the add-on's render operator (the local render's bits). Last, the
add-on zip (blender/build.py) installs as an extension and exports the same files.
Prints one JSON line of figures; exits non-zero on a failure.

    python blender/tests/compare_cycles.py COORDINATOR_EXE WORK_DIR [SPP]
"""

import json
import math
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

import bpy  # noqa: E402
import mathutils  # noqa: E402
import numpy as np  # noqa: E402

import tilefarm_blender  # noqa: E402
from tilefarm_blender.export import export_scene  # noqa: E402

W = H = 64
BOUNCES = 6


def fresh():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def principled(name, color, emission=None, texture=None):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    p = m.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (*color, 1.0)
    p.inputs["Roughness"].default_value = 1.0
    # A pure Lambertian base: no dielectric coat.
    p.inputs["Specular IOR Level"].default_value = 0.0
    if emission is not None:
        p.inputs["Emission Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        p.inputs["Emission Strength"].default_value = emission
        p.inputs["Base Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    if texture is not None:
        tex = m.node_tree.nodes.new("ShaderNodeTexImage")
        tex.image = texture
        tex.interpolation = "Linear"
        m.node_tree.links.new(tex.outputs["Color"], p.inputs["Base Color"])
    return m


def quad(name, corners, material):
    """A one-quad mesh object; `corners` counter-clockwise seen from its front."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([mathutils.Vector(c) for c in corners], [], [(0, 1, 2, 3)])
    mesh.materials.append(material)
    ob = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def texture(work):
    """An asymmetric pattern (red rising left to right, green bottom to top, blue in
    waves), so a flipped or mirrored mapping shows. Smooth: Cycles interpolates 8-bit
    sRGB texels before decoding them to linear and tilefarm after, which differs only
    where neighbouring texels differ much."""
    n = 32
    img = bpy.data.images.new("pattern", n, n)
    px = np.zeros((n, n, 4), np.float32)
    for y in range(n):
        for x in range(n):
            u, v = (x + 0.5) / n, (y + 0.5) / n
            px[y, x] = (0.15 + 0.8 * u, 0.1 + 0.85 * v * v, 0.4 + 0.3 * math.sin(2 * math.pi * u) * v, 1.0)
    img.pixels[:] = px.ravel()
    img.filepath_raw = os.path.join(work, "pattern.png")
    img.file_format = "PNG"
    img.save()
    return img


def camera(scene, at, look):
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.location = at
    cam.rotation_euler = (mathutils.Vector(look) - mathutils.Vector(at)).to_track_quat("-Z", "Y").to_euler()
    cam.data.lens = 35.0
    return cam


def cornell(work):
    """A 2 m Cornell-like box (Z up), an emissive ceiling panel, a textured cube and a
    grey sphere, seen from the open side (−Y)."""
    scene = fresh()
    white = principled("white", (0.75, 0.75, 0.75))
    red = principled("red", (0.65, 0.06, 0.05))
    green = principled("green", (0.12, 0.48, 0.10))
    lamp = principled("lamp", (0, 0, 0), emission=12.0)
    s = 1.0
    quad("floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], white)
    quad("back", [(-s, s, 0), (s, s, 0), (s, s, 2), (-s, s, 2)], white)
    quad("left", [(-s, -s, 0), (-s, s, 0), (-s, s, 2), (-s, -s, 2)], red)
    quad("right", [(s, -s, 0), (s, -s, 2), (s, s, 2), (s, s, 0)], green)
    # The lamp hangs just under a hole in the ceiling: Blender's emission is two-sided,
    # tilefarm's one-sided, and this way the back's light leaves the box in both.
    a = 0.3
    for k, (x0, x1, y0, y1) in enumerate([(-s, s, -s, -a), (-s, s, a, s), (-s, -a, -a, a), (a, s, -a, a)]):
        quad(f"ceiling{k}", [(x0, y0, 2), (x0, y1, 2), (x1, y1, 2), (x1, y0, 2)], white)
    quad("lamp", [(-a, -a, 1.999), (-a, a, 1.999), (a, a, 1.999), (a, -a, 1.999)], lamp)
    # Clear of the floor: coplanar faces render as each renderer's rounding decides.
    bpy.ops.mesh.primitive_cube_add(size=0.7, location=(-0.35, 0.3, 0.36), rotation=(0, 0, 0.4))
    bpy.context.object.data.materials.append(principled("textured", (1, 1, 1), texture=texture(work)))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.3, location=(0.45, -0.2, 0.31), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(principled("grey", (0.5, 0.5, 0.5)))
    camera(scene, (0, -3.4, 1.0), (0, 0, 1.0))
    return scene


def lamps(work):
    """A corner of a room lit by a point, a spot, a sun and an area light (Blender's
    light objects, whose units the exporter converts). The area light (behind the
    camera, lighting the room from there) is tilefarm's `type = "area"`: unseen and
    casting no shadow, as Blender's (compare_area_lights.py holds it to Cycles up
    close: rectangles and disks, their noise, what is behind them)."""
    scene = fresh()
    white = principled("white", (0.7, 0.7, 0.7))
    quad("floor", [(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)], white)
    quad("back", [(-3, 2, 0), (3, 2, 0), (3, 2, 3), (-3, 2, 3)], principled("blue", (0.2, 0.3, 0.7)))
    quad("left", [(-2, -3, 0), (-2, 3, 0), (-2, 3, 3), (-2, -3, 3)], principled("orange", (0.8, 0.4, 0.1)))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0.3, 0.6, 0.5), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(white)

    def light(kind, at, energy, color=(1, 1, 1), aim=None, **props):
        ob = bpy.data.objects.new(kind.lower(), bpy.data.lights.new(kind.lower(), kind))
        scene.collection.objects.link(ob)
        ob.location = at
        ob.data.energy, ob.data.color = energy, color
        if aim is not None:
            ob.rotation_euler = (mathutils.Vector(aim) - mathutils.Vector(at)).to_track_quat("-Z", "Y").to_euler()
        for k, v in props.items():
            setattr(ob.data, k, v)

    light("POINT", (-1.0, 0.0, 2.0), 150.0, (1.0, 0.9, 0.8), shadow_soft_size=0.0)
    light("SPOT", (1.5, -1.0, 2.5), 400.0, (0.8, 0.9, 1.0), aim=(0.5, 1.0, 0.0), shadow_soft_size=0.0,
          spot_size=math.radians(50), spot_blend=0.0)
    light("SUN", (0, 0, 5), 1.5, (1.0, 1.0, 0.9), aim=(0.4, 0.8, 0.0), angle=0.0)
    light("AREA", (0.5, -4.5, 2.5), 300.0, aim=(0.0, -1.0, 0.0), shape="RECTANGLE", size=0.6, size_y=0.3)
    camera(scene, (0.5, -3.5, 1.4), (0.0, 1.0, 0.6))
    return scene


def right_of_camera(work):
    """A dark room with a bright sphere to the camera's right (its +X), lit by a sun."""
    scene = fresh()
    quad("floor", [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], principled("floor", (0.005, 0.005, 0.005)))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.4, location=(1.0, 0.0, 0.5))
    bpy.context.object.data.materials.append(principled("bright", (0.9, 0.9, 0.9)))
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    scene.collection.objects.link(sun)
    sun.data.energy = 3.0
    sun.data.angle = 0.0
    # The camera looks along +Y: its right (+X) is world +X.
    camera(scene, (0, -4, 0.5), (0, 0, 0.5))
    return scene


def cycles_settings(scene, spp, seed):
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = spp
    c.seed = seed
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.max_bounces = c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = BOUNCES
    c.transparent_max_bounces = BOUNCES
    scene.render.resolution_x, scene.render.resolution_y = W, H
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"


def cycles(scene, path):
    scene.render.filepath = path
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    bpy.ops.render.render(write_still=True)


def layer(path, name):
    """A layer of an EXR (rows top to bottom), read with PyPI's OpenEXR, which groups a
    layer's channels into one array: `RGBA` (h, w, 4), `variance` (h, w, 3)."""
    import OpenEXR

    return np.asarray(OpenEXR.File(path).channels()[name].pixels, dtype=np.float64)


def pixels(path):
    return layer(path, "RGBA")[..., :3]


def tilefarm(coordinator, folder, out, spp):
    cmd = [coordinator, "render", os.path.join(folder, "scene.toml"), "-q", "--spp", str(spp), "--aovs",
           "--local-workers", "0", "--tile", "16", "-o", out]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if run.returncode != 0:
        raise SystemExit(f"tilefarm render failed: {run.stderr}")


def blocks(a, n=8):
    h, w = a.shape[:2]
    return a[: h // n * n, : w // n * n].reshape(h // n, n, w // n, n, -1).mean(axis=(1, 3))


def means_and_blocks(kind, cy1, cy2, tf1, tf2, var, figures, failed, n=8):
    """Two seeds of Cycles against two of tilefarm (`var`: tilefarm's variance layer):
    channel means within 2 %, and n × n blocks within their noise, against the mean of
    Cycles' two seeds (a block's variance that of tilefarm's own plus half of it, so that
    one seed's firefly weighs half). Adds the figures; a failure is a line of `failed`.
    Returns the two renderers' channel means."""
    means_cy = (cy1 + cy2).reshape(-1, 3).mean(0) / 2
    means_tf = (tf1 + tf2).reshape(-1, 3).mean(0) / 2
    figures["means_cycles"] = means_cy.round(5).tolist()
    figures["means_tilefarm"] = means_tf.round(5).tolist()
    figures["means_ratio"] = (means_tf / means_cy).round(4).tolist()
    if not (np.abs(means_tf / means_cy - 1.0) < 0.02).all():
        failed.append(f"{kind}: channel means differ: tilefarm / Cycles {figures['means_ratio']} (more than 2 %)")
    z = (blocks(tf1, n) - blocks((cy1 + cy2) / 2, n)) / np.sqrt(1.5 * blocks(var, n) / (n * n) + 1e-12)
    figures["block_z_rms"] = round(float(np.sqrt(np.mean(z * z))), 3)
    figures["blocks_over_4"] = f"{int((np.abs(z) > 4).sum())} of {z.size}"
    if figures["block_z_rms"] > 2.0 or (np.abs(z) > 4).sum() > max(1, z.size // 50):
        failed.append(f"{kind}: blocks differ beyond their noise: rms z {figures['block_z_rms']}, "
                      f"{figures['blocks_over_4']} over 4")
    return means_cy, means_tf


def compare(coordinator, work, spp, name, build):
    scene = build(work)
    cycles_settings(scene, spp, seed=1)
    folder = os.path.join(work, name)
    t = time.perf_counter()
    report = export_scene(folder, scene)
    export_s = time.perf_counter() - t
    cy_path, tf_path = os.path.join(work, f"{name}-cycles.exr"), os.path.join(work, f"{name}-tilefarm.exr")
    cycles(scene, cy_path)
    tilefarm(coordinator, folder, tf_path, spp)
    cy, tf = pixels(cy_path), pixels(tf_path)
    var = layer(tf_path, "variance")
    means_cy, means_tf = cy.reshape(-1, 3).mean(0), tf.reshape(-1, 3).mean(0)
    rel = np.abs(means_tf - means_cy) / means_cy
    # A block's mean has the variance of its pixels' means over its pixel count; the
    # two renders are independent, with about the same noise: twice tilefarm's.
    n = 8
    var_block = blocks(var, n) / (n * n)
    z = (blocks(tf, n) - blocks(cy, n)) / np.sqrt(2.0 * var_block + 1e-12)
    figures = {
        "spp": spp,
        "export_s": round(export_s, 3),
        "warnings": report.warnings,
        "means_cycles": means_cy.round(5).tolist(),
        "means_tilefarm": means_tf.round(5).tolist(),
        "mean_rel_diff": rel.round(5).tolist(),
        "block_z_rms": round(float(np.sqrt(np.mean(z * z))), 3),
        "block_z_max": round(float(np.abs(z).max()), 3),
        "blocks_over_4": int((np.abs(z) > 4).sum()),
        "blocks": int(z.size),
    }
    failed = []
    if not (rel < 0.02).all():
        failed.append(f"{name}: channel means differ by {rel.round(4).tolist()} (more than 2 %)")
    if figures["block_z_rms"] > 2.0 or figures["blocks_over_4"] > max(1, z.size // 50):
        failed.append(f"{name}: blocks differ beyond their noise: rms z {figures['block_z_rms']:.2f}, "
                      f"{figures['blocks_over_4']} of {z.size} over 4")
    return figures, failed


def camera_convention(coordinator, work):
    scene = right_of_camera(work)
    cycles_settings(scene, 16, seed=1)
    folder = os.path.join(work, "right")
    export_scene(folder, scene)
    out = os.path.join(work, "right.exr")
    tilefarm(coordinator, folder, out, 16)
    px = pixels(out).mean(-1)
    left, right = px[:, : W // 2].mean(), px[:, W // 2 :].mean()
    return left, right


def headless_and_add_on(coordinator, work, spp):
    """The same scene saved as a .blend, exported by `python -m tilefarm_blender` and by
    the add-on's export operator, is the same folder as exported here; with a farm
    (TILEFARM_COORDINATOR set), the add-on's render operator submits it and opens an
    image whose pixels are the local render's bits."""
    scene = cornell(work)
    cycles_settings(scene, spp, seed=1)
    direct = os.path.join(work, "direct")
    export_scene(direct, scene)
    blend = os.path.join(work, "cornell.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    by_cli = os.path.join(work, "by-cli")
    env = dict(os.environ, PYTHONPATH=os.path.dirname(HERE))
    run = subprocess.run([sys.executable, "-m", "tilefarm_blender", by_cli, "--blend", blend],
                         capture_output=True, text=True, timeout=300, env=env)
    if run.returncode != 0:
        raise SystemExit(f"python -m tilefarm_blender failed: {run.stderr}")
    by_operator = os.path.join(work, "by-operator")
    bpy.ops.tilefarm.export_scene(directory=by_operator)
    for other in (by_cli, by_operator):
        for name in sorted(os.listdir(direct)):
            with open(os.path.join(direct, name), "rb") as a, open(os.path.join(other, name), "rb") as b:
                if a.read() != b.read():
                    raise SystemExit(f"{other}/{name} differs from the direct export's")
    checks = {"cli_stdout": run.stdout.strip()}
    if os.environ.get("TILEFARM_COORDINATOR"):
        farm_out = os.path.join(work, "farm.exr")
        done = bpy.ops.tilefarm.render(output=farm_out)
        if done != {"FINISHED"}:
            raise SystemExit(f"the render operator ended {done}")
        local = os.path.join(work, "local.exr")
        tilefarm(coordinator, direct, local, spp)
        if not np.array_equal(pixels(farm_out), pixels(local)):
            raise SystemExit("the farm's image is not the local render's bits")
        loaded = [i for i in bpy.data.images if i.filepath and os.path.samefile(bpy.path.abspath(i.filepath), farm_out)]
        if not loaded:
            raise SystemExit("the render operator did not open the farm's image")
        checks["farm"] = "same bits as a local render"
        checks.update(progress_and_cancel(coordinator, work, scene))
    return checks


def progress_and_cancel(coordinator, work, scene):
    """The add-on's submission as its modal operator drives it (polled every half second
    for the status bar's text) on a long render: the percent passes through values
    between 0 and 100, and Esc's cancel cancels the job on the farm."""
    from tilefarm_blender import farm

    spp = scene.cycles.samples
    cycles_settings(scene, 1 << 16, seed=1)
    folder = os.path.join(work, "long")
    export_scene(folder, scene)
    cycles_settings(scene, spp, seed=1)  # the scene as the later checks expect it
    url = os.environ["TILEFARM_COORDINATOR"]
    sub = farm.Submission(coordinator, url, os.environ.get("TILEFARM_TOKEN", ""),
                          os.path.join(folder, "scene.toml"), os.path.join(work, "long.exr"), "progress")
    seen, text, start = set(), "", time.monotonic()
    while len(seen) < 2 and time.monotonic() - start < 120:
        time.sleep(0.5)
        code = sub.poll()
        if code is not None:
            raise SystemExit(f"the long render ended early ({code}): {sub.error()}")
        if 0 < sub.percent < 100:
            seen.add(sub.percent)
            text = sub.status_text(time.monotonic() - start)
    if len(seen) < 2:
        raise SystemExit(f"the status bar's percent did not move: {sorted(seen)}; heard {sub.lines[-5:]}")
    sub.cancel()
    status = subprocess.run([coordinator, "status", sub.job], capture_output=True, text=True, timeout=60,
                            env=dict(os.environ, TILEFARM_COORDINATOR=url))
    if sub.proc.poll() is None or " cancelled " not in status.stdout:
        raise SystemExit(f"cancelling did not cancel {sub.job} on the farm:\n{status.stdout}{status.stderr}")
    return {"status_bar": text, "percents_seen": sorted(seen), "cancelled_on_the_farm": sub.job}


def installed_extension(work):
    """The add-on packed by blender/build.py installs as a Blender extension (into the
    HOME the test gives), enables, and its export operator writes the same folder as the
    module's own (the current scene: the Cornell box). Run after the module's classes
    are unregistered, as the extension registers the same ones."""
    sys.path.insert(0, os.path.dirname(HERE))
    import build

    zip_path = build.build(os.path.join(work, "tilefarm_blender.zip"))
    done = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    module = "bl_ext.user_default.tilefarm"
    if done != {"FINISHED"} or module not in bpy.context.preferences.addons:
        raise SystemExit(f"the extension did not install and enable ({done})")
    prefs = bpy.context.preferences.addons[module].preferences
    out = os.path.join(work, "by-extension")
    bpy.ops.tilefarm.export_scene(directory=out)
    direct = os.path.join(work, "direct")
    for name in sorted(os.listdir(direct)):
        with open(os.path.join(direct, name), "rb") as a, open(os.path.join(out, name), "rb") as b:
            if a.read() != b.read():
                raise SystemExit(f"the extension's export of {name} differs")
    return {"extension": module, "extension_farm": prefs.url}


def main():
    coordinator, work = sys.argv[1], sys.argv[2]
    spp = int(sys.argv[3]) if len(sys.argv) > 3 else 256
    os.makedirs(work, exist_ok=True)
    tilefarm_blender.register()  # as Blender does when the add-on is enabled
    figures, failed = {}, []
    for name, build in [("cornell", cornell), ("lamps", lamps)]:
        figures[name], problems = compare(coordinator, work, spp, name, build)
        failed += problems
    left, right = camera_convention(coordinator, work)
    figures["right_of_camera"] = {"left_half": round(float(left), 5), "right_half": round(float(right), 5)}
    figures.update(headless_and_add_on(coordinator, work, 16))
    tilefarm_blender.unregister()
    figures.update(installed_extension(work))
    print(json.dumps(figures))
    if not right > 2.0 * left:
        failed.append(f"the object right of the camera is not on the image's right ({left:.4f} | {right:.4f})")
    if failed:
        print("FAILED: " + "; ".join(failed), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    code = main()
    # bpy 4.2 as a Python module can crash while the interpreter shuts down after a
    # render (seen: SIGSEGV at exit, every line above already printed): end without the
    # shutdown, so that the exit code is this script's.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
