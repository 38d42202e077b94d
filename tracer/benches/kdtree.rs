//! kd-tree build time and single-thread ray throughput.
//!
//! `cargo bench -p tracer --bench kdtree` runs the criterion benchmarks and prints
//! Mrays/s. With `KDTREE_TUNE=1` (or a list of Ci/Ct ratios, `KDTREE_TUNE=1,2,4`) it instead sweeps the build parameters (cost ratio, empty
//! bonus, leaf size) and prints build time, size and throughput for each. With
//! `KDTREE_QUICK=all` (or `build`, `closest`, `any`, optionally `,TRIANGLES`) it prints
//! medians of the 1M-triangle build and of single-thread throughput, without criterion.
//! `KDTREE_AB=CI_A,CI_B[,TRIANGLES]` builds the mesh's tree with two intersection costs
//! and times them against each other in one process, in alternating short slices: on a
//! host whose speed drifts within minutes, the ratio of the two is far steadier than
//! figures from separate runs (A against itself: 1.01, median of 200 slices; Ci 0.08 and
//! 0.18 against the default 0.12: 0.97–1.01 on the 1M mesh). To compare code rather than
//! parameters, give the two trees the variants to compare; `KDTREE_AB_SIMD=baseline,avx2`
//! builds them under two `TILEFARM_SIMD` settings (sixteen-lane leaves, tried this way:
//! 0.99–1.01 of eight, on the 1M and 100k meshes and with Ci 0.06, so not kept).
//! `KDTREE_SERVE=TRIANGLES,REPEAT,RAYS` builds the mesh's tree (REPEAT times, printing
//! the median build) and then answers lines on stdin, `closest` or `any`, with one
//! timed pass over the rays each: `closest SECONDS HITS`. `bench/embree_compare.py`
//! drives it, alternating pass by pass with Embree in its own process.
//! `KDTREE_PACKETS=TRIANGLES[,ROUNDS]` times the eight-ray packet queries against one ray
//! at a time on the mesh, in interleaved rounds (medians): a pinhole camera's rays in
//! packets of 4×2 pixels, the shadow rays from their hits towards a point light, and
//! incoherent rays eight at a time.
//! `KDTREE_RAYS=surface|camera` makes `KDTREE_QUICK` trace other rays than the incoherent
//! ones: from points on the mesh in uniform directions (as bounces leave a surface), or a
//! pinhole camera's in scanline order (coherent). `KDTREE_SCENE=scene.toml` with
//! `KDTREE_QUICK=x` times both kinds on that scene's own tree instead.

#[path = "shared/packets.rs"]
mod packets;

use std::hint::black_box;
use std::time::Instant;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::Vec3;
use tracer::accel::bvh8::{Bvh8, Bvh8Params};
use tracer::accel::ray_packets::RayPacket;
use tracer::accel::{BuildParams, KdTree};
use tracer::geometry::{Aabb, Ray};
use tracer::scene::generate::displaced_sphere;

use packets::{camera_packets, packets_of, shadow_packets};
use tracer::scene::{Geometry, Sphere};

const RAYS: usize = 100_000;

struct Rng(u64);

