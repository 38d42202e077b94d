"""Export-level tests of the Principled mapping (issue 49): materials built in `bpy`
(PyPI's, no .blend file), one plane each, exported together with tilefarm_blender;
the written scene.toml is read with `tomllib` and its `[materials]` tables, texture
references, transforms and the one warning are checked, and the MTL beside them. No
rendering. Each case is a function that builds its material and returns its check.
Prints one JSON line (cases, failures, seconds); exits non-zero on a failure.

    python blender/tests/principled_export.py WORK_DIR
"""

import json
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

import bpy  # noqa: E402
import mathutils  # noqa: E402

import compare_cycles as cc  # noqa: E402
from export_testing import (WHITE, Build, Exported, cli_prints_one_warning,  # noqa: E402
                            every_mesh_material_has_a_table, expect, no_warning)
from tilefarm_blender.export import export_scene  # noqa: E402

CASES = []


def case(fn):
    CASES.append(fn)
    return fn


# Formerly silent cases --------------------------------------------------------------------


@case
def textured_metal_exports_its_texture(b):
    """An Image Texture into Base Color of a metal: a map (it used to be dropped)."""
    _, nt, p = b.material("TexturedMetal")
    t = b.texture(nt, b.image("color"))
    nt.links.new(t.outputs["Color"], p.inputs["Base Color"])
    p.inputs["Metallic"].default_value = 1.0
    p.inputs["Roughness"].default_value = 0.3

    def check(x):
        t = x.table("TexturedMetal")
        expect("metallic", t["metallic"], 1.0)
        expect("roughness", t["roughness"], 0.3)
        x.ref("TexturedMetal", "base_color_map", file="color.png", colorspace="srgb", channel="rgb",
              scale=[1.0, 1.0], offset=[0.0, 0.0], rotation=0.0, clamp=False, interpolation="linear")
        assert x.mtl_key("TexturedMetal", "map_Kd")[-1] == "color.png"
        expect("MTL Pm", float(x.mtl_key("TexturedMetal", "Pm")[0]), 1.0)
        no_warning(x, "TexturedMetal")
    return check


@case
def hidden_value_under_a_texture_is_not_multiplied(b):
    """Base Color's own value (0.8) is ignored once an image is linked into it."""
    _, nt, p = b.material("HiddenGrey")
    p.inputs["Base Color"].default_value = (0.8, 0.8, 0.8, 1.0)
    p.inputs["Roughness"].default_value = 0.25
    t = b.texture(nt, b.image("color"))
    nt.links.new(t.outputs["Color"], p.inputs["Base Color"])
    nt.links.new(t.outputs["Color"], p.inputs["Roughness"])

    def check(x):
        t = x.table("HiddenGrey")
        expect("base_color beside its map", t["base_color"], WHITE)
        expect("roughness beside its map", t["roughness"], 1.0)
        expect("MTL Kd beside map_Kd", [float(c) for c in x.mtl_key("HiddenGrey", "Kd")], WHITE)
        x.ref("HiddenGrey", "roughness_map", channel="luminance")
    return check


@case
def mapping_node_scale_is_exported(b):
    """Texture Coordinate UV → Mapping (Point, scale 4) → Image Texture: scale [4, 4]."""
    _, nt, p = b.material("Scaled")
    t = b.texture(nt, b.image("color"))
    mp = nt.nodes.new("ShaderNodeMapping")
    mp.inputs["Scale"].default_value = (4.0, 4.0, 1.0)
    tc = nt.nodes.new("ShaderNodeTexCoord")
    nt.links.new(tc.outputs["UV"], mp.inputs["Vector"])
    nt.links.new(mp.outputs["Vector"], t.inputs["Vector"])
    nt.links.new(t.outputs["Color"], p.inputs["Base Color"])

    def check(x):
        x.ref("Scaled", "base_color_map", scale=[4.0, 4.0], offset=[0.0, 0.0], rotation=0.0)
        assert x.mtl_key("Scaled", "map_Kd")[:4] == ["-s", "4", "4", "1"], x.mtl_key("Scaled", "map_Kd")
        no_warning(x, "Scaled")
    return check


