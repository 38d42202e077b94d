"""Export-level tests of the world (issue 50): worlds built in `bpy` (PyPI's, no .blend
file), each in a scene of its own with a plane and a camera, exported with
tilefarm_blender; the written scene.toml is read with `tomllib` and its `[background]`
(and a Sky Texture's sun light) and the warning's lines are checked. One case asks
Cycles itself where it looks a direction up in the map, against the orientation the
export wrote. Given the coordinator, every exported scene is also loaded and rendered
(one sample) by tilefarm. Prints one JSON line (cases, failures, seconds); exits
non-zero on a failure.

    python blender/tests/world_export.py WORK_DIR [COORDINATOR_EXE]
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
import OpenEXR  # noqa: E402

import compare_cycles as cc  # noqa: E402
from export_testing import expect, save_image  # noqa: E402
from tilefarm_blender import world as world_mod  # noqa: E402
from tilefarm_blender.export import export_scene  # noqa: E402

CASES = []


def case(fn):
    CASES.append(fn)
    return fn


class World:
    """A new world with its Background node, and nodes added to it."""

    def __init__(self, scene):
        self.world = bpy.data.worlds.new("world")
        scene.world = self.world
        self.world.use_nodes = True
        self.nt = self.world.node_tree
        self.bg = self.nt.nodes["Background"]

    def node(self, kind, into=None, out="Color", **props):
        n = self.nt.nodes.new(kind)
        for k, v in props.items():
            setattr(n, k, v)
        if into is not None:
            self.nt.links.new(n.outputs[out], into)
        return n

    def environment(self, image, strength=1.0):
        self.bg.inputs["Strength"].default_value = strength
        return self.node("ShaderNodeTexEnvironment", self.bg.inputs["Color"], image=image)

    def mapping(self, into, kind="POINT", rotation=(0.0, 0.0, 0.0), location=None, scale=None, coords="Generated"):
        """A Mapping node (rotation in degrees) into `into`, fed by Texture Coordinate's
        `coords` output (or by nothing)."""
        mp = self.node("ShaderNodeMapping", into, out="Vector", vector_type=kind)
        mp.inputs["Rotation"].default_value = tuple(math.radians(a) for a in rotation)
        if location is not None:
            mp.inputs["Location"].default_value = location
        if scale is not None:
            mp.inputs["Scale"].default_value = scale
        if coords is not None:
            self.node("ShaderNodeTexCoord", mp.inputs["Vector"], out=coords)
        return mp


def hdri(work, name="spot", on_disk=True):
    """A small float image written with OpenEXR (linear numbers exactly) and loaded."""
    y, x = np.mgrid[0:8, 0:16] / np.array([7.0, 15.0])[:, None, None]
    px = np.stack([0.2 + x, 0.1 + y, 0.5 + 0.0 * x], -1).astype(np.float32)
    path = os.path.join(work, name + ".exr")
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"RGB": px}).write(path)
    image = bpy.data.images.load(path)
    if not on_disk:
        image.pack()
        os.remove(path)
    return image, px


def png(work, name, colorspace):
    y, x = np.mgrid[0:8, 0:16] / np.array([7.0, 15.0])[:, None, None]
    return save_image(work, name, np.stack([x, y, 0.5 + 0.0 * x, 1.0 + 0.0 * x], -1), colorspace)


class Exported:
    def __init__(self, folder, report):
        self.folder = folder
        self.report = report
        with open(os.path.join(folder, "scene.toml"), "rb") as f:
            self.scene = tomllib.load(f)
        self.bg = self.scene.get("background")
        self.warned = [w for w in report.warnings if w.startswith("world: ")]

    def background(self, **want):
        assert self.bg is not None, "no [background]"
        for key, value in want.items():
            assert key in self.bg, f"background: no {key} ({self.bg})"
            if isinstance(value, (int, float, list)) and not isinstance(value, bool):
                expect(f"background.{key}", self.bg[key], value, 1e-4)
            else:
                assert self.bg[key] == value, f"background.{key}: {self.bg[key]!r}, expected {value!r}"
        if "map" in self.bg:
            assert os.path.isfile(os.path.join(self.folder, self.bg["map"])), f"{self.bg['map']} not written"
            assert "radiance" not in self.bg, "radiance beside a map"

    def no_background(self):
        """Black: no `[background]`, or one with only its `warning`."""
        assert self.bg is None or set(self.bg) == {"warning"}, f"a [background] {self.bg}"

    def lines(self, *want):
        """The world's lines of the export's warning, all also in the table's `warning`."""
        assert self.warned == list(want), "the world's warning lines:\n  " + "\n  ".join(self.warned)
        note = (self.bg or {}).get("warning")
        if not want:
            assert note is None, f"background.warning without a warning: {note!r}"
            return
        assert note is not None and note.startswith("the Blender world is not exactly this: "), note
        for line in want:
            assert line[len("world: "):] in note, f"not in background.warning: {line}"


