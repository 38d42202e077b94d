//! Acceleration structures. The kd-tree is generic over a [`Primitives`] set so that it
//! can be tested against brute force on any shapes, and is monomorphised (no `dyn`) for
//! the scene's triangles and spheres.

mod block_test;
pub mod bvh8;
mod exact;
pub mod instances;
pub mod kdtree;
#[cfg(target_arch = "x86_64")]
pub mod ray_packets;
mod store;
pub mod triangle_blocks;

pub use kdtree::{BuildParams, KdTree, KdTreeStats};

use crate::geometry::{Aabb, Ray};

/// A hit reported by a primitive: distance and two surface parameters (barycentrics
/// `b1, b2` for triangles; unused for spheres), and for a primitive that holds others
/// (an instance of a mesh) which of them was hit (0 otherwise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrimHit {
    pub t: f32,
    pub u: f32,
    pub v: f32,
    pub sub: u32,
}

/// A hit found by a query over a whole primitive set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub prim: u32,
    pub u: f32,
    pub v: f32,
}

/// Per-ray data computed once per query and shared by every primitive test.
#[derive(Clone, Copy, Debug)]
pub struct RayPrecomp {
    pub inv_dir: glam::Vec3,
    pub shear: crate::geometry::triangle::RayShear,
}

impl RayPrecomp {
    #[inline]
    pub fn new(ray: &Ray) -> Self {
        Self { inv_dir: ray.dir.recip(), shear: crate::geometry::triangle::RayShear::for_ray(ray.origin, ray.dir) }
    }
}

pub use crate::memory::advise_huge_pages;

/// A structure over a primitive set whose leaves can give the set its storage order
/// ([`crate::shapes::Geometry::store_in_leaf_order`]).
pub trait LeafOrdered {
    /// Calls `f` with each non-empty leaf's primitives, in depth-first order.
    fn for_each_leaf(&self, f: &mut dyn FnMut(&[u32]));

    /// Renames primitive `i` to `new_index[i]` throughout, after the set was permuted
    /// (see [`LeafOrdered::leaf_order`]). Each leaf's list is sorted, so a leaf reads its
    /// primitives in ascending address order. The answers stay bit-identical to brute
    /// force over the permuted set: a query's result does not depend on the order within
    /// a leaf.
    fn remap(&mut self, new_index: &[u32]);

    /// A permutation of the primitive indices `0..n` (`order[new] = old`): every index
    /// the leaves list, in order of its first listing in depth-first leaf order, then
    /// the unlisted ones in index order. Storing the primitives in this order puts a
    /// leaf's primitives next to each other in memory, and neighbouring leaves' close by.
    /// Deterministic: a function of the structure alone.
    fn leaf_order(&self, n: usize) -> Vec<u32> {
        let mut seen = vec![false; n];
        let mut order = Vec::with_capacity(n);
        self.for_each_leaf(&mut |ids| {
            for &g in ids {
                if !std::mem::replace(&mut seen[g as usize], true) {
                    order.push(g);
                }
            }
        });
        order.extend((0..n as u32).filter(|&i| !seen[i as usize]));
        order
    }
}

/// Renames the primitives of leaf lists stored as `[count, ids..]` runs, and sorts each
/// list: the shared part of [`LeafOrdered::remap`].
fn remap_leaf_lists(leaves: &mut [u32], new_index: &[u32]) {
    let mut i = 0;
    while i < leaves.len() {
        let n = leaves[i] as usize;
        let ids = &mut leaves[i + 1..i + 1 + n];
        for id in ids.iter_mut() {
            *id = new_index[*id as usize];
        }
        ids.sort_unstable();
        i += 1 + n;
    }
}

/// A set of primitives addressed by index `0..len()`.
pub trait Primitives: Sync {
    fn len(&self) -> usize;

    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bounds of primitive `i`.
    fn bounds(&self, i: u32) -> Aabb;

    /// Bounds of the part of primitive `i` that lies inside `clip` ("perfect splits").
    /// The default is conservative; triangles override it with exact polygon clipping.
    fn clipped_bounds(&self, i: u32, clip: &Aabb) -> Aabb {
        self.bounds(i).intersection(*clip)
    }

