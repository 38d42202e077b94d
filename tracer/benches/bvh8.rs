//! The eight-wide BVH (`accel/bvh8`) against the kd-tree: build time and single-thread
//! ray throughput on the displaced sphere, same rays, in interleaved rounds (medians,
//! and the median of the rounds' ratios; this host's speed drifts within minutes).
//!
//! `BVH8=TRIANGLES[,ROUNDS] cargo bench -p tracer --bench bvh8` (default 1,000,000
//! and 7). `BVH8_CI` / `BVH8_CT` set the BVH's SAH costs (defaults: `Bvh8Params`).
//! Each structure reads its own copy of the mesh stored in its leaf order, as the
//! renderer stores a scene's. Rays: incoherent (origins on the bounding sphere towards
//! uniform points in the box; any hit up to that point) and a pinhole camera's in
//! scanline order. Then the packet queries (`Bvh8::intersect8` / `occluded8`) against
//! the same rays one at a time: a camera's rays in packets of 4×2 pixels, the shadow
//! rays from their hits towards a point light, and the incoherent rays eight by eight
//! (what the packet query must not make much worse).

#[path = "shared/packets.rs"]
mod packets;

use std::hint::black_box;
use std::time::Instant;

use glam::Vec3;
use tracer::accel::bvh8::{Bvh8, Bvh8Params};
use tracer::accel::{BuildParams, KdTree};
use tracer::geometry::{Aabb, Ray};
use tracer::scene::Geometry;
use tracer::scene::generate::displaced_sphere;

use packets::{camera_packets, packets_of, shadow_packets};

const RAYS: usize = 100_000;

/// A row of the table: its name, its rays (with any-hit lengths), and whether any hit.
type Kind<'a> = (&'a str, &'a [(Ray, f32)], bool);

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// A pinhole camera's rays over the mesh, scanline order, closest-hit only (any-hit
/// length infinite).
fn camera_rays(b: Aabb, n: usize) -> Vec<(Ray, f32)> {
    let side = (n as f64).sqrt() as usize;
    let (c, size) = (b.center(), b.diagonal().length());
    let eye = c + Vec3::new(0.3, 0.4, 3.0).normalize() * (1.5 * size);
    let fwd = (c - eye).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    (0..side * side)
        .map(|i| {
            let (x, y) = ((i % side) as f32 / side as f32 - 0.5, (i / side) as f32 / side as f32 - 0.5);
            (Ray::new(eye, (fwd + (right * x + up * y) * 0.7).normalize()), f32::INFINITY)
        })
        .collect()
}

trait Accel {
    fn hit(&self, geo: &Geometry, ray: &Ray) -> bool;
    fn occluded(&self, geo: &Geometry, ray: &Ray, len: f32) -> bool;
}

impl Accel for KdTree {
    fn hit(&self, geo: &Geometry, ray: &Ray) -> bool {
        self.intersect(geo, ray, f32::INFINITY).is_some()
    }
    fn occluded(&self, geo: &Geometry, ray: &Ray, len: f32) -> bool {
        KdTree::occluded(self, geo, ray, len)
    }
}

impl Accel for Bvh8 {
    fn hit(&self, geo: &Geometry, ray: &Ray) -> bool {
        self.intersect(geo, ray, f32::INFINITY).is_some()
    }
    fn occluded(&self, geo: &Geometry, ray: &Ray, len: f32) -> bool {
        Bvh8::occluded(self, geo, ray, len)
    }
}

/// Seconds for one pass and its count of hits.
fn pass(a: &impl Accel, geo: &Geometry, rays: &[(Ray, f32)], any: bool) -> (f64, usize) {
    let t = Instant::now();
    let n = if any {
        rays.iter().filter(|(r, len)| a.occluded(geo, r, *len)).count()
    } else {
        rays.iter().filter(|(r, _)| a.hit(geo, r)).count()
    };
    (t.elapsed().as_secs_f64(), black_box(n))
}

fn env_f32(name: &str) -> Option<f32> {
    std::env::var(name).ok().and_then(|x| x.parse().ok())
}