def map_pixels(x):
    return np.asarray(OpenEXR.File(os.path.join(x.folder, x.bg["map"])).channels()["RGB"].pixels)


# Environment Texture ---------------------------------------------------------------------


@case
def environment_texture_through_a_mapping_node(w, work):
    """Texture Coordinate Generated → Mapping (Point, Z 30°) → Environment Texture, Strength
    2.5: the map beside the scene, rotate 90° − 30°, up z."""
    image, px = hdri(work)
    env = w.environment(image, strength=2.5)
    w.mapping(env.inputs["Vector"], rotation=(0, 0, 30))

    def check(x):
        x.background(map="spot.exr", strength=2.5, rotate=60.0, up="z")
        expect("the map's pixels", map_pixels(x), px)
        x.lines()
    return check


@case
def default_orientation_is_a_quarter_turn(w, work):
    """No Mapping node (Generated straight into the Vector): rotate 90°."""
    env = w.environment(hdri(work)[0])
    w.node("ShaderNodeTexCoord", env.inputs["Vector"], out="Generated")

    def check(x):
        x.background(map="spot.exr", strength=1.0, rotate=90.0, up="z")
        x.lines()
    return check


@case
def texture_type_turns_the_other_way(w, work):
    env = w.environment(hdri(work)[0])
    w.mapping(env.inputs["Vector"], kind="TEXTURE", rotation=(0, 0, 30))

    def check(x):
        x.background(rotate=120.0)
        x.lines()
    return check


@case
def chained_mappings_and_uniform_scale_compose(w, work):
    """Vector (Z 20°, scale 2) then Point (Z 10°): a 30° turn (Cycles normalises the
    direction, so a uniform scale changes nothing)."""
    env = w.environment(hdri(work)[0])
    last = w.mapping(env.inputs["Vector"], kind="POINT", rotation=(0, 0, 10), coords=None)
    w.mapping(last.inputs["Vector"], kind="VECTOR", rotation=(0, 0, 20), scale=(2.0, 2.0, 2.0))

    def check(x):
        x.background(rotate=60.0)
        x.lines()
    return check


@case
def half_turns_about_x_and_y_are_a_turn_about_z(w, work):
    env = w.environment(hdri(work)[0])
    w.mapping(env.inputs["Vector"], rotation=(180, 180, 0))

    def check(x):
        x.background(rotate=-90.0)
        x.lines()
    return check


@case
def packed_image_is_saved_beside_the_scene(w, work):
    image, px = hdri(work, "packed", on_disk=False)
    w.environment(image)

    def check(x):
        x.background(map="packed.exr", rotate=90.0)
        expect("the saved map's pixels", map_pixels(x), px)
        x.lines()
    return check


@case
def srgb_png_is_read_as_srgb(w, work):
    w.environment(png(work, "ldr", "sRGB"))

    def check(x):
        x.background(map="ldr.png")
        x.lines()
    return check


@case
def linear_png_is_reported(w, work):
    w.environment(png(work, "ldr-linear", "Non-Color"))

    def check(x):
        x.background(map="ldr-linear.png")
        x.lines('world: Environment Texture "ldr-linear": colour space "Non-Color" on an 8- or 16-bit image read '
                "as sRGB")
    return check


