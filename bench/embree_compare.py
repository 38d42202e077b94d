#!/usr/bin/env python3
"""Single-ray throughput of tilefarm's kd-tree against Embree, same mesh, same rays.

Needs: `pip install embreex numpy` (this script installs nothing) and a Rust toolchain.

What is measured, on one thread each:
  * tilefarm: `KdTree::intersect` / `KdTree::occluded` called once per ray in a loop
    (`KDTREE_QUICK=all,N,REPEAT,0,RAYS cargo bench -p tracer --bench kdtree`).
  * Embree (embreex 4.x): `EmbreeScene.run(origins, dirs, query=...)`, whose C loop calls
    `rtcIntersect1` / `rtcOccluded1` once per ray on the calling thread and writes the
    hit to NumPy arrays: single-ray queries, like ours, plus a few stores per ray. The
    Embree scene is Embree's default (a BVH, non-robust mode; ours is watertight and
    bit-exact against brute force).
Both traverse the displaced sphere of `cargo bench --bench kdtree` (seed 0, N triangles) and
the incoherent rays `tracer::accel::incoherent_rays` makes (origins on the bounding
sphere aimed at uniform points in the box; closest hit with tmax = inf, any hit with
tmax = the distance to that point), exported by `coordinator bench --export-mesh /
--export-rays`. Figures are medians of REPEAT passes; hit counts are printed for both as
a check that the same work is done. Embree's build runs on all threads (TBB); ours too.

The two alternate for `--rounds` rounds (this host's speed drifts); the last line gives
the median ratio over rounds and its range.

Usage: python3 bench/embree_compare.py [--triangles 1000000] [--rays 100000] [--repeat 5] [--rounds 3]
"""

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

try:
    import numpy as np
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh
except ImportError as e:  # pragma: no cover
    sys.exit(f"{e}: run `pip install embreex numpy` first")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def read_mesh(path):
    with open(path, "rb") as f:
        data = f.read()
    assert data[:8] == b"TFMESH01", "not a tilefarm mesh export"
    nv, nt = np.frombuffer(data, dtype="<u4", count=2, offset=8)
    off = 16
    verts = np.frombuffer(data, dtype="<f4", count=3 * nv, offset=off).reshape(nv, 3)
    off += 12 * int(nv)
    tris = np.frombuffer(data, dtype="<u4", count=3 * nt, offset=off).reshape(nt, 3)
    return np.ascontiguousarray(verts, dtype=np.float32), np.ascontiguousarray(tris, dtype=np.int32)


def read_rays(path):
    with open(path, "rb") as f:
        data = f.read()
    assert data[:8] == b"TFRAYS01", "not a tilefarm ray export"
    (n,) = np.frombuffer(data, dtype="<u4", count=1, offset=8)
    r = np.frombuffer(data, dtype="<f4", count=7 * int(n), offset=12).reshape(n, 7)
    return (np.ascontiguousarray(r[:, 0:3]), np.ascontiguousarray(r[:, 3:6]), np.ascontiguousarray(r[:, 6]))


def median_rate(n, repeat, f):
    times = []
    out = None
    for _ in range(repeat):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return n / statistics.median(times) / 1e6, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--triangles", type=int, default=1_000_000)
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=5, help="passes per measurement (median)")
    ap.add_argument("--rounds", type=int, default=3,
                    help="alternations of tilefarm and Embree; the summary is the median over rounds")
    a = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        mesh_path, rays_path = os.path.join(tmp, "mesh.bin"), os.path.join(tmp, "rays.bin")
        subprocess.run(
            ["cargo", "run", "--release", "-q", "-p", "coordinator", "--", "bench",
             "--mesh-triangles", str(a.triangles), "--rays", str(a.rays),
             "--export-mesh", mesh_path, "--export-rays", rays_path],
            cwd=ROOT, check=True)
        verts, tris = read_mesh(mesh_path)
        origins, dirs, tmax = read_rays(rays_path)
    n = len(origins)
    print(f"mesh: {len(tris)} triangles, {len(verts)} vertices; {n} incoherent rays")

    t = time.perf_counter()
    scene = rtcs.EmbreeScene()
    TriangleMesh(scene, verts, tris)
    scene.run(origins[:1], dirs[:1])  # commits (builds) the scene
    embree_build = time.perf_counter() - t

    # This host is shared and its speed drifts by tens of percent within minutes, so
    # the two renderers alternate, round by round, and each round gives its own ratios.
    rows = []
    for r in range(a.rounds):
        closest_e, ids = median_rate(n, a.repeat, lambda: scene.run(origins, dirs, query="INTERSECT"))
        any_e, occ = median_rate(n, a.repeat, lambda: scene.run(origins, dirs, dists=tmax, query="OCCLUDED"))
        hits_e, occl_e = int((np.asarray(ids) >= 0).sum()), int((np.asarray(occ) >= 0).sum())

        env = dict(os.environ, KDTREE_QUICK=f"all,{a.triangles},{a.repeat},0,{a.rays}")
        out = subprocess.run(["cargo", "bench", "-q", "-p", "tracer", "--bench", "kdtree"],
                             cwd=ROOT, env=env, check=True, capture_output=True, text=True).stdout
        build = float(re.search(r"build median ([0-9.]+) s", out).group(1))
        m = re.search(r"closest-hit ([0-9.]+) Mrays/s \((\d+) hit\)", out)
        closest_t, hits_t = float(m.group(1)), int(m.group(2))
        m = re.search(r"any-hit ([0-9.]+) Mrays/s \((\d+) occluded\)", out)
        any_t, occl_t = float(m.group(1)), int(m.group(2))
        if (hits_t, occl_t) != (hits_e, occl_e):
            sys.exit(f"hit counts differ: tilefarm {hits_t} / {occl_t}, Embree {hits_e} / {occl_e}")

        print(f"round {r + 1}:{'':4}{'tilefarm':>14}{'Embree':>14}{'ratio':>9}")
        if r == 0:
            print(f"{'build (s)':12}{build:>14.3f}{embree_build:>14.3f}{build / embree_build:>9.2f}   (all threads)")
        else:
            print(f"{'build (s)':12}{build:>14.3f}")
        print(f"{'closest-hit':12}{closest_t:>14.3f}{closest_e:>14.3f}{closest_t / closest_e:>9.2f}   "
              f"Mrays/s, one thread; hits {hits_t} / {hits_e}")
        print(f"{'any-hit':12}{any_t:>14.3f}{any_e:>14.3f}{any_t / any_e:>9.2f}   "
              f"Mrays/s, one thread; occluded {occl_t} / {occl_e}")
        rows.append((build, closest_t / closest_e, any_t / any_e))

    def span(xs):
        return f"median {statistics.median(xs):.2f} (range {min(xs):.2f}-{max(xs):.2f})"

    print(f"over {a.rounds} rounds: build {span([b for b, _, _ in rows])} s; ratio to Embree "
          f"closest-hit {span([c for _, c, _ in rows])}, any-hit {span([x for _, _, x in rows])}")


if __name__ == "__main__":
    main()
