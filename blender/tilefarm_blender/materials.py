"""Blender materials as MTL materials: the Principled BSDF (and the plain Diffuse,
Emission and Glass shaders) mapped onto the keys tilefarm shades (see README.md,
"From Blender"). What cannot be mapped is reported, never silently dropped."""

import os
import re
import shutil

# Principled inputs that change the look and have no MTL counterpart: reported when
# used (a weight above zero, or any link into them).
UNMAPPED_INPUTS = {
    "Subsurface Weight": "subsurface",
    "Sheen Weight": "sheen",
    "Coat Weight": "coat",
    "Anisotropic": "anisotropy",
    "Thin Film Thickness": "thin film",
}


ONE_SIDED = "emits from its front faces only (Blender: both sides)"


def safe_name(name, taken):
    """An MTL/OBJ-safe name (no spaces), unique among `taken` (which it joins)."""
    base = re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "material"
    out, k = base, 1
    while out in taken:
        k += 1
        out = f"{base}_{k}"
    taken.add(out)
    return out


def _value(node, name, default):
    sock = node.inputs.get(name)
    if sock is None:
        return default
    v = sock.default_value
    try:
        return tuple(v)
    except TypeError:
        return v


def _linked(node, name):
    sock = node.inputs.get(name)
    return sock is not None and sock.is_linked


def _linked_node(node, name):
    sock = node.inputs.get(name)
    if sock is None or not sock.is_linked:
        return None
    return sock.links[0].from_node


def _rgb(v):
    return tuple(float(c) for c in v[:3])


def _fmt(v):
    return " ".join(f"{c:.6g}" for c in v)


def ns_from_roughness(roughness):
    """A Blinn-Phong exponent with about the highlight of a GGX lobe of this roughness
    (alpha = roughness², Ns = 2 / alpha² − 2), within tilefarm's 0–1000."""
    alpha = max(float(roughness), 1e-3) ** 2
    return min(max(2.0 / (alpha * alpha) - 2.0, 0.0), 1000.0)


class Mapped:
    """One material as MTL lines, with what could not be mapped."""

    def __init__(self, name):
        self.name = name
        self.lines = []
        self.problems = []
        self.texture = None  # (source path or image, file name in the scene folder)

    def mtl(self):
        return "\n".join([f"newmtl {self.name}"] + self.lines) + "\n"


def _surface_node(material):
    if not material.use_nodes or material.node_tree is None:
        return None
    out = None
    for n in material.node_tree.nodes:
        if n.type == "OUTPUT_MATERIAL" and (out is None or n.is_active_output):
            out = n
    if out is None:
        return None
    return _linked_node(out, "Surface")


def _texture_of(node, name, m):
    """The image texture linked straight into input `name`, if any (else reported)."""
    src = _linked_node(node, name)
    if src is None:
        return None
    if src.type == "TEX_IMAGE" and src.image is not None:
        return src.image
    m.problems.append(f"{name.lower()} from a {src.bl_idname} node (only an image texture maps)")
    return None


def map_material(material, name):
    """`material` (a bpy Material) as MTL, named `name`."""
    m = Mapped(name)
    if material is None:
        m.lines += ["Kd 0.8 0.8 0.8"]
        return m
    node = _surface_node(material)
    if node is None:
        m.lines.append("Kd " + _fmt(_rgb(material.diffuse_color)))
        if material.use_nodes:
            m.problems.append("no shader connected to the material output")
        return m
    kind = node.type
    if kind == "BSDF_PRINCIPLED":
        _principled(node, m)
    elif kind == "BSDF_DIFFUSE":
        m.lines.append("Kd " + _fmt(_rgb(_value(node, "Color", (0.8, 0.8, 0.8)))))
        m.texture = _texture_of(node, "Color", m)
        if float(_value(node, "Roughness", 0.0)) > 0.0:
            m.problems.append("diffuse roughness (Oren-Nayar): rendered Lambertian")
    elif kind == "EMISSION":
        strength = float(_value(node, "Strength", 1.0))
        m.lines += ["Kd 0 0 0", "Ke " + _fmt([c * strength for c in _rgb(_value(node, "Color", (1, 1, 1)))])]
        m.problems.append(ONE_SIDED)
    elif kind == "BSDF_GLASS":
        tint = _rgb(_value(node, "Color", (1, 1, 1)))
        m.lines += ["Kd 0 0 0", "Ks 1 1 1", "Tf " + _fmt(tint), f"Ni {float(_value(node, 'IOR', 1.45)):.6g}", "illum 7"]
        if float(_value(node, "Roughness", 0.0)) > 0.0:
            m.problems.append("rough glass: rendered smooth")
    elif kind == "BSDF_GLOSSY":
        color = _rgb(_value(node, "Color", (0.8, 0.8, 0.8)))
        rough = float(_value(node, "Roughness", 0.5))
        if rough < 0.05:
            m.lines += ["Kd 0 0 0", "Ks " + _fmt(color), "illum 3"]
        else:
            m.lines += ["Kd 0 0 0", "Ks " + _fmt(color), f"Ns {ns_from_roughness(rough):.6g}"]
    else:
        m.lines.append("Kd 0.8 0.8 0.8")
        m.problems.append(f"a {node.bl_idname} shader (not mapped): grey diffuse")
    return m