def blender_mapping(kind, loc, rot, scale, uv):
    """Blender's Mapping node on (u, v, 0), from its manual's formulas, with mathutils."""
    v = mathutils.Vector((uv[0], uv[1], 0.0))
    r = mathutils.Euler(rot, "XYZ").to_matrix()
    s, t = mathutils.Vector(scale), mathutils.Vector(loc)
    if kind == "POINT":
        out = r @ (v * s) + t
    elif kind == "TEXTURE":
        out = r.transposed() @ (v - t)
        out = mathutils.Vector([out[i] / s[i] for i in range(3)])
    else:
        out = r @ (v * s)
    return [out[0], out[1]]


def ours(ref, uv):
    """A texture reference's transform (README: scale, rotate CCW by degrees, offset)."""
    a = math.radians(ref["rotation"])
    x, y = uv[0] * ref["scale"][0], uv[1] * ref["scale"][1]
    return [math.cos(a) * x - math.sin(a) * y + ref["offset"][0], math.sin(a) * x + math.cos(a) * y + ref["offset"][1]]


MAPPINGS = {
    "MapPoint": ("POINT", (0.25, 0.5, 0.7), (0.0, 0.0, math.radians(30)), (2.0, 3.0, 1.0)),
    "MapTexture": ("TEXTURE", (0.1, -0.2, 0.0), (0.0, 0.0, math.radians(-50)), (0.5, 0.5, 2.0)),
    "MapVector": ("VECTOR", (9.0, 9.0, 9.0), (0.0, 0.0, math.radians(90)), (1.0, -2.0, 1.0)),
}


@case
def mapping_node_transforms_match_blender(b):
    """Point, Texture and Vector Mappings (from a UV Map node or the Texture Coordinate
    node's UV) give the same coordinates as Blender's formulas at a few points."""
    for k, (name, (kind, loc, rot, scale)) in enumerate(MAPPINGS.items()):
        _, nt, p = b.material(name)
        t = b.texture(nt, b.image("color"))
        mp = nt.nodes.new("ShaderNodeMapping")
        mp.inputs["Location"].default_value = loc
        mp.inputs["Rotation"].default_value = rot
        mp.inputs["Scale"].default_value = scale
        mp.vector_type = kind  # Vector hides Location (and Blender ignores it)
        if k == 0:
            uv = nt.nodes.new("ShaderNodeUVMap").outputs["UV"]
        else:
            uv = nt.nodes.new("ShaderNodeTexCoord").outputs["UV"]
        nt.links.new(uv, mp.inputs["Vector"])
        nt.links.new(mp.outputs["Vector"], t.inputs["Vector"])
        nt.links.new(t.outputs["Color"], p.inputs["Base Color"])

    def check(x):
        for name, (kind, loc, rot, scale) in MAPPINGS.items():
            ref = x.ref(name, "base_color_map")
            for uv in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.3, 0.7)]:
                expect(f"{name} at {uv}", ours(ref, uv), blender_mapping(kind, loc, rot, scale, uv), 1e-5)
            no_warning(x, name)
        expect("MapPoint rotation", x.table("MapPoint")["base_color_map"]["rotation"], 30.0)
    return check


@case
def red_specular_tint_is_exported(b):
    _, _, p = b.material("RedTint")
    p.inputs["Specular Tint"].default_value = (1.0, 0.0, 0.0, 1.0)

    def check(x):
        expect("specular_tint", x.table("RedTint")["specular_tint"], [1.0, 0.0, 0.0])
        no_warning(x, "RedTint")
    return check


