// Tests may use the C library's functions: they check values, not platform-free bits.
#![allow(clippy::disallowed_methods)]

use glam::Vec3;
use proptest::prelude::*;

/// Proptest settings for CI: a fixed seed, so a run is repeatable (a new failure is
/// hunted with `PROPTEST_RNG_SEED=<n>`, which this leaves in charge).
pub(in crate::accel) fn pinned(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig { cases, failure_persistence: None, ..ProptestConfig::default() };
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = proptest::test_runner::RngSeed::Fixed(0x7469_6c65_6661_726d);
    }
    c
}

use super::treelet::Treelet;
use super::*;
use crate::accel::LeafOrdered;
use crate::accel::ray_packets::{PacketHits, RayPacket};
use crate::accel::{RayPrecomp, brute_force_intersect, brute_force_occluded};
use crate::scene::generate::displaced_sphere;
use crate::shapes::{Geometry, NONE, Sphere, Tri, TriangleMesh};

/// Small deterministic generator so that one proptest seed describes a whole scene.
pub(in crate::accel) struct Rng(pub(in crate::accel) u64);

impl Rng {
    pub(in crate::accel) fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    pub(in crate::accel) fn f(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    pub(in crate::accel) fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f()
    }
    pub(in crate::accel) fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    pub(in crate::accel) fn v(&mut self, lo: f32, hi: f32) -> Vec3 {
        Vec3::new(self.range(lo, hi), self.range(lo, hi), self.range(lo, hi))
    }
    /// A point on the grid of quarters in [-1, 1]: exact split positions and ties.
    pub(in crate::accel) fn grid(&mut self) -> Vec3 {
        let mut g = || (self.below(9) as f32 - 4.0) * 0.25;
        Vec3::new(g(), g(), g())
    }
    pub(in crate::accel) fn dir(&mut self) -> Vec3 {
        loop {
            let d = self.v(-1.0, 1.0);
            if d.length_squared() > 1e-4 && d.length_squared() <= 1.0 {
                return d.normalize();
            }
        }
    }
}

pub(in crate::accel) fn geometry(tris: &[[Vec3; 3]], spheres: Vec<Sphere>) -> Geometry {
    let mut mesh = TriangleMesh::default();
    for t in tris {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend_from_slice(t);
        mesh.tris.push(Tri { v: [base, base + 1, base + 2], n: [NONE; 3], uv: [NONE; 3], material: 0 });
    }
    Geometry::new(mesh, spheres)
}

