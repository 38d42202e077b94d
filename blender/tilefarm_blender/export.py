"""A Blender scene as a tilefarm scene folder: `scene.toml`, one OBJ per distinct mesh
(modifiers applied, in its object's space, placed by its world matrix) with an MTL of
its materials, both named by the digest of their content (meshes that are the same, in
one frame or across an animation's frames, share one file), and the textures. Each
material is also a `[materials.NAME]` table at the end of scene.toml (materials.py),
which overrides its MTL namesake with everything MTL cannot say. The world is
`[background]` (world.py): a constant colour, an Environment Texture's image as a map,
a Sky Texture rendered by Cycles into one.

Blender's world coordinates are kept as they are (Z up): the camera's `up` says which
way is up, and both are right-handed, so nothing is mirrored. The camera looks down its
local −Z with +Y up and +X right; tilefarm's right is forward × up, which is that +X, so
an object to the camera's right in Blender is on the image's right.

Light units, measured against Cycles 4.2 (a white Lambertian plane under each light):
a point or spot light of power P watts has intensity P / 4π W/sr, and its Radius is
`radius`, a disk of that radius facing the point it lights (Cycles' Soft Falloff); a sun
of strength S gives irradiance S W/m², and its Angle is `angle` (degrees), a disc of
directions of that diameter; an area light of power P and area A has radiance P / (π A),
emitted from its front (local −Z) only (tilefarm's `type = "area"` takes Blender's
power, size and matrix as they are); an Emission shader of strength s emits s × its
colour.
"""

import hashlib
import math
import os
import time

import bpy
import mathutils
import numpy as np

from . import materials as mats
from . import textures as tex
from . import world as world_mod

MESH_TYPES = {"MESH", "CURVE", "SURFACE", "META", "FONT"}


class Report:
    """What an export wrote and what it could not map."""

    def __init__(self):
        self.warnings = []
        self.meshes = 0
        self.mesh_files = 0
        self.triangles = 0
        self.seconds = 0.0

    def warn(self, what):
        if what not in self.warnings:
            self.warnings.append(what)

    def summary(self):
        """The one warning listing everything not mapped, or None."""
        if not self.warnings:
            return None
        return f"tilefarm export: {len(self.warnings)} thing(s) not mapped exactly:\n  - " + "\n  - ".join(self.warnings)


def _rows(tag, a):
    """OBJ lines `tag x y …` of the rows of `a`, formatted in one go (a million
    triangles' worth in seconds, not minutes)."""
    if len(a) == 0:
        return ""
    line = tag + " %.9g" * a.shape[1] + "\n"  # float32 round-trips in 9 digits
    return (line * len(a)) % tuple(a.astype(np.float64).ravel().tolist())


def _vec(v):
    return "[" + ", ".join(f"{float(c):.9g}" for c in v) + "]"


def _matrix(m):
    rows = [[float(m[r][c]) for c in range(4)] for r in range(4)]
    rows[3] = [0.0, 0.0, 0.0, 1.0]
    return "[" + ", ".join(_vec(r) for r in rows) + "]"


