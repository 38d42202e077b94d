#!/usr/bin/env python3
"""Side-by-side comparison of tilefarm with Mitsuba 3 on the same scene.

For each scene (a tilefarm TOML scene with OBJ/MTL meshes, spheres and lights) this
script, in one run on one machine:

1. converts the scene to a Mitsuba 3 scene dict (same camera, max_depth, box filter,
   spp; Lambertian -> `diffuse`, area lights -> `area` emitters, ...);
2. renders it with tilefarm (`coordinator render --local-workers 0`, the time printed by
   the renderer itself) and with Mitsuba `scalar_rgb` (and `llvm_ad_rgb` when libLLVM is
   available), timing only `mi.render`;
3. renders a high-spp reference with tilefarm (`--ref-factor` x spp) and reports each
   image's RMSE against it, the time ratio, and the RMSE at equal wall time (both
   extrapolated from the measured efficiency 1 / (RMSE^2 x time) and, for tilefarm, by an
   actual render at the spp that takes Mitsuba scalar_rgb's time);
4. checks that both renderers converge to the same image: per-channel means of
   tilefarm's reference against a high-spp Mitsuba render, block-wise differences in
   units of their noise, and a mirrored-image check (a mirrored camera is a bug).

Optional for CI: needs `pip install mitsuba numpy`. Standard library + numpy + mitsuba.

    python3 bench/compare_mitsuba.py                       # Cornell box + Veach MIS
    python3 bench/compare_mitsuba.py scenes/cornell-box/scene.toml --spp 16 --width 256
    python3 bench/compare_mitsuba.py --large 1310720 --large 10000000 --width 256   # + large scenes

Known model mismatches (see bench/README.md): tilefarm's normalised Blinn-Phong lobe is
mapped to Mitsuba's `roughconductor` (Beckmann, alpha = sqrt(2 / (Ns + 2)), no Fresnel,
Smith shadowing), which is not the same BRDF; spot-light falloff curves differ; OBJ
smoothing groups are not converted (faces without `vn` are flat).
"""

from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
DEFAULT_SCENES = ["scenes/cornell-box/scene.toml", "scenes/veach-mis/scene.toml"]


# --------------------------------------------------------------------------------------
# Scene parsing (the subset of tilefarm's format the bundled scenes use, plus the rest of
# the documented keys where Mitsuba has an equivalent)
# --------------------------------------------------------------------------------------


@dataclass
class Material:
    name: str
    kd: tuple = (0.0, 0.0, 0.0)
    ks: tuple = (0.0, 0.0, 0.0)
    ke: tuple = (0.0, 0.0, 0.0)
    tf: tuple = (1.0, 1.0, 1.0)
    ns: float = 0.0
    ni: float = 1.0
    d: float = 1.0
    illum: int | None = None
    map_kd: str | None = None

    @staticmethod
    def default() -> "Material":
        return Material("default", kd=(0.8, 0.8, 0.8))


@dataclass
class Mesh:
    material: Material
    positions: list = field(default_factory=list)  # flat triangle soup: 3 vertices per face
    normals: list | None = None


def _colour(vals):
    v = [float(x) for x in vals]
    if len(v) == 1:
        v = v * 3
    return tuple(v[:3])


def parse_mtl(path: Path) -> dict[str, Material]:
    mats: dict[str, Material] = {}
    cur = None
    if not path.exists():
        print(f"warning: missing MTL {path}", file=sys.stderr)
        return mats
    for line in path.read_text().splitlines():
        tok = line.split("#", 1)[0].split()
        if not tok:
            continue
        key, args = tok[0].lower(), tok[1:]
        if key == "newmtl":
            cur = Material(" ".join(args))
            mats[cur.name] = cur
        elif cur is None:
            continue
        elif key in ("kd", "ks", "ke", "tf"):
            setattr(cur, key, _colour(args))
        elif key == "ns":
            cur.ns = float(args[0])
        elif key == "ni":
            cur.ni = float(args[0])
        elif key == "d":
            cur.d = float(args[0])
        elif key == "tr":
            cur.d = 1.0 - float(args[0])
        elif key == "illum":
            cur.illum = int(args[0])
        elif key == "map_kd":
            cur.map_kd = str((path.parent / args[-1]).resolve())
    return mats


