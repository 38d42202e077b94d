"""Blender's world as tilefarm's `[background]` (README.md, "Environment maps"): a
constant colour × strength as `radiance`; an Environment Texture (equirectangular) on
the Background, maybe through Mapping nodes, as `map`, `strength`, `rotate` and
`up = "z"`; a Sky Texture rendered by Cycles into a small map (its sun disc a
directional light). What does not map is one line of the export's warning each, never
dropped silently.

Orientation (checked against Cycles 4.2: blender/tests/world_export.py and
compare_world.py): Blender looks a direction d up in an equirectangular image at
u = 1/2 − atan2(d_y, d_x)/2π, v (from the bottom) = 1/2 + asin(d_z)/π; tilefarm with
`up = "z"` at u = 1/2 − atan2(x', −y')/2π, v (from the top) = acos(z')/π, where d' is d
turned by −rotate about +Z. The two agree when rotate = 90°. A Mapping node turning its
input by φ about Z (types Point, Vector, Normal; Texture turns by −φ) makes Blender look
up Rz(φ)·d, which tilefarm does with rotate = 90° − φ. Blender's rows are pixels (row i
at v = (i + ½)/H), tilefarm's, as Mitsuba's, samples from pole to pole (row i at
i/(H − 1)): the same at the horizon, half a row apart at the poles (of a 64-row map,
1.4° there; the map's total 1.6 % brighter).
"""

import hashlib
import json
import math
import os
import shutil
import tempfile

import bpy
import mathutils
import numpy as np

from . import textures as tex

# The Blender colour spaces whose numbers are linear Rec.709 (what an EXR or HDR file
# is read as).
LINEAR = {"Linear Rec.709", "Non-Color", "Linear", "Linear BT.709", "Raw"}
FLOAT_FILES = (".exr", ".hdr")
SKY_PROPS = ("sky_type", "sun_disc", "sun_size", "sun_intensity", "sun_elevation", "sun_rotation", "altitude",
             "air_density", "dust_density", "ozone_density", "turbidity", "ground_albedo", "sun_direction")
SKY_W, SKY_H = 128, 64  # a Sky Texture's map
_SKY_CACHE = {}  # a world's fingerprint -> its map and sun, so that an animation renders it once


def _vec(v):
    return "[" + ", ".join(f"{float(c):.9g}" for c in v) + "]"


def _clean(x):
    r = round(x, 4)
    return 0.0 if r == 0.0 else r


def background(world, folder, write_image, warn):
    """The `[background]` table's lines for `world` (none when it is black), and a Sky
    Texture's sun as a `[[light]]`. `write_image(image)` writes an image into the scene
    `folder` and returns its file name (raising if it cannot); `warn(line)` adds a line
    to the export's warning. What it says is also the table's `warning`, which tilefarm
    repeats whenever it loads the scene."""
    said = []

    def note(line):
        said.append(line)
        warn(line)

    lines = _background(world, folder, write_image, note)
    if not said:
        return lines
    text = "the Blender world is not exactly this: " + "; ".join(w[len("world: "):] for w in said)
    if "[background]" not in lines:
        lines = ["", "[background]"] + lines
    at = lines.index("[background]") + 1
    return lines[:at] + [f"warning = {json.dumps(text, ensure_ascii=False)}"] + lines[at:]


def _background(world, folder, write_image, warn):
    if world is None:
        return []
    if not world.use_nodes or world.node_tree is None:
        return _constant([float(c) for c in world.color])
    out = next((n for n in world.node_tree.nodes if n.type == "OUTPUT_WORLD" and n.is_active_output), None)
    src = tex.source(out.inputs["Surface"]) if out is not None else None
    if src is None:
        return []
    node = src[0]
    if node.type != "BACKGROUND":
        warn(f"world: {_a(node)} as its surface: not mapped (black here)")
        return []
    color = tex.source(node.inputs["Color"])
    if color is not None and color[0].type == "TEX_SKY":
        return _sky(world, color[0], folder, warn)  # the whole world, as Cycles renders it
    strength = float(node.inputs["Strength"].default_value)
    linked = tex.source(node.inputs["Strength"])
    if linked is not None:
        warn(f"world: the Background's Strength from {_a(linked[0])}: not mapped "
             f"(its unlinked value {strength:.6g} used)")
    if color is None:
        return _constant([float(c) * strength for c in node.inputs["Color"].default_value[:3]])
    cnode, cout = color
    if cnode.type == "RGB":
        return _constant([float(c) * strength for c in cout.default_value[:3]])
    if cnode.type == "TEX_ENVIRONMENT":
        return _environment(cnode, cout, strength, write_image, warn)
    warn(f"world: the Background's Color from {_a(cnode)}: not mapped (black here)")
    return []


