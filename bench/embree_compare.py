#!/usr/bin/env python3
"""Single-ray throughput of tilefarm's BVH (or kd-tree) against Embree, same mesh, same rays.

Needs: `pip install embreex numpy` (this script installs nothing) and a Rust toolchain.

What is measured, on one thread each:
  * tilefarm: `Bvh8::intersect` / `Bvh8::occluded` (or the kd-tree's) called once per
    ray in a loop (`KDTREE_SERVE=N,REPEAT,RAYS KDTREE_SERVE_ACCEL=bvh8 cargo bench -p
    tracer --bench kdtree`, a process that times one pass over the rays whenever asked).
  * Embree (embreex 4.x): `EmbreeScene.run(origins, dirs, query=...)`, whose C loop calls
    `rtcIntersect1` / `rtcOccluded1` once per ray on the calling thread and writes the
    hit to NumPy arrays: single-ray queries, like ours, plus a few stores per ray. The
    Embree scene is Embree's default (a BVH, non-robust mode; ours is watertight and
    bit-exact against brute force).
Both traverse the displaced sphere of `cargo bench --bench kdtree` (seed 0, N triangles) and
the incoherent rays `tracer::accel::incoherent_rays` makes (origins on the bounding
sphere aimed at uniform points in the box; closest hit with tmax = inf, any hit with
tmax = the distance to that point), exported by `coordinator bench --export-mesh /
--export-rays`. Hit counts are checked equal on every pass, so the same work is done.
Embree's build runs on all threads (TBB); ours too.

This host's speed drifts by tens of percent within minutes, so the two alternate pass
by pass (`--passes` pairs per query kind, the order flipping every pair) and the ratio
printed is the median of the pairs' ratios, with its quartiles.

tilefarm's side is the eight-wide BVH that traces a scene's own primitives
(`tracer/src/accel/bvh8`), or with `--accel kdtree` the kd-tree it replaced.

Usage: python3 bench/embree_compare.py [--triangles 1000000] [--rays 100000] [--repeat 3] [--passes 20] [--accel kdtree]
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
    ap.add_argument("--repeat", type=int, default=3, help="tilefarm builds (median)")
    ap.add_argument("--passes", type=int, default=20,
                    help="alternated passes per query kind; the ratio is the median over pass pairs")
    ap.add_argument("--accel", choices=("bvh8", "kdtree"), default="bvh8",
                    help="tilefarm's structure: the eight-wide BVH the renderer uses, or the kd-tree it "
                         "replaced")
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
    # the two alternate pass by pass (each pass: all rays, one query kind), the order
    # flipping every pair, and each pair gives a ratio; the summary is their median.
    # tilefarm runs as one long-lived process (`KDTREE_SERVE`) that times a pass when
    # asked; Embree runs on this thread.
    env = dict(os.environ, KDTREE_SERVE=f"{a.triangles},{a.repeat},{a.rays}", KDTREE_SERVE_ACCEL=a.accel)
    tf = subprocess.Popen(["cargo", "bench", "-q", "-p", "tracer", "--bench", "kdtree"],
                          cwd=ROOT, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        ready = tf.stdout.readline()
        m = re.search(r"ready (\d+) triangles, build median ([0-9.]+) s", ready)
        if not m:
            sys.exit(f"tilefarm bench did not start: {ready!r}")
        build = float(m.group(2))

        def tilefarm(query):
            tf.stdin.write(query + "\n")
            tf.stdin.flush()
            kind, secs, count = tf.stdout.readline().split()
            return float(secs), int(count)

        def embree(query):
            t = time.perf_counter()
            if query == "closest":
                out = scene.run(origins, dirs, query="INTERSECT")
            else:
                out = scene.run(origins, dirs, dists=tmax, query="OCCLUDED")
            secs = time.perf_counter() - t
            return secs, int((np.asarray(out) >= 0).sum())

        results = {}
        for query in ("closest", "any"):
            tilefarm(query), embree(query)  # warm caches and branch predictors
            pairs = []
            for k in range(a.passes):
                if k % 2 == 0:
                    e, t = embree(query), tilefarm(query)
                else:
                    t, e = tilefarm(query), embree(query)
                if t[1] != e[1]:
                    sys.exit(f"{query}: hit counts differ: tilefarm {t[1]}, Embree {e[1]}")
                pairs.append((t[0], e[0], t[1]))
            results[query] = pairs
    finally:
        tf.stdin.close()
        tf.wait(timeout=60)

    def q(xs, f):
        xs = sorted(xs)
        return xs[int((len(xs) - 1) * f)]

    print(f"{'':14}{'tilefarm':>10}{'Embree':>10}{'ratio':>8}")
    print(f"{'build (s)':14}{build:>10.3f}{embree_build:>10.3f}{build / embree_build:>8.2f}   (all threads; "
          f"tilefarm median of {a.repeat}, Embree one)")
    for query, name in (("closest", "closest-hit"), ("any", "any-hit")):
        pairs = results[query]
        ratios = [e / t for t, e, _ in pairs]
        rate_t = statistics.median(n / t / 1e6 for t, _, _ in pairs)
        rate_e = statistics.median(n / e / 1e6 for _, e, _ in pairs)
        print(f"{name:14}{rate_t:>10.3f}{rate_e:>10.3f}{statistics.median(ratios):>8.2f}   Mrays/s on one thread "
              f"(medians); ratio: median of {len(pairs)} pass pairs, quartiles {q(ratios, 0.25):.2f}-"
              f"{q(ratios, 0.75):.2f}; {'hits' if query == 'closest' else 'occluded'} {pairs[0][2]} in both")


if __name__ == "__main__":
    main()