class _Exporter:
    def __init__(self, folder, scene, report):
        self.folder = folder
        self.scene = scene
        self.report = report
        self.names = set()
        self.materials = {}  # material (or None) -> Mapped
        self.by_name = {}  # its MTL name -> Mapped
        self.textures = {}  # image name -> file name (or why it could not be written)
        self.texture_names = set()
        self.objs = {}  # digest -> file name
        self.toml = []

    # Materials -----------------------------------------------------------------------

    def material(self, material):
        key = material.original if material is not None else None
        if key in self.materials:
            return self.materials[key].name
        label = material.name if material is not None else "default"
        name = mats.safe_name(label, self.names)
        mapped = mats.map_material(material, name, self.names)
        for ref in mapped.refs():
            image = ref.image
            try:
                ref.file = self.texture_file(image)
            except Exception as e:  # a texture that cannot be saved is reported, not fatal
                why = " ".join(str(e).split()) or type(e).__name__
                self.report.warn(f"material {label}: texture {image.name} not written ({why}; the input's "
                                 "own value used)")
        mapped.resolve()
        for p in mapped.problems:
            self.report.warn(f"material {label}: {p}")
        self.materials[key] = mapped
        self.by_name[name] = mapped
        return name

    def texture_file(self, image):
        """`image` written into the folder (once, by its name): its file name there.
        Raises if it cannot be written (and again for each later use)."""
        if image.name not in self.textures:
            try:
                self.textures[image.name] = tex.write_texture(image, self.folder, self.texture_names, mats.safe_name)
            except Exception as e:
                self.textures[image.name] = e
                raise
        if isinstance(self.textures[image.name], Exception):
            raise self.textures[image.name]
        return self.textures[image.name]

    def material_tables(self):
        """scene.toml's `[materials]` tables of the materials written (they override the
        MTL materials of the same names)."""
        out = []
        for mapped in self.materials.values():
            out += mapped.toml()
        return out

    # Meshes --------------------------------------------------------------------------

    def mesh(self, ob, matrix):
        try:
            mesh = ob.to_mesh()
        except RuntimeError:
            mesh = None
        if mesh is None:
            return
        try:
            mesh.calc_loop_triangles()
            n_tris = len(mesh.loop_triangles)
            if n_tris == 0:
                return
            body, used = self.obj_text(ob, mesh, n_tris)
        finally:
            ob.to_mesh_clear()
        file_name = self.write_obj("mesh", body, used)
        self.report.meshes += 1
        self.report.triangles += n_tris
        if matrix.determinant() < 0:
            self.report.warn(f"object {ob.name}: mirrored by a negative scale (its faces' fronts flip)")
        self.toml += ["", "[[mesh]]", f"# {ob.name}", f'obj = "{file_name}"', f"matrix = {_matrix(matrix)}"]

    def write_obj(self, prefix, body, used):
        """Writes an OBJ of `body` (its lines after `mtllib`) and an MTL of the materials
        it `used`, both named by the digest of their content, so that what does not
        change between frames (or objects) is one file; the OBJ's name."""
        mtl = "# exported from Blender by tilefarm_blender\n" + "".join("\n" + self.by_name[n].mtl() for n in used)
        digest = hashlib.sha256((body + "\0" + mtl).encode()).hexdigest()
        name = f"{prefix}-{digest[:16]}"
        # Content-addressed: a file already there (an earlier frame's) is this one.
        if digest not in self.objs and not os.path.isfile(os.path.join(self.folder, name + ".obj")):
            self.objs[digest] = name
            with open(os.path.join(self.folder, name + ".mtl"), "w", encoding="utf-8") as f:
                f.write(mtl)
            with open(os.path.join(self.folder, name + ".obj"), "w", encoding="utf-8") as f:
                f.write(f"# exported from Blender by tilefarm_blender\nmtllib {name}.mtl\n" + body)
            self.report.mesh_files += 1
        return name + ".obj"

    def obj_text(self, ob, mesh, n_tris):
        nv, nl = len(mesh.vertices), len(mesh.loops)
        co = np.empty(nv * 3, np.float32)
        mesh.vertices.foreach_get("co", co)
        tri_v = np.empty(n_tris * 3, np.int64)
        mesh.loop_triangles.foreach_get("vertices", tri_v)
        tri_l = np.empty(n_tris * 3, np.int64)
        mesh.loop_triangles.foreach_get("loops", tri_l)
        tri_m = np.empty(n_tris, np.int64)
        mesh.loop_triangles.foreach_get("material_index", tri_m)
        normals = np.empty(nl * 3, np.float32)
        mesh.corner_normals.foreach_get("vector", normals)
        uv = None
        if mesh.uv_layers.active is not None:
            uv = np.empty(nl * 2, np.float32)
            mesh.uv_layers.active.data.foreach_get("uv", uv)
        # Corners share normals and uvs: each distinct one is written once.
        normals, normal_of = np.unique(normals.reshape(-1, 3), axis=0, return_inverse=True)
        out = [_rows("v", co.reshape(-1, 3)), _rows("vn", normals)]
        used = []
        uv_of = None
        if uv is not None:
            uvs, uv_of = np.unique(uv.reshape(-1, 2), axis=0, return_inverse=True)
            out.append(_rows("vt", uvs))
        slots = ob.material_slots
        tri_v = tri_v.reshape(-1, 3) + 1
        corner_n = normal_of.reshape(-1)[tri_l].reshape(-1, 3) + 1
        corner_t = uv_of.reshape(-1)[tri_l].reshape(-1, 3) + 1 if uv_of is not None else None
        for mi in np.unique(tri_m):
            material = slots[mi].material if mi < len(slots) else None
            used.append(self.material(material))
            out.append(f"usemtl {used[-1]}\n")
            pick = tri_m == mi
            if corner_t is not None:
                corners = np.stack([tri_v[pick], corner_t[pick], corner_n[pick]], -1).reshape(-1, 9)
                out.append(("f %d/%d/%d %d/%d/%d %d/%d/%d\n" * len(corners)) % tuple(corners.ravel().tolist()))
            else:
                corners = np.stack([tri_v[pick], corner_n[pick]], -1).reshape(-1, 6)
                out.append(("f %d//%d %d//%d %d//%d\n" * len(corners)) % tuple(corners.ravel().tolist()))
        return "".join(out), used

    # Lights --------------------------------------------------------------------------

    def light(self, ob, matrix):
        light = ob.data
        color = [float(c) for c in light.color]
        pos = matrix.translation
        aim = -(matrix.to_3x3() @ mathutils.Vector((0.0, 0.0, 1.0))).normalized()
        if light.use_nodes:
            self.report.warn(f"light {ob.name}: its node tree (only its colour and power are used)")
        if light.type in {"POINT", "SPOT"}:
            intensity = [c * light.energy / (4.0 * math.pi) for c in color]
            radius = float(light.shadow_soft_size)
            self.toml += ["", "[[light]]", f"# {ob.name}", f'type = "{light.type.lower()}"', f"position = {_vec(pos)}"]
            if light.type == "SPOT":
                half = light.spot_size / 2.0
                cos_half = math.cos(half)
                full = math.acos(min(1.0, cos_half + (1.0 - cos_half) * light.spot_blend))
                self.toml += [f"direction = {_vec(aim)}", f"cone_angle = {math.degrees(half):.6g}",
                              f"falloff_start = {math.degrees(min(full, half)):.6g}"]
            self.toml.append(f"intensity = {_vec(intensity)}")
            if radius > 0.0:
                # Blender's Radius, as Cycles uses it: a disk of that radius facing the
                # point it lights (Soft Falloff, Blender's default), radiance I / (π r²).
                self.toml.append(f"radius = {radius:.9g}")
                if not getattr(light, "use_soft_falloff", True):
                    self.report.warn(f"light {ob.name}: Soft Falloff off (Cycles makes it a sphere of radius "
                                     f"{radius:.3g}, I / d² up to its surface; here a disk facing what it lights, "
                                     "I / (d² + r²): darker within a few radii)")
        elif light.type == "SUN":
            irradiance = [c * light.energy for c in color]
            self.toml += ["", "[[light]]", f"# {ob.name}", 'type = "directional"', f"direction = {_vec(aim)}",
                          f"irradiance = {_vec(irradiance)}"]
            angle = math.degrees(light.angle)
            if angle > 0.0:
                # Blender's Angle (the disc's angular diameter), in degrees; tilefarm takes
                # less than 180°.
                if angle >= 179.99:
                    self.report.warn(f"light {ob.name}: sun angle {angle:.4g}° (179.99° here)")
                    angle = 179.99
                self.toml.append(f"angle = {angle:.9g}")
        elif light.type == "AREA":
            self.area_light(ob, light, color, matrix)
        else:
            self.report.warn(f"light {ob.name}: type {light.type}")

    def area_light(self, ob, light, color, matrix):
        """An area light as `type = "area"`: its shape and size, placed by its world
        matrix (whose scale scales it, as in Blender), its power and colour, and
        `visible` from the object's camera visibility (off by default for lights)."""
        cy = getattr(light, "cycles", None)
        if cy is not None and cy.is_portal:
            self.report.warn(f"light {ob.name}: a portal (skipped: in Cycles it only guides the world's sampling)")
            return
        shape = light.shape
        size = [light.size, light.size_y] if shape in {"RECTANGLE", "ELLIPSE"} else [light.size, light.size]
        m = matrix.copy()
        x, y = m.col[0].xyz, m.col[1].xyz
        if min(size) <= 0.0 or x.length * size[0] <= 0.0 or y.length * size[1] <= 0.0:
            self.report.warn(f"light {ob.name}: zero area (skipped)")
            return
        if abs(x.normalized().dot(y.normalized())) > 1e-4:
            # A sheared frame (a non-uniform scale under a rotated parent): tilefarm's
            # light is a rectangle or ellipse, so its y axis is turned square to its x.
            y_square = (y - x * (x.dot(y) / x.dot(x))).normalized() * y.length
            for r in range(3):
                m[r][1] = y_square[r]
            self.report.warn(f"light {ob.name}: a sheared shape (its y axis made square to its x)")
            y = y_square
        # Blender's light emits along its matrix's −Z; tilefarm's along the normal of its
        # x and y on that side. Cycles lights nothing with a Z scaled to nothing (its
        # direction is lost); a Z sheared off the normal becomes the unit normal.
        z, n = m.col[2].xyz, x.cross(y).normalized()
        if abs(z.dot(n)) <= 1e-6 * max(x.length, y.length):
            self.report.warn(f"light {ob.name}: its Z axis is scaled to nothing (Cycles lights nothing with it: "
                             "skipped)")
            return
        if (z - n * z.dot(n)).length > 1e-4 * z.length:
            n = -n if z.dot(n) < 0.0 else n
            for r in range(3):
                m[r][2] = n[r]
            self.report.warn(f"light {ob.name}: its Z axis is sheared off its plane's normal (the normal used)")
        kind = {"SQUARE": "rectangle", "RECTANGLE": "rectangle", "DISK": "disk", "ELLIPSE": "ellipse"}[shape]
        size_text = f"{size[0]:.9g}" if shape in {"SQUARE", "DISK"} else _vec(size)
        visible = bool(ob.visible_camera)
        self.toml += ["", "[[light]]", f"# {ob.name}", 'type = "area"', f'shape = "{kind}"', f"size = {size_text}",
                      f"matrix = {_matrix(m)}", f"power = {light.energy:.9g}", f"color = {_vec(color)}",
                      f"visible = {'true' if visible else 'false'}"]
        if visible:
            self.report.warn(f"light {ob.name}: visible to the camera: an emissive surface here, which also "
                             "casts shadows (Blender's does not)")
        if light.spread < math.pi - 1e-6:
            self.report.warn(f"light {ob.name}: spread {math.degrees(light.spread):.3g}° (180° here: its light "
                             "is not narrowed)")
        unseen = [what for what, flag in [("diffuse", "visible_diffuse"), ("glossy", "visible_glossy"),
                                          ("transmission", "visible_transmission")] if not getattr(ob, flag)]
        if unseen:
            self.report.warn(f"light {ob.name}: off for {', '.join(unseen)} rays (it lights every surface here)")
        if not light.use_shadow:
            self.report.warn(f"light {ob.name}: shadows off (shadowed here)")
        if cy is not None and not cy.use_multiple_importance_sampling:
            self.report.warn(f"light {ob.name}: multiple importance sampling off (on here)")

    # Camera, world and settings ------------------------------------------------------

    def camera(self, width, height):
        cam_ob = self.scene.camera
        if cam_ob is None:
            raise ValueError("the scene has no active camera")
        cam = cam_ob.data
        m = cam_ob.matrix_world
        pos = m.translation
        forward = -(m.to_3x3() @ mathutils.Vector((0.0, 0.0, 1.0))).normalized()
        up = (m.to_3x3() @ mathutils.Vector((0.0, 1.0, 0.0))).normalized()
        if cam.type != "PERSP":
            self.report.warn(f"camera {cam_ob.name}: {cam.type.lower()} projection (exported as perspective)")
        if cam.shift_x or cam.shift_y:
            self.report.warn(f"camera {cam_ob.name}: lens shift")
        fit = cam.sensor_fit
        if fit == "AUTO":
            fit, sensor = ("HORIZONTAL" if width >= height else "VERTICAL"), cam.sensor_width
        else:
            sensor = cam.sensor_width if fit == "HORIZONTAL" else cam.sensor_height
        half = sensor / (2.0 * cam.lens)
        tan_v = half * height / width if fit == "HORIZONTAL" else half
        fov = math.degrees(2.0 * math.atan(tan_v))
        distance = 1.0
        lens = []
        if cam.dof.use_dof:
            if cam.dof.focus_object is not None:
                distance = max((cam.dof.focus_object.matrix_world.translation - pos).dot(forward), 1e-4)
            else:
                distance = cam.dof.focus_distance
            unit = self.scene.unit_settings.scale_length or 1.0
            aperture = 0.5 * cam.lens * 1e-3 / cam.dof.aperture_fstop / unit
            lens = [f"aperture = {aperture:.9g}", f"focus_distance = {distance:.9g}"]
            if cam.dof.aperture_blades > 0:
                self.report.warn(f"camera {cam_ob.name}: {cam.dof.aperture_blades}-bladed aperture (a round one here)")
        look_at = pos + forward * distance
        return ["[camera]", f"# {cam_ob.name}", f"position = {_vec(pos)}", f"look_at = {_vec(look_at)}",
                f"up = {_vec(up)}", f"fov = {fov:.9g}", f"width = {width}", f"height = {height}"] + lens

    def background(self):
        """The `[background]` table (world.py), and a Sky Texture's sun as a light."""
        return world_mod.background(self.scene.world, self.folder, self.texture_file, self.report.warn)

    def render_settings(self):
        r = self.scene.render
        lines = ["[render]"]
        if r.engine == "CYCLES":
            c = self.scene.cycles
            lines += [f"spp = {c.samples}", f"max_depth = {c.max_bounces + 2}", f"seed = {c.seed}"]
            for what, used in [
                ("denoising (render with --denoise for OIDN)", c.use_denoising),
                ("sample clamping", c.sample_clamp_direct > 0 or c.sample_clamp_indirect > 0),
                ("fewer diffuse/glossy/transmission bounces than the total",
                 min(c.diffuse_bounces, c.glossy_bounces, c.transmission_bounces) < c.max_bounces),
            ]:
                if used:
                    self.report.warn(f"render: {what}")
        else:
            lines += ["spp = 64", "max_depth = 8"]
            self.report.warn(f"render: engine {r.engine} (Cycles' settings map; 64 spp, 8 segments here)")
        return lines