    /// Nearest hit of primitive `i` with `0 < t < tmax`.
    fn intersect(&self, i: u32, ray: &Ray, pre: &RayPrecomp, tmax: f32) -> Option<PrimHit>;

    /// Whether primitive `i` has any hit with `0 < t < tmax`: `intersect(..).is_some()`,
    /// which a primitive holding others (an instance) answers by an any-hit query.
    #[inline(always)]
    fn occludes(&self, i: u32, ray: &Ray, pre: &RayPrecomp, tmax: f32) -> bool {
        self.intersect(i, ray, pre, tmax).is_some()
    }

    /// The index a query reports for hit `h` on primitive `i` ([`Hit::prim`]): `i`
    /// itself, or for an instance the scene-wide index of the triangle `h.sub` of its copy.
    #[inline(always)]
    fn hit_prim(&self, i: u32, h: &PrimHit) -> u32 {
        let _ = h;
        i
    }

    /// The triangles among the primitives, when they are primitives `0..n` stored as
    /// corners (what the kd-tree's eight-lane leaf test gathers from); empty otherwise.
    /// Primitive `i < n`'s [`Primitives::intersect`] must then be the watertight test
    /// of `triangle_corners()[i]` with barycentrics `(u, v) = (b1, b2)`.
    #[inline(always)]
    fn triangle_corners(&self) -> &[[glam::Vec3; 3]] {
        &[]
    }

    /// A hint that primitive `i` is about to be tested: start loading its data into the
    /// cache. No effect on any result.
    #[inline(always)]
    fn prefetch(&self, _i: u32) {}
}

/// The O(N) reference query: the kd-tree must give exactly this answer.
pub fn brute_force_intersect<P: Primitives>(prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
    let pre = RayPrecomp::new(ray);
    let mut best: Option<Hit> = None;
    let mut tmax = tmax;
    for i in 0..prims.len() as u32 {
        if let Some(h) = prims.intersect(i, ray, &pre, tmax) {
            tmax = h.t;
            best = Some(Hit { t: h.t, prim: prims.hit_prim(i, &h), u: h.u, v: h.v });
        }
    }
    best
}

/// The O(N) reference any-hit query.
pub fn brute_force_occluded<P: Primitives>(prims: &P, ray: &Ray, tmax: f32) -> bool {
    let pre = RayPrecomp::new(ray);
    (0..prims.len() as u32).any(|i| prims.occludes(i, ray, &pre, tmax))
}

/// The benchmarks' incoherent rays (`cargo bench --bench kdtree`, `coordinator bench
/// --export-rays`, `bench/embree_compare.py`): origins uniform on the bounding sphere of
/// `bounds`, each aimed at a uniform point in the box, with the distance to that point
/// (the any-hit query's `tmax`). Deterministic in `seed`.
pub fn incoherent_rays(bounds: Aabb, n: usize, seed: u64) -> Vec<(Ray, f32)> {
    let mut state = seed;
    let mut f = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    };
    let (c, radius) = (bounds.center(), 0.5 * bounds.diagonal().length());
    (0..n)
        .map(|_| {
            let unit = loop {
                let v = glam::Vec3::new(f(), f(), f()) * 2.0 - 1.0;
                let l = v.length_squared();
                if l > 1e-4 && l <= 1.0 {
                    break v / l.sqrt();
                }
            };
            let o = c + unit * radius;
            let target = bounds.min + bounds.diagonal() * glam::Vec3::new(f(), f(), f());
            let d = target - o;
            let len = d.length();
            (Ray::new(o, d / len), len)
        })
        .collect()
}

/// Hints the cache to load `p`'s line (no effect on results; nothing is dereferenced).
#[inline(always)]
pub(crate) fn prefetch<T>(p: *const T) {
    // SAFETY: a prefetch is a hint; it never faults and reads no memory into the
    // program, whatever the address (SSE is part of the x86_64 baseline).
    #[cfg(target_arch = "x86_64")]
    unsafe {
        core::arch::x86_64::_mm_prefetch::<{ core::arch::x86_64::_MM_HINT_T0 }>(p.cast())
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}