@case
def orientation_is_where_cycles_looks(w, work):
    """Cycles renders single pixels of a world whose map holds each texel's (u, v),
    through a Mapping node (Point, Z 30°); tilefarm's lookup (the README's formula, with
    the rotate the export wrote) finds the same texel for each direction."""
    n_u, n_v = 360, 180
    y, x = np.mgrid[0:n_v, 0:n_u]
    px = np.stack([(x + 0.5) / n_u, (y + 0.5) / n_v, 0.0 * x], -1).astype(np.float32)  # v from the top
    path = os.path.join(work, "uv.exr")
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"RGB": px}).write(path)
    env = w.environment(bpy.data.images.load(path))
    env.interpolation = "Closest"
    w.mapping(env.inputs["Vector"], rotation=(0, 0, 30))
    scene = bpy.context.scene
    cam = scene.camera
    lens, res = cam.data.lens, (scene.render.resolution_x, scene.render.resolution_y)
    cam.data.lens = 5000.0
    scene.render.resolution_x = scene.render.resolution_y = 1
    directions = [(1, 0, 0), (0, 1, 0), (-1, 0.01, 0), (0, -1, 0), (1, 0, 1), (0, 1, -1), (0.3, -0.5, 0.2),
                  (-0.6, -0.2, 0.5)]
    seen = []
    scene.cycles.samples = 1
    for d in directions:
        cam.rotation_euler = mathutils.Vector(d).to_track_quat("-Z", "Y").to_euler()
        out = os.path.join(work, "probe.exr")
        cc.cycles(scene, out)
        seen.append(cc.pixels(out)[0, 0, :2])
    cam.data.lens = lens
    scene.render.resolution_x, scene.render.resolution_y = res

    def check(x):
        rotate = x.bg["rotate"]
        for d, (u_cy, v_cy) in zip(directions, seen):
            d = np.array(d, float) / np.linalg.norm(d)
            a = math.radians(-rotate)
            dx, dy = math.cos(a) * d[0] - math.sin(a) * d[1], math.sin(a) * d[0] + math.cos(a) * d[1]
            wx, wy, wz = dx, d[2], -dy  # up = "z": (x, y, z) as the y-up (x, z, −y)
            u = (0.5 - math.atan2(wx, wz) / (2 * math.pi)) % 1.0
            v = math.acos(max(-1.0, min(1.0, wy))) / math.pi
            du = (u - u_cy + 0.5) % 1.0 - 0.5
            assert abs(du) <= 1.0 / n_u and abs(v - v_cy) <= 1.0 / n_v, \
                f"direction {d.round(3)}: Cycles reads texel ({u_cy:.4f}, {v_cy:.4f}), tilefarm ({u:.4f}, {v:.4f})"
        x.lines('world: Environment Texture "uv.exr": Closest interpolation rendered linear')
    return check


# What does not map -----------------------------------------------------------------------


@case
def tilted_and_moved_mapping_is_reported(w, work):
    env = w.environment(hdri(work)[0])
    w.mapping(env.inputs["Vector"], rotation=(20, 0, 30), location=(0.5, 0.0, 0.0))

    def check(x):
        x.background(rotate=60.0)
        x.lines('world: Environment Texture "spot.exr": the Mapping node\'s Location (0.5, 0, 0) offsets the direction '
                "(dropped)",
                'world: Environment Texture "spot.exr": its coordinates are tilted, mirrored or stretched (only their '
                "turn about Z, 30°, used)")
    return check


@case
def other_coordinates_are_reported(w, work):
    env = w.environment(hdri(work)[0])
    w.node("ShaderNodeTexCoord", env.inputs["Vector"], out="Window")

    def check(x):
        x.background(rotate=90.0)
        x.lines('world: Environment Texture "spot.exr": Window texture coordinates (the view direction used)')
    return check


@case
def mirror_ball_is_reported(w, work):
    w.environment(hdri(work)[0]).projection = "MIRROR_BALL"

    def check(x):
        x.no_background()
        x.lines('world: Environment Texture "spot.exr": mirror-ball projection: not mapped (equirectangular only; '
                "black here)")
    return check


@case
def other_textures_are_reported(w, work):
    w.node("ShaderNodeTexGradient", w.bg.inputs["Color"])

    def check(x):
        x.no_background()
        x.lines("world: the Background's Color from a Gradient Texture node: not mapped (black here)")
    return check


@case
def other_surfaces_are_reported(w, work):
    w.node("ShaderNodeEmission", w.nt.nodes["World Output"].inputs["Surface"], out="Emission")

    def check(x):
        x.no_background()
        x.lines("world: an Emission node as its surface: not mapped (black here)")
    return check


@case
def constant_colour_times_strength(w, work):
    w.bg.inputs["Color"].default_value = (0.2, 0.4, 0.6, 1.0)
    w.bg.inputs["Strength"].default_value = 1.5

    def check(x):
        x.background(radiance=[0.3, 0.6, 0.9])
        assert set(x.bg) == {"radiance"}, x.bg  # nothing else: no strength, rotate or up
        x.lines()
    return check