def parse_obj(path: Path, transform) -> list[Mesh]:
    """Triangle soups grouped by material; fans for polygons, CCW order kept."""
    verts, norms = [], []
    mats: dict[str, Material] = {}
    by_mat: dict[str, Mesh] = {}
    cur = None
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        tok = line.split("#", 1)[0].split()
        if not tok:
            continue
        key, args = tok[0], tok[1:]
        if key == "v":
            verts.append([float(x) for x in args[:3]])
        elif key == "vn":
            norms.append([float(x) for x in args[:3]])
        elif key == "mtllib":
            for name in args:
                mats.update(parse_mtl(path.parent / name))
        elif key == "usemtl":
            cur = " ".join(args)
        elif key == "f":
            idx = []
            for a in args:
                parts = a.split("/")
                vi = int(parts[0])
                vi = vi - 1 if vi > 0 else len(verts) + vi
                ni = None
                if len(parts) >= 3 and parts[2]:
                    ni = int(parts[2])
                    ni = ni - 1 if ni > 0 else len(norms) + ni
                idx.append((vi, ni))
            name = cur if cur in mats else None
            if cur is not None and name is None:
                print(f"warning: {path}:{lineno}: unknown material {cur!r}, grey diffuse", file=sys.stderr)
            key_m = name or "<default>"
            mesh = by_mat.get(key_m)
            if mesh is None:
                mesh = by_mat[key_m] = Mesh(mats[name] if name else Material.default())
            for k in range(1, len(idx) - 1):
                tri = [idx[0], idx[k], idx[k + 1]]
                for vi, _ in tri:
                    mesh.positions.append(verts[vi])
                if all(n is not None for _, n in tri):
                    if mesh.normals is None:
                        mesh.normals = [None] * (len(mesh.positions) - 3)
                    mesh.normals.extend(norms[n] for _, n in tri)
                elif mesh.normals is not None:
                    mesh.normals.extend([None] * 3)
    meshes = list(by_mat.values())
    for m in meshes:
        p = np.asarray(m.positions, dtype=np.float64)
        lin, off = transform
        m.positions = p @ lin.T + off
        if m.normals is not None and all(n is not None for n in m.normals):
            n = np.asarray(m.normals, dtype=np.float64) @ np.linalg.inv(lin)
            m.normals = n / np.linalg.norm(n, axis=1, keepdims=True)
        else:
            m.normals = None  # flat (geometric) normals, like faces without `vn` here
    return meshes


def mesh_transform(entry: dict):
    s = entry.get("scale", 1.0)
    s = [float(s)] * 3 if isinstance(s, (int, float)) else [float(x) for x in s]
    a = math.radians(float(entry.get("rotate_y", 0.0)))
    # glam's Mat3::from_rotation_y (right-handed): x' = x cos + z sin, z' = -x sin + z cos.
    rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    lin = rot @ np.diag(s)
    off = np.array([float(x) for x in entry.get("translate", [0.0, 0.0, 0.0])])
    return lin, off


def inline_material(entry: dict, name: str) -> Material:
    keys = ("kd", "ks", "ke", "ns", "ni", "d", "illum", "tf")
    if not any(k in entry for k in keys):
        return Material(name, kd=(0.8, 0.8, 0.8))
    m = Material(name)
    for k in ("kd", "ks", "ke", "tf"):
        if k in entry:
            setattr(m, k, _colour(entry[k]))
    for k in ("ns", "ni", "d"):
        if k in entry:
            setattr(m, k, float(entry[k]))
    if "illum" in entry:
        m.illum = int(entry["illum"])
    return m


@dataclass
class Scene:
    path: Path
    camera: dict
    spp: int
    max_depth: int
    meshes: list
    spheres: list  # (center, radius, Material)
    lights: list  # raw [[light]] tables
    background: tuple


def load_scene(path: Path) -> Scene:
    data = tomllib.loads(path.read_text())
    cam = dict(data["camera"])
    render = data.get("render", {})
    meshes = []
    for entry in data.get("mesh", []):
        meshes += parse_obj((path.parent / entry["obj"]).resolve(), mesh_transform(entry))
    spheres = []
    for i, s in enumerate(data.get("sphere", [])):
        spheres.append((tuple(s["center"]), float(s["radius"]), inline_material(s, f"sphere{i}")))
    bg = tuple(data.get("background", {}).get("radiance", [0.0, 0.0, 0.0]))
    return Scene(
        path=path,
        camera=cam,
        spp=int(render.get("spp", 64)),
        max_depth=int(render.get("max_depth", 8)),
        meshes=meshes,
        spheres=spheres,
        lights=data.get("light", []),
        background=bg,
    )


