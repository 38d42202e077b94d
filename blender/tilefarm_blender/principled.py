"""Blender's shader nodes as Principled material tables (README.md, "Principled
materials"): the Principled BSDF input by input, and the Diffuse, Glossy, Glass,
Refraction, Emission, Sheen and Transparent BSDFs as its special cases. An input linked
to an Image Texture becomes `NAME_map` and its constant the neutral 1 (Blender ignores a
linked socket's own value: the texture is the input, whether the tracer multiplies the
two or lets the map replace the constant); an RGB or Value node is its constant; any
other node is noted in `problems` and the socket's own value used."""

from . import textures as tex

COLOR, SCALAR = "color", "scalar"

# The Principled BSDF's inputs as the table's keys.
INPUTS = [
    ("base_color", "Base Color", COLOR),
    ("metallic", "Metallic", SCALAR),
    ("roughness", "Roughness", SCALAR),
    ("ior", "IOR", SCALAR),
    ("specular_ior_level", "Specular IOR Level", SCALAR),
    ("specular_tint", "Specular Tint", COLOR),
    ("transmission", "Transmission Weight", SCALAR),
    ("coat", "Coat Weight", SCALAR),
    ("coat_roughness", "Coat Roughness", SCALAR),
    ("coat_ior", "Coat IOR", SCALAR),
    ("coat_tint", "Coat Tint", COLOR),
    ("sheen", "Sheen Weight", SCALAR),
    ("sheen_roughness", "Sheen Roughness", SCALAR),
    ("sheen_tint", "Sheen Tint", COLOR),
    ("anisotropic", "Anisotropic", SCALAR),
    ("anisotropic_rotation", "Anisotropic Rotation", SCALAR),
    ("alpha", "Alpha", SCALAR),
    ("emission_color", "Emission Color", COLOR),
    ("emission_strength", "Emission Strength", SCALAR),
]

# The inputs tilefarm can texture (its `NAME_map` keys): an image on any other input is
# reported and its constant used.
TEXTURED = {"base_color", "metallic", "roughness", "transmission", "coat", "sheen", "alpha", "emission_color",
            "factor"}

# The format's defaults (README.md), which are also Blender's.
DEFAULTS = {
    "base_color": [0.8, 0.8, 0.8], "metallic": 0.0, "roughness": 0.5, "ior": 1.5, "specular_ior_level": 0.5,
    "specular_tint": [1.0, 1.0, 1.0], "transmission": 0.0, "coat": 0.0, "coat_roughness": 0.03, "coat_ior": 1.5,
    "coat_tint": [1.0, 1.0, 1.0], "sheen": 0.0, "sheen_roughness": 0.5, "sheen_tint": [1.0, 1.0, 1.0],
    "anisotropic": 0.0, "anisotropic_rotation": 0.0, "alpha": 1.0, "emission_color": [1.0, 1.0, 1.0],
    "emission_strength": 0.0, "distribution": "multiscatter_ggx",
}

DISTRIBUTIONS = {"GGX": "ggx", "MULTI_GGX": "multiscatter_ggx"}

# Blender's scene-linear Rec.709 luminance: how Cycles turns a colour into a number.
LUMINANCE = (0.2126, 0.7152, 0.0722)

# cos of the angle at which the F82-tint Fresnel takes its tint: acos(1/7), about 82°.
F82_COS = 1.0 / 7.0


def defaults(**values):
    """A full table: the defaults, with `values`."""
    t = {k: (list(v) if isinstance(v, list) else v) for k, v in DEFAULTS.items()}
    t.update(values)
    return t


def luminance(rgb):
    return sum(c * w for c, w in zip(rgb, LUMINANCE))


def constant(value, kind):
    """A socket's value as `kind`: a colour's RGB (its alpha dropped), or a number (a
    colour's luminance, as Cycles converts one)."""
    try:
        v = [float(c) for c in value][:3]
    except TypeError:
        v = float(value)
    if kind == COLOR:
        return v if isinstance(v, list) else [v, v, v]
    return luminance(v) if isinstance(v, list) else v


def show(v):
    if isinstance(v, list):
        return "(" + ", ".join(f"{c:.3g}" for c in v) + ")"
    return f"{v:.3g}"