def _a(node):
    """A node as the warning names it, with its article."""
    text = tex.describe(node)
    return ("an " if text[0].lower() in "aeiou" else "a ") + text


def _constant(radiance):
    if not any(c > 0 for c in radiance):
        return []
    return ["", "[background]", f"radiance = {_vec([max(0.0, c) for c in radiance])}"]


# Environment Texture --------------------------------------------------------------------


def _environment(node, out, strength, write_image, warn):
    image = node.image
    what = "world: Environment Texture"
    if image is None:
        warn(f"{what} with no image: not mapped (Cycles shows magenta; black here)")
        return []
    what = f'world: Environment Texture "{image.name}"'
    if out.name != "Color":
        warn(f"{what}: its {out.name} output into the Background's Color: not mapped (black here)")
        return []
    if node.projection != "EQUIRECTANGULAR":
        warn(f"{what}: {node.projection.lower().replace('_', '-')} projection: not mapped (equirectangular "
             "only; black here)")
        return []
    if strength <= 0.0:
        if strength < 0.0:
            warn(f"world: the Background's Strength {strength:.6g} is negative (black here)")
        return []
    if node.interpolation != "Linear":
        warn(f"{what}: {node.interpolation} interpolation rendered linear")
    if image.source in {"SEQUENCE", "MOVIE", "TILED"}:
        warn(f"{what}: an image {image.source.lower()} (one image of it written)")
    problems = []
    m = direction_matrix(node.inputs["Vector"], problems)
    for p in problems:
        warn(f"{what}: {p}")
    rotate, exact = rotate_of(m)
    if not exact:
        warn(f"{what}: its coordinates are tilted, mirrored or stretched (only their turn about Z, "
             f"{90.0 - rotate:.6g}°, used)")
    try:
        file = write_image(image)
    except Exception as e:  # an image that cannot be written is reported, not fatal
        why = " ".join(str(e).split()) or type(e).__name__
        warn(f"{what}: not written ({why}; black here)")
        return []
    _colorspace(image, file, what, warn)
    return ["", "[background]", f"# the world's Environment Texture {json.dumps(image.name, ensure_ascii=False)}",
            f"map = {json.dumps(file, ensure_ascii=False)}", f"strength = {strength:.9g}", f"rotate = {rotate:.9g}",
            'up = "z"']


def _colorspace(image, file, what, warn):
    """tilefarm reads an EXR or HDR file's numbers as linear and decodes any other
    image from sRGB; Blender's colour space setting says what the numbers are."""
    space = image.colorspace_settings.name
    float_file = file.lower().endswith(FLOAT_FILES)
    if float_file and space not in LINEAR:
        warn(f'{what}: colour space "{space}" on a float image read as linear Rec.709')
    elif not float_file and space != "sRGB":
        warn(f'{what}: colour space "{space}" on an 8- or 16-bit image read as sRGB')


def _mapping_matrix(node, problems):
    """A Mapping node as the 3×3 matrix it applies to a direction (before Cycles
    normalises it); a Location that moves the direction is noted in `problems`."""
    values = {}
    for name in ("Location", "Rotation", "Scale"):
        sock = node.inputs.get(name)
        values[name] = tuple(float(x) for x in sock.default_value) if sock is not None else (0.0, 0.0, 0.0)
        if sock is not None and sock.enabled and tex.source(sock) is not None:
            problems.append(f"the Mapping node's {name} from {_a(tex.source(sock)[0])} "
                            "(its unlinked value used)")
    r = np.array(tex._euler(*values["Rotation"]))
    s = np.array(values["Scale"])
    kind = node.vector_type
    inv = np.array([1.0 / x if x != 0.0 else 0.0 for x in s])  # Blender's safe_divide
    if kind == "TEXTURE":  # out = Rᵀ·(v − T) / S
        m = np.diag(inv) @ r.T
    elif kind == "NORMAL":  # out = normalize(R·(v / S))
        m = r @ np.diag(inv)
    else:  # POINT: out = R·(S ⊙ v) + T; VECTOR: without T
        m = r @ np.diag(s)
    if kind in {"POINT", "TEXTURE"} and any(abs(x) > 1e-9 for x in values["Location"]):
        loc = ", ".join(f"{x:.3g}" for x in values["Location"])
        problems.append(f"the Mapping node's Location ({loc}) offsets the direction (dropped)")
    return m