fn main() {
    let spec = std::env::var("BVH8").unwrap_or_default();
    let mut parts = spec.split(',').map(|x| x.parse::<usize>().ok());
    let n = parts.next().flatten().unwrap_or(1_000_000);
    let rounds = parts.next().flatten().unwrap_or(7);
    let mut params = Bvh8Params::default();
    params.intersection_cost = env_f32("BVH8_CI").unwrap_or(params.intersection_cost);
    params.traversal_cost = env_f32("BVH8_CT").unwrap_or(params.traversal_cost);

    let mut kgeo = Geometry::new(displaced_sphere(n, 0), vec![]);
    let t = Instant::now();
    let mut kd = KdTree::build(&kgeo, &BuildParams::default());
    let kd_build = t.elapsed().as_secs_f64();
    kgeo.store_in_leaf_order(&mut kd);

    let mut bgeo = Geometry::new(displaced_sphere(n, 0), vec![]);
    let t = Instant::now();
    let mut bvh = Bvh8::build(&bgeo, &params);
    let bvh_build = t.elapsed().as_secs_f64();
    bgeo.store_in_leaf_order(&mut bvh);
    let ntri = bgeo.triangle_count();

    let ks = kd.stats();
    let bs = bvh.stats();
    println!(
        "{ntri} triangles, {} threads: kd-tree build {kd_build:.3} s, {} B; BVH8 (Ci {}, Ct {}) build {bvh_build:.3} s, {} B, \
         {} nodes, {:.2} children per node, {:.2} primitives per leaf, depth {}",
        rayon::current_num_threads(),
        ks.bytes,
        params.intersection_cost,
        params.traversal_cost,
        bs.bytes,
        bs.nodes,
        bs.mean_children,
        bs.mean_leaf_prims,
        bs.max_depth
    );
    let incoherent = tracer::accel::incoherent_rays(kd.bounds(), RAYS, 1);
    let camera = camera_rays(kd.bounds(), RAYS);
    let kinds: [Kind; 3] = [
        ("incoherent, closest hit", &incoherent, false),
        ("incoherent, any hit", &incoherent, true),
        ("camera, closest hit", &camera, false),
    ];
    println!("{:<26}{:>12}{:>12}{:>8}   (Mrays/s, one thread, {rounds} rounds)", "rays", "kd-tree", "BVH8", "ratio");
    for (name, rays, any) in kinds {
        let (mut a, mut b, mut ratio) = (Vec::new(), Vec::new(), Vec::new());
        for round in 0..rounds {
            let (ka, kb) = if round % 2 == 0 {
                let k = pass(&kd, &kgeo, rays, any);
                (k, pass(&bvh, &bgeo, rays, any))
            } else {
                let b = pass(&bvh, &bgeo, rays, any);
                (pass(&kd, &kgeo, rays, any), b)
            };
            assert_eq!(ka.1, kb.1, "{name}: the two structures found different numbers of hits");
            let m = rays.len() as f64 / 1e6;
            a.push(m / ka.0);
            b.push(m / kb.0);
            ratio.push(ka.0 / kb.0);
        }
        println!("{name:<26}{:>12.3}{:>12.3}{:>8.2}", median(a), median(b), median(ratio));
    }
    packet_table(&bvh, &bgeo, rounds);
}

/// Packets against one ray at a time on the same rays: Mrays/s of each and the median of
/// the rounds' ratios.
fn packet_table(bvh: &Bvh8, geo: &Geometry, rounds: usize) {
    let camera = camera_packets(bvh.bounds(), 512);
    let shadow = shadow_packets(bvh.bounds(), &camera, |p| bvh.intersect8(geo, p));
    let incoherent = packets_of(&tracer::accel::incoherent_rays(bvh.bounds(), RAYS, 2));
    println!("{:<26}{:>12}{:>12}{:>8}   (BVH8, Mrays/s, one thread)", "packets of 8", "one by one", "packets", "ratio");
    for (name, packets, any) in [
        ("camera, closest hit", &camera, false),
        ("shadow, any hit", &shadow, true),
        ("incoherent, closest hit", &incoherent, false),
        ("incoherent, any hit", &incoherent, true),
    ] {
        let n: usize = packets.iter().map(|p| p.active.count_ones() as usize).sum();
        let one = || {
            let t = Instant::now();
            let mut found = 0usize;
            for p in packets.iter() {
                for l in (0..8).filter(|l| p.active & (1 << l) != 0) {
                    let (r, tmax) = (p.ray(l), p.tmax[l]);
                    found += usize::from(if any {
                        bvh.occluded(geo, &r, tmax)
                    } else {
                        bvh.intersect(geo, &r, tmax).is_some()
                    });
                }
            }
            (t.elapsed().as_secs_f64(), black_box(found))
        };
        let eight = || {
            let t = Instant::now();
            let found: usize = packets
                .iter()
                .map(|p| if any { bvh.occluded8(geo, p) } else { bvh.intersect8(geo, p).found }.count_ones() as usize)
                .sum();
            (t.elapsed().as_secs_f64(), black_box(found))
        };
        let (mut a, mut b, mut ratio) = (Vec::new(), Vec::new(), Vec::new());
        for round in 0..rounds {
            let (x, y) = if round % 2 == 0 {
                let x = one();
                (x, eight())
            } else {
                let y = eight();
                (one(), y)
            };
            assert_eq!(x.1, y.1, "{name}: packets found other hits than single rays");
            a.push(n as f64 / x.0 / 1e6);
            b.push(n as f64 / y.0 / 1e6);
            ratio.push(x.0 / y.0);
        }
        println!("{name:<26}{:>12.3}{:>12.3}{:>8.2}", median(a), median(b), median(ratio));
    }
}