# --------------------------------------------------------------------------------------
# Conversion to Mitsuba
# --------------------------------------------------------------------------------------


def mi_bsdf(mat: Material):
    """The closest Mitsuba BSDF to tilefarm's interpretation of an MTL material."""
    kd, ks = np.array(mat.kd), np.array(mat.ks)
    illum = mat.illum
    if illum in (4, 6, 7) or (mat.d < 1.0 and mat.ni != 1.0):
        return {
            "type": "dielectric",
            "int_ior": float(mat.ni),
            "ext_ior": 1.0,
            "specular_transmittance": {"type": "rgb", "value": list(mat.tf)},
        }
    if illum in (3, 5):
        return {
            "type": "conductor",
            "material": "none",
            "specular_reflectance": {"type": "rgb", "value": ks.tolist()},
        }
    # Energy clamp as tilefarm: kd, ks scaled per channel by 1 / max(1, kd + ks).
    scale = 1.0 / np.maximum(kd + ks, 1.0)
    kd, ks = kd * scale, ks * scale
    if mat.map_kd and kd.max() > 0:
        if not np.allclose(kd, 1.0):
            print(f"warning: {mat.name}: map_Kd x Kd approximated by map_Kd alone", file=sys.stderr)
        diffuse = {"type": "diffuse", "reflectance": {"type": "bitmap", "filename": mat.map_kd}}
    else:
        diffuse = {"type": "diffuse", "reflectance": {"type": "rgb", "value": kd.tolist()}}
    if ks.max() <= 0.0:
        return diffuse
    # Normalised Blinn-Phong (Ashikhmin-Shirley without Fresnel) -> a Beckmann microfacet
    # conductor with Fresnel = 1 ('none'); the usual exponent <-> roughness mapping.
    alpha = math.sqrt(2.0 / (max(mat.ns, 0.0) + 2.0))
    glossy = {
        "type": "roughconductor",
        "material": "none",
        "distribution": "beckmann",
        "alpha": alpha,
        "sample_visible": True,
        "specular_reflectance": {"type": "rgb", "value": ks.tolist()},
    }
    if kd.max() <= 0.0:
        return glossy
    # tilefarm sums the lobes: kd/pi + f_s  ==  0.5 (2 kd/pi) + 0.5 (2 f_s).
    diffuse["reflectance"] = (
        {"type": "rgb", "value": (2 * kd).tolist()} if not mat.map_kd else diffuse["reflectance"]
    )
    glossy["specular_reflectance"] = {"type": "rgb", "value": (2 * ks).tolist()}
    return {"type": "blendbsdf", "weight": 0.5, "a": diffuse, "b": glossy}


def with_material(shape: dict, mat: Material) -> dict:
    bsdf = mi_bsdf(mat)
    # tilefarm's reflective BSDFs are two-sided (they shade the side a ray arrives
    # from); Mitsuba's are one-sided and black from behind unless wrapped. Glass is
    # oriented in both.
    shape["bsdf"] = bsdf if bsdf["type"] == "dielectric" else {"type": "twosided", "bsdf": bsdf}
    if max(mat.ke) > 0.0:
        shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": list(mat.ke)}}
    if mat.d < 1.0 and mat.ni == 1.0 and mat.illum not in (4, 6, 7):
        shape["bsdf"] = {"type": "mask", "opacity": float(mat.d), "bsdf": shape["bsdf"]}
    return shape


def camera_basis(cam: dict):
    pos = np.array(cam["position"], dtype=float)
    target = np.array(cam["look_at"], dtype=float)
    up = np.array(cam.get("up", [0.0, 1.0, 0.0]), dtype=float)
    return pos, target, up