def export_scene(folder, scene=None, frame=None, toml="scene.toml"):
    """Writes `scene` (the current one by default), at `frame` if given, as a tilefarm
    scene folder (its scene file named `toml`); returns a Report. Raises ValueError when
    there is nothing to render."""
    started = time.perf_counter()
    scene = scene or bpy.context.scene
    if frame is not None:
        scene.frame_set(frame)
    os.makedirs(folder, exist_ok=True)
    report = Report()
    ex = _Exporter(folder, scene, report)
    r = scene.render
    width = max(1, round(r.resolution_x * r.resolution_percentage / 100))
    height = max(1, round(r.resolution_y * r.resolution_percentage / 100))
    if r.pixel_aspect_x != r.pixel_aspect_y:
        report.warn("render: non-square pixels")
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for inst in depsgraph.object_instances:
        ob = inst.object
        if ob.original.hide_render or (ob.type in MESH_TYPES and not ob.visible_camera):
            continue
        matrix = inst.matrix_world.copy()
        if ob.type in MESH_TYPES:
            ex.mesh(ob, matrix)
        elif ob.type == "LIGHT":
            ex.light(ob, matrix)
        elif ob.type not in {"CAMERA", "EMPTY", "ARMATURE", "LATTICE", "SPEAKER", "LIGHT_PROBE"}:
            report.warn(f"object {ob.name}: type {ob.type}")
    if report.meshes == 0:
        raise ValueError("nothing to render: the scene has no visible mesh")
    head = ["# exported from Blender " + bpy.app.version_string + " by tilefarm_blender", ""]
    head += ex.camera(width, height) + [""] + ex.render_settings()
    head += ex.background()
    with open(os.path.join(folder, toml), "w", encoding="utf-8") as f:
        f.write("\n".join(head + ex.toml + ex.material_tables()) + "\n")
    report.seconds = time.perf_counter() - started
    return report


def frame_file(frame):
    """The scene file of `frame` in an animation's folder: `scene.0007.toml`, the
    pattern `coordinator submit 'DIR/scene.####.toml' --frames A-B` reads."""
    return f"scene.{frame:04d}.toml"


def export_animation(folder, first, last, scene=None):
    """Writes frames `first` to `last` of `scene` into one folder, one scene file each
    ([`frame_file`]); meshes, materials and textures that do not change between frames
    are one file for all of them. Returns one Report for the whole range."""
    if last < first:
        raise ValueError(f"frames {first}-{last}: the last comes before the first")
    scene = scene or bpy.context.scene
    total = Report()
    started = time.perf_counter()
    files_before = set(os.listdir(folder)) if os.path.isdir(folder) else set()
    for frame in range(first, last + 1):
        r = export_scene(folder, scene, frame=frame, toml=frame_file(frame))
        for w in r.warnings:
            total.warn(w)
        total.meshes += r.meshes
        total.triangles += r.triangles
    total.mesh_files = len([f for f in os.listdir(folder) if f.endswith(".obj") and f not in files_before])
    total.seconds = time.perf_counter() - started
    return total