def direction_matrix(vector, problems):
    """The matrix M the texture's Vector input applies to the view direction d (the
    texture looks up M·d): unlinked or Texture Coordinate's Generated (d itself, in the
    world), through any chain of Mapping nodes."""
    m = np.eye(3)
    src = tex.source(vector)
    for _ in range(16):
        if src is None or src[0].type != "MAPPING":
            break
        m = m @ _mapping_matrix(src[0], problems)
        src = tex.source(src[0].inputs["Vector"])
        if src is None:
            problems.append("a Mapping node with nothing linked into its Vector (a constant in Blender; the view "
                            "direction used)")
    if src is not None:
        node, out = src
        if node.type == "TEX_COORD" and out.name == "Generated":
            pass
        elif node.type == "TEX_COORD":
            problems.append(f"{out.name} texture coordinates (the view direction used)")
        else:
            problems.append(f"texture coordinates from {_a(node)} (the view direction used)")
    return m


def rotate_of(m):
    """`rotate` (degrees, `up = "z"`) that looks a direction d up where Blender looks up
    M·d, and whether M is exactly a positive multiple of a turn about Z (else only its
    turn about Z is kept)."""
    phi = math.atan2(m[1][0], m[0][0]) if abs(m[0][0]) + abs(m[1][0]) > 0.0 else 0.0
    c = m[2][2]
    turn = np.array([[math.cos(phi), -math.sin(phi), 0.0], [math.sin(phi), math.cos(phi), 0.0], [0.0, 0.0, 1.0]])
    exact = c > 0.0 and np.allclose(m / c, turn, atol=1e-6)
    rotate = (90.0 - math.degrees(phi) + 180.0) % 360.0 - 180.0
    return _clean(rotate), bool(exact)


# Sky Texture ----------------------------------------------------------------------------


def sun_direction(sky):
    """The Nishita sun's direction in the texture's coordinates (measured in Cycles 4.2:
    azimuth 90° − Sun Rotation from +X, elevation Sun Elevation)."""
    e, r = sky.sun_elevation, sky.sun_rotation
    return np.array([math.cos(e) * math.sin(r), math.cos(e) * math.cos(r), math.sin(e)])


def _sky(world, node, folder, warn):
    what = f"world: a Sky Texture node ({node.sky_type.replace('_', '-').title()})"
    try:
        key = _fingerprint(world)
        if key not in _SKY_CACHE:
            _SKY_CACHE.clear()
            _SKY_CACHE[key] = _measure_sky(world, node)
        exr, peak, sun = _SKY_CACHE[key]
    except Exception as e:  # Cycles could not render it: said, and black
        why = " ".join(str(e).split()) or type(e).__name__
        warn(f"{what}: not mapped, and Cycles could not render it into a map ({why}; black here)")
        return []
    lines = []
    file = None
    if peak > 0.0:
        file = f"sky-{hashlib.sha256(exr).hexdigest()[:16]}.exr"
        with open(os.path.join(folder, file), "wb") as f:
            f.write(exr)
        # The panorama's left edge looks along −Y (Blender's u = 3/4): a half turn.
        lines += ["", "[background]", "# the world's Sky Texture as Cycles renders it (its sun disc a light)",
                  f"map = {json.dumps(file, ensure_ascii=False)}", "strength = 1", "rotate = 180", 'up = "z"']
    line = (f"{what}: not mapped exactly; rendered by Cycles into a {SKY_W} × {SKY_H} map "
            f"({file or 'black: nothing'}, smooth at that size)")
    if sun is not None:
        direction, irradiance = sun
        # The disc's angular diameter, as a soft sun (tilefarm takes angles under 180°).
        angle = min(math.degrees(node.sun_size), 179.99)
        line += f", its sun disc a directional light of irradiance {_vec(irradiance)} and angle {angle:.4g}°"
        lines += ["", "[[light]]", "# the Sky Texture's sun disc", 'type = "directional"',
                  f"direction = {_vec(direction)}", f"irradiance = {_vec(irradiance)}", f"angle = {angle:.9g}"]
    warn(line)
    return lines


def _fingerprint(world):
    nodes = []
    for n in world.node_tree.nodes:
        inputs = []
        for s in n.inputs:
            v = getattr(s, "default_value", None)
            inputs.append(tuple(v) if hasattr(v, "__len__") else v)
        props = tuple(getattr(n, p, None) for p in SKY_PROPS + ("vector_type", "mute", "is_active_output"))
        props = tuple(tuple(p) if hasattr(p, "__len__") and not isinstance(p, str) else p for p in props)
        nodes.append((n.name, n.bl_idname, props, tuple(inputs)))
    links = tuple((k.from_node.name, k.from_socket.identifier, k.to_node.name, k.to_socket.identifier, k.is_muted)
                  for k in world.node_tree.links)
    return (world.name, tuple(nodes), links)


