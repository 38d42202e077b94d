//! The hierarchy against brute force, on the kd-tree's hard cases (`kdtree/tests.rs`).

use glam::Vec3;
use proptest::prelude::*;

use super::*;
use crate::accel::kdtree::tests::{
    Exact, ExactPackets, Rng, check, check_rays, geometry, packets_on_displaced_sphere, packets_on_random_scene,
    pinned, random_ray, random_scene,
};
use crate::accel::ray_packets::{PacketHits, RayPacket};
use crate::geometry::Aabb;
use crate::scene::generate::displaced_sphere;
use crate::shapes::{Geometry, Sphere};

impl Exact for Bvh8 {
    fn hit<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        self.intersect(prims, ray, tmax)
    }
    fn occ<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        self.occluded(prims, ray, tmax)
    }
    fn hit_baseline<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        self.intersect_impl::<P, false>(prims, ray, tmax)
    }
    fn occ_baseline<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        self.occluded_impl::<P, false>(prims, ray, tmax)
    }
}

fn random_params(r: &mut Rng) -> Bvh8Params {
    match r.below(3) {
        0 => Bvh8Params::default(),
        1 => Bvh8Params { traversal_cost: 1.0, intersection_cost: 4.0 },
        _ => Bvh8Params { traversal_cost: r.range(0.1, 4.0), intersection_cost: r.range(0.05, 4.0) },
    }
}

proptest! {
    #![proptest_config(pinned(160))]

    #[test]
    fn agrees_with_brute_force_on_random_scenes(seed in any::<u64>(), size in 0usize..4, rays_seed in any::<u64>()) {
        let n = [0, 1 + (seed % 16) as usize, 50 + (seed % 200) as usize, 500 + (seed % 2500) as usize][size];
        let geo = random_scene(seed, n);
        let mut r = Rng(rays_seed);
        let bvh = Bvh8::build(&geo, &random_params(&mut r));
        let rays = if n > 1000 { 60 } else { 150 };
        check_rays(&geo, &bvh, &mut r, rays)?;
    }

    #[test]
    fn leaf_order_storage_gives_the_same_hits(seed in any::<u64>(), size in 1usize..4, rays_seed in any::<u64>()) {
        let n = [0, 1 + (seed % 16) as usize, 50 + (seed % 200) as usize, 500 + (seed % 2500) as usize][size];
        let mut geo = random_scene(seed, n);
        let mut bvh = Bvh8::build(&geo, &Bvh8Params::default());
        geo.store_in_leaf_order(&mut bvh);
        check_rays(&geo, &bvh, &mut Rng(rays_seed), 60)?;
    }
}

/// A closed mesh (every ray crossing an edge hits one of its two triangles) with spheres;
/// nodes hold several children and leaves fit one eight-lane pass.
#[test]
fn agrees_with_brute_force_on_displaced_sphere_with_spheres() {
    let mesh = displaced_sphere(20_000, 3);
    let mut r = Rng(7);
    let spheres =
        (0..300).map(|_| Sphere { center: r.v(-1.5, 1.5), radius: r.range(0.01, 0.15), material: 0 }).collect();
    let geo = Geometry::new(mesh, spheres);
    let bvh = Bvh8::build(&geo, &Bvh8Params::default());
    let s = bvh.stats();
    assert!(s.mean_children > 3.0 && s.mean_leaf_prims <= MAX_LEAF as f64 && s.max_depth < 20, "{s:?}");
    for _ in 0..600 {
        let ray = random_ray(&mut r);
        check(&geo, &bvh, &ray, f32::INFINITY).unwrap();
        check(&geo, &bvh, &ray, r.range(0.0, 3.0)).unwrap();
    }
}

#[test]
fn empty_and_invalid_sets_never_hit() {
    let geo = Geometry::default();
    let bvh = Bvh8::build(&geo, &Bvh8Params::default());
    assert!(bvh.bounds().is_empty());
    assert_eq!(bvh.heap_bytes(), 0);
    let ray = Ray::new(Vec3::ZERO, Vec3::X);
    assert_eq!(bvh.intersect(&geo, &ray, f32::INFINITY), None);
    assert!(!bvh.occluded(&geo, &ray, f32::INFINITY));
    let geo = geometry(&[[Vec3::NAN, Vec3::X, Vec3::Y]], vec![]);
    let bvh = Bvh8::build(&geo, &Bvh8Params::default());
    assert_eq!(bvh.intersect(&geo, &Ray::new(Vec3::new(0.1, 0.1, 1.0), -Vec3::Z), f32::INFINITY), None);
}