impl Rng {
    fn f(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Incoherent rays: origins on the bounding sphere towards uniform points in the box,
/// with the distance to that point (the shadow-ray length).
fn random_rays(b: Aabb, n: usize, seed: u64) -> Vec<(Ray, f32)> {
    tracer::accel::incoherent_rays(b, n, seed)
}

/// Rays leaving the surface, as a renderer's bounces do: from random points of random
/// triangles (nudged off along the ray), uniform directions; any-hit length 1/4 of the
/// scene's size.
fn surface_rays(geo: &Geometry, n: usize) -> Vec<(Ray, f32)> {
    let mut r = Rng(5);
    let ntri = geo.triangle_count();
    let size = (0..ntri)
        .fold(Aabb::EMPTY, |b, i| {
            let t = geo.triangle(i);
            b.union(Aabb::new(t[0], t[0]))
        })
        .diagonal()
        .length();
    (0..n)
        .map(|_| {
            let t = geo.triangle(((r.f() * ntri as f32) as usize).min(ntri - 1));
            let (mut u, mut v) = (r.f(), r.f());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let p = t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v;
            let d = loop {
                let d = Vec3::new(r.f(), r.f(), r.f()) * 2.0 - 1.0;
                if d.length_squared() > 1e-4 && d.length_squared() <= 1.0 {
                    break d.normalize();
                }
            };
            (Ray::new(p + d * (1e-4 * size), d), 0.25 * size)
        })
        .collect()
}

/// A pinhole camera's rays in scanline order (coherent), from 1.5 diagonals away from the
/// box's center, through a square grid covering it; any-hit length: to the center.
fn camera_rays(b: Aabb, n: usize) -> Vec<(Ray, f32)> {
    let side = (n as f64).sqrt().ceil() as usize;
    let (c, size) = (b.center(), b.diagonal().length());
    let eye = c + Vec3::new(0.3, 0.4, 3.0).normalize() * (1.5 * size);
    let fwd = (c - eye).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    (0..n)
        .map(|i| {
            let (x, y) = ((i % side) as f32 / side as f32 - 0.5, (i / side) as f32 / side as f32 - 0.5);
            let d = (fwd + (right * x + up * y) * 0.7).normalize();
            (Ray::new(eye, d), (c - eye).length())
        })
        .collect()
}

fn closest(tree: &KdTree, geo: &Geometry, rays: &[(Ray, f32)]) -> usize {
    rays.iter().filter(|(r, _)| tree.intersect(geo, r, f32::INFINITY).is_some()).count()
}

fn any(tree: &KdTree, geo: &Geometry, rays: &[(Ray, f32)]) -> usize {
    rays.iter().filter(|(r, len)| tree.occluded(geo, r, *len)).count()
}

/// Best-of-3 Mrays/s of one pass.
fn mrays(f: impl Fn() -> usize, n: usize) -> f64 {
    (0..3)
        .map(|_| {
            let t = Instant::now();
            black_box(f());
            n as f64 / t.elapsed().as_secs_f64() / 1e6
        })
        .fold(0.0, f64::max)
}

fn spheres_scene() -> Geometry {
    let mut r = Rng(11);
    let spheres = (0..10_000)
        .map(|_| Sphere {
            center: Vec3::new(r.f(), r.f(), r.f()) * 20.0 - 10.0,
            radius: 0.05 + 0.3 * r.f() * r.f(),
            material: 0,
        })
        .collect();
    let mut mesh = displaced_sphere(20_000, 1);
    for p in &mut mesh.positions {
        *p *= 4.0;
    }
    Geometry::new(mesh, spheres)
}

fn timed_build(geo: &Geometry, params: &BuildParams) -> (KdTree, f64) {
    let t = Instant::now();
    let tree = KdTree::build(geo, params);
    (tree, t.elapsed().as_secs_f64())
}

fn tune() {
    let mid = Geometry::new(displaced_sphere(100_000, 0), vec![]);
    let scenes = [("100k mesh", &mid), ("spheres", &spheres_scene())];
    let mut variants = Vec::new();
    let grid: Vec<f32> = std::env::var("KDTREE_TUNE")
        .ok()
        .and_then(|v| v.split(',').map(|x| x.parse().ok()).collect())
        .unwrap_or(vec![0.75, 1.0, 1.5, 2.0, 3.0, 5.0]);
    let base = BuildParams { intersection_cost: grid[0], ..Default::default() };
    for &ci in &grid {
        variants.push(BuildParams { intersection_cost: ci, ..Default::default() });
    }
    for eb in [0.0f32, 0.5, 0.8] {
        variants.push(BuildParams { empty_bonus: eb, ..base.clone() });
    }
    for leaf in [0usize, 2, 4] {
        variants.push(BuildParams { max_leaf_prims: leaf, ..base.clone() });
    }
    for (name, geo) in scenes {
        let tree0 = KdTree::build(geo, &BuildParams::default());
        let rays = random_rays(tree0.bounds(), RAYS, 5);
        for p in &variants {
            let (mut tree, secs) = timed_build(geo, p);
            let mut geo = geo.clone();
            geo.store_in_leaf_order(&mut tree);
            let s = tree.stats();
            let c = mrays(|| closest(&tree, &geo, &rays), rays.len());
            let a = mrays(|| any(&tree, &geo, &rays), rays.len());
            println!(
                "tune {name:>9}: Ci/Ct {:.2} eb {:.1} leaf {}: build {:.3} s, {} nodes, {} refs, depth {}, \
                 closest {c:.2} Mrays/s, any {a:.2} Mrays/s",
                p.intersection_cost / p.traversal_cost,
                p.empty_bonus,
                p.max_leaf_prims,
                secs,
                s.nodes,
                s.prim_refs,
                s.max_depth,
            );
        }
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// `KDTREE_SCENE=scene.toml`: a kd-tree over the scene's geometry (as the loader stores
/// it, in its BVH's leaf order), surface and camera rays.
fn scene_quick(path: &str, reps: usize) {
    let sc = tracer::scene::load_scene(std::path::Path::new(path)).unwrap();
    let geo = &sc.geometry;
    let tree = &KdTree::build(geo, &BuildParams::for_scene(geo.triangle_count(), geo.spheres.len()));
    for mode in ["surface", "camera"] {
        let rays = if mode == "surface" { surface_rays(geo, RAYS) } else { camera_rays(tree.bounds(), RAYS) };
        for any_hit in [false, true] {
            let v: Vec<f64> = (0..reps)
                .map(|_| {
                    let t = Instant::now();
                    black_box(if any_hit { any(tree, geo, &rays) } else { closest(tree, geo, &rays) });
                    rays.len() as f64 / t.elapsed().as_secs_f64() / 1e6
                })
                .collect();
            println!("{mode} {} {:.3} Mrays/s", if any_hit { "any" } else { "closest" }, median(v));
        }
    }
}

/// `KDTREE_QUICK=all|build|closest|any[,triangles[,repeats[,mesh seed[,rays]]]]`: medians without criterion, for
/// before/after comparisons and for profiling one query kind in isolation.
fn quick(spec: &str) {
    if let Ok(p) = std::env::var("KDTREE_SCENE") {
        return scene_quick(&p, 20);
    }
    let mut parts = spec.split(',');
    let what = parts.next().unwrap_or("all").to_string();
    let n: usize = parts.next().and_then(|x| x.parse().ok()).unwrap_or(1_000_000);
    let reps: usize = parts.next().and_then(|x| x.parse().ok()).unwrap_or(if what == "all" { 5 } else { 3 });
    let seed: u64 = parts.next().and_then(|x| x.parse().ok()).unwrap_or(0);
    let nrays: usize = parts.next().and_then(|x| x.parse().ok()).unwrap_or(RAYS);
    let mut geo = Geometry::new(displaced_sphere(n, seed), vec![]);
    // `KDTREE_CI=x`: another intersection cost (Ci/Ct) than the default, for tuning.
    let params = match std::env::var("KDTREE_CI").ok().and_then(|x| x.parse().ok()) {
        Some(ci) => BuildParams { intersection_cost: ci, ..Default::default() },
        None => BuildParams::default(),
    };
    let mut builds = Vec::new();
    let mut tree = None;
    for _ in 0..(if matches!(what.as_str(), "all" | "build") { reps } else { 1 }) {
        let (t, secs) = timed_build(&geo, &params);
        builds.push(secs);
        tree = Some(t);
    }
    let mut tree = tree.unwrap();
    // Of the tree as built (before leaf-order storage renames its indices).
    let fingerprint = tree.fingerprint();
    let t = Instant::now();
    geo.store_in_leaf_order(&mut tree);
    let reorder = t.elapsed().as_secs_f64();
    let s = tree.stats();
    let ntri = geo.triangle_count();
    println!(
        "{ntri} triangles: build median {:.3} s of {:?}, leaf-order storage {reorder:.3} s; {} nodes, {} refs, \
         depth {}, tree {:.1} B/tri, fingerprint {:016x}",
        median(builds.clone()),
        builds.iter().map(|b| (b * 1000.0).round() / 1000.0).collect::<Vec<_>>(),
        s.nodes,
        s.prim_refs,
        s.max_depth,
        s.bytes as f64 / ntri as f64,
        fingerprint
    );
    let rays = match std::env::var("KDTREE_RAYS").as_deref() {
        Ok("surface") => surface_rays(&geo, nrays),
        Ok("camera") => camera_rays(tree.bounds(), nrays),
        _ => random_rays(tree.bounds(), nrays, 1),
    };
    let rate = |f: &dyn Fn() -> usize| {
        let v: Vec<f64> = (0..reps)
            .map(|_| {
                let t = Instant::now();
                black_box(f());
                rays.len() as f64 / t.elapsed().as_secs_f64() / 1e6
            })
            .collect();
        median(v)
    };
    if what == "check" {
        // The tree against brute force on the first rays (slow: O(N) per ray).
        let bad = rays[..nrays.min(300)]
            .iter()
            .filter(|(r, len)| {
                tree.intersect(&geo, r, f32::INFINITY) != tracer::accel::brute_force_intersect(&geo, r, f32::INFINITY)
                    || tree.occluded(&geo, r, *len) != tracer::accel::brute_force_occluded(&geo, r, *len)
            })
            .count();
        println!("check: {bad} disagreements with brute force");
    }
    if matches!(what.as_str(), "all" | "closest") {
        let hits = closest(&tree, &geo, &rays);
        println!("closest-hit {:.3} Mrays/s ({hits} hit)", rate(&|| closest(&tree, &geo, &rays)));
    }
    if matches!(what.as_str(), "all" | "any") {
        let occl = any(&tree, &geo, &rays);
        println!("any-hit {:.3} Mrays/s ({occl} occluded)", rate(&|| any(&tree, &geo, &rays)));
    }
}

/// `KDTREE_AB=CI_A,CI_B[,TRIANGLES]`: B's throughput over A's, closest and any hit, as
/// the median over slices of the rays, each traced by both (one thread).
fn ab(spec: &str) {
    let v: Vec<f64> = spec.split(',').filter_map(|x| x.parse().ok()).collect();
    let (ci_a, ci_b) = (v.first().copied().unwrap_or(0.12) as f32, v.get(1).copied().unwrap_or(0.12) as f32);
    let n = v.get(2).map_or(1_000_000, |&t| t as usize);
    let mesh = displaced_sphere(n, 0);
    // `KDTREE_AB_SIMD=A,B`: the instruction sets (`TILEFARM_SIMD`) the two trees use.
    let simd: Vec<String> = std::env::var("KDTREE_AB_SIMD").unwrap_or_default().split(',').map(String::from).collect();
    let make = |ci: f32, which: usize| {
        if let Some(s) = simd.get(which).filter(|s| !s.is_empty()) {
            // SAFETY: the bench is single-threaded here (no other thread reads the
            // environment while it changes).
            unsafe { std::env::set_var("TILEFARM_SIMD", s) };
        }
        let mut geo = Geometry::new(mesh.clone(), vec![]);
        let (mut tree, _) = timed_build(&geo, &BuildParams { intersection_cost: ci, ..Default::default() });
        geo.store_in_leaf_order(&mut tree);
        (geo, tree)
    };
    let (a, b) = (make(ci_a, 0), make(ci_b, 1));
    let rays = random_rays(a.1.bounds(), RAYS, 1);
    assert_eq!(closest(&a.1, &a.0, &rays), closest(&b.1, &b.0, &rays), "A and B disagree");
    let slice = 5_000;
    const ROUNDS: usize = 10;
    let time = |t: &(Geometry, KdTree), rays: &[(Ray, f32)], any_hit: bool| {
        let s = Instant::now();
        black_box(if any_hit { any(&t.1, &t.0, rays) } else { closest(&t.1, &t.0, rays) });
        s.elapsed().as_secs_f64()
    };
    for (name, any_hit) in [("closest-hit", false), ("any-hit", true)] {
        let mut ratios = Vec::new();
        let (mut ta, mut tb) = (0.0, 0.0);
        for _round in 0..ROUNDS {
            for (k, chunk) in rays.chunks(slice).enumerate() {
                // A then B, or B then A, on each slice, never one twice in a row on the
                // same rays (the second pass would find its own nodes in the cache).
                let (ra, rb) = if k % 2 == 0 {
                    let ra = time(&a, chunk, any_hit);
                    (ra, time(&b, chunk, any_hit))
                } else {
                    let rb = time(&b, chunk, any_hit);
                    (time(&a, chunk, any_hit), rb)
                };
                ratios.push(ra / rb);
                (ta, tb) = (ta + ra, tb + rb);
            }
        }
        ratios.sort_by(f64::total_cmp);
        let q = |f: f64| ratios[((ratios.len() - 1) as f64 * f) as usize];
        let rate = |t: f64| ROUNDS as f64 * rays.len() as f64 / t / 1e6;
        println!(
            "{name}: B/A throughput {:.3} (median of {} slice pairs; quartiles {:.3}-{:.3}); A {:.3}, B {:.3} Mrays/s \
             (Ci {ci_a} vs {ci_b}, {} triangles)",
            q(0.5),
            ratios.len(),
            q(0.25),
            q(0.75),
            rate(ta),
            rate(tb),
            a.0.triangle_count()
        );
    }
}

/// `KDTREE_SERVE=TRIANGLES,REPEAT,RAYS`: see the module comment. With
/// `KDTREE_SERVE_ACCEL=bvh8` the eight-wide BVH answers instead of the kd-tree.
fn serve(spec: &str) {
    use std::io::{BufRead, Write};
    let v: Vec<usize> = spec.split(',').filter_map(|x| x.parse().ok()).collect();
    let (n, reps, nrays) =
        (v.first().copied().unwrap_or(1_000_000), v.get(1).copied().unwrap_or(3), v.get(2).copied().unwrap_or(RAYS));
    let bvh = std::env::var("KDTREE_SERVE_ACCEL").is_ok_and(|a| a == "bvh8");
    let mut geo = Geometry::new(displaced_sphere(n, 0), vec![]);
    // Both answer for the same rays: the kd-tree's bounds are the mesh's.
    let mut tree = timed_build(&geo, &BuildParams::default()).0;
    let rays = random_rays(tree.bounds(), nrays, 1);
    type Query = Box<dyn Fn(&str, &Geometry) -> usize>;
    let (build, query): (f64, Query) = if bvh {
        let builds: Vec<(Bvh8, f64)> = (0..reps.max(1))
            .map(|_| {
                let t = Instant::now();
                let b = Bvh8::build(&geo, &Bvh8Params::default());
                (b, t.elapsed().as_secs_f64())
            })
            .collect();
        let build = median(builds.iter().map(|b| b.1).collect());
        let mut b = builds.into_iter().next_back().unwrap().0;
        geo.store_in_leaf_order(&mut b);
        (
            build,
            Box::new(move |q, geo| match q {
                "closest" => rays.iter().filter(|(r, _)| b.intersect(geo, r, f32::INFINITY).is_some()).count(),
                _ => rays.iter().filter(|(r, len)| b.occluded(geo, r, *len)).count(),
            }),
        )
    } else {
        let builds: Vec<f64> = (1..reps.max(1)).map(|_| timed_build(&geo, &BuildParams::default()).1).collect();
        let build = median(builds.into_iter().chain([timed_build(&geo, &BuildParams::default()).1]).collect());
        geo.store_in_leaf_order(&mut tree);
        (
            build,
            Box::new(move |q, geo| match q {
                "closest" => closest(&tree, geo, &rays),
                _ => any(&tree, geo, &rays),
            }),
        )
    };
    let mut out = std::io::stdout().lock();
    writeln!(out, "ready {} triangles, build median {build:.4} s", geo.triangle_count()).unwrap();
    out.flush().unwrap();
    for line in std::io::stdin().lock().lines() {
        let line = line.unwrap();
        let t = Instant::now();
        let count = match line.trim() {
            q @ ("closest" | "any") => query(q, &geo),
            "" => continue,
            other => panic!("KDTREE_SERVE: unknown command {other:?} (closest, any)"),
        };
        writeln!(out, "{} {:.6} {count}", line.trim(), t.elapsed().as_secs_f64()).unwrap();
        out.flush().unwrap();
    }
}

/// `KDTREE_PACKETS=TRIANGLES[,ROUNDS]`: see the module comment.
fn packets(spec: &str) {
    let mut parts = spec.split(',').map(|x| x.parse::<usize>().ok());
    let n = parts.next().flatten().unwrap_or(1_000_000);
    let rounds = parts.next().flatten().unwrap_or(9);
    let mut geo = Geometry::new(displaced_sphere(n, 0), vec![]);
    let (mut tree, _) = timed_build(&geo, &BuildParams::default());
    geo.store_in_leaf_order(&mut tree);
    let camera = camera_packets(tree.bounds(), 512);
    let shadow = shadow_packets(tree.bounds(), &camera, |p| tree.intersect8(&geo, p));
    let random = packets_of(&random_rays(tree.bounds(), RAYS, 1));
    let lanes = |ps: &[RayPacket]| ps.iter().map(|p| p.active.count_ones() as usize).sum::<usize>();
    println!("{} triangles, one thread, Mrays/s, medians of {rounds} interleaved rounds:", geo.triangle_count());
    println!("{:<28}{:>10}{:>10}{:>8}", "rays", "one", "packets", "ratio");
    for (name, ps, any_hit) in [
        ("camera, closest hit", &camera, false),
        ("shadow to a point, any hit", &shadow, true),
        ("incoherent, closest hit", &random, false),
        ("incoherent, any hit", &random, true),
    ] {
        let n = lanes(ps) as f64;
        let one = || {
            ps.iter()
                .map(|p| {
                    (0..8)
                        .filter(|&l| p.active & (1 << l) != 0)
                        .filter(|&l| {
                            let r = p.ray(l);
                            if any_hit {
                                tree.occluded(&geo, &r, p.tmax[l])
                            } else {
                                tree.intersect(&geo, &r, p.tmax[l]).is_some()
                            }
                        })
                        .count()
                })
                .sum::<usize>()
        };
        let eight = || {
            ps.iter()
                .map(|p| {
                    (if any_hit { tree.occluded8(&geo, p) } else { tree.intersect8(&geo, p).found }).count_ones()
                        as usize
                })
                .sum::<usize>()
        };
        assert_eq!(one(), eight(), "{name}: packets and single rays disagree");
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for _ in 0..rounds {
            let t = Instant::now();
            black_box(one());
            a.push(n / t.elapsed().as_secs_f64() / 1e6);
            let t = Instant::now();
            black_box(eight());
            b.push(n / t.elapsed().as_secs_f64() / 1e6);
        }
        let ratios: Vec<f64> = a.iter().zip(&b).map(|(x, y)| y / x).collect();
        println!("{name:<28}{:>10.3}{:>10.3}{:>8.2}", median(a), median(b), median(ratios));
    }
}

fn bench(c: &mut Criterion) {
    if let Ok(spec) = std::env::var("KDTREE_PACKETS") {
        packets(&spec);
        return;
    }
    if std::env::var_os("KDTREE_TUNE").is_some() {
        tune();
        return;
    }
    if let Ok(spec) = std::env::var("KDTREE_QUICK") {
        quick(&spec);
        return;
    }
    if let Ok(spec) = std::env::var("KDTREE_AB") {
        ab(&spec);
        return;
    }
    if let Ok(spec) = std::env::var("KDTREE_SERVE") {
        serve(&spec);
        return;
    }
    let params = BuildParams::default();
    let mut big = Geometry::new(displaced_sphere(1_000_000, 0), vec![]);
    let mid = Geometry::new(displaced_sphere(100_000, 0), vec![]);

    let (mut tree, secs) = timed_build(&big, &params);
    big.store_in_leaf_order(&mut tree);
    let s = tree.stats();
    println!(
        "1M displaced sphere: {} triangles, build {secs:.3} s on {} threads; {s:?}",
        big.triangle_count(),
        rayon::current_num_threads()
    );

    let mut g = c.benchmark_group("kdtree_build");
    g.sample_size(10);
    g.bench_function("displaced_sphere_1m", |b| b.iter(|| KdTree::build(black_box(&big), &params)));
    g.bench_function("displaced_sphere_100k", |b| b.iter(|| KdTree::build(black_box(&mid), &params)));
    g.finish();

    let rays = random_rays(tree.bounds(), RAYS, 1);
    let mut g = c.benchmark_group("kdtree_trace_1m");
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.sample_size(20);
    g.bench_function("closest_hit", |b| b.iter(|| closest(&tree, &big, &rays)));
    g.bench_function("any_hit", |b| b.iter(|| any(&tree, &big, &rays)));
    g.finish();

    let hits = closest(&tree, &big, &rays);
    let occl = any(&tree, &big, &rays);
    println!(
        "1M displaced sphere, {} incoherent rays ({hits} hit, {occl} occluded), single thread: \
         closest-hit {:.2} Mrays/s, any-hit {:.2} Mrays/s",
        rays.len(),
        mrays(|| closest(&tree, &big, &rays), rays.len()),
        mrays(|| any(&tree, &big, &rays), rays.len()),
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
