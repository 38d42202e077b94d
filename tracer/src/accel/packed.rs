//! Brute force, eight triangles at a time: the accelerator for scenes so small that a
//! tree does not pay for itself.
//!
//! A Cornell box has 32 triangles. The kd-tree answers a ray there after ~13 scalar
//! triangle tests plus node steps and the bookkeeping that makes it exact; testing all
//! 32 in blocks of eight lanes (structure-of-arrays, which the compiler vectorises) is
//! several times cheaper, and brute force is exact by definition.
//!
//! Exactness. The block pass repeats the first half of the watertight test
//! ([`intersect_triangle_corners`]) lane by lane with the same operations in the same
//! order, so its edge functions `u, v, w`, `det` and `t·det` are the scalar test's bits.
//! It keeps a lane when the scalar test could accept it with the block's starting `tmax`
//! (or when an edge function is exactly zero, where the scalar test switches to double
//! precision). Kept lanes then run the scalar test itself, in index order, with the
//! current `tmax`: since a smaller `tmax` only rejects more, this is exactly the loop of
//! [`brute_force_intersect`] / [`brute_force_occluded`], and so also exactly what the
//! kd-tree returns.
//!
//! [`intersect_triangle_corners`]: crate::geometry::triangle::intersect_triangle_corners
//! [`brute_force_intersect`]: super::brute_force_intersect
//! [`brute_force_occluded`]: super::brute_force_occluded

use glam::Vec3;

use super::{Hit, Primitives, RayPrecomp};
use crate::geometry::triangle::RayShear;
use crate::geometry::{Aabb, Ray};
use crate::scene::Geometry;

const LANES: usize = 8;

/// Largest scene traced by [`PackedTriangles`] instead of the kd-tree. Full renders
/// (`coordinator render SCENE --local-workers 0 --width 256 --spp 16`, median of 5,
/// M samples/s, kd-tree → packed with block culling): Cornell box (32 triangles) 1.00 →
/// 1.57, Veach MIS (12 + 5 spheres) 1.58 → 2.02, glass (12 + 2) 1.13 → 1.63, cube (52)
/// 2.94 → 3.71, room (74 + 1) 0.62 → 0.85; bumpy spheres over a plane, 66 triangles
/// 9.1 → 10.5, 130: 8.6 → 10.1, 258: 8.7 → 9.0, 514: 9.3 → 7.8.
pub const SMALL_TRIANGLES: usize = 256;
pub const SMALL_SPHERES: usize = 16;

/// Blocks are culled by their boxes only from this many blocks on: with fewer, each box
/// spans most of the scene and the slab tests cost more than they save.
const CULL_MIN_BLOCKS: usize = 6;

/// Eight triangles: `p[vertex][axis][lane]`.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
struct Block {
    p: [[[f32; LANES]; 3]; 3],
}

/// The first `len` primitives of a [`Primitives`] set, when they are triangles, packed for
/// the block test. Queries take the set itself for the exact tests and for the primitives
/// after the triangles (spheres), which are tested one by one.
#[derive(Clone, Debug)]
pub struct PackedTriangles {
    blocks: Vec<Block>,
    len: usize,
    /// Bounds of every primitive of the set: rays that miss them skip all tests.
    bounds: Aabb,
    /// Bounds of each block's triangles: a block the ray cannot reach before the nearest
    /// hit so far is skipped (index order is kept, so the answer is still brute force's;
    /// triangles that are neighbours in a file are usually neighbours in space).
    boxes: Vec<Aabb>,
    simd: Simd,
}

impl PackedTriangles {
    /// Packs triangles `0..len` from their corners (in index order); `bounds` must hold
    /// every primitive of the set the queries will pass.
    pub fn new(corners: impl ExactSizeIterator<Item = [Vec3; 3]>, bounds: Aabb) -> Self {
        let len = corners.len();
        let mut blocks = vec![Block { p: [[[0.0; LANES]; 3]; 3] }; len.div_ceil(LANES)];
        let mut boxes = vec![Aabb::EMPTY; blocks.len()];
        for (i, tri) in corners.enumerate() {
            boxes[i / LANES] = tri.iter().fold(boxes[i / LANES], |b, &p| b.union(Aabb::new(p, p)));
            let b = &mut blocks[i / LANES];
            for (v, corner) in tri.iter().enumerate() {
                for a in 0..3 {
                    b.p[v][a][i % LANES] = corner[a];
                }
            }
        }
        Self { blocks, len, bounds, boxes, simd: Simd::detect() }
    }

