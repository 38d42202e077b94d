"""Image Texture nodes as tilefarm texture references (README.md, "Principled
materials": `{ file, scale, offset, rotation, colorspace, interpolation, channel,
clamp }`), the Mapping node in front of one as its scale, rotation and offset, and the
images themselves written into the scene folder. What does not map is noted in the
`problems` list given, never dropped silently."""

import math
import os
import shutil

# The image's colour space setting as the tracer reads the file: "srgb" (decoded to
# linear) or "non-color" (the numbers as they are).
EXACT_COLORSPACES = {"sRGB": "srgb", "Non-Color": "non-color", "Linear Rec.709": "non-color"}
FILE_TYPES = (".png", ".jpg", ".jpeg", ".tga", ".bmp", ".tif", ".tiff", ".hdr", ".exr")


def source(socket):
    """The node and output socket feeding `socket`, through reroutes, muted nodes and
    past muted or invalid links; None when nothing does (then Blender uses the socket's
    own value)."""
    for _ in range(64):  # a loop in the graph is Blender's error; give up quietly
        links = [k for k in socket.links if k.is_valid and not k.is_muted] if socket.is_linked else []
        if not links:
            return None
        node, out = links[0].from_node, links[0].from_socket
        if node.type == "REROUTE":
            socket = node.inputs[0]
            continue
        if node.mute:
            through = [k.from_socket for k in node.internal_links if k.to_socket == out]
            if not through:
                return None
            socket = through[0]
            continue
        return node, out
    return None


def describe(node):
    """A node as the warning names it: its label in Blender's Add menu, a group by name."""
    if node.type == "GROUP" and node.node_tree is not None:
        return f'node group "{node.node_tree.name}"'
    return f"{node.bl_label} node"


class TextureRef:
    """An image as one input of a material reads it, with its coordinates' transform."""

    def __init__(self, image, channel):
        self.image = image
        self.channel = channel  # "rgb", "luminance" or "alpha"
        self.colorspace = "srgb"
        self.interpolation = "linear"
        self.scale = (1.0, 1.0)
        self.offset = (0.0, 0.0)
        self.rotation = 0.0  # degrees, counter-clockwise
        self.clamp = False
        self.extra = {}  # strength (normal and bump maps), distance (bump maps)
        self.fallback = None  # the input's own value, if the image cannot be written
        self.file = None  # its file in the scene folder, once written

    def fields(self):
        """The reference's keys, all of them, in the README's order."""
        out = {"file": self.file, "colorspace": self.colorspace, "interpolation": self.interpolation,
               "channel": self.channel, "scale": list(self.scale), "offset": list(self.offset),
               "rotation": self.rotation, "clamp": self.clamp}
        out.update(self.extra)
        return out

    def mtl_options(self):
        """MTL's `-s`, `-o` and `-clamp` options (MTL has no rotation)."""
        opts = []
        if self.scale != (1.0, 1.0):
            opts.append(f"-s {self.scale[0]:.6g} {self.scale[1]:.6g} 1")
        if self.offset != (0.0, 0.0):
            opts.append(f"-o {self.offset[0]:.6g} {self.offset[1]:.6g} 0")
        if self.clamp:
            opts.append("-clamp on")
        return " ".join(opts + [""])


def image_ref(node, out, kind, where, problems):
    """The reference an Image Texture `node` gives through its output `out` to an input
    of `kind` ("color" or "scalar"), or None (noted) if it has no image."""
    image = node.image
    if image is None:
        problems.append(f"{where}: an Image Texture with no image (Cycles shows magenta; the input's value used)")
        return None
    if out.name == "Alpha":
        channel = "alpha"
    else:
        # Cycles turns a colour into a number by its luminance.
        channel = "rgb" if kind == "color" else "luminance"
    ref = TextureRef(image, channel)
    what = f'{where}: image "{image.name}"'
    space = image.colorspace_settings.name
    if space in EXACT_COLORSPACES:
        ref.colorspace = EXACT_COLORSPACES[space]
    elif space.startswith("Linear") or space.startswith("ACES"):
        ref.colorspace = "non-color"
        problems.append(f'{what}: colour space "{space}" read as non-color (its primaries are not Rec.709)')
    else:
        problems.append(f'{what}: colour space "{space}" read as srgb')
    if node.interpolation == "Closest":
        ref.interpolation = "closest"
    elif node.interpolation != "Linear":
        problems.append(f"{what}: {node.interpolation} interpolation rendered linear")
    if node.projection != "FLAT":
        problems.append(f"{what}: {node.projection.lower()} projection (flat, from the UVs, here)")
    if node.extension == "EXTEND":
        ref.clamp = True
    elif node.extension == "CLIP":
        ref.clamp = True
        problems.append(f"{what}: extension Clip (transparent outside the image in Blender) held at the edge here")
    elif node.extension == "MIRROR":
        problems.append(f"{what}: extension Mirror repeated here")
    if image.source in {"SEQUENCE", "MOVIE", "TILED"}:
        problems.append(f"{what}: an image {image.source.lower()} (one image of it written)")
    coordinates(node.inputs["Vector"], ref, what, problems)
    return ref