/// A random scene mixing the cases that stress exactness: overlapping and duplicated
/// triangles, axis-aligned and coplanar ones on a grid, degenerate ones, clusters,
/// shared-edge fans, and spheres (some duplicated, some tiny).
// Long on purpose: A test-scene generator: one arm per kind of hard case.
pub(in crate::accel) fn random_scene(seed: u64, n: usize) -> Geometry {
    let mut r = Rng(seed);
    let mut tris: Vec<[Vec3; 3]> = Vec::with_capacity(n);
    let mut spheres = Vec::new();
    let cluster = r.v(-0.8, 0.8);
    let plane_z = (r.below(9) as f32 - 4.0) * 0.25;
    let mut i = 0;
    while i < n {
        i += 1;
        match r.below(12) {
            0 | 1 => {
                let c = r.v(-1.0, 1.0);
                let s = r.range(0.01, 0.4);
                tris.push([c + r.v(-s, s), c + r.v(-s, s), c + r.v(-s, s)]);
            }
            2 => tris.push([r.v(-1.0, 1.0), r.v(-1.0, 1.0), r.v(-1.0, 1.0)]),
            3 => {
                // Axis-aligned on the grid.
                let a = r.below(3) as usize;
                let (mut p, mut q, mut s) = (r.grid(), r.grid(), r.grid());
                q[a] = p[a];
                s[a] = p[a];
                if r.below(2) == 0 {
                    p[a] = s[a];
                }
                tris.push([p, q, s]);
            }
            4 => {
                // Coplanar in one shared plane, overlapping each other.
                let mut t = [r.v(-1.0, 1.0), r.v(-1.0, 1.0), r.v(-1.0, 1.0)];
                for p in &mut t {
                    p.z = plane_z;
                }
                tris.push(t);
            }
            5 => {
                // Degenerate: a segment, a point, or two equal vertices.
                let (p, q) = (r.v(-1.0, 1.0), r.v(-1.0, 1.0));
                tris.push(match r.below(3) {
                    0 => [p, q, p + (q - p) * 0.5],
                    1 => [p, p, p],
                    _ => [p, q, q],
                });
            }
            6 => {
                let s = 0.02;
                tris.push([cluster + r.v(-s, s), cluster + r.v(-s, s), cluster + r.v(-s, s)]);
            }
            7 if !tris.is_empty() => {
                // An exact duplicate (or a vertex rotation) of an earlier triangle.
                let t = tris[r.below(tris.len() as u64) as usize];
                tris.push(if r.below(2) == 0 { t } else { [t[1], t[2], t[0]] });
            }
            8 => {
                // A fan around a grid vertex: shared edges and a shared vertex.
                let c = r.grid();
                let k = 3 + r.below(5) as usize;
                let a = r.below(3) as usize;
                let ring: Vec<Vec3> = (0..k)
                    .map(|j| {
                        let ang = j as f32 / k as f32 * std::f32::consts::TAU;
                        let mut p = c;
                        p[(a + 1) % 3] += 0.25 * ang.cos();
                        p[(a + 2) % 3] += 0.25 * ang.sin();
                        p
                    })
                    .collect();
                for j in 0..k {
                    tris.push([c, ring[j], ring[(j + 1) % k]]);
                }
                i += k - 1;
            }
            9 => {
                let radius = if r.below(4) == 0 { r.range(1e-3, 0.01) } else { r.range(0.02, 0.4) };
                spheres.push(Sphere { center: r.v(-1.0, 1.0), radius, material: 0 });
            }
            10 if !spheres.is_empty() => spheres.push(spheres[r.below(spheres.len() as u64) as usize]),
            _ => {
                let c = r.v(-1.0, 1.0);
                let s = r.range(0.001, 0.05);
                tris.push([c + r.v(-s, s), c + r.v(-s, s), c + r.v(-s, s)]);
            }
        }
    }
    geometry(&tris, spheres)
}

pub(in crate::accel) fn random_ray(r: &mut Rng) -> Ray {
    let origin = match r.below(5) {
        0 | 1 => r.v(-1.2, 1.2),
        2 => r.v(-4.0, 4.0),
        3 => r.grid(),
        _ => r.dir() * 3.0,
    };
    let dir = match r.below(6) {
        0 => {
            // Axis-parallel, with signed zeros in the other components.
            let mut d = Vec3::new(if r.below(2) == 0 { 0.0 } else { -0.0 }, 0.0, -0.0);
            d[r.below(3) as usize] = if r.below(2) == 0 { 1.0 } else { -1.0 };
            d
        }
        1 => {
            // Parallel to a coordinate plane.
            let mut d = r.dir();
            d[r.below(3) as usize] = 0.0;
            if d.length_squared() == 0.0 { Vec3::X } else { d.normalize() }
        }
        2 => (r.grid() - origin).normalize_or(Vec3::Y),
        3 => {
            // Towards the origin, not normalised.
            let d = -origin + r.v(-0.3, 0.3);
            if d.length_squared() == 0.0 { Vec3::Z } else { d }
        }
        _ => r.dir(),
    };
    Ray::new(origin, dir)
}

pub(in crate::accel) fn key(h: Option<Hit>) -> Option<(u32, u32, u32, u32)> {
    h.map(|h| (h.t.to_bits(), h.prim, h.u.to_bits(), h.v.to_bits()))
}

/// A structure whose queries must be brute force's, with the path of CPUs without AVX2
/// (leaf triangles one by one) reachable for tests.
pub(in crate::accel) trait Exact {
    fn hit<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit>;
    fn occ<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool;
    fn hit_baseline<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit>;
    fn occ_baseline<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool;
}