@case
def linked_strength_is_reported(w, work):
    env = w.environment(hdri(work)[0], strength=3.0)
    w.node("ShaderNodeLightPath", w.bg.inputs["Strength"], out="Is Camera Ray")
    del env

    def check(x):
        x.background(strength=3.0)
        x.lines("world: the Background's Strength from a Light Path node: not mapped (its unlinked value 3 used)")
    return check


# Sky Texture -----------------------------------------------------------------------------


@case
def nishita_sky_is_a_map_and_a_sun(w, work):
    """A Nishita sky (sun at 30° elevation, rotation 40°): its sky rendered into a map,
    its sun disc a directional light coming from its direction, both said."""
    sky = w.node("ShaderNodeTexSky", w.bg.inputs["Color"], sun_elevation=math.radians(30),
                 sun_rotation=math.radians(40))
    sun = world_mod.sun_direction(sky)

    def check(x):
        x.background(strength=1.0, rotate=180.0, up="z")
        assert x.bg["map"].startswith("sky-") and x.bg["map"].endswith(".exr"), x.bg
        rgb = np.asarray(OpenEXR.File(os.path.join(x.folder, x.bg["map"])).channels()["RGBA"].pixels)[..., :3]
        # Blender's Nishita sky fades to black 23.6° below the horizon (its row 42 of 64).
        top, bottom = rgb[: rgb.shape[0] // 2].mean(), rgb[44:].mean()
        assert top > 0.1 and bottom < 1e-3 * top, f"the sky map: upper half {top}, below −33° {bottom}"
        lights = x.scene.get("light", [])
        assert len(lights) == 1 and lights[0]["type"] == "directional", lights
        expect("the sun's direction", lights[0]["direction"], (-sun).round(4).tolist(), 1e-3)
        assert min(lights[0]["irradiance"]) > 1.0, lights[0]
        assert len(x.warned) == 1 and x.warned[0].startswith("world: a Sky Texture node (Nishita): not mapped "
                                                             "exactly; rendered by Cycles into a 128 × 64 map"), \
            x.warned
        assert "its sun disc a directional light of irradiance" in x.warned[0], x.warned
        x.lines(*x.warned)
    return check


@case
def preetham_sky_is_a_map_without_a_sun(w, work):
    w.node("ShaderNodeTexSky", w.bg.inputs["Color"], sky_type="PREETHAM")

    def check(x):
        x.background(rotate=180.0)
        assert "light" not in x.scene, x.scene["light"]
        assert len(x.warned) == 1 and "(Preetham)" in x.warned[0] and "sun disc" not in x.warned[0], x.warned
        x.lines(*x.warned)
    return check


def build(fn, work):
    scene = cc.fresh()
    cc.cycles_settings(scene, 16, seed=1)
    cc.quad("floor", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], cc.principled("grey", (0.5, 0.5, 0.5)))
    cc.camera(scene, (0.0, -4.0, 2.0), (0.0, 0.0, 0.0))
    return scene, fn(World(scene), work)


def loads_in_tilefarm(coordinator, folder):
    cmd = [coordinator, "render", os.path.join(folder, "scene.toml"), "-q", "--spp", "1", "--width", "16",
           "--height", "16", "--local-workers", "0", "-o", os.path.join(folder, "render.exr")]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, f"tilefarm does not render it: {run.stderr.strip()}"


def main():
    work = sys.argv[1]
    coordinator = sys.argv[2] if len(sys.argv) > 2 else None
    os.makedirs(work, exist_ok=True)
    started = time.perf_counter()
    failed = {}
    for fn in CASES:
        name = fn.__name__
        try:
            scene, check = build(fn, work)
            folder = os.path.join(work, name)
            check(Exported(folder, export_scene(folder, scene)))
            if coordinator:
                loads_in_tilefarm(coordinator, folder)
        except AssertionError as e:
            failed[name] = str(e)
    print(json.dumps({"cases": [fn.__name__ for fn in CASES], "failed": failed,
                      "rendered": bool(coordinator), "seconds": round(time.perf_counter() - started, 2)}))
    for name, why in failed.items():
        print(f"FAILED {name}: {why}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # bpy 4.2 can crash at interpreter shutdown (see compare_cycles.py)