def coordinates(vector, ref, what, problems):
    """The texture coordinates linked into an Image Texture's Vector: the UV map, maybe
    through one Mapping node, whose transform goes into `ref`."""
    src = source(vector)
    if src is None:
        return  # the UV map
    mapping = None
    if src[0].type == "MAPPING":
        mapping = src[0]
        src = source(mapping.inputs["Vector"])
        if src is None:
            problems.append(f"{what}: a Mapping node with nothing linked into its Vector (a constant in "
                            "Blender; the UV map used)")
    if src is not None:
        node, out = src
        if node.type == "UVMAP" or (node.type == "TEX_COORD" and out.name == "UV"):
            pass
        elif node.type == "MAPPING":
            problems.append(f"{what}: Mapping nodes in a chain (only the last one used)")
        elif node.type == "TEX_COORD":
            problems.append(f"{what}: {out.name} texture coordinates (the UV map used)")
        else:
            problems.append(f"{what}: texture coordinates from a {describe(node)} (the UV map used)")
    if mapping is not None:
        apply_mapping(mapping, ref, what, problems)


def _euler(rx, ry, rz):
    """Blender's XYZ Euler rotation as a 3×3 matrix (rows): Rz · Ry · Rx."""
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    return [[cy * cz, sx * sy * cz - cx * sz, cx * sy * cz + sx * sz],
            [cy * sz, sx * sy * sz + cx * cz, cx * sy * sz - sx * cz],
            [-sy, sx * cy, cx * cy]]


def _div(a, b):
    return a / b if b != 0.0 else 0.0  # Blender's safe_divide


def mapping_affine(kind, location, rotation, scale):
    """The Mapping node's output (x, y) for the input (u, v, 0) as `(M, c)`, out = M·uv + c
    (M as rows), and whether that is exact (the Normal type normalises)."""
    r = _euler(*rotation)
    if kind == "TEXTURE":  # out = (Rᵀ·(v − T)) / S
        m = [[_div(r[k][i], scale[i]) for k in range(2)] for i in range(3)]
        c = [-_div(sum(r[k][i] * location[k] for k in range(3)), scale[i]) for i in range(3)]
    elif kind == "NORMAL":  # out = normalize(R·(v / S))
        m = [[r[i][k] * _div(1.0, scale[k]) for k in range(2)] for i in range(3)]
        c = [0.0, 0.0, 0.0]
    else:  # POINT: out = R·(S ⊙ v) + T; VECTOR: the same without T
        m = [[r[i][k] * scale[k] for k in range(2)] for i in range(3)]
        c = list(location) if kind == "POINT" else [0.0, 0.0, 0.0]
    return [m[0], m[1]], c[:2], kind != "NORMAL"


def decompose(m):
    """`m` (2×2, rows) as rotation(φ) · diag(sx, sy): (sx, sy, φ in degrees, the shear
    left over, 0 when exact)."""
    sx = math.hypot(m[0][0], m[1][0])
    phi = math.atan2(m[1][0], m[0][0]) if sx > 0.0 else 0.0
    c, s = math.cos(phi), math.sin(phi)
    sy = -s * m[0][1] + c * m[1][1]
    shear = c * m[0][1] + s * m[1][1]
    return sx, sy, math.degrees(phi), shear


def apply_mapping(node, ref, what, problems):
    """A Mapping node's transform of the UVs as `ref`'s scale, rotation and offset."""
    values = {}
    for name in ("Location", "Rotation", "Scale"):
        sock = node.inputs.get(name)
        values[name] = tuple(float(x) for x in sock.default_value) if sock is not None else (0.0, 0.0, 0.0)
        if sock is not None and source(sock) is not None:
            problems.append(f"{what}: the Mapping node's {name} from a {describe(source(sock)[0])} "
                            "(its unlinked value used)")
    kind = node.vector_type
    m, c, exact = mapping_affine(kind, values["Location"], values["Rotation"], values["Scale"])
    sx, sy, degrees, shear = decompose(m)
    if abs(degrees) < 1e-9:
        degrees = 0.0
    ref.scale, ref.offset, ref.rotation = (_clean(sx), _clean(sy)), (_clean(c[0]), _clean(c[1])), _clean(degrees)
    if not exact:
        problems.append(f"{what}: a Mapping node of type Normal (normalises; used without that)")
    rx, ry = values["Rotation"][0], values["Rotation"][1]
    if rx != 0.0 or ry != 0.0:
        problems.append(f"{what}: a Mapping node rotating about X or Y "
                        f"({math.degrees(rx):.3g}°, {math.degrees(ry):.3g}°: its effect in the UV plane used)")
    if abs(shear) > 1e-6 * max(1.0, abs(sx), abs(sy)):
        problems.append(f"{what}: the Mapping node shears the UVs (not expressible as scale, rotation, offset; "
                        "the shear dropped)")


def _clean(x):
    """Rounding noise off a transform's number (1e-12 of it), for readable files."""
    r = round(x, 9)
    return 0.0 if r == 0.0 else r


def write_texture(image, folder, taken, safe_name):
    """Writes `image` (a bpy Image) into `folder`; its file name there. A file on disk is
    copied; a packed, generated or edited one saved (PNG, or OpenEXR if it holds floats,
    keeping its linear values)."""
    src = image.filepath_raw and os.path.abspath(_bpy_abspath(image.filepath_raw))
    ext = os.path.splitext(src)[1].lower() if src else ""
    name = safe_name(os.path.splitext(os.path.basename(src))[0] if src else image.name, taken)
    if src and os.path.isfile(src) and not image.packed_file and not image.is_dirty and ext in FILE_TYPES:
        out = name + ext
        shutil.copyfile(src, os.path.join(folder, out))
        return out
    fmt, out = ("OPEN_EXR", name + ".exr") if image.is_float else ("PNG", name + ".png")
    copy = image.copy()
    try:
        copy.filepath_raw = os.path.join(folder, out)
        copy.file_format = fmt
        copy.save()
    finally:
        import bpy
        bpy.data.images.remove(copy)
    return out


def _bpy_abspath(path):
    import bpy
    return bpy.path.abspath(path)