impl Exact for KdTree {
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

pub(in crate::accel) fn check<P: Primitives>(
    prims: &P,
    tree: &impl Exact,
    ray: &Ray,
    tmax: f32,
) -> Result<(), TestCaseError> {
    let expect = brute_force_intersect(prims, ray, tmax);
    let got = tree.hit(prims, ray, tmax);
    prop_assert_eq!(key(got), key(expect), "intersect, ray {:?} tmax {}", ray, tmax);
    let expect_occ = brute_force_occluded(prims, ray, tmax);
    prop_assert_eq!(tree.occ(prims, ray, tmax), expect_occ, "occluded, ray {:?} tmax {}", ray, tmax);
    let base = tree.hit_baseline(prims, ray, tmax);
    prop_assert_eq!(key(base), key(expect), "intersect (baseline), ray {:?} tmax {}", ray, tmax);
    let base_occ = tree.occ_baseline(prims, ray, tmax);
    prop_assert_eq!(base_occ, expect_occ, "occluded (baseline), ray {:?} tmax {}", ray, tmax);
    Ok(())
}

/// Checks a batch of rays, each with infinite, random finite, and hit-distance tmax
/// (the brute-force hit's own t, and just above it: ties with the limit).
pub(in crate::accel) fn check_rays<P: Primitives>(
    prims: &P,
    tree: &impl Exact,
    r: &mut Rng,
    rays: usize,
) -> Result<(), TestCaseError> {
    for _ in 0..rays {
        let ray = random_ray(r);
        check(prims, tree, &ray, f32::INFINITY)?;
        check(prims, tree, &ray, r.range(0.0, 4.0))?;
        if let Some(h) = brute_force_intersect(prims, &ray, f32::INFINITY) {
            check(prims, tree, &ray, h.t)?;
            check(prims, tree, &ray, f32::from_bits(h.t.to_bits() + 1))?;
        }
    }
    Ok(())
}

fn random_params(r: &mut Rng) -> BuildParams {
    match r.below(4) {
        0 => BuildParams::default(),
        1 => BuildParams { max_depth: Some(r.below(6) as u32), ..Default::default() },
        2 => BuildParams { max_leaf_prims: r.below(6) as usize, empty_bonus: r.f(), ..Default::default() },
        _ => BuildParams {
            traversal_cost: r.range(0.1, 4.0),
            intersection_cost: r.range(0.2, 4.0),
            ..Default::default()
        },
    }
}

proptest! {
    #![proptest_config(pinned(160))]

    #[test]
    fn agrees_with_brute_force_on_random_scenes(seed in any::<u64>(), size in 0usize..4, rays_seed in any::<u64>()) {
        let n = [0, 1 + (seed % 16) as usize, 50 + (seed % 200) as usize, 500 + (seed % 2500) as usize][size];
        let geo = random_scene(seed, n);
        let mut r = Rng(rays_seed);
        let tree = KdTree::build(&geo, &random_params(&mut r));
        let rays = if n > 1000 { 60 } else { 150 };
        check_rays(&geo, &tree, &mut r, rays)?;
    }
}

/// Boxes on the quarter grid with rays from grid points along the axes and grid
/// diagonals: rays in split planes, through shared edges and vertices, starting on
/// faces.
#[test]
fn agrees_with_brute_force_on_grid_boxes() {
    let mut r = Rng(42);
    let mut tris = Vec::new();
    for _ in 0..60 {
        let (a, b) = (r.grid(), r.grid());
        let (lo, hi) = (a.min(b), a.max(b) + 0.25);
        let c = |x: usize, y: usize, z: usize| Vec3::new([lo.x, hi.x][x], [lo.y, hi.y][y], [lo.z, hi.z][z]);
        for axis in 0..3 {
            for side in 0..2 {
                let q = |u: usize, v: usize| {
                    let mut i = [0; 3];
                    i[axis] = side;
                    i[(axis + 1) % 3] = u;
                    i[(axis + 2) % 3] = v;
                    c(i[0], i[1], i[2])
                };
                tris.push([q(0, 0), q(1, 0), q(1, 1)]);
                tris.push([q(0, 0), q(1, 1), q(0, 1)]);
            }
        }
    }
    let geo = geometry(&tris, vec![Sphere { center: Vec3::ZERO, radius: 0.5, material: 0 }]);
    let tree = KdTree::build(&geo, &BuildParams::default());
    for _ in 0..4000 {
        let o = r.grid() + Vec3::new(0.0, 0.125 * r.below(2) as f32, 0.0);
        let mut d = Vec3::ZERO;
        d[r.below(3) as usize] = if r.below(2) == 0 { 1.0 } else { -1.0 };
        if r.below(3) == 0 {
            d[r.below(3) as usize] += 1.0;
        }
        let ray = Ray::new(o, d);
        check(&geo, &tree, &ray, f32::INFINITY).unwrap();
        check(&geo, &tree, &ray, 0.5).unwrap();
    }
    check_rays(&geo, &tree, &mut r, 500).unwrap();
}

/// A closed mesh (every ray crossing an edge hits one of its two triangles) with spheres.
#[test]
fn agrees_with_brute_force_on_displaced_sphere_with_spheres() {
    let mesh = displaced_sphere(20_000, 3);
    let mut r = Rng(7);
    let spheres =
        (0..300).map(|_| Sphere { center: r.v(-1.5, 1.5), radius: r.range(0.01, 0.15), material: 0 }).collect();
    let geo = Geometry::new(mesh, spheres);
    let tree = KdTree::build(&geo, &BuildParams::default());
    let s = tree.stats();
    assert!(s.leaves > 1000 && s.max_depth <= s.depth_limit, "{s:?}");
    for _ in 0..600 {
        let ray = random_ray(&mut r);
        check(&geo, &tree, &ray, f32::INFINITY).unwrap();
        check(&geo, &tree, &ray, r.range(0.0, 3.0)).unwrap();
    }
}

#[test]
fn empty_and_invalid_sets_never_hit() {
    let geo = Geometry::default();
    let tree = KdTree::build(&geo, &BuildParams::default());
    assert!(tree.bounds().is_empty());
    assert_eq!(tree.stats().prim_refs, 0);
    let ray = Ray::new(Vec3::ZERO, Vec3::X);
    assert_eq!(tree.intersect(&geo, &ray, f32::INFINITY), None);
    assert!(!tree.occluded(&geo, &ray, f32::INFINITY));
    // NaN coordinates are left out of the tree (they cannot be hit).
    let geo = geometry(&[[Vec3::NAN, Vec3::X, Vec3::Y]], vec![]);
    let tree = KdTree::build(&geo, &BuildParams::default());
    assert_eq!(tree.intersect(&geo, &Ray::new(Vec3::new(0.1, 0.1, 1.0), -Vec3::Z), f32::INFINITY), None);
}

#[test]
fn nodes_are_compact_and_tree_is_shareable() {
    fn send_sync<T: Send + Sync>() {}
    send_sync::<KdTree>();
    assert_eq!(size_of::<Node>(), 8);
    assert_eq!((size_of::<Treelet>(), align_of::<Treelet>()), (64, 64));
    let geo = random_scene(5, 3000);
    let tree = KdTree::build(&geo, &BuildParams::default());
    let s = tree.stats();
    assert_eq!(s.nodes, 2 * s.leaves - 1);
    assert!(s.prim_refs >= geo.triangle_count() / 2, "{s:?}");
    assert_eq!(s.bytes, 64 * tree.treelets.len() + 4 * tree.leaves.len());
    assert_eq!(s.treelets, tree.treelets.len());
    // Every reference points inside its array, leaves of several primitives are
    // `[count, ids..]` runs that tile `leaves`, and the walk from the root meets each
    // treelet once and each non-empty leaf's primitives once.
    let mut runs = std::collections::BTreeMap::new();
    let mut i = 0;
    while i < tree.leaves.len() {
        let n = tree.leaves[i] as usize;
        assert!(n >= 2 && i + 1 + n <= tree.leaves.len());
        runs.insert(i, false);
        i += 1 + n;
    }
    let (mut seen, mut refs) = (vec![false; tree.treelets.len()], 0);
    let mut stack = vec![tree.root];
    while let Some(r) = stack.pop() {
        let at = (r >> 2) as usize;
        match r & 3 {
            treelet::TREELET => {
                assert!(!std::mem::replace(&mut seen[at], true));
                stack.extend(tree.treelets[at].child);
            }
            treelet::LEAF => {
                assert_eq!(runs.insert(at, true), Some(false));
                refs += tree.leaves[at] as usize;
            }
            treelet::ONE => refs += 1,
            _ => {}
        }
    }
    assert!(seen.iter().all(|&x| x) && runs.values().all(|&x| x));
    assert_eq!(refs, s.prim_refs);
    let mut listed = 0;
    tree.for_each_leaf(&mut |ids: &[u32]| listed += ids.len());
    assert_eq!(listed, s.prim_refs);
    // A depth limit of 0 gives one leaf with everything.
    let one = KdTree::build(&geo, &BuildParams { max_depth: Some(0), ..Default::default() });
    assert_eq!((one.stats().nodes, one.stats().prim_refs), (1, geo.triangle_count() + geo.spheres.len()));
    assert_eq!((one.root & 3, one.treelets.len()), (treelet::LEAF, 0));
}

#[test]
fn flat_primitives_in_split_planes() {
    // A stack of axis-aligned squares: the SAH splits at their planes, and they must be
    // found from both sides and by rays lying in their plane.
    let mut tris = Vec::new();
    for k in 0..8 {
        let z = k as f32 * 0.25;
        let (a, b, c, d) =
            (Vec3::new(0.0, 0.0, z), Vec3::new(1.0, 0.0, z), Vec3::new(1.0, 1.0, z), Vec3::new(0.0, 1.0, z));
        tris.push([a, b, c]);
        tris.push([a, c, d]);
    }
    let geo = geometry(&tris, vec![]);
    // Expensive intersections make the SAH split at the planes.
    let tree = KdTree::build(&geo, &BuildParams { intersection_cost: 4.0, ..Default::default() });
    assert!(tree.stats().leaves > 4);
    for (o, d) in [
        (Vec3::new(0.5, 0.5, -1.0), Vec3::Z),
        (Vec3::new(0.5, 0.5, 3.0), -Vec3::Z),
        (Vec3::new(0.5, 0.5, 0.5), Vec3::Z),
        (Vec3::new(0.5, 0.5, 0.5), -Vec3::Z),
        (Vec3::new(0.5, 0.25, 0.5), Vec3::new(0.0, 1.0, 1.0)),
        (Vec3::new(-1.0, 0.5, 0.5), Vec3::X),
        (Vec3::new(0.25, 0.25, 0.25), Vec3::new(1.0, 1.0, 0.0)),
    ] {
        let ray = Ray::new(o, d);
        let h = tree.intersect(&geo, &ray, f32::INFINITY);
        assert_eq!(key(h), key(brute_force_intersect(&geo, &ray, f32::INFINITY)), "{ray:?}");
    }
}

/// The same answers, up to the permutation, after the triangles are stored in leaf order
/// and the tree's indices renamed; and the renamed tree is still exact against brute
/// force over the permuted set. Hits may name another primitive only in a tie (duplicate
/// or coincident primitives, which brute force settles by index order).
fn check_leaf_order(geo: Geometry, params: &BuildParams, r: &mut Rng, rays: usize) -> Result<(), TestCaseError> {
    let tree = KdTree::build(&geo, params);
    let (mut moved, mut moved_tree) = (geo.clone(), KdTree::build(&geo, params));
    let order = moved.store_in_leaf_order(&mut moved_tree);
    let (mut again, mut again_tree) = (geo.clone(), KdTree::build(&geo, params));
    prop_assert_eq!(&order, &again.store_in_leaf_order(&mut again_tree), "not deterministic");
    prop_assert_eq!(&again_tree.treelets, &moved_tree.treelets);
    prop_assert_eq!(&again_tree.leaves, &moved_tree.leaves);
    let ntri = geo.triangle_count();
    let mut sorted = order.clone();
    sorted.sort_unstable();
    prop_assert!(sorted.iter().copied().eq(0..ntri as u32), "not a permutation");
    for (new, &old) in order.iter().enumerate() {
        let o = old as usize;
        prop_assert_eq!(moved.material(new), geo.material(o));
        prop_assert_eq!(moved.normal_indices(new), geo.normal_indices(o));
        prop_assert_eq!(moved.uv_indices(new), geo.uv_indices(o));
        prop_assert_eq!(moved.triangle(new), geo.triangle(old as usize));
    }
    prop_assert_eq!(&moved.spheres, &geo.spheres);
    let old = |p: u32| if (p as usize) < ntri { order[p as usize] } else { p };
    for _ in 0..rays {
        let ray = random_ray(r);
        for tmax in [f32::INFINITY, r.range(0.0, 4.0)] {
            check(&moved, &moved_tree, &ray, tmax)?;
            prop_assert_eq!(tree.occluded(&geo, &ray, tmax), moved_tree.occluded(&moved, &ray, tmax));
            match (tree.intersect(&geo, &ray, tmax), moved_tree.intersect(&moved, &ray, tmax)) {
                (None, None) => {}
                (Some(a), Some(b)) if old(b.prim) == a.prim => {
                    prop_assert_eq!(key(Some(a)), key(Some(Hit { prim: a.prim, ..b })))
                }
                (Some(a), Some(b)) => {
                    // A tie: the other primitive hits (nearly) as close.
                    let pre = RayPrecomp::new(&ray);
                    let other = geo.intersect(old(b.prim), &ray, &pre, f32::INFINITY);
                    prop_assert!(other.is_some_and(|h| (h.t - a.t).abs() <= 1e-5 * a.t), "{:?} vs {:?}", a, b);
                }
                (a, b) => prop_assert!(false, "{:?} vs {:?}, ray {:?}", a, b, ray),
            }
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(pinned(48))]

    #[test]
    fn leaf_order_storage_gives_the_same_hits(seed in any::<u64>(), size in 0usize..4, rays_seed in any::<u64>()) {
        let n = [0, 1 + (seed % 16) as usize, 50 + (seed % 200) as usize, 500 + (seed % 2500) as usize][size];
        let mut r = Rng(rays_seed);
        let params = random_params(&mut r);
        check_leaf_order(random_scene(seed, n), &params, &mut r, 100)?;
    }
}

#[test]
fn leaf_order_storage_on_displaced_sphere_with_spheres() {
    let mut r = Rng(9);
    let spheres =
        (0..200).map(|_| Sphere { center: r.v(-1.5, 1.5), radius: r.range(0.01, 0.15), material: 0 }).collect();
    let geo = Geometry::new(displaced_sphere(20_000, 5), spheres);
    check_leaf_order(geo, &BuildParams::default(), &mut r, 600).unwrap();
}

/// After the reordering, the stored order is the tree's leaf order: each leaf's
/// triangles not listed by an earlier leaf are adjacent, following the previous leaf's.
#[test]
fn leaf_order_follows_the_leaves() {
    let mut geo = Geometry::new(displaced_sphere(5_000, 1), vec![]);
    let mut tree = KdTree::build(&geo, &BuildParams::default());
    geo.store_in_leaf_order(&mut tree);
    let first = tree.leaf_order(geo.len());
    assert!(first.iter().copied().eq(0..geo.len() as u32), "the stored order is the tree's leaf order");
}

#[test]
fn scene_parameters_follow_size_and_composition() {
    let ci = |t, o| BuildParams::for_scene(t, o).intersection_cost;
    // Small scenes: deep trees; meshes: the default; sphere-heavy sets: smaller leaves.
    assert_eq!(ci(1000, 24), 2.0);
    assert_eq!(ci(1_000_000, 0), BuildParams::default().intersection_cost);
    assert_eq!(ci(1_000_000, 1000), BuildParams::default().intersection_cost);
    assert_eq!(ci(20_000, 10_000), super::OTHER_PRIMS_INTERSECTION_COST);
    assert!(BuildParams::default().intersection_cost < super::OTHER_PRIMS_INTERSECTION_COST);
}

/// Eight rays for a packet: scattered (mixed direction signs); coherent (one origin,
/// directions in a narrow cone, as a tile's camera rays); or converging (origins spread
/// around a point, directions towards a common target, as shadow rays towards a light).
/// Some lanes inactive, some coherent lanes with a zero direction component; each
/// lane's `tmax` infinite, random, or its brute-force hit's own `t`.
pub(in crate::accel) fn random_packet<P: Primitives>(prims: &P, r: &mut Rng) -> RayPacket {
    let mut p = RayPacket::default();
    let kind = r.below(3);
    let base = random_ray(r);
    let target = r.v(-1.0, 1.0);
    let spread = r.range(0.0, 0.3);
    for l in 0..8 {
        if r.below(8) == 0 {
            continue;
        }
        let mut ray = match kind {
            0 => random_ray(r),
            1 => {
                let d = base.dir + r.v(-0.05, 0.05) * base.dir.length();
                Ray::new(base.origin, if d.length_squared() > 0.0 { d } else { base.dir })
            }
            _ => {
                let o = base.origin + r.v(-spread, spread);
                let d = target - o;
                Ray::new(o, if d.length_squared() > 0.0 { d } else { base.dir })
            }
        };
        if kind != 0 && r.below(16) == 0 {
            ray.dir[r.below(3) as usize] = 0.0;
            if ray.dir.length_squared() == 0.0 {
                ray.dir = base.dir;
            }
        }
        let tmax = match r.below(3) {
            0 => f32::INFINITY,
            1 => r.range(0.0, 4.0),
            _ => brute_force_intersect(prims, &ray, f32::INFINITY).map_or(f32::INFINITY, |h| h.t),
        };
        p.set(l, &ray, tmax);
    }
    p
}

/// A structure with packet queries that must be its one-ray queries' (brute force's).
pub(in crate::accel) trait ExactPackets {
    fn hit8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> PacketHits;
    fn occ8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> u32;
}

impl ExactPackets for KdTree {
    fn hit8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> PacketHits {
        self.intersect8(prims, rays)
    }
    fn occ8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> u32 {
        self.occluded8(prims, rays)
    }
}

/// Every active lane of a packet query is its one-ray query's answer (and so brute
/// force's), bit for bit, whatever the other lanes hold.
fn check_packets<P: Primitives>(
    prims: &P,
    tree: &impl ExactPackets,
    r: &mut Rng,
    packets: usize,
) -> Result<(), TestCaseError> {
    for _ in 0..packets {
        let p = random_packet(prims, r);
        let hits = tree.hit8(prims, &p);
        let occluded = tree.occ8(prims, &p);
        prop_assert_eq!(hits.found & !p.active, 0);
        prop_assert_eq!(occluded & !p.active, 0);
        for l in (0..8).filter(|l| p.active & (1 << l) != 0) {
            let (ray, tmax) = (p.ray(l), p.tmax[l]);
            prop_assert_eq!(
                key(hits.get(l)),
                key(brute_force_intersect(prims, &ray, tmax)),
                "lane {} ray {:?} tmax {}",
                l,
                ray,
                tmax
            );
            prop_assert_eq!(
                occluded & (1 << l) != 0,
                brute_force_occluded(prims, &ray, tmax),
                "lane {} ray {:?} tmax {}",
                l,
                ray,
                tmax
            );
        }
    }
    Ok(())
}

/// A random scene (as the one-ray proptests') and 40 random packets through the
/// structure `build` makes over it.
pub(in crate::accel) fn packets_on_random_scene<T: ExactPackets>(
    seed: u64,
    size: usize,
    rays_seed: u64,
    build: impl Fn(&Geometry, &mut Rng) -> T,
) -> Result<(), TestCaseError> {
    let n = [0, 1 + (seed % 16) as usize, 50 + (seed % 200) as usize, 500 + (seed % 2500) as usize][size];
    let geo = random_scene(seed, n);
    let mut r = Rng(rays_seed);
    let tree = build(&geo, &mut r);
    check_packets(&geo, &tree, &mut r, 40)
}

/// Packets on a closed mesh with spheres: coherent packets hit neighbouring triangles
/// and share most of their walk.
pub(in crate::accel) fn packets_on_displaced_sphere<T: ExactPackets>(build: impl Fn(&Geometry) -> T) {
    let mesh = displaced_sphere(20_000, 3);
    let mut r = Rng(11);
    let spheres =
        (0..300).map(|_| Sphere { center: r.v(-1.5, 1.5), radius: r.range(0.01, 0.15), material: 0 }).collect();
    let geo = Geometry::new(mesh, spheres);
    let tree = build(&geo);
    check_packets(&geo, &tree, &mut r, 400).unwrap();
}

proptest! {
    #![proptest_config(pinned(120))]

    #[test]
    fn packets_agree_with_brute_force_on_random_scenes(seed in any::<u64>(), size in 0usize..4, rays_seed in any::<u64>()) {
        packets_on_random_scene(seed, size, rays_seed, |geo, r| KdTree::build(geo, &random_params(r)))?;
    }
}

#[test]
fn packets_agree_with_brute_force_on_displaced_sphere() {
    packets_on_displaced_sphere(|geo| KdTree::build(geo, &BuildParams::default()));
}