@case
def textures_on_roughness_metallic_alpha_emission(b):
    """Scalar maps read luminance (Color output) or alpha (Alpha output: the base
    colour's own image into Alpha); Emission Color takes an RGB map, its strength stays."""
    _, nt, p = b.material("ScalarMaps")
    color = b.texture(nt, b.image("color", alpha=True))
    rough = b.texture(nt, b.image("rough", colorspace="Non-Color"))
    nt.links.new(color.outputs["Color"], p.inputs["Base Color"])
    nt.links.new(color.outputs["Alpha"], p.inputs["Alpha"])
    nt.links.new(rough.outputs["Color"], p.inputs["Roughness"])
    nt.links.new(rough.outputs["Color"], p.inputs["Metallic"])
    nt.links.new(color.outputs["Color"], p.inputs["Emission Color"])
    p.inputs["Emission Strength"].default_value = 3.0
    p.inputs["Alpha"].default_value = 0.2

    def check(x):
        t = x.table("ScalarMaps")
        x.ref("ScalarMaps", "alpha_map", file="color.png", channel="alpha")
        x.ref("ScalarMaps", "roughness_map", file="rough.png", channel="luminance", colorspace="non-color")
        x.ref("ScalarMaps", "metallic_map", file="rough.png", channel="luminance", colorspace="non-color")
        x.ref("ScalarMaps", "emission_color_map", file="color.png", channel="rgb", colorspace="srgb")
        for key in ("alpha", "roughness", "metallic"):
            expect(key, t[key], 1.0)
        expect("emission_color", t["emission_color"], WHITE)
        expect("emission_strength", t["emission_strength"], 3.0)
        assert x.mtl_key("ScalarMaps", "map_d")[-1] == "color.png"
        assert x.mtl_key("ScalarMaps", "map_Pr")[-1] == "rough.png"
        assert x.mtl_key("ScalarMaps", "map_Ke")[-1] == "color.png"
        assert x.warned("ScalarMaps") == ["emits from its front faces only (Blender: both sides)"], \
            x.warned("ScalarMaps")
    return check


@case
def normal_map_node(b):
    _, nt, p = b.material("NormalMapped")
    t = b.texture(nt, b.image("normal", colorspace="Non-Color"))
    nm = nt.nodes.new("ShaderNodeNormalMap")
    nm.inputs["Strength"].default_value = 0.7
    nt.links.new(t.outputs["Color"], nm.inputs["Color"])
    nt.links.new(nm.outputs["Normal"], p.inputs["Normal"])

    def check(x):
        x.ref("NormalMapped", "normal_map", file="normal.png", colorspace="non-color", channel="rgb", strength=0.7)
        assert x.mtl_key("NormalMapped", "norm")[-1] == "normal.png"
        no_warning(x, "NormalMapped")
    return check


@case
def bump_node_inverted_over_a_normal_map(b):
    """Bump (inverted: negative strength; distance) with a Normal Map into its Normal:
    both maps; a plain Bump on a Diffuse BSDF."""
    _, nt, p = b.material("Bumped")
    height = b.texture(nt, b.image("height", colorspace="Non-Color"))
    bump = nt.nodes.new("ShaderNodeBump")
    bump.invert = True
    bump.inputs["Strength"].default_value = 0.4
    bump.inputs["Distance"].default_value = 0.02
    nt.links.new(height.outputs["Color"], bump.inputs["Height"])
    nm = nt.nodes.new("ShaderNodeNormalMap")
    nm.inputs["Strength"].default_value = 1.5
    nt.links.new(b.texture(nt, b.image("normal", colorspace="Non-Color")).outputs["Color"], nm.inputs["Color"])
    nt.links.new(nm.outputs["Normal"], bump.inputs["Normal"])
    nt.links.new(bump.outputs["Normal"], p.inputs["Normal"])
    _, nt, d = b.shader("BumpedDiffuse", "ShaderNodeBsdfDiffuse")
    bump = nt.nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = 0.5
    nt.links.new(b.texture(nt, b.image("height", colorspace="Non-Color")).outputs["Color"], bump.inputs["Height"])
    nt.links.new(bump.outputs["Normal"], d.inputs["Normal"])

    def check(x):
        x.ref("Bumped", "bump_map", file="height.png", channel="luminance", strength=-0.4, distance=0.02)
        x.ref("Bumped", "normal_map", file="normal.png", strength=1.5)
        assert x.mtl_key("Bumped", "map_Bump")[:2] == ["-bm", "-0.4"], x.mtl_key("Bumped", "map_Bump")
        x.ref("BumpedDiffuse", "bump_map", strength=0.5, distance=1.0)
        no_warning(x, "Bumped")
        no_warning(x, "BumpedDiffuse")
    return check


# Every input, explicitly ------------------------------------------------------------------

