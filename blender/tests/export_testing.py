"""Helpers of the export-level tests (`principled_export.py`, and the scenes of
`compare_principled.py`): images on disk, materials on planes, and the exported folder
read back (`tomllib` for scene.toml, the MTL files, the report's warning)."""

import glob
import os
import subprocess
import sys
import tomllib

import bpy
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
WHITE = [1.0, 1.0, 1.0]


def close(a, b, tol=1e-5):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= tol * np.maximum(1.0, np.abs(b))))


def expect(what, got, want, tol=1e-5):
    assert close(got, want, tol), f"{what}: {got!r}, expected {want!r}"


def save_image(work, name, px, colorspace="sRGB", float_buffer=False, on_disk=True):
    """A bpy image of `px` (rows bottom to top, RGBA), saved into `work` as PNG (or
    OpenEXR if `float_buffer`) unless not `on_disk`, with its colour space set."""
    h, w = px.shape[:2]
    img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=float_buffer)
    img.pixels[:] = np.asarray(px, np.float32).ravel()
    if on_disk:
        img.filepath_raw = os.path.join(work, name + (".exr" if float_buffer else ".png"))
        img.file_format = "OPEN_EXR" if float_buffer else "PNG"
        img.save()
    img.colorspace_settings.name = colorspace
    return img


class Build:
    """The scene under construction: images on disk in WORK, one plane per material."""

    def __init__(self, work):
        self.work = work
        self.planes = 0
        self.images = {}

    def image(self, name, colorspace="sRGB", alpha=False, float_buffer=False, on_disk=True):
        if name in self.images:
            return self.images[name]
        y, x = np.mgrid[0:8, 0:8] / 7.0
        px = np.stack([x, y, 0.5 + 0.4 * np.sin(6 * x) * y, 1.0 - 0.8 * x * y if alpha else np.ones_like(x)], -1)
        self.images[name] = save_image(self.work, name, px, colorspace, float_buffer, on_disk)
        return self.images[name]

    def material(self, name):
        """A new material with its default Principled BSDF on a plane of its own."""
        m = bpy.data.materials.new(name)
        m.use_nodes = True
        nt = m.node_tree
        bpy.ops.mesh.primitive_plane_add(size=1.0, location=(1.5 * (self.planes % 10), 1.5 * (self.planes // 10), 0))
        self.planes += 1
        bpy.context.object.data.materials.append(m)
        return m, nt, nt.nodes["Principled BSDF"]

    def shader(self, name, kind):
        """A material whose surface is a new `kind` node (the Principled BSDF removed)."""
        m, nt, p = self.material(name)
        nt.nodes.remove(p)
        node = nt.nodes.new(kind)
        nt.links.new(node.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
        return m, nt, node

    def texture(self, nt, image, interpolation="Linear", extension="REPEAT"):
        t = nt.nodes.new("ShaderNodeTexImage")
        t.image = image
        t.interpolation = interpolation
        t.extension = extension
        return t


class Exported:
    """What the export wrote: the tables, the MTL materials, the report."""

    def __init__(self, folder, report):
        self.folder = folder
        self.report = report
        with open(os.path.join(folder, "scene.toml"), "rb") as f:
            self.scene = tomllib.load(f)
        self.tables = self.scene.get("materials", {})
        self.mtl = {}
        for path in glob.glob(os.path.join(folder, "*.mtl")):
            name = None
            for line in open(path, encoding="utf-8"):
                words = line.split()
                if words and words[0] == "newmtl":
                    name = words[1]
                    self.mtl[name] = []
                elif words and name and not words[0].startswith("#"):
                    self.mtl[name].append(words)

    def table(self, name):
        assert name in self.tables, f"no [materials.{name}] in scene.toml (has {sorted(self.tables)})"
        return self.tables[name]

    def warned(self, material):
        """The warning's lines about `material`, without the `material NAME: ` prefix."""
        prefix = f"material {material}: "
        return [w[len(prefix):] for w in self.report.warnings if w.startswith(prefix)]

    def mtl_key(self, material, key):
        lines = [w for w in self.mtl[material] if w[0] == key]
        assert lines, f"{material}: no {key} in the MTL ({self.mtl[material]})"
        return lines[0][1:]

    def ref(self, material, key, **want):
        t = self.table(material)
        assert key in t, f"{material}: no {key} (keys {sorted(t)})"
        ref = t[key]
        assert isinstance(ref, dict), f"{material}.{key} is not a texture reference: {ref!r}"
        for field in ("file", "colorspace", "interpolation", "channel", "scale", "offset", "rotation", "clamp"):
            assert field in ref, f"{material}.{key}: no {field} (full, explicit references): {ref}"
        assert os.path.isfile(os.path.join(self.folder, ref["file"])), f"{ref['file']} not written"
        for field, value in want.items():
            got = ref.get(field)
            if isinstance(value, (int, float, list)) and not isinstance(value, bool):
                expect(f"{material}.{key}.{field}", got, value)
            else:
                assert got == value, f"{material}.{key}.{field}: {got!r}, expected {value!r}"
        return ref


def no_warning(x, name):
    assert not x.warned(name), f"{name}: unexpected warnings {x.warned(name)}"


def cli_prints_one_warning(x, work):
    """`python -m tilefarm_blender` on the saved scene prints the one warning (all of the
    export's lines) and writes the same scene.toml."""
    blend = os.path.join(work, "principled.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    out = os.path.join(work, "by-cli")
    env = dict(os.environ, PYTHONPATH=os.path.dirname(HERE))
    run = subprocess.run([sys.executable, "-m", "tilefarm_blender", out, "--blend", blend],
                         capture_output=True, text=True, timeout=300, env=env)
    assert run.returncode == 0, run.stderr
    assert run.stderr.count("tilefarm export:") == 1, run.stderr
    lines = [w[4:] for w in run.stderr.splitlines() if w.startswith("  - ")]
    assert lines == x.report.warnings, f"the CLI's warning differs:\n{run.stderr}"
    with open(os.path.join(out, "scene.toml"), "rb") as f:
        assert tomllib.load(f)["materials"] == x.tables, "the CLI's tables differ"


def every_mesh_material_has_a_table(x):
    """Every material an OBJ uses has its table (which overrides it by name)."""
    used = set()
    for path in glob.glob(os.path.join(x.folder, "*.obj")):
        used |= {line.split()[1] for line in open(path, encoding="utf-8") if line.startswith("usemtl ")}
    missing = sorted(used - set(x.tables))
    assert not missing, f"materials without a table: {missing}"
    for name, t in x.tables.items():
        for part in t.get("mix", []):
            assert part in x.tables, f"{name} mixes {part}, which has no table"