class Reader:
    """Reads one shader node's inputs into a table; `where` prefixes what it notes."""

    def __init__(self, node, problems, where=""):
        self.node = node
        self.problems = problems
        self.where = where

    def note(self, what):
        self.problems.append(self.where + what)

    def value(self, name, kind=SCALAR):
        return constant(self.node.inputs[name].default_value, kind)

    def linked(self, name):
        sock = self.node.inputs.get(name)
        return sock is not None and tex.source(sock) is not None

    def read(self, table, key, name, kind):
        """Input `name` into `table[key]`, and `table[key + "_map"]` if an image gives it."""
        sock = self.node.inputs[name]
        own = constant(sock.default_value, kind)
        table[key] = own
        src = tex.source(sock)
        if src is None:
            return
        node, out = src
        if node.type == "TEX_IMAGE" and key not in TEXTURED:
            self.note(f"{name} from an image: not mapped (its unlinked value {show(own)} used)")
        elif node.type == "TEX_IMAGE":
            ref = tex.image_ref(node, out, kind, self.where + name, self.problems)
            if ref is not None:
                table[key] = [1.0, 1.0, 1.0] if kind == COLOR else 1.0
                ref.fallback = own
                table[key + "_map"] = ref
        elif node.type in {"RGB", "VALUE"}:
            table[key] = constant(out.default_value, kind)
        else:
            self.note(f"{name} from a {tex.describe(node)}: not mapped (its unlinked value {show(own)} used)")

    def fixed(self, name, kind=SCALAR):
        """An input that only maps as a constant: its value, noting a link."""
        src = tex.source(self.node.inputs[name])
        own = self.value(name, kind)
        if src is not None:
            self.note(f"{name} from a {tex.describe(src[0])}: not mapped (its unlinked value {show(own)} used)")
        return own

    def normal(self, table, name="Normal"):
        """A Normal Map or Bump node (or a Bump over a Normal Map) linked into `name`."""
        src = tex.source(self.node.inputs[name])
        if src is None:
            return
        node = src[0]
        if node.type == "BUMP":
            self.bump(table, node)
        elif node.type == "NORMAL_MAP":
            self.normal_map(table, node)
        else:
            self.note(f"{name} from a {tex.describe(node)}: not mapped (the surface's own normal used)")

    def normal_map(self, table, node):
        inner = Reader(node, self.problems, self.where + "Normal Map node: ")
        if node.space != "TANGENT":
            inner.note(f"{node.space.lower()} space not mapped (tangent space only; the surface's own normal used)")
            return
        strength = inner.fixed("Strength")
        src = tex.source(node.inputs["Color"])
        if src is None:
            color = inner.value("Color", COLOR)
            if max(abs(c - f) for c, f in zip(color, (0.5, 0.5, 1.0))) > 1e-6:
                inner.note(f"a constant Color {show(color)} (a tilted normal) not mapped")
            return
        if src[0].type != "TEX_IMAGE":
            inner.note(f"Color from a {tex.describe(src[0])}: not mapped (the surface's own normal used)")
            return
        ref = tex.image_ref(src[0], src[1], COLOR, inner.where + "Color", self.problems)
        if ref is not None:
            ref.extra = {"strength": strength}
            table["normal_map"] = ref

    def bump(self, table, node):
        inner = Reader(node, self.problems, self.where + "Bump node: ")
        strength = inner.fixed("Strength")
        distance = inner.fixed("Distance")
        if node.invert:
            strength = -strength
        below = tex.source(node.inputs["Normal"])
        if below is not None:
            if below[0].type == "NORMAL_MAP":
                self.normal_map(table, below[0])
            else:
                inner.note(f"Normal from a {tex.describe(below[0])}: not mapped (the surface's own normal under "
                           "the bump)")
        src = tex.source(node.inputs["Height"])
        if src is None:
            return  # a constant height: no bump
        if src[0].type != "TEX_IMAGE":
            inner.note(f"Height from a {tex.describe(src[0])}: not mapped (no bump)")
            return
        ref = tex.image_ref(src[0], src[1], SCALAR, inner.where + "Height", self.problems)
        if ref is not None:
            ref.extra = {"strength": strength, "distance": distance}
            table["bump_map"] = ref


def principled(node, r):
    t = {}
    for key, name, kind in INPUTS:
        r.read(t, key, name, kind)
    t["distribution"] = DISTRIBUTIONS.get(node.distribution, "multiscatter_ggx")
    r.normal(t)
    weight = r.value("Subsurface Weight")
    if weight > 0.0 or r.linked("Subsurface Weight"):
        r.note(f"subsurface scattering (weight {show(weight)}) not mapped (rendered without)")
    film = r.value("Thin Film Thickness")
    if film > 0.0 or r.linked("Thin Film Thickness"):
        r.note(f"thin film ({show(film)} nm) not mapped (rendered without)")
    if r.linked("Coat Normal"):
        r.note("Coat Normal not mapped (the coat keeps the surface's own normal)")
    tangent(r, t)
    return t


def tangent(r, t):
    """tilefarm stretches anisotropic lobes along the UV map's tangent; Blender's default
    (the Tangent socket unlinked) is radial about the object's Z axis. The two agree on
    a UV sphere, not in general: said whenever anisotropy is on."""
    if r.linked("Tangent"):
        r.note("Tangent not mapped (anisotropy along the UV map's tangent)")
    elif t.get("anisotropic", 0.0) > 0.0 or "anisotropic_map" in t:
        r.note("anisotropy along the UV map's tangent (Blender's default is radial about the object's Z axis: "
               "the same on a UV sphere)")


def diffuse(node, r):
    t = defaults(specular_ior_level=0.0, roughness=1.0)
    r.read(t, "base_color", "Color", COLOR)
    rough = r.value("Roughness")
    if rough > 0.0 or r.linked("Roughness"):
        r.note(f"Diffuse BSDF roughness {show(rough)} (Oren-Nayar) rendered Lambertian")
    r.normal(t)
    return t