def to_mitsuba(mi, scene: Scene, spp: int, width: int, height: int, sampler: str):
    ST = mi.ScalarTransform4f
    cam = scene.camera
    pos, target, up = camera_basis(cam)
    # Mitsuba's look_at puts cross(up, dir) on the image's left, as tilefarm (whose right
    # is dir x up); both have row 0 at the top. fov_axis 'y' = our vertical fov.
    sensor = {
        "type": "perspective",
        "fov_axis": "y",
        "fov": float(cam["fov"]),
        "to_world": ST().look_at(origin=pos.tolist(), target=target.tolist(), up=up.tolist()),
        "film": {
            "type": "hdrfilm",
            "width": width,
            "height": height,
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
            "component_format": "float32",
        },
        "sampler": {"type": sampler, "sample_count": spp},
    }
    if float(cam.get("aperture", 0.0)) > 0.0:
        sensor["type"] = "thinlens"
        sensor["aperture_radius"] = float(cam["aperture"])
        sensor["focus_distance"] = float(cam.get("focus_distance", np.linalg.norm(target - pos)))
    integrator = {"type": "path", "max_depth": scene.max_depth, "rr_depth": 5}
    d = {"type": "scene", "integrator": integrator, "sensor": sensor}
    for i, m in enumerate(scene.meshes):
        f = write_ply(m, f"mesh{i}")
        d[f"mesh{i}"] = with_material({"type": "ply", "filename": str(f), "face_normals": m.normals is None},
                                      m.material)
    for i, (c, r, mat) in enumerate(scene.spheres):
        d[f"sphere{i}"] = with_material({"type": "sphere", "center": list(c), "radius": r}, mat)
    for i, l in enumerate(scene.lights):
        kind = l.get("type")
        if kind == "point":
            d[f"light{i}"] = {
                "type": "point",
                "position": l["position"],
                "intensity": {"type": "rgb", "value": l["intensity"]},
            }
        elif kind == "spot":
            p = np.array(l["position"], float)
            dirn = np.array(l["direction"], float)
            upv = [0, 1, 0] if abs(dirn[1]) < 0.9 * np.linalg.norm(dirn) else [1, 0, 0]
            d[f"light{i}"] = {
                "type": "spot",
                "to_world": ST().look_at(origin=p.tolist(), target=(p + dirn).tolist(), up=upv),
                "intensity": {"type": "rgb", "value": l["intensity"]},
                "cutoff_angle": float(l["cone_angle"]),
                "beam_width": float(l.get("falloff_start", l["cone_angle"])),
            }
        elif kind == "directional":
            d[f"light{i}"] = {
                "type": "directional",
                "direction": l["direction"],
                "irradiance": {"type": "rgb", "value": l["irradiance"]},
            }
        else:
            raise SystemExit(f"light type {kind!r} not converted")
    if max(scene.background) > 0.0:
        d["background"] = {"type": "constant", "radiance": {"type": "rgb", "value": list(scene.background)}}
    return d


def write_ply(m: Mesh, name: str) -> Path:
    """A binary little-endian PLY of the triangle soup (3 vertices per face, CCW kept)."""
    tmp = Path(tempfile.gettempdir()) / f"tilefarm-compare-{os.getpid()}"
    tmp.mkdir(exist_ok=True)
    path = tmp / f"{name}.ply"
    pos = np.asarray(m.positions, dtype="<f4")
    nv, nf = len(pos), len(pos) // 3
    props = ["property float x", "property float y", "property float z"]
    cols = [pos]
    if m.normals is not None:
        props += ["property float nx", "property float ny", "property float nz"]
        cols.append(np.asarray(m.normals, dtype="<f4"))
    header = "\n".join(
        ["ply", "format binary_little_endian 1.0", f"element vertex {nv}", *props, f"element face {nf}",
         "property list uchar int vertex_indices", "end_header"]
    ) + "\n"
    faces = np.zeros(nf, dtype=[("n", "u1"), ("i", "<i4", 3)])
    faces["n"] = 3
    faces["i"] = np.arange(nv, dtype="<i4").reshape(nf, 3)
    with open(path, "wb") as fh:
        fh.write(header.encode())
        fh.write(np.ascontiguousarray(np.hstack(cols), dtype="<f4").tobytes())
        fh.write(faces.tobytes())
    return path


# --------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------


def coordinator_binary(given: Path | None) -> Path:
    if given is not None:
        exe = given
    else:
        r = subprocess.run(["cargo", "build", "--release", "-q", "-p", "coordinator"], cwd=REPO)
        target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
        exe = target / "release" / "coordinator"
        if r.returncode != 0:
            if not exe.exists():
                raise SystemExit("cargo build failed and there is no target/release/coordinator")
            print(f"warning: cargo build failed; using the existing {exe}", file=sys.stderr)
    # A private copy: a concurrent `cargo build` elsewhere must not swap it mid-run.
    copy = Path(tempfile.gettempdir()) / f"tilefarm-compare-{os.getpid()}" / "coordinator"
    copy.parent.mkdir(exist_ok=True)
    shutil.copy2(exe, copy)
    return copy