def _measure_sky(world, node):
    """Renders `world` with Cycles (a copy, in a scene of its own): its sky without the
    sun disc as an equirectangular panorama, the OpenEXR file's bytes and its brightest
    value; and, for a Nishita sun disc above the horizon, its direction and irradiance
    (a narrow view of the disc, less the same view without it)."""
    # What is needed of the node, read before new data blocks may move it.
    name, nishita = node.name, node.sky_type == "NISHITA"
    disc = nishita and node.sun_disc and node.sun_elevation > -node.sun_size / 2
    size = max(node.sun_size, math.radians(0.05))
    sun_dir = None
    if disc:
        vector = next((i for i in node.inputs if i.identifier == "Vector"), None)  # 4.2 hides it
        m = direction_matrix(vector, []) if vector is not None else np.eye(3)
        if abs(np.linalg.det(m)) > 1e-12:
            sun_dir = np.linalg.solve(m, sun_direction(node))
            sun_dir = sun_dir / np.linalg.norm(sun_dir)
    copy = world.copy()
    folder = tempfile.mkdtemp(prefix="tilefarm-sky-")
    scene = bpy.data.scenes.new("tilefarm-sky")
    cam_data = bpy.data.cameras.new("tilefarm-sky")
    cam = bpy.data.objects.new("tilefarm-sky", cam_data)
    try:
        scene.world = copy
        scene.collection.objects.link(cam)
        scene.camera = cam
        scene.render.engine = "CYCLES"
        c = scene.cycles
        c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = "CPU", 16, False, False
        scene.render.image_settings.file_format = "OPEN_EXR"
        scene.render.image_settings.color_depth = "32"
        scene.render.image_settings.exr_codec = "ZIP"
        sky = copy.node_tree.nodes[name]
        if nishita:
            sky.sun_disc = False
        # The whole sphere, its poles on ±Z: rows from the zenith (top) to the nadir,
        # the left edge looking along −Y.
        cam_data.type = "PANO"
        cam_data.panorama_type = "EQUIRECTANGULAR"
        cam.rotation_euler = (math.pi / 2, 0.0, 0.0)
        path, px = _render(scene, folder, SKY_W, SKY_H)
        with open(path, "rb") as f:
            exr = f.read()
        sun = _measure_disc(scene, cam, cam_data, folder, sky, sun_dir, size) if sun_dir is not None else None
        return exr, float(px.max()), sun
    finally:
        bpy.data.scenes.remove(scene)
        bpy.data.objects.remove(cam)
        bpy.data.cameras.remove(cam_data)
        bpy.data.worlds.remove(copy)
        shutil.rmtree(folder, ignore_errors=True)


def _measure_disc(scene, cam, cam_data, folder, sky, d, size):
    """The sun disc's irradiance on a surface facing it: a square view of twice its
    diameter rendered with the disc and without, the difference summed over the
    pixels' solid angles. None when it adds nothing (below the horizon)."""
    n = 32
    cam_data.type = "PERSP"
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.angle = 2.0 * size
    cam.rotation_euler = mathutils.Vector(d.tolist()).to_track_quat("-Z", "Y").to_euler()
    scene.cycles.samples = 64
    sky.sun_disc = True
    lit = _render(scene, folder, n, n)[1]
    sky.sun_disc = False
    unlit = _render(scene, folder, n, n)[1]
    t = math.tan(size)
    x = (np.arange(n) + 0.5) / n * 2.0 * t - t
    r2 = x[None, :] ** 2 + x[:, None] ** 2
    d_omega = (2.0 * t / n) ** 2 / (1.0 + r2) ** 1.5
    irradiance = ((lit - unlit) * d_omega[..., None]).sum(axis=(0, 1))
    if not (irradiance > 0.0).any():
        return None
    return [_clean(float(v)) for v in -d], [float(max(0.0, v)) for v in irradiance]


def _render(scene, folder, width, height):
    """`scene` rendered by Cycles: its OpenEXR file, and its linear RGB (rows top to
    bottom)."""
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    path = os.path.join(folder, f"render-{width}x{height}.exr")
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True, scene=scene.name)
    img = bpy.data.images.load(path)
    try:
        px = np.empty(width * height * 4, np.float32)
        img.pixels.foreach_get(px)
    finally:
        bpy.data.images.remove(img)
    return path, px.reshape(height, width, 4)[::-1, :, :3].astype(np.float64)