def f82_tint(color):
    """The F82 edge tint that holds a metal of F0 = `color` at `color` at 82° too (Schlick
    alone rises towards white): the closest the Principled metal comes to Glossy's
    reflectance, which is the colour at every angle."""
    f5 = (1.0 - F82_COS) ** 5
    return [min(1.0, c / (c + (1.0 - c) * f5)) if c > 0.0 else 0.0 for c in color]


def glossy(node, r):
    t = defaults(metallic=1.0)
    r.read(t, "base_color", "Color", COLOR)
    r.read(t, "roughness", "Roughness", SCALAR)
    if "base_color_map" not in t:
        t["specular_tint"] = f82_tint(t["base_color"])
    distribution(node, r, t, "Glossy BSDF")
    # Glossy: anisotropy a in (−1, 1) gives α_x : α_y = (1 − a) : 1/(1 − a) (a > 0 stretches
    # along the bitangent); Principled's a' in [0, 1] gives α_x : α_y = 1 : (1 − 0.9 a').
    if r.linked("Anisotropy") or r.linked("Rotation"):
        r.read(t, "anisotropic", "Anisotropy", SCALAR)
        r.read(t, "anisotropic_rotation", "Rotation", SCALAR)
        r.note("Glossy BSDF anisotropy from a texture: used as the Principled anisotropy (another parametrisation)")
    else:
        a = r.value("Anisotropy")
        ratio = (1.0 - min(abs(a), 0.99)) ** 2
        t["anisotropic"] = min(1.0, (1.0 - ratio) / 0.9)
        t["anisotropic_rotation"] = r.value("Rotation") + (0.25 if a > 0.0 else 0.0)
        if (1.0 - ratio) / 0.9 > 1.0 + 1e-6:
            r.note(f"Glossy BSDF anisotropy {show(a)} beyond the Principled's (stretched 10:1 at most)")
    tangent(r, t)
    r.normal(t)
    return t


def distribution(node, r, t, label):
    if node.distribution in DISTRIBUTIONS:
        t["distribution"] = DISTRIBUTIONS[node.distribution]
    else:
        t["distribution"] = "ggx"
        r.note(f"{label} distribution {node.distribution.title()} rendered GGX")


def glass(node, r, label="Glass BSDF"):
    # Cycles' Glass BSDF tints reflection and refraction by its colour C; the Principled
    # glass tints each refraction by √(base colour) and F0 by the specular tint.
    t = defaults(transmission=1.0)
    r.read(t, "base_color", "Color", COLOR)
    if "base_color_map" in t:
        r.note(f"{label} Color from a texture: the Principled glass tints refraction by the square root of its "
               "base colour (lighter here), and its reflection not at all")
    else:
        color = t["base_color"]
        t["base_color"] = [c * c for c in color]
        t["specular_tint"] = list(color)
    r.read(t, "roughness", "Roughness", SCALAR)
    r.read(t, "ior", "IOR", SCALAR)
    distribution(node, r, t, label)
    r.normal(t)
    return t


def refraction(node, r):
    r.note("Refraction BSDF rendered as glass (with a reflection it does not have)")
    return glass(node, r, "Refraction BSDF")


def emission(node, r):
    t = defaults(base_color=[0.0, 0.0, 0.0], specular_ior_level=0.0, roughness=1.0)
    r.read(t, "emission_color", "Color", COLOR)
    r.read(t, "emission_strength", "Strength", SCALAR)
    return t


def sheen(node, r):
    t = defaults(base_color=[0.0, 0.0, 0.0], specular_ior_level=0.0, roughness=1.0, sheen=1.0)
    r.read(t, "sheen_tint", "Color", COLOR)
    r.read(t, "sheen_roughness", "Roughness", SCALAR)
    if node.distribution != "MICROFIBER":
        r.note(f"Sheen BSDF distribution {node.distribution.title()} rendered Microfiber")
    r.normal(t)
    return t


def transparent(node, r):
    color = r.fixed("Color", COLOR)
    t = defaults(base_color=[0.0, 0.0, 0.0], specular_ior_level=0.0, roughness=1.0)
    t["alpha"] = min(1.0, max(0.0, 1.0 - luminance(color)))
    if max(color) - min(color) > 1e-6:
        r.note(f"Transparent BSDF colour {show(color)}: a grey cut-out passing its luminance")
    return t


SHADERS = {
    "BSDF_PRINCIPLED": principled,
    "BSDF_DIFFUSE": diffuse,
    "BSDF_GLOSSY": glossy,
    "BSDF_GLASS": glass,
    "BSDF_REFRACTION": refraction,
    "EMISSION": emission,
    "BSDF_SHEEN": sheen,
    "BSDF_TRANSPARENT": transparent,
}


def table_of(node, problems, where=""):
    """The Principled table of one shader node (not a Mix Shader), or None (noted) if
    it does not map."""
    read = SHADERS.get(node.type)
    if read is None:
        problems.append(f"{where}{tex.describe(node)}: not mapped (grey diffuse here)")
        return None
    return read(node, Reader(node, problems, where))

