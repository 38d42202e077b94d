"""Blender materials as tilefarm Principled materials (README.md, "Principled
materials"): each one a `[materials.NAME]` table in scene.toml, full and explicit, and
an MTL material of the same name with the PBR keys (`Kd`, `Pr`, `Pm`, …) for other
programs, which the table overrides. A Mix Shader is a table mixing two tables of
derived names. `principled.py` reads the shader nodes, `textures.py` the images and
their mapping; what cannot be mapped is reported, never silently dropped."""

import json
import re

from . import principled as pr
from . import textures as tex

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


class Mapped:
    """One material: its tables for scene.toml (the first its own, then a Mix Shader's
    parts), the table its MTL describes, and what could not be mapped."""

    def __init__(self, name):
        self.name = name
        self.tables = []  # [(name, {key: value})]
        self.mtl_table = None
        self.problems = []

    def refs(self):
        """The texture references of its tables (each once)."""
        seen = {}
        for _, table in self.tables:
            for v in table.values():
                if isinstance(v, tex.TextureRef):
                    seen[id(v)] = v
        return list(seen.values())

    def resolve(self):
        """Once the textures are written: a reference whose image could not be written
        gives way to the input's own value."""
        for _, table in self.tables:
            for key in [k for k, v in table.items() if isinstance(v, tex.TextureRef) and v.file is None]:
                ref = table.pop(key)
                base = key[: -len("_map")]
                if base in table and ref.fallback is not None:
                    table[base] = ref.fallback

    def mtl(self):
        return "\n".join([f"newmtl {self.name}"] + mtl_lines(self.mtl_table)) + "\n"

    def toml(self):
        out = []
        for name, table in self.tables:
            out += ["", f"[materials.{toml_key(name)}]"]
            out += [f"{k} = {toml_value(v)}" for k, v in table.items()]
        return out


def map_material(material, name, taken):
    """`material` (a bpy Material, or None: Cycles' default surface) as a Mapped named
    `name`; names of a Mix Shader's parts are derived from it, unique among `taken`."""
    m = Mapped(name)
    if material is None:
        m.tables.append((name, pr.defaults(specular_ior_level=0.0, roughness=1.0)))
    elif not material.use_nodes or material.node_tree is None:
        # Cycles renders a material without nodes as a diffuse of its viewport colour.
        color = [float(c) for c in material.diffuse_color[:3]]
        m.tables.append((name, pr.defaults(base_color=color, specular_ior_level=0.0, roughness=1.0)))
    else:
        out = _output(material)
        src = tex.source(out.inputs["Surface"]) if out is not None else None
        if out is not None:
            for other in ("Volume", "Displacement"):
                if other in out.inputs and tex.source(out.inputs[other]) is not None:
                    m.problems.append(f"{other.lower()} not mapped")
        if src is None:
            m.problems.append("no shader connected to the material output (black, as in Cycles)")
            m.tables.append((name, pr.defaults(base_color=[0.0, 0.0, 0.0], specular_ior_level=0.0)))
        else:
            _shader(m, src[0], name, taken, "")
    m.mtl_table = _mtl_part(m, name)
    for _, table in m.tables:
        if _emits(table):
            m.problems.append(ONE_SIDED)
            break
    return m


def _output(material):
    """The Material Output node Cycles uses: the active one among those for Cycles."""
    outs = [n for n in material.node_tree.nodes if n.type == "OUTPUT_MATERIAL" and n.target in {"ALL", "CYCLES"}]
    active = [n for n in outs if n.is_active_output]
    return (active or outs or [None])[0]