def _principled(node, m):
    base = _rgb(_value(node, "Base Color", (0.8, 0.8, 0.8)))
    metallic = float(_value(node, "Metallic", 0.0))
    rough = float(_value(node, "Roughness", 0.5))
    transmission = float(_value(node, "Transmission Weight", 0.0))
    ior = float(_value(node, "IOR", 1.5))
    spec_level = float(_value(node, "Specular IOR Level", 0.5))
    alpha = float(_value(node, "Alpha", 1.0))
    emission = _rgb(_value(node, "Emission Color", (1, 1, 1)))
    strength = float(_value(node, "Emission Strength", 0.0))
    m.texture = _texture_of(node, "Base Color", m)
    for sock, what in UNMAPPED_INPUTS.items():
        if _linked(node, sock) or (sock in node.inputs and float(_value(node, sock, 0.0)) > 0.0):
            m.problems.append(what)
    for sock in ("Normal", "Metallic", "Roughness", "Alpha", "Transmission Weight", "Emission Color"):
        if _linked(node, sock):
            m.problems.append(f"a texture on {sock.lower()} (its default value is used)")
    if transmission >= 0.5:
        m.lines += ["Kd 0 0 0", "Ks 1 1 1", "Tf " + _fmt(base), f"Ni {ior:.6g}", "illum 7"]
        if rough > 0.05:
            m.problems.append("rough transmission: rendered as smooth glass")
        m.texture = None
    elif metallic >= 0.5:
        if rough < 0.05:
            m.lines += ["Kd 0 0 0", "Ks " + _fmt(base), "illum 3"]
        else:
            m.lines += ["Kd 0 0 0", "Ks " + _fmt(base), f"Ns {ns_from_roughness(rough):.6g}"]
            m.problems.append("rough metal: a Blinn-Phong lobe")
        m.texture = None
    else:
        if 0.0 < metallic or 0.0 < transmission:
            m.problems.append("partly metallic or transmissive: rendered as a dielectric")
        # The dielectric coat's reflectance at normal incidence: F0 of the IOR, scaled
        # as the Principled BSDF scales it (level 0.5 = as the IOR says).
        f0 = ((ior - 1.0) / (ior + 1.0)) ** 2 * 2.0 * spec_level
        m.lines.append("Kd " + _fmt(base))
        if f0 > 0.0:
            m.lines += [f"Ks {f0:.6g} {f0:.6g} {f0:.6g}", f"Ns {ns_from_roughness(rough):.6g}"]
        if alpha < 1.0:
            m.lines += [f"d {alpha:.6g}"]
    if strength > 0.0 and any(c > 0.0 for c in emission):
        m.lines.append("Ke " + _fmt([c * strength for c in emission]))
        m.problems.append(ONE_SIDED)


def write_texture(image, folder, taken):
    """Writes `image` (a bpy Image) into `folder`; its file name there."""
    src = image.filepath_raw and os.path.abspath(_bpy_abspath(image.filepath_raw))
    ext = os.path.splitext(src)[1].lower() if src else ""
    name = safe_name(os.path.splitext(os.path.basename(src))[0] if src else image.name, taken)
    if src and os.path.isfile(src) and not image.packed_file and ext in (".png", ".jpg", ".jpeg", ".tga", ".bmp",
                                                                        ".tif", ".tiff", ".hdr", ".exr"):
        out = name + ext
        shutil.copyfile(src, os.path.join(folder, out))
        return out
    # Packed, generated or edited in Blender: saved as PNG.
    out = name + ".png"
    copy = image.copy()
    try:
        copy.filepath_raw = os.path.join(folder, out)
        copy.file_format = "PNG"
        copy.save()
    finally:
        import bpy
        bpy.data.images.remove(copy)
    return out


def _bpy_abspath(path):
    import bpy
    return bpy.path.abspath(path)


def texture_line(file_name):
    return f"map_Kd {file_name}"