RENDERED = re.compile(r"rendered (\d+)\D(\d+) \((\d+) samples\) in ([0-9.]+)s")


def render_tilefarm(exe: Path, scene: Path, spp: int, width: int, height: int, out: Path, max_depth=None, seed=None):
    cmd = [str(exe), "render", str(scene), "--spp", str(spp), "--width", str(width), "--height", str(height),
           "--local-workers", "0", "-q", "-o", str(out)]
    if seed is not None:
        cmd += ["--seed", str(seed)]
    if max_depth is not None:
        cmd += ["--max-depth", str(max_depth)]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"tilefarm failed: {' '.join(cmd)}\n{r.stdout}\n{r.stderr}")
    m = RENDERED.search(r.stdout + r.stderr)
    secs = float(m.group(4)) if m else wall
    return read_exr(out), secs, wall


def read_exr(path: Path) -> np.ndarray:
    import mitsuba as mi

    return np.array(mi.Bitmap(str(path)), dtype=np.float64)[..., :3]


def render_mitsuba(mi, variant: str, scene: Scene, spp: int, width: int, height: int, sampler: str, repeat=1):
    """Returns (image, [times of each mi.render call])."""
    mi.set_variant(variant)
    # (Mitsuba splits the wavefront of the vectorised variants into passes by itself.)
    d = to_mitsuba(mi, scene, spp, width, height, sampler)
    sc = mi.load_dict(d)
    times = []
    img = None
    for k in range(repeat):
        t0 = time.perf_counter()
        img = mi.render(sc, spp=spp, seed=k)
        arr = np.array(img, dtype=np.float64)  # forces evaluation of the JIT variants
        times.append(time.perf_counter() - t0)
        img = arr
    return img[..., :3], times


# --------------------------------------------------------------------------------------
# Statistics
# --------------------------------------------------------------------------------------


def rmse(a, b) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