/// Many primitives with one centroid (split by index) and a deep, skewed set: the build
/// ends, and the answers stay brute force's.
#[test]
fn coincident_and_skewed_sets() {
    let t = [Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)];
    let mut tris = vec![t; 100];
    // Triangles halving in size towards the origin: one split per level.
    for k in 0..80 {
        let s = 0.5f32.powi(k);
        tris.push([Vec3::new(s, 0.0, 1.0), Vec3::new(2.0 * s, 0.0, 1.0), Vec3::new(s, s, 1.0)]);
    }
    let geo = geometry(&tris, vec![]);
    let bvh = Bvh8::build(&geo, &Bvh8Params::default());
    let mut r = Rng(3);
    check_rays(&geo, &bvh, &mut r, 400).unwrap();
    for k in 0..80 {
        let s = 0.5f32.powi(k);
        let ray = Ray::new(Vec3::new(1.2 * s, 0.1 * s, 0.0), Vec3::Z);
        check(&geo, &bvh, &ray, f32::INFINITY).unwrap();
    }
}

impl ExactPackets for Bvh8 {
    fn hit8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> PacketHits {
        self.intersect8(prims, rays)
    }
    fn occ8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> u32 {
        self.occluded8(prims, rays)
    }
}

proptest! {
    #![proptest_config(pinned(120))]

    #[test]
    fn packets_agree_with_brute_force_on_random_scenes(seed in any::<u64>(), size in 0usize..4, rays_seed in any::<u64>()) {
        packets_on_random_scene(seed, size, rays_seed, |geo, r| Bvh8::build(geo, &random_params(r)))?;
    }
}

#[test]
fn packets_agree_with_brute_force_on_displaced_sphere() {
    packets_on_displaced_sphere(|geo| Bvh8::build(geo, &Bvh8Params::default()));
}

/// Packets walk together only when their rays are close: a camera's neighbouring rays
/// form one group; a ray from a far-apart point, one 26° off, and one with a zero
/// direction component go alone, and so do most scattered rays.
#[cfg(target_arch = "x86_64")]
#[test]
fn only_coherent_lanes_walk_together() {
    use super::packet::coherent_groups;
    let bounds = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0));
    let eye = Vec3::new(0.1, 0.2, -5.0);
    let mut camera = RayPacket::default();
    for l in 0..8 {
        let d = Vec3::new(0.003 + 0.01 * (l % 4) as f32, 0.002 + 0.01 * (l / 4) as f32, 1.0);
        camera.set(l, &Ray::new(eye, d), f32::INFINITY);
    }
    assert_eq!(coherent_groups(&camera, &bounds).collect::<Vec<_>>(), vec![0xff]);

    let mut mixed = camera;
    mixed.set(3, &Ray::new(eye + Vec3::new(2.0, 0.0, 0.0), Vec3::Z), f32::INFINITY);
    mixed.set(5, &Ray::new(eye, Vec3::new(0.5, 0.01, 1.0)), f32::INFINITY);
    mixed.set(6, &Ray::new(eye, Vec3::new(0.0, 0.01, 1.0)), f32::INFINITY);
    assert_eq!(coherent_groups(&mixed, &bounds).collect::<Vec<_>>(), vec![0xff & !(1 << 3 | 1 << 5 | 1 << 6)]);

    let mut r = Rng(5);
    let mut scattered = RayPacket::default();
    for l in 0..8 {
        scattered.set(l, &Ray::new(r.v(-1.0, 1.0), r.dir()), f32::INFINITY);
    }
    let groups: Vec<u32> = coherent_groups(&scattered, &bounds).collect();
    assert!(groups.iter().all(|g| g.count_ones() >= 2), "{groups:?}");
    assert!(groups.iter().map(|g| g.count_ones()).sum::<u32>() < 8, "{groups:?}");
}