    /// The packed triangles of `geo` when brute force beats its kd-tree: at most
    /// [`SMALL_TRIANGLES`] triangles and [`SMALL_SPHERES`] spheres.
    pub fn for_small_scene(geo: &Geometry) -> Option<Self> {
        let n = geo.triangle_count();
        (n <= SMALL_TRIANGLES && geo.spheres.len() <= SMALL_SPHERES).then(|| {
            let bounds = (0..geo.len() as u32).fold(Aabb::EMPTY, |b, i| b.union(geo.bounds(i)));
            Self::new((0..n).map(|i| *geo.triangle(i)), bounds)
        })
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes allocated for the blocks and their boxes.
    pub fn bytes(&self) -> usize {
        self.blocks.capacity() * size_of::<Block>() + self.boxes.capacity() * size_of::<Aabb>()
    }

    /// The margin by which boxes are widened for this ray: far above the rounding of the
    /// slab test and of the primitives' tests (which can report hits a few ulps outside
    /// a primitive), so culling by boxes never drops a hit.
    #[inline]
    fn margin(&self, ray: &Ray) -> f32 {
        1e-3 * (self.bounds.diagonal().max_element() + ray.origin.abs().max_element())
    }

    /// Whether the ray can reach box `b`, widened by `pad`, within `tmax`.
    #[inline(always)]
    fn reaches(b: &Aabb, pad: f32, ray: &Ray, pre: &RayPrecomp, tmax: f32) -> bool {
        let (lo, hi) = (b.min - Vec3::splat(pad), b.max + Vec3::splat(pad));
        let (t0, t1) = ((lo - ray.origin) * pre.inv_dir, (hi - ray.origin) * pre.inv_dir);
        // NaN (0 · inf, a ray in a slab's plane) must not exclude: compare so it passes.
        let near = t0.min(t1).max_element();
        let far = t0.max(t1).min_element();
        !(near > far || far < 0.0 || near > tmax)
    }

    /// Lanes of block `b` that hold a triangle (the last block may be partial).
    #[inline]
    fn valid(&self, b: usize) -> u32 {
        let n = (self.len - b * LANES).min(LANES);
        if n == LANES { u32::MAX } else { (1 << n) - 1 }
    }

    /// Nearest hit with `0 < t < tmax` among all of `prims`: exactly
    /// [`super::brute_force_intersect`]`(prims, ray, tmax)`.
    pub fn intersect<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        match self.simd {
            Simd::Baseline => self.intersect_impl(prims, ray, tmax),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Avx2` is only chosen when the CPU reports AVX2.
            Simd::Avx2 => unsafe { self.intersect_avx2(prims, ray, tmax) },
        }
    }

    /// Whether anything in `prims` is hit with `0 < t < tmax`: exactly
    /// [`super::brute_force_occluded`]`(prims, ray, tmax)`.
    pub fn occluded<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        match self.simd {
            Simd::Baseline => self.occluded_impl(prims, ray, tmax),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `intersect`.
            Simd::Avx2 => unsafe { self.occluded_avx2(prims, ray, tmax) },
        }
    }

    // The whole query is compiled for AVX2, not just the block test, so that the block
    // test inlines into the loop. Only wider registers, never fused multiply-adds (Rust
    // does not contract `a * b + c`): the bits are the baseline's.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn intersect_avx2<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        self.intersect_impl(prims, ray, tmax)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn occluded_avx2<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        self.occluded_impl(prims, ray, tmax)
    }

    #[inline(always)]
    fn intersect_impl<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        let pre = RayPrecomp::new(ray);
        let pad = self.margin(ray);
        if !Self::reaches(&self.bounds, pad, ray, &pre, tmax) {
            return None;
        }
        let mut best = None;
        let mut tmax = tmax;
        let mut hit = |i: u32, tmax: &mut f32| {
            if let Some(h) = prims.intersect(i, ray, &pre, *tmax) {
                *tmax = h.t;
                best = Some(Hit { t: h.t, prim: i, u: h.u, v: h.v });
            }
        };
        let cull = self.blocks.len() >= CULL_MIN_BLOCKS;
        for (bi, block) in self.blocks.iter().enumerate() {
            if cull && !Self::reaches(&self.boxes[bi], pad, ray, &pre, tmax) {
                continue;
            }
            let mut keep = candidates(block, &pre.shear, tmax) & self.valid(bi);
            while keep != 0 {
                let lane = keep.trailing_zeros() as usize;
                keep &= keep - 1;
                hit((bi * LANES + lane) as u32, &mut tmax);
            }
        }
        for i in self.len..prims.len() {
            hit(i as u32, &mut tmax);
        }
        best
    }

    #[inline(always)]
    fn occluded_impl<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        let pre = RayPrecomp::new(ray);
        let pad = self.margin(ray);
        if !Self::reaches(&self.bounds, pad, ray, &pre, tmax) {
            return false;
        }
        let cull = self.blocks.len() >= CULL_MIN_BLOCKS;
        for (bi, block) in self.blocks.iter().enumerate() {
            if cull && !Self::reaches(&self.boxes[bi], pad, ray, &pre, tmax) {
                continue;
            }
            let mut keep = candidates(block, &pre.shear, tmax) & self.valid(bi);
            while keep != 0 {
                let lane = keep.trailing_zeros() as usize;
                keep &= keep - 1;
                if prims.intersect((bi * LANES + lane) as u32, ray, &pre, tmax).is_some() {
                    return true;
                }
            }
        }
        (self.len..prims.len()).any(|i| prims.intersect(i as u32, ray, &pre, tmax).is_some())
    }
}

/// Which instruction set the block test runs with, decided once per process.
#[derive(Clone, Copy, Debug)]
enum Simd {
    Baseline,
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl Simd {
    #[inline]
    fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            return Simd::Avx2;
        }
        Simd::Baseline
    }
}

/// Bit mask of the lanes whose triangle the watertight test may accept with `tmax` (see
/// the module comment). Written lane-wise without branches so that it vectorises.
#[inline(always)]
fn candidates(b: &Block, shear: &RayShear, tmax: f32) -> u32 {
    let ([kx, ky, kz], [sx, sy, sz], [ox, oy, oz]) = shear.parts();
    let (p0, p1, p2) = (&b.p[0], &b.p[1], &b.p[2]);
    let (p0x, p0y, p0z) = (&p0[kx], &p0[ky], &p0[kz]);
    let (p1x, p1y, p1z) = (&p1[kx], &p1[ky], &p1[kz]);
    let (p2x, p2y, p2z) = (&p2[kx], &p2[ky], &p2[kz]);
    // Lane l's verdict as bit l, combined below by OR: shifts and ORs vectorise, where
    // packing an array of bools into a mask did not.
    let mut keep = [0u32; LANES];
    for l in 0..LANES {
        // The same operations, in the same order, as `intersect_triangle_corners`.
        let (a_x, a_y, a_z) = (p0x[l] - ox, p0y[l] - oy, p0z[l] - oz);
        let (b_x, b_y, b_z) = (p1x[l] - ox, p1y[l] - oy, p1z[l] - oz);
        let (c_x, c_y, c_z) = (p2x[l] - ox, p2y[l] - oy, p2z[l] - oz);
        let ax = a_x - sx * a_z;
        let ay = a_y - sy * a_z;
        let bx = b_x - sx * b_z;
        let by = b_y - sy * b_z;
        let cx = c_x - sx * c_z;
        let cy = c_y - sy * c_z;
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        let zero = (u == 0.0) | (v == 0.0) | (w == 0.0);
        let mixed = ((u < 0.0) | (v < 0.0) | (w < 0.0)) & ((u > 0.0) | (v > 0.0) | (w > 0.0));
        let det = u + v + w;
        let t_scaled = u * (sz * a_z) + v * (sz * b_z) + w * (sz * c_z);
        let limit = tmax * det;
        let out_neg = (det < 0.0) & ((t_scaled >= 0.0) | (t_scaled < limit));
        let out_pos = (det > 0.0) & ((t_scaled <= 0.0) | (t_scaled > limit));
        keep[l] = u32::from(zero | (!mixed & (det != 0.0) & !out_neg & !out_pos)) << l;
    }
    keep.iter().fold(0, |m, &k| m | k)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::{brute_force_intersect, brute_force_occluded};
    use crate::scene::{Sphere, Tri, TriangleMesh};

    struct Rng(u64);
    impl Rng {
        fn f(&mut self) -> f32 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
        }
        fn v(&mut self) -> Vec3 {
            Vec3::new(self.f(), self.f(), self.f()) * 2.0 - 1.0
        }
    }

    /// Random triangles, a closed grid of quads sharing edges and vertices (rays through
    /// them exercise the exact-zero path), duplicates, and a few spheres.
    fn scene(r: &mut Rng, n: usize) -> Geometry {
        let mut mesh = TriangleMesh::default();
        let none = [crate::scene::NONE; 3];
        let tri = |mesh: &mut TriangleMesh, p: [Vec3; 3]| {
            let base = mesh.positions.len() as u32;
            mesh.positions.extend_from_slice(&p);
            mesh.tris.push(Tri { v: [base, base + 1, base + 2], n: none, uv: none, material: 0 });
        };
        for _ in 0..n {
            let c = r.v();
            tri(&mut mesh, [c, c + r.v() * 0.4, c + r.v() * 0.4]);
        }
        // A 4×4 grid of unit quads in the z = 0.25 plane, two triangles each.
        for i in 0..4 {
            for j in 0..4 {
                let p = |a: i32, b: i32| Vec3::new((i + a) as f32 * 0.5 - 1.0, (j + b) as f32 * 0.5 - 1.0, 0.25);
                tri(&mut mesh, [p(0, 0), p(1, 0), p(1, 1)]);
                tri(&mut mesh, [p(0, 0), p(1, 1), p(0, 1)]);
            }
        }
        let dup = mesh.corners(3);
        tri(&mut mesh, dup);
        let spheres = (0..3).map(|_| Sphere { center: r.v(), radius: 0.1 + 0.2 * r.f(), material: 0 }).collect();
        Geometry::new(mesh, spheres)
    }

    #[test]
    fn block_test_is_exactly_brute_force() {
        let mut r = Rng(3);
        for n in [0, 1, 7, 8, 9, 40] {
            let geo = scene(&mut r, n);
            let detected = PackedTriangles::for_small_scene(&geo).expect("small");
            // The instruction set found here, and the x86-64 baseline.
            let baseline = PackedTriangles { simd: Simd::Baseline, ..detected.clone() };
            for (k, packed) in (0..8000).map(|k| (k / 2, if k % 2 == 0 { &detected } else { &baseline })) {
                let o = r.v() * 2.0;
                // Every fourth ray aims exactly at a grid vertex or edge point.
                let target = if k % 4 == 0 {
                    Vec3::new((k / 4 % 9) as f32 * 0.25 - 1.0, (k / 36 % 9) as f32 * 0.25 - 1.0, 0.25)
                } else {
                    r.v()
                };
                let ray = Ray::new(o, (target - o).normalize());
                let tmax = if k % 3 == 0 { f32::INFINITY } else { (target - o).length() * (0.5 + r.f()) };
                let expected = brute_force_intersect(&geo, &ray, tmax);
                assert_eq!(packed.intersect(&geo, &ray, tmax), expected, "n {n} ray {k}");
                assert_eq!(packed.occluded(&geo, &ray, tmax), brute_force_occluded(&geo, &ray, tmax), "n {n} ray {k}");
                // tmax at and just around a hit's own distance: where `t·det` meets
                // `tmax·det` and the block test must keep exactly the lanes that can pass.
                if let Some(h) = expected {
                    for tmax in [h.t, h.t.next_up(), h.t.next_down(), h.t * (1.0 + 4.0 * f32::EPSILON)] {
                        let bf = brute_force_intersect(&geo, &ray, tmax);
                        assert_eq!(packed.intersect(&geo, &ray, tmax), bf, "n {n} ray {k} tmax {tmax}");
                        let bo = brute_force_occluded(&geo, &ray, tmax);
                        assert_eq!(packed.occluded(&geo, &ray, tmax), bo, "n {n} ray {k} tmax {tmax}");
                    }
                }
            }
        }
    }

    #[test]
    fn finds_hits_and_misses() {
        let mut r = Rng(5);
        let geo = scene(&mut r, 0);
        let packed = PackedTriangles::for_small_scene(&geo).expect("small");
        // Straight down onto the grid (spheres are somewhere in [-1, 1]³: aim between).
        let ray = Ray::new(Vec3::new(-0.9, -0.9, 5.0), -Vec3::Z);
        let h = packed.intersect(&geo, &ray, f32::INFINITY).expect("the grid is hit");
        assert!((h.t - 4.75).abs() < 1e-5 || h.prim as usize >= geo.triangle_count(), "{h:?}");
        let away = Ray::new(Vec3::new(0.0, 0.0, 5.0), Vec3::Z);
        assert!(packed.intersect(&geo, &away, f32::INFINITY).is_none());
        assert!(!packed.occluded(&geo, &away, f32::INFINITY));
    }
}