def block_means(img, k):
    h, w = img.shape[0] // k * k, img.shape[1] // k * k
    return img[:h, :w].reshape(h // k, k, w // k, k, 3).mean(axis=(1, 3))


def convergence_report(ours, theirs, ours_lo, theirs_lo, factors, label):
    """Compares two high-spp images: per-channel means, and k x k block means against
    their estimated noise (from the low-spp images' deviation from the same renderer's
    high-spp image, scaled by the spp `factors` (ours, theirs) between them)."""
    lines = []
    m_o, m_t = ours.mean(axis=(0, 1)), theirs.mean(axis=(0, 1))
    rel = (m_t - m_o) / np.maximum(m_o, 1e-12)
    lines.append(
        f"  image mean  tilefarm {fmt3(m_o)}   {label} {fmt3(m_t)}   rel diff {fmt3(rel, '{:+.2%}')}"
    )
    for k in (32, 8):
        bo, bt = block_means(ours, k), block_means(theirs, k)
        # Noise of a block mean, scaled from the low-spp renders to the high-spp ones.
        so = block_means(ours_lo, k) - bo
        st = block_means(theirs_lo, k) - bt
        sigma = np.sqrt(so.var() / factors[0] + st.var() / factors[1]) + 1e-12
        diff = bt - bo
        lum = lambda x: 0.2126 * x[..., 0] + 0.7152 * x[..., 1] + 0.0722 * x[..., 2]  # noqa: E731
        rel_blocks = np.abs(lum(diff)) / np.maximum(lum(bo), 1e-3)
        worst = np.unravel_index(np.argmax(rel_blocks), rel_blocks.shape)
        lines.append(
            f"  {k}x{k} blocks: median |rel diff| {np.median(rel_blocks):.2%}, worst {rel_blocks[worst]:.2%} at "
            f"block row {worst[0]}, col {worst[1]} (pixels y {worst[0] * k}.., x {worst[1] * k}..); "
            f"rms diff {np.sqrt((diff ** 2).mean()):.4g} vs noise ~{sigma:.2g}"
        )
    mirrored = rmse(ours[:, ::-1], theirs)
    straight = rmse(ours, theirs)
    flipped = rmse(ours[::-1], theirs)
    verdict = "OK" if straight < min(mirrored, flipped) else "MIRRORED OR FLIPPED -- camera conversion bug"
    lines.append(
        f"  orientation: rmse {straight:.4g} as is, {mirrored:.4g} mirrored left-right, {flipped:.4g} upside down: {verdict}"
    )
    return lines


def fmt3(v, f="{:.4f}"):
    return "(" + ", ".join(f.format(x) for x in v) + ")"


def choose_libllvm() -> None:
    """Points Dr.Jit at the newest system libLLVM of version 16 or later, unless
    DRJIT_LIBLLVM_PATH is set. Left to itself Dr.Jit can load Debian's LLVM 14 or 15,
    which abort while compiling for AVX-512 ("Cannot select ... fminimum")."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return
    found = []
    for lib in Path("/usr/lib").glob("*/libLLVM*.so*"):
        m = re.match(r"libLLVM[-.]?(?:so\.)?(\d+)", lib.name)
        if m and int(m.group(1)) >= 16:
            found.append((int(m.group(1)), str(lib)))
    if found:
        os.environ["DRJIT_LIBLLVM_PATH"] = max(found)[1]


def llvm_available(mi) -> tuple[bool, str]:
    try:
        mi.set_variant("llvm_ad_rgb")
        x = mi.Float([1.0, 2.0]) * 2
        np.array(x)
        return True, "llvm_ad_rgb available"
    except Exception as e:  # noqa: BLE001
        return False, f"llvm_ad_rgb unavailable ({str(e).splitlines()[0] if str(e) else type(e).__name__}); "
    finally:
        mi.set_variant("scalar_rgb")


def save_png(mi, img, path):
    mi.set_variant("scalar_rgb")
    mi.util.write_bitmap(str(path), img.astype(np.float32))


# --------------------------------------------------------------------------------------


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", default=DEFAULT_SCENES)
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel of the timed renders (power of two)")
    ap.add_argument("--ref-factor", type=int, default=16, help="reference spp = spp x this (tilefarm)")
    ap.add_argument("--mitsuba-ref-factor", type=int, default=None,
                    help="Mitsuba's high-spp render for the convergence check (default: --ref-factor; uses "
                         "llvm_ad_rgb when available, else scalar_rgb)")
    ap.add_argument("--width", type=int, default=None, help="override the scene's width (height follows aspect)")
    ap.add_argument("--max-depth", type=int, default=None, help="override the scene's max_depth")
    ap.add_argument("--sampler", default="independent",
                    help="Mitsuba sampler of the timed renders: independent (default, Mitsuba's default), or "
                         "ldsampler (Sobol-based like ours, but biased here: see bench/README.md), multijitter...")
    ap.add_argument("--no-llvm", action="store_true", help="skip llvm_ad_rgb")
    ap.add_argument("--no-equal-time", action="store_true", help="skip the extra equal-time tilefarm render")
    ap.add_argument("--coordinator", type=Path, default=None,
                    help="coordinator binary to use (default: cargo build --release -p coordinator)")
    ap.add_argument("--large", type=int, action="append", default=[], metavar="TRIANGLES",
                    help="also compare the Cornell box with a displaced sphere of about this many triangles "
                         "inside, generated by bench/make_big_scene.py (repeatable; given alone, only these)")
    ap.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "tilefarm-compare",
                    help="folder for the images")
    args = ap.parse_args()

    choose_libllvm()
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    args.out.mkdir(parents=True, exist_ok=True)
    has_llvm, llvm_note = (False, "skipped (--no-llvm)") if args.no_llvm else llvm_available(mi)
    if not has_llvm and not args.no_llvm:
        llvm_note += "install Debian's libllvm19 (apt-get install -y libllvm19) to enable it"
    print(f"mitsuba {mi.__version__}; {llvm_note}; cores: {os.cpu_count()}")
    exe = coordinator_binary(args.coordinator)
    spp = args.spp

    scenes = list(args.scenes) if args.scenes != DEFAULT_SCENES or not args.large else []
    for tris in args.large:
        folder = args.out / f"large-{tris}"
        if not (folder / "scene.toml").exists():
            subprocess.run([sys.executable, str(REPO / "bench/make_big_scene.py"), str(folder),
                            "--triangles", str(tris)], check=True)
        scenes.append(str((folder / "scene.toml").resolve()))

    for scene_arg in scenes:
        path = (Path(scene_arg) if Path(scene_arg).is_absolute() else Path.cwd() / scene_arg).resolve()
        if not path.exists():
            path = (REPO / scene_arg).resolve()
        scene = load_scene(path)
        if args.max_depth is not None:
            scene.max_depth = args.max_depth
        w0, h0 = int(scene.camera["width"]), int(scene.camera["height"])
        width = args.width or w0
        height = round(h0 * width / w0) if args.width else h0
        tag = path.parent.name
        n = width * height * spp
        print(f"\n=== {tag}: {width}x{height}, {spp} spp, max_depth {scene.max_depth}, "
              f"Mitsuba sampler {args.sampler} ===")

        # High-spp tilefarm reference.
        ref_spp = spp * args.ref_factor
        # A different seed: with the same one the reference would contain the test
        # render's samples, and their error would partly cancel.
        ref, t_ref, _ = render_tilefarm(exe, path, ref_spp, width, height, args.out / f"{tag}-ref.exr",
                                        args.max_depth, seed=12345)
        print(f"reference: tilefarm {ref_spp} spp in {t_ref:.2f} s")

        rows = []
        ours, t_ours, wall = render_tilefarm(exe, path, spp, width, height, args.out / f"{tag}-tilefarm.exr",
                                             args.max_depth)
        rows.append(("tilefarm", t_ours, rmse(ours, ref), ours, f"(process wall {wall:.2f} s)"))
        img_s, ts = render_mitsuba(mi, "scalar_rgb", scene, spp, width, height, args.sampler)
        rows.append(("mitsuba scalar_rgb", ts[0], rmse(img_s, ref), img_s, ""))
        if has_llvm:
            img_l, tl = render_mitsuba(mi, "llvm_ad_rgb", scene, spp, width, height, args.sampler, repeat=2)
            rows.append(("mitsuba llvm_ad_rgb", tl[1], rmse(img_l, ref), img_l,
                         f"(warm; first call incl. JIT {tl[0]:.2f} s)"))

        print(f"{'renderer':<22}{'time s':>9}{'M samples/s':>13}{'RMSE vs ref':>13}{'RMSE^2 x time':>15}")
        for name, t, e, _, note in rows:
            print(f"{name:<22}{t:>9.3f}{n / t / 1e6:>13.3f}{e:>13.5f}{e * e * t:>15.4g}  {note}")
        print(f"time ratio tilefarm / scalar_rgb: {t_ours / rows[1][1]:.3f}"
              f"  (issue target <= 0.5)")
        if has_llvm:
            print(f"time ratio tilefarm / llvm_ad_rgb: {t_ours / rows[2][1]:.3f}")

        # Equal time: RMSE ~ 1/sqrt(time) at fixed per-sample cost and variance.
        t_eq = rows[1][1]
        print(f"RMSE at equal wall time ({t_eq:.2f} s = Mitsuba scalar_rgb's), extrapolated as RMSE x sqrt(t / T):")
        for name, t, e, _, _ in rows:
            print(f"  {name:<22}{e * math.sqrt(t / t_eq):.5f}")
        if not args.no_equal_time:
            spp_eq = max(1, round(spp * t_eq / t_ours))
            eq, t_eq_ours, _ = render_tilefarm(exe, path, spp_eq, width, height,
                                               args.out / f"{tag}-tilefarm-eqtime.exr", args.max_depth)
            print(f"  measured: tilefarm at {spp_eq} spp took {t_eq_ours:.2f} s, RMSE {rmse(eq, ref):.5f}"
                  f"  vs Mitsuba scalar_rgb {rows[1][2]:.5f} at {spp} spp in {t_eq:.2f} s")

        # Convergence: do both renderers converge to the same image?
        mfac = args.mitsuba_ref_factor or args.ref_factor
        mvar = "llvm_ad_rgb" if has_llvm else "scalar_rgb"
        # Always the independent sampler: Mitsuba's ldsampler does not converge to the
        # right image on the Cornell box (3% dark on surfaces lit only indirectly).
        mref, tm = render_mitsuba(mi, mvar, scene, spp * mfac, width, height, "independent")
        print(f"convergence check: tilefarm {ref_spp} spp vs Mitsuba {mvar} independent {spp * mfac} spp "
              f"({tm[0]:.1f} s)")
        for line in convergence_report(ref, mref, ours, img_s, (args.ref_factor, mfac), "mitsuba"):
            print(line)
        for name, img in (("ref", ref), ("mitsuba-ref", mref), ("tilefarm", ours), ("mitsuba", img_s)):
            save_png(mi, img, args.out / f"{tag}-{name}.png")
        np.save(args.out / f"{tag}-mitsuba-ref.npy", mref)
        print(f"images in {args.out}")


if __name__ == "__main__":
    main()