PRINCIPLED_VALUES = {
    "Base Color": ("base_color", (0.2, 0.4, 0.6, 1.0)), "Metallic": ("metallic", 0.35),
    "Roughness": ("roughness", 0.15), "IOR": ("ior", 1.45), "Alpha": ("alpha", 0.9),
    "Specular IOR Level": ("specular_ior_level", 0.7), "Specular Tint": ("specular_tint", (0.9, 0.8, 0.7, 1.0)),
    "Transmission Weight": ("transmission", 0.3), "Coat Weight": ("coat", 0.6),
    "Coat Roughness": ("coat_roughness", 0.1), "Coat IOR": ("coat_ior", 1.6),
    "Coat Tint": ("coat_tint", (0.9, 0.95, 1.0, 1.0)), "Sheen Weight": ("sheen", 0.4),
    "Sheen Roughness": ("sheen_roughness", 0.3), "Sheen Tint": ("sheen_tint", (1.0, 0.5, 0.25, 1.0)),
    "Anisotropic": ("anisotropic", 0.5), "Anisotropic Rotation": ("anisotropic_rotation", 0.125),
    "Emission Color": ("emission_color", (1.0, 0.9, 0.8, 1.0)), "Emission Strength": ("emission_strength", 2.5),
}
KEYS = ["base_color", "metallic", "roughness", "ior", "specular_ior_level", "specular_tint", "transmission", "coat",
        "coat_roughness", "coat_ior", "coat_tint", "sheen", "sheen_roughness", "sheen_tint", "anisotropic",
        "anisotropic_rotation", "alpha", "emission_color", "emission_strength", "distribution"]


@case
def every_principled_input_explicit(b):
    """Every input's value (and the distribution) in the table; a default Principled
    BSDF is every default, written out."""
    _, _, p = b.material("AllInputs")
    for name, (_, value) in PRINCIPLED_VALUES.items():
        p.inputs[name].default_value = value
    p.distribution = "GGX"
    b.material("Default")

    def check(x):
        t = x.table("AllInputs")
        for name, (key, value) in PRINCIPLED_VALUES.items():
            expect(key, t[key], list(value[:3]) if isinstance(value, tuple) else value)
        assert t["distribution"] == "ggx", t["distribution"]
        d = x.table("Default")
        assert sorted(d) == sorted(KEYS), f"the default table's keys: {sorted(d)}"
        defaults = {"base_color": [0.8] * 3, "metallic": 0.0, "roughness": 0.5, "ior": 1.5, "specular_ior_level": 0.5,
                    "specular_tint": WHITE, "transmission": 0.0, "coat": 0.0, "coat_roughness": 0.03, "coat_ior": 1.5,
                    "coat_tint": WHITE, "sheen": 0.0, "sheen_roughness": 0.5, "sheen_tint": WHITE,
                    "anisotropic": 0.0, "anisotropic_rotation": 0.0, "alpha": 1.0, "emission_color": WHITE,
                    "emission_strength": 0.0}
        for key, value in defaults.items():
            expect(f"default {key}", d[key], value)
        assert d["distribution"] == "multiscatter_ggx"
        m = x.mtl["AllInputs"]
        for key, value in [("Pr", 0.15), ("Pm", 0.35), ("Ni", 1.45), ("d", 0.9), ("Ps", 0.4), ("Pc", 0.6),
                           ("Pcr", 0.1), ("aniso", 0.5), ("anisor", 0.125)]:
            expect(f"MTL {key}", float(x.mtl_key("AllInputs", key)[0]), value)
        expect("MTL Ke", [float(c) for c in x.mtl_key("AllInputs", "Ke")], [2.5, 2.25, 2.0])
        assert ["illum", "2"] in m, m
        no_warning(x, "Default")
    return check