def _shader(m, node, name, taken, where):
    """Adds the table(s) of shader `node` to `m`, the first named `name`."""
    if node.type != "MIX_SHADER":
        table = pr.table_of(node, m.problems, where)
        if table is None:
            table = pr.defaults(specular_ior_level=0.0, roughness=1.0)
        m.tables.append((name, table))
        return
    mix = {}
    reader = pr.Reader(node, m.problems, where + "Mix Shader ")
    reader.read(mix, "factor", "Fac", pr.SCALAR)
    mix["factor"] = min(1.0, max(0.0, mix["factor"]))
    parts = [tex.source(node.inputs[1]), tex.source(node.inputs[2])]
    if "factor_map" not in mix and mix["factor"] in (0.0, 1.0):
        # All of one side: that side alone (the other is not even evaluated in Cycles).
        _part(m, parts[int(mix["factor"])], name, taken, where)
        return
    at = len(m.tables)
    m.tables.append((name, mix))
    names = []
    for k, part in enumerate(parts):
        names.append(safe_name(f"{name}.{'ab'[k]}", taken))
        _part(m, part, names[-1], taken, f"{where}{names[-1]}: ")
    m.tables[at] = (name, {"mix": names, **mix})


def _part(m, src, name, taken, where):
    if src is None:
        # An empty shader socket: no closure, which absorbs everything (black).
        m.tables.append((name, pr.defaults(base_color=[0.0, 0.0, 0.0], specular_ior_level=0.0)))
    else:
        _shader(m, src[0], name, taken, where)


def _mtl_part(m, name):
    """The table the MTL describes: a mix's larger part (its first with a map), down to
    a table that is not a mix."""
    tables = dict(m.tables)
    table = tables[name]
    while "mix" in table:
        table = tables[table["mix"][1 if "factor_map" not in table and table["factor"] > 0.5 else 0]]
    return table


def _emits(t):
    if "emission_strength" not in t:
        return False
    strength = "emission_strength_map" in t or t["emission_strength"] > 0.0
    color = "emission_color_map" in t or max(t["emission_color"]) > 0.0
    return strength and color


# MTL ------------------------------------------------------------------------------------


def _fmt(v):
    if isinstance(v, list):
        return " ".join(f"{c:.6g}" for c in v)
    return f"{v:.6g}"


def mtl_lines(t):
    """A Principled table in MTL's PBR keys (README.md: what tilefarm reads them as,
    which is also what Blender's OBJ importer and tinyobjloader make of them)."""
    lines = []

    def put(key, value, table_key):
        lines.append(f"{key} {_fmt(value)}")
        ref = t.get(table_key + "_map")
        if ref is not None:
            lines.append(f"map_{key} {ref.mtl_options()}{ref.file}")

    put("Kd", t["base_color"], "base_color")
    put("Pr", t["roughness"], "roughness")
    put("Pm", t["metallic"], "metallic")
    if t["sheen"] > 0.0 or "sheen_map" in t:
        put("Ps", t["sheen"], "sheen")
    if t["coat"] > 0.0 or "coat_map" in t:
        lines += [f"Pc {_fmt(t['coat'])}", f"Pcr {_fmt(t['coat_roughness'])}"]
    if t["anisotropic"] > 0.0:
        lines += [f"aniso {_fmt(t['anisotropic'])}", f"anisor {_fmt(t['anisotropic_rotation'])}"]
    lines.append(f"Ni {_fmt(t['ior'])}")
    if t["alpha"] < 1.0 or "alpha_map" in t:
        put("d", t["alpha"], "alpha")
    if _emits(t):
        put("Ke", [c * t["emission_strength"] for c in t["emission_color"]], "emission_color")
    lines.append("illum 7" if t["transmission"] >= 0.5 else "illum 2")
    if "normal_map" in t:
        ref = t["normal_map"]
        lines.append(f"norm {ref.mtl_options()}{ref.file}")
    if "bump_map" in t:
        ref = t["bump_map"]
        lines.append(f"map_Bump -bm {ref.extra['strength']:.6g} {ref.mtl_options()}{ref.file}")
    return lines


# TOML -----------------------------------------------------------------------------------


def toml_key(name):
    return name if re.fullmatch(r"[A-Za-z0-9_-]+", name) else json.dumps(name, ensure_ascii=False)


def toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        s = f"{float(v):.7g}"
        if s in ("nan", "inf", "-inf"):
            raise ValueError(f"not a finite number: {s}")
        return s if any(c in s for c in ".e") else s + ".0"
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, tex.TextureRef):
        v = v.fields()
    return "{ " + ", ".join(f"{toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + " }"