@case
def image_settings(b):
    """Colour space from the image, interpolation and extension from the node."""
    settings = {
        "ImgClosest": ("rough", "Non-Color", "Closest", "REPEAT"),
        "ImgCubic": ("linear", "Linear Rec.709", "Cubic", "EXTEND"),
        "ImgSmart": ("color", "sRGB", "Smart", "CLIP"),
        "ImgFiltered": ("filmic", "Filmic sRGB", "Linear", "MIRROR"),
    }
    for name, (image, space, interpolation, extension) in settings.items():
        _, nt, p = b.material(name)
        t = b.texture(nt, b.image(image, colorspace=space, float_buffer=image == "linear"), interpolation, extension)
        nt.links.new(t.outputs["Color"], p.inputs["Base Color"])
    # A generated float image with no file: written as OpenEXR, its values kept.
    _, nt, p = b.material("ImgGenerated")
    t = b.texture(nt, b.image("generated", colorspace="Linear Rec.709", float_buffer=True, on_disk=False))
    nt.links.new(t.outputs["Color"], p.inputs["Base Color"])

    def check(x):
        x.ref("ImgClosest", "base_color_map", colorspace="non-color", interpolation="closest", clamp=False)
        no_warning(x, "ImgClosest")
        x.ref("ImgCubic", "base_color_map", file="linear.exr", colorspace="non-color", interpolation="linear",
              clamp=True)
        assert x.warned("ImgCubic") == ['Base Color: image "linear": Cubic interpolation rendered linear'], \
            x.warned("ImgCubic")
        x.ref("ImgSmart", "base_color_map", colorspace="srgb", interpolation="linear", clamp=True)
        assert x.warned("ImgSmart") == [
            'Base Color: image "color": Smart interpolation rendered linear',
            'Base Color: image "color": extension Clip (transparent outside the image in Blender) held at the edge '
            'here'], x.warned("ImgSmart")
        x.ref("ImgFiltered", "base_color_map", colorspace="srgb", clamp=False)
        assert x.warned("ImgFiltered") == [
            'Base Color: image "filmic": colour space "Filmic sRGB" read as srgb',
            'Base Color: image "filmic": extension Mirror repeated here'], x.warned("ImgFiltered")
        ref = x.ref("ImgGenerated", "base_color_map", file="generated.exr", colorspace="non-color")
        written = bpy.data.images.load(os.path.join(x.folder, ref["file"]))
        assert written.is_float, "the generated float image was not written as floats"
    return check


# Mix Shader ------------------------------------------------------------------------------


@case
def mix_shader_of_two_bsdfs(b):
    """A constant factor mixes two derived materials; an image's Alpha into Fac is a
    factor map; factor 0 is its first shader alone."""
    _, nt, p = b.material("Leaf")
    glossy = nt.nodes.new("ShaderNodeBsdfAnisotropic")
    mix = nt.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.3
    p.inputs["Base Color"].default_value = (0.1, 0.5, 0.1, 1.0)
    nt.links.new(p.outputs[0], mix.inputs[1])
    nt.links.new(glossy.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], nt.nodes["Material Output"].inputs["Surface"])

    _, nt, p = b.material("Cutout")
    transparent = nt.nodes.new("ShaderNodeBsdfTransparent")
    mix = nt.nodes.new("ShaderNodeMixShader")
    t = b.texture(nt, b.image("color", alpha=True))
    nt.links.new(t.outputs["Alpha"], mix.inputs["Fac"])
    nt.links.new(transparent.outputs[0], mix.inputs[1])
    nt.links.new(p.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], nt.nodes["Material Output"].inputs["Surface"])

    _, nt, p = b.material("MixZero")
    mix = nt.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.0
    p.inputs["Roughness"].default_value = 0.11
    nt.links.new(p.outputs[0], mix.inputs[1])
    nt.links.new(nt.nodes.new("ShaderNodeEmission").outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], nt.nodes["Material Output"].inputs["Surface"])

    def check(x):
        t = x.table("Leaf")
        assert t["mix"] == ["Leaf.a", "Leaf.b"], t
        expect("factor", t["factor"], 0.3)
        expect("Leaf.a base_color", x.table("Leaf.a")["base_color"], [0.1, 0.5, 0.1])
        expect("Leaf.b metallic", x.table("Leaf.b")["metallic"], 1.0)
        expect("the MTL describes the larger part", [float(c) for c in x.mtl_key("Leaf", "Kd")], [0.1, 0.5, 0.1])
        c = x.table("Cutout")
        assert c["mix"] == ["Cutout.a", "Cutout.b"], c
        x.ref("Cutout", "factor_map", channel="alpha")
        expect("transparent alpha", x.table("Cutout.a")["alpha"], 0.0)
        z = x.table("MixZero")
        assert "mix" not in z and "MixZero.a" not in x.tables, z
        expect("MixZero roughness", z["roughness"], 0.11)
        for name in ("Leaf", "Cutout", "MixZero"):
            no_warning(x, name)
    return check


# Other BSDFs as Principled -------------------------------------------------------------------


@case
def other_bsdfs_as_principled(b):
    _, _, g = b.shader("Glossy", "ShaderNodeBsdfAnisotropic")
    g.inputs["Color"].default_value = (0.9, 0.6, 0.2, 1.0)
    g.inputs["Roughness"].default_value = 0.2
    g.distribution = "GGX"
    _, _, g = b.shader("GlossyAniso", "ShaderNodeBsdfAnisotropic")
    g.inputs["Anisotropy"].default_value = 0.5
    g.inputs["Rotation"].default_value = 0.1
    _, _, g = b.shader("Glass", "ShaderNodeBsdfGlass")
    g.inputs["Color"].default_value = (0.5, 0.8, 1.0, 1.0)
    g.inputs["Roughness"].default_value = 0.3
    g.inputs["IOR"].default_value = 1.33
    _, _, d = b.shader("Diffuse", "ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (0.3, 0.2, 0.1, 1.0)
    d.inputs["Roughness"].default_value = 0.0
    _, _, e = b.shader("Lamp", "ShaderNodeEmission")
    e.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    e.inputs["Strength"].default_value = 4.0
    _, _, s = b.shader("Velvet", "ShaderNodeBsdfSheen")
    s.inputs["Color"].default_value = (0.6, 0.1, 0.2, 1.0)
    s.inputs["Roughness"].default_value = 0.4
    b.shader("Refraction", "ShaderNodeBsdfRefraction")

    def check(x):
        g = x.table("Glossy")
        expect("glossy metallic", g["metallic"], 1.0)
        expect("glossy base", g["base_color"], [0.9, 0.6, 0.2])
        expect("glossy roughness", g["roughness"], 0.2)
        assert g["distribution"] == "ggx"
        # The F82 tint that brings Schlick's curve back to the colour at acos(1/7).
        f5 = (6.0 / 7.0) ** 5
        for c, tint in zip([0.9, 0.6, 0.2], g["specular_tint"]):
            expect("glossy F82 tint", (c + (1 - c) * f5) * tint, c, 1e-5)
        a = x.table("GlossyAniso")
        expect("anisotropic (α ratio (1 − 0.5)² = 1 − 0.9 a')", a["anisotropic"], 0.75 / 0.9)
        expect("rotation: a > 0 stretches along the bitangent", a["anisotropic_rotation"], 0.35)
        gl = x.table("Glass")
        expect("glass transmission", gl["transmission"], 1.0)
        expect("glass base colour: its colour squared (√ per refraction)", gl["base_color"], [0.25, 0.64, 1.0])
        expect("glass specular tint", gl["specular_tint"], [0.5, 0.8, 1.0])
        expect("glass roughness", gl["roughness"], 0.3)
        expect("glass ior", gl["ior"], 1.33)
        assert x.mtl_key("Glass", "illum") == ["7"]
        d = x.table("Diffuse")
        expect("diffuse base", d["base_color"], [0.3, 0.2, 0.1])
        expect("diffuse specular_ior_level", d["specular_ior_level"], 0.0)
        expect("diffuse roughness", d["roughness"], 1.0)
        lamp = x.table("Lamp")
        expect("lamp base", lamp["base_color"], [0.0, 0.0, 0.0])
        expect("lamp specular", lamp["specular_ior_level"], 0.0)
        expect("lamp emission", lamp["emission_color"], [1.0, 0.5, 0.25])
        expect("lamp strength", lamp["emission_strength"], 4.0)
        expect("MTL Ke", [float(c) for c in x.mtl_key("Lamp", "Ke")], [4.0, 2.0, 1.0])
        v = x.table("Velvet")
        expect("sheen", v["sheen"], 1.0)
        expect("sheen tint", v["sheen_tint"], [0.6, 0.1, 0.2])
        expect("sheen roughness", v["sheen_roughness"], 0.4)
        expect("sheen base", v["base_color"], [0.0, 0.0, 0.0])
        for name in ("Glossy", "Glass", "Diffuse", "Velvet"):
            no_warning(x, name)
        assert x.warned("GlossyAniso") == [
            "anisotropy along the UV map's tangent (Blender's default is radial about the object's Z axis: the same "
            "on a UV sphere)"], x.warned("GlossyAniso")
        assert x.warned("Lamp") == ["emits from its front faces only (Blender: both sides)"], x.warned("Lamp")
        assert x.warned("Refraction") == ["Refraction BSDF rendered as glass (with a reflection it does not have)",
                                          "Refraction BSDF distribution Beckmann rendered GGX"], x.warned("Refraction")
    return check


@case
def rgb_and_value_nodes_are_constants(b):
    _, nt, p = b.material("Constants")
    rgb = nt.nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = (0.1, 0.2, 0.3, 1.0)
    val = nt.nodes.new("ShaderNodeValue")
    val.outputs[0].default_value = 0.65
    nt.links.new(rgb.outputs[0], p.inputs["Base Color"])
    nt.links.new(val.outputs[0], p.inputs["Roughness"])
    reroute = nt.nodes.new("NodeReroute")
    nt.links.new(val.outputs[0], reroute.inputs[0])
    nt.links.new(reroute.outputs[0], p.inputs["Metallic"])

    def check(x):
        t = x.table("Constants")
        expect("base from an RGB node", t["base_color"], [0.1, 0.2, 0.3])
        expect("roughness from a Value node", t["roughness"], 0.65)
        expect("metallic through a reroute", t["metallic"], 0.65)
        no_warning(x, "Constants")
    return check


# What does not map: listed, one warning --------------------------------------------------


@case
def unwritable_texture_gives_the_inputs_own_value(b):
    """An image whose file has gone (and has no pixels in Blender): one warning line,
    and the input's own value instead of the map."""
    path = os.path.join(b.work, "gone.png")
    b.image("gone")  # written, then loaded as a file image and deleted
    image = bpy.data.images.load(os.path.join(b.work, "gone.png"))
    image.name = "gone-file"
    os.remove(path)
    _, nt, p = b.material("Gone")
    p.inputs["Base Color"].default_value = (0.3, 0.2, 0.1, 1.0)
    nt.links.new(b.texture(nt, image).outputs["Color"], p.inputs["Base Color"])

    def check(x):
        t = x.table("Gone")
        assert "base_color_map" not in t, t
        expect("base_color: the socket's own value", t["base_color"], [0.3, 0.2, 0.1])
        got = x.warned("Gone")
        assert len(got) == 1 and got[0].startswith("texture gone-file not written (") and \
            got[0].endswith("; the input's own value used)"), got
    return check


@case
def unmapped_things_are_listed(b):
    _, nt, p = b.material("Unmapped")
    p.inputs["Subsurface Weight"].default_value = 0.5
    p.inputs["Thin Film Thickness"].default_value = 300.0
    p.inputs["Roughness"].default_value = 0.4
    math_node = nt.nodes.new("ShaderNodeMath")
    nt.links.new(math_node.outputs[0], p.inputs["Roughness"])
    nt.links.new(nt.nodes.new("ShaderNodeValToRGB").outputs["Color"], p.inputs["Base Color"])
    nt.links.new(nt.nodes.new("ShaderNodeVertexColor").outputs["Color"], p.inputs["Specular Tint"])
    nt.links.new(nt.nodes.new("ShaderNodeTexNoise").outputs["Fac"], p.inputs["Coat Weight"])
    # An image on an input tilefarm cannot texture: reported, its constant used.
    nt.links.new(b.texture(nt, b.image("rough", colorspace="Non-Color")).outputs["Color"], p.inputs["IOR"])
    group = bpy.data.node_groups.new("Rust", "ShaderNodeTree")
    group.interface.new_socket("Value", in_out="OUTPUT", socket_type="NodeSocketFloat")
    gnode = nt.nodes.new("ShaderNodeGroup")
    gnode.node_tree = group
    nt.links.new(gnode.outputs[0], p.inputs["Metallic"])
    nm = nt.nodes.new("ShaderNodeNormalMap")
    nm.space = "OBJECT"
    nt.links.new(b.texture(nt, b.image("normal", colorspace="Non-Color")).outputs["Color"], nm.inputs["Color"])
    nt.links.new(nm.outputs[0], p.inputs["Normal"])
    t = b.texture(nt, b.image("color"))
    t.projection = "BOX"
    mp = nt.nodes.new("ShaderNodeMapping")
    mp.inputs["Rotation"].default_value = (math.radians(20), 0.0, 0.0)
    nt.links.new(nt.nodes.new("ShaderNodeTexCoord").outputs["Generated"], mp.inputs["Vector"])
    nt.links.new(mp.outputs[0], t.inputs["Vector"])
    nt.links.new(t.outputs["Color"], p.inputs["Emission Color"])
    p.inputs["Emission Strength"].default_value = 1.0
    _, nt, add = b.shader("Added", "ShaderNodeAddShader")
    _, nt, p = b.material("Displaced")
    nt.links.new(nt.nodes.new("ShaderNodeDisplacement").outputs[0], nt.nodes["Material Output"].inputs["Displacement"])

    def check(x):
        got = x.warned("Unmapped")
        want = [
            "Base Color from a Color Ramp node: not mapped (its unlinked value (0.8, 0.8, 0.8) used)",
            "Metallic from a node group \"Rust\": not mapped (its unlinked value 0 used)",
            "Roughness from a Math node: not mapped (its unlinked value 0.4 used)",
            "IOR from an image: not mapped (its unlinked value 1.5 used)",
            "Specular Tint from a Color Attribute node: not mapped (its unlinked value (1, 1, 1) used)",
            "Coat Weight from a Noise Texture node: not mapped (its unlinked value 0 used)",
            "Emission Color: image \"color\": box projection (flat, from the UVs, here)",
            "Emission Color: image \"color\": Generated texture coordinates (the UV map used)",
            "Emission Color: image \"color\": a Mapping node rotating about X or Y (20°, 0°: its effect in the UV "
            "plane used)",
            "Normal Map node: object space not mapped (tangent space only; the surface's own normal used)",
            "subsurface scattering (weight 0.5) not mapped (rendered without)",
            "thin film (300 nm) not mapped (rendered without)",
            "emits from its front faces only (Blender: both sides)",
        ]
        assert got == want, "the warning's lines:\n  " + "\n  ".join(got)
        t = x.table("Unmapped")
        expect("roughness: the socket's own value", t["roughness"], 0.4)
        expect("ior: the socket's own value (no ior_map)", t["ior"], 1.5)
        assert "ior_map" not in t, t
        assert "normal_map" not in t, t
        ref = x.ref("Unmapped", "emission_color_map")
        expect("X rotation 20°: v scaled by cos 20°", ref["scale"], [1.0, math.cos(math.radians(20))])
        assert x.warned("Added") == ["Add Shader node: not mapped (grey diffuse here)"], x.warned("Added")
        assert x.warned("Displaced") == ["displacement not mapped"], x.warned("Displaced")
        summary = x.report.summary()
        assert summary.startswith("tilefarm export: ") and summary.count("tilefarm export") == 1, summary
        for line in want:
            assert f"  - material Unmapped: {line}" in summary.split("\n"), f"not in the warning: {line}"
    return check


def main():
    work = sys.argv[1]
    os.makedirs(work, exist_ok=True)
    started = time.perf_counter()
    scene = cc.fresh()
    cc.cycles_settings(scene, 16, seed=1)
    cc.camera(scene, (7.0, -12.0, 8.0), (7.0, 2.0, 0.0))
    b = Build(work)
    checks = [(fn.__name__, fn(b)) for fn in CASES]
    folder = os.path.join(work, "scene")
    t = time.perf_counter()
    x = Exported(folder, export_scene(folder, scene))
    export_s = time.perf_counter() - t
    checks += [("every_mesh_material_has_a_table", every_mesh_material_has_a_table),
               ("cli_prints_one_warning", lambda x: cli_prints_one_warning(x, work))]
    failed = {}
    for name, check in checks:
        try:
            check(x)
        except AssertionError as e:
            failed[name] = str(e)
    print(json.dumps({"cases": [n for n, _ in checks], "failed": failed, "materials": len(x.tables),
                      "export_s": round(export_s, 3), "seconds": round(time.perf_counter() - started, 2)}))
    for name, why in failed.items():
        print(f"FAILED {name}: {why}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # bpy 4.2 can crash at interpreter shutdown (see compare_cycles.py)
