//! Brute force, eight triangles at a time (sixteen with AVX-512): the accelerator for
//! scenes so small that a tree does not pay for itself.
//!
//! A Cornell box has 32 triangles. The kd-tree answers a ray there after ~13 scalar
//! triangle tests plus node steps and the bookkeeping that makes it exact; testing all
//! 32 in blocks of eight lanes (structure-of-arrays, which the compiler vectorises) is
//! several times cheaper, and brute force is exact by definition. With AVX-512 two
//! blocks are tested at once, which pays (`bench/RESULTS.md`; `TILEFARM_SIMD=avx2`
//! selects eight lanes).
//!
//! Exactness. Each block runs the eight-lane pass of `accel/block_test.rs`, whose kept lanes
//! then finish with the scalar test's own last step (or run the scalar test, on an
//! edge), in index order, with the current `tmax`: exactly the loop of
//! [`brute_force_intersect`] / [`brute_force_occluded`], and so also exactly what the
//! kd-tree returns.
//!
//! [`brute_force_intersect`]: super::brute_force_intersect
//! [`brute_force_occluded`]: super::brute_force_occluded

use glam::Vec3;

use super::block_test::{InstructionSet, LANES, Lanes};
#[cfg(target_arch = "x86_64")]
use super::block_test::{WIDE, watertight_avx2, watertight_avx512};
use super::{Hit, PrimHit, Primitives, RayPrecomp};
use crate::geometry::triangle::RayShear;
use crate::geometry::{Aabb, Ray};
use crate::shapes::Geometry;

mod runs;
pub(super) use runs::Run;

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

/// Boxes are widened by this times (the scene's extent + the largest coordinate of the
/// ray's origin): far above the rounding of the slab test and of the primitives' tests
/// (which can report hits a few ulps outside a primitive), so culling by boxes never
/// drops a hit. The one-ray culling and the packets' runs (`ray_packets.rs`) both use it.
pub(super) const MARGIN: f32 = 1e-3;

/// The lane mask of a full block (eight bits: a pair's second block is shifted above it).
const FULL: u32 = (1 << LANES) - 1;

/// Eight triangles: `p[vertex][axis][lane]`.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
#[repr(C, align(32))]
struct Block {
    p: [[[f32; LANES]; 3]; 3],
}

/// One triangle's corners, each padded to four floats: what a 16-byte load broadcasts
/// to the lanes of a packet query (`accel/ray_packets.rs`). The first corner's padding
/// says whether [`Corners4::follows_fan`].
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
#[repr(C, align(16))]
pub(super) struct Corners4(pub(super) [[f32; 4]; 3]);

impl Corners4 {
    /// Corners 0 and 1 are, bit for bit, corners 0 and 2 of the triangle before: the
    /// second half of a quad split as a fan, as OBJ faces are. (A packet query then
    /// reuses those corners' sheared coordinates.)
    #[inline(always)]
    pub(super) fn follows_fan(&self) -> bool {
        self.0[0][3] != 0.0
    }

    /// The three corners.
    #[inline]
    pub(super) fn corners(&self) -> [Vec3; 3] {
        self.0.map(|[x, y, z, _]| Vec3::new(x, y, z))
    }

    fn new(tri: &[Vec3; 3], before: Option<&[Vec3; 3]>) -> Self {
        let same = |a: Vec3, b: Vec3| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits);
        let fan = before.is_some_and(|b| same(tri[0], b[0]) && same(tri[1], b[2]));
        let mut c = Corners4(tri.map(|p| [p.x, p.y, p.z, 0.0]));
        c.0[0][3] = if fan { 1.0 } else { 0.0 };
        c
    }
}

/// Eight spheres: `c[axis][lane]` and `r[lane]`.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
#[repr(C, align(32))]
struct SphereBlock {
    c: [[f32; LANES]; 3],
    r: [f32; LANES],
}

/// The first `len` primitives of a [`Primitives`] set, when they are triangles, packed for
/// the block test, and the spheres that follow them, packed for a block pre-test. Queries
/// take the set itself for the exact tests and for any primitives after those.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct PackedTriangles {
    blocks: Vec<Block>,
    len: usize,
    /// Bounds of every primitive of the set: rays that miss them skip all tests.
    bounds: Aabb,
    /// Bounds of each block's triangles: a block the ray cannot reach before the nearest
    /// hit so far is skipped (index order is kept, so the answer is still brute force's;
    /// triangles that are neighbours in a file are usually neighbours in space).
    boxes: Vec<Aabb>,
    /// Lanes of the last block that hold a triangle.
    tail: u32,
    /// The spheres, primitives `len..len + spheres`.
    sphere_blocks: Vec<SphereBlock>,
    spheres: usize,
    #[serde(skip, default = "InstructionSet::detect")]
    pub(super) simd: InstructionSet,
    /// The triangles again, one by one, and the spheres (center, radius): for packets.
    corners4: Vec<Corners4>,
    /// The triangles in runs with boxes, for packets (`triangle_blocks/runs.rs`).
    runs: Vec<Run>,
    sphere_list: Vec<(Vec3, f32)>,
}

impl PackedTriangles {
    /// Packs triangles `0..len` from their corners (in index order) and the spheres
    /// (center, radius) that follow them, primitives `len..len + spheres.len()`; `bounds`
    /// must hold every primitive of the set the queries will pass.
    pub fn new(corners: impl ExactSizeIterator<Item = [Vec3; 3]>, spheres: &[(Vec3, f32)], bounds: Aabb) -> Self {
        let len = corners.len();
        let mut corners4 = Vec::with_capacity(len);
        let mut blocks = vec![Block { p: [[[0.0; LANES]; 3]; 3] }; len.div_ceil(LANES)];
        let mut boxes = vec![Aabb::EMPTY; blocks.len()];
        let mut before = None;
        for (i, tri) in corners.enumerate() {
            corners4.push(Corners4::new(&tri, before.as_ref()));
            before = Some(tri);
            boxes[i / LANES] = tri.iter().fold(boxes[i / LANES], |b, &p| b.union(Aabb::new(p, p)));
            let b = &mut blocks[i / LANES];
            for (v, corner) in tri.iter().enumerate() {
                for a in 0..3 {
                    b.p[v][a][i % LANES] = corner[a];
                }
            }
        }
        let tail = match len % LANES {
            0 => FULL,
            n => (1 << n) - 1,
        };
        let mut sphere_blocks =
            vec![SphereBlock { c: [[0.0; LANES]; 3], r: [0.0; LANES] }; spheres.len().div_ceil(LANES)];
        for (i, &(c, r)) in spheres.iter().enumerate() {
            let b = &mut sphere_blocks[i / LANES];
            for a in 0..3 {
                b.c[a][i % LANES] = c[a];
            }
            b.r[i % LANES] = r;
        }
        let runs = runs::plan(corners4.len(), |i| corners4[i].corners(), &bounds);
        Self {
            blocks,
            len,
            bounds,
            boxes,
            tail,
            sphere_blocks,
            spheres: spheres.len(),
            simd: InstructionSet::detect(),
            corners4,
            runs,
            sphere_list: spheres.to_vec(),
        }
    }

    /// The packed triangles of `geo` when brute force beats its kd-tree: at most
    /// [`SMALL_TRIANGLES`] triangles and [`SMALL_SPHERES`] spheres.
    pub fn for_small_scene(geo: &Geometry) -> Option<Self> {
        let n = geo.triangle_count();
        (n <= SMALL_TRIANGLES && geo.spheres.len() <= SMALL_SPHERES).then(|| {
            let bounds = (0..geo.len() as u32).fold(Aabb::EMPTY, |b, i| b.union(geo.bounds(i)));
            let spheres: Vec<(Vec3, f32)> = geo.spheres.iter().map(|s| (s.center, s.radius)).collect();
            Self::new((0..n).map(|i| *geo.triangle(i)), &spheres, bounds)
        })
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes allocated for the triangle blocks, their boxes, the sphere blocks and the
    /// packet queries' copies.
    pub fn bytes(&self) -> usize {
        self.blocks.capacity() * size_of::<Block>()
            + self.boxes.capacity() * size_of::<Aabb>()
            + self.sphere_blocks.capacity() * size_of::<SphereBlock>()
            + self.corners4.capacity() * size_of::<Corners4>()
            + self.runs.capacity() * size_of::<Run>()
            + self.sphere_list.capacity() * size_of::<(Vec3, f32)>()
    }

    /// The triangles' corners one by one, in index order.
    pub(super) fn corners4(&self) -> &[Corners4] {
        &self.corners4
    }

    /// The triangles in runs, in index order, each with the box to test first or none.
    pub(super) fn runs(&self) -> &[Run] {
        &self.runs
    }

    /// The longest side of the scene's bounds, from which [`Self::margin`] widens boxes
    /// (a packet query computes the margin for eight origins).
    #[inline(always)]
    pub(super) fn extent(&self) -> f32 {
        self.bounds.diagonal().max_element()
    }

    /// The spheres (center, radius), primitives `len()..`.
    pub(super) fn sphere_list(&self) -> &[(Vec3, f32)] {
        &self.sphere_list
    }

    /// Whether the packet queries of `accel/ray_packets.rs` may run: the CPU has AVX2 and
    /// `TILEFARM_SIMD` does not ask for the baseline.
    pub fn packets(&self) -> bool {
        self.simd != InstructionSet::Baseline
    }

    /// The block test's instruction set, for reports (`TILEFARM_SIMD` can lower it).
    pub fn instruction_set(&self) -> &'static str {
        self.simd.name()
    }

    /// Lanes of sphere block `b` that hold a sphere.
    #[inline]
    fn sphere_valid(&self, b: usize) -> u32 {
        let n = (self.spheres - b * LANES).min(LANES);
        if n == LANES { u32::MAX } else { (1 << n) - 1 }
    }

    /// The margin by which boxes are widened for this ray (see [`MARGIN`]).
    #[inline]
    fn margin(&self, ray: &Ray) -> f32 {
        MARGIN * (self.extent() + ray.origin.abs().max_element())
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
        if b + 1 < self.blocks.len() { FULL } else { self.tail }
    }

    /// Nearest hit with `0 < t < tmax` among all of `prims`: exactly
    /// [`super::brute_force_intersect`]`(prims, ray, tmax)`.
    pub fn intersect<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        match self.simd {
            InstructionSet::Baseline => self.intersect_impl::<P, 0>(prims, ray, tmax),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Avx2` is only chosen when the CPU reports AVX2.
            InstructionSet::Avx2 => unsafe { self.intersect_avx2(prims, ray, tmax) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Avx512` is only chosen when the CPU reports AVX2 and AVX-512F.
            InstructionSet::Avx512 => unsafe { self.intersect_avx512(prims, ray, tmax) },
        }
    }

    /// Whether anything in `prims` is hit with `0 < t < tmax`: exactly
    /// [`super::brute_force_occluded`]`(prims, ray, tmax)`.
    pub fn occluded<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        match self.simd {
            InstructionSet::Baseline => self.occluded_impl::<P, 0>(prims, ray, tmax),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `intersect`.
            InstructionSet::Avx2 => unsafe { self.occluded_avx2(prims, ray, tmax) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `intersect`.
            InstructionSet::Avx512 => unsafe { self.occluded_avx512(prims, ray, tmax) },
        }
    }

    // The whole query is compiled for AVX2, not just the block test, so that the block
    // test inlines into the loop. Only wider registers, never fused multiply-adds (Rust
    // does not contract `a * b + c`): the bits are the baseline's.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn intersect_avx2<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        self.intersect_impl::<P, LANES>(prims, ray, tmax)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn occluded_avx2<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        self.occluded_impl::<P, LANES>(prims, ray, tmax)
    }

    /// Two blocks at a time in sixteen lanes; the rest as [`Self::intersect_avx2`].
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,avx512f")]
    unsafe fn intersect_avx512<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        self.intersect_impl::<P, WIDE>(prims, ray, tmax)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,avx512f")]
    unsafe fn occluded_avx512<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        self.occluded_impl::<P, WIDE>(prims, ray, tmax)
    }

    /// `W`: lanes of the block test, 0 for the portable one, [`LANES`] (AVX2) or `WIDE`
    /// (AVX-512, two blocks at once).
    #[inline(always)]
    fn intersect_impl<P: Primitives, const W: usize>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        let mut best = None;
        self.each_hit::<P, W>(prims, ray, tmax, |prim, h| {
            best = Some(Hit { t: h.t, prim, u: h.u, v: h.v });
            Some(h.t)
        });
        best
    }

    #[inline(always)]
    fn occluded_impl<P: Primitives, const W: usize>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        let mut found = false;
        self.each_hit::<P, W>(prims, ray, tmax, |_, _| {
            found = true;
            None
        });
        found
    }

    /// The brute-force loop: every primitive of `prims` in index order, tested with the
    /// current `tmax`, with the block tests skipping those that cannot pass. `hit` gets
    /// each hit and returns the `tmax` to go on with, or `None` to stop.
    #[inline(always)]
    // Long on purpose: The block loop with its exact finishing step; one function so the compiler keeps the block in registers.
    fn each_hit<P: Primitives, const W: usize>(
        &self,
        prims: &P,
        ray: &Ray,
        mut tmax: f32,
        mut hit: impl FnMut(u32, PrimHit) -> Option<f32>,
    ) {
        let pre = RayPrecomp::new(ray);
        let pad = self.margin(ray);
        // From inside the (padded) bounds every ray reaches them, as the slab test would
        // also say; the point test is cheaper.
        let inside = ray.origin.cmpge(self.bounds.min - Vec3::splat(pad)).all()
            && ray.origin.cmple(self.bounds.max + Vec3::splat(pad)).all();
        if !inside && !Self::reaches(&self.bounds, pad, ray, &pre, tmax) {
            return;
        }
        let mut lanes = Lanes::default();
        let cull = self.blocks.len() >= CULL_MIN_BLOCKS;
        let reach = |bi: usize, tmax: f32| !cull || Self::reaches(&self.boxes[bi], pad, ray, &pre, tmax);
        // One block alone: its first triangle, kept lanes and zero lanes.
        let test = |c: usize, tmax: f32, lanes: &mut Lanes| {
            let (keep, zero) = block_test::<W>(&self.blocks[c], &pre.shear, tmax, lanes);
            (c * LANES, keep & self.valid(c), zero)
        };
        let mut bi = 0;
        while bi < self.blocks.len() {
            // The lanes to finish: lane l is triangle `first + l` (with sixteen lanes,
            // of block `first / 8` and the next one).
            let (first, mut keep, zero) = if W == WIDE_LANES && bi + 1 < self.blocks.len() {
                let (a, b) = (bi, bi + 1);
                bi += 2;
                match (reach(a, tmax), reach(b, tmax)) {
                    (true, true) => {
                        let (keep, zero) = pair_test(&self.blocks[a], &self.blocks[b], &pre.shear, tmax, &mut lanes);
                        (a * LANES, keep & (self.valid(a) | self.valid(b) << LANES), zero)
                    }
                    (true, false) => test(a, tmax, &mut lanes),
                    (false, true) => test(b, tmax, &mut lanes),
                    (false, false) => continue,
                }
            } else {
                bi += 1;
                if !reach(bi - 1, tmax) {
                    continue;
                }
                test(bi - 1, tmax, &mut lanes)
            };
            while keep != 0 {
                let lane = keep.trailing_zeros() as usize;
                keep &= keep - 1;
                let i = (first + lane) as u32;
                // Lanes with an edge function exactly zero need the scalar test's double
                // precision; the others finish from the block's own values.
                let h = if zero & (1 << lane) != 0 {
                    prims.intersect(i, ray, &pre, tmax)
                } else {
                    lanes.finish(lane, tmax)
                };
                if let Some(h) = h {
                    let Some(t) = hit(i, h) else { return };
                    tmax = t;
                }
            }
        }
        let sphere_a = ray.dir.length_squared();
        for (bi, block) in self.sphere_blocks.iter().enumerate() {
            let mut keep = sphere_pretest::<W>(block, ray, sphere_a) & self.sphere_valid(bi);
            while keep != 0 {
                let lane = keep.trailing_zeros() as usize;
                keep &= keep - 1;
                let i = (self.len + bi * LANES + lane) as u32;
                if let Some(h) = prims.intersect(i, ray, &pre, tmax) {
                    let Some(t) = hit(i, h) else { return };
                    tmax = t;
                }
            }
        }
        for i in (self.len + self.spheres) as u32..prims.len() as u32 {
            if let Some(h) = prims.intersect(i, ray, &pre, tmax) {
                let Some(t) = hit(i, h) else { return };
                tmax = t;
            }
        }
    }
}

/// Sixteen lanes where the target has them: [`WIDE`] on x86_64, never elsewhere.
#[cfg(target_arch = "x86_64")]
const WIDE_LANES: usize = WIDE;
#[cfg(not(target_arch = "x86_64"))]
const WIDE_LANES: usize = usize::MAX;

/// The block test with the instruction set chosen at compile time (`W` lanes of the
/// query; one block is eight lanes either way): `(keep, zero)` as [`block_test_lanes`]
/// returns them.
#[inline(always)]
fn block_test<const W: usize>(b: &Block, shear: &RayShear, tmax: f32, out: &mut Lanes) -> (u32, u32) {
    #[cfg(target_arch = "x86_64")]
    if W > 0 {
        // SAFETY: `W > 0` only on the paths `InstructionSet::Avx2` and `InstructionSet::Avx512` select,
        // which run on CPUs that report AVX2.
        return unsafe { block_test_avx2(b, shear, tmax, out) };
    }
    block_test_lanes(b, shear, tmax, out)
}

/// Blocks `a` and `b` in sixteen lanes (`a` in lanes 0..8): only on the AVX-512 path.
#[inline(always)]
fn pair_test(a: &Block, b: &Block, shear: &RayShear, tmax: f32, out: &mut Lanes) -> (u32, u32) {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: called only from `each_hit::<_, WIDE>`, on the paths `InstructionSet::Avx512`
        // selects, which run on CPUs that report AVX2 and AVX-512F.
        unsafe { pair_test_avx512(a, b, shear, tmax, out) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (a, b, shear, tmax, out);
        unreachable!("sixteen-lane tests run on x86_64 only")
    }
}

/// [`block_test_avx2`] for two blocks at once in AVX-512 ([`watertight_avx512`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f")]
#[inline]
fn pair_test_avx512(a: &Block, b: &Block, shear: &RayShear, tmax: f32, out: &mut Lanes) -> (u32, u32) {
    use core::arch::x86_64::*;
    let ([kx, ky, kz], _, _) = shear.parts();
    // SAFETY: as in `block_test_avx2`, for both blocks.
    let ld = |v: usize, k: usize| unsafe {
        let lo = _mm256_load_ps(a.p.get_unchecked(v).get_unchecked(k).as_ptr());
        let hi = _mm256_load_ps(b.p.get_unchecked(v).get_unchecked(k).as_ptr());
        // (AVX-512F has no `vinsertf32x8`; the 64-bit form moves the same 256 bits.)
        _mm512_castpd_ps(_mm512_insertf64x4::<1>(_mm512_castpd256_pd512(_mm256_castps_pd(lo)), _mm256_castps_pd(hi)))
    };
    let p = [ld(0, kx), ld(0, ky), ld(0, kz), ld(1, kx), ld(1, ky), ld(1, kz), ld(2, kx), ld(2, ky), ld(2, kz)];
    watertight_avx512(&p, shear, tmax, out)
}

/// Bit masks of the lanes whose triangle the watertight test may accept with `tmax`
/// (`keep`, see the module comment), and of those with an edge function exactly zero
/// (`zero`, a subset of `keep`: they need the scalar test). Fills `out` for the others.
/// Written lane-wise without branches so that it vectorises.
#[inline(always)]
fn block_test_lanes(b: &Block, shear: &RayShear, tmax: f32, out: &mut Lanes) -> (u32, u32) {
    let ([kx, ky, kz], [sx, sy, sz], [ox, oy, oz]) = shear.parts();
    let (p0, p1, p2) = (&b.p[0], &b.p[1], &b.p[2]);
    let (p0x, p0y, p0z) = (&p0[kx], &p0[ky], &p0[kz]);
    let (p1x, p1y, p1z) = (&p1[kx], &p1[ky], &p1[kz]);
    let (p2x, p2y, p2z) = (&p2[kx], &p2[ky], &p2[kz]);
    // Lane l's verdict as bit l, combined below by OR: shifts and ORs vectorise, where
    // packing an array of bools into a mask did not.
    let mut keep = [0u32; LANES];
    let mut zeros = [0u32; LANES];
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
        zeros[l] = u32::from(zero) << l;
        (out.v[l], out.w[l], out.det[l], out.t_scaled[l]) = (v, w, det, t_scaled);
    }
    (keep.iter().fold(0, |m, &k| m | k), zeros.iter().fold(0, |m, &k| m | k))
}

/// [`block_test_lanes`] in AVX2 intrinsics ([`watertight_avx2`]): the same bits, with
/// the verdicts gathered by one `movemask` instead of shifts and ORs.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn block_test_avx2(b: &Block, shear: &RayShear, tmax: f32, out: &mut Lanes) -> (u32, u32) {
    use core::arch::x86_64::*;
    let ([kx, ky, kz], _, _) = shear.parts();
    // SAFETY: `Block` is 32-byte aligned and each `[f32; 8]` row starts at a multiple of
    // 32 bytes in it; kx, ky, kz are a permutation of 0, 1, 2 (`RayShear::for_ray`).
    let ld = |v: usize, k: usize| unsafe { _mm256_load_ps(b.p.get_unchecked(v).get_unchecked(k).as_ptr()) };
    let p = [ld(0, kx), ld(0, ky), ld(0, kz), ld(1, kx), ld(1, ky), ld(1, kz), ld(2, kx), ld(2, ky), ld(2, kz)];
    watertight_avx2(&p, shear, tmax, out)
}

/// Bit mask of the lanes of a sphere block whose sphere the ray's line may meet: the
/// discriminant of [`intersect_sphere`] with the same operations in the same order, so a
/// lane is dropped only where the scalar test returns at its first check (`disc < 0`).
/// `a` is `|d|²` as the scalar test computes it.
///
/// [`intersect_sphere`]: crate::geometry::sphere::intersect_sphere
/// [`sphere_candidates`] with the instruction set chosen at compile time.
#[inline(always)]
fn sphere_pretest<const W: usize>(b: &SphereBlock, ray: &Ray, a: f32) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if W > 0 {
        // SAFETY: as in `block_test`.
        return unsafe { sphere_candidates_avx2(b, ray, a) };
    }
    sphere_candidates(b, ray, a)
}

/// [`sphere_candidates`] in AVX2 intrinsics, the same IEEE operations in the same order
/// (the compiler left the lane loop scalar: ~130 instructions a block). `!(disc < 0)`
/// is the unordered not-less-than predicate (true for NaN, like the scalar negation).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn sphere_candidates_avx2(b: &SphereBlock, ray: &Ray, a: f32) -> u32 {
    use core::arch::x86_64::*;
    let (o, d) = (ray.origin, ray.dir);
    // SAFETY: `SphereBlock` is 32-byte aligned and each `[f32; 8]` row starts at a
    // multiple of 32 bytes in it.
    let ld = |row: &[f32; LANES]| unsafe { _mm256_load_ps(row.as_ptr()) };
    let (dx, dy, dz) = (_mm256_set1_ps(d.x), _mm256_set1_ps(d.y), _mm256_set1_ps(d.z));
    let fx = _mm256_sub_ps(_mm256_set1_ps(o.x), ld(&b.c[0]));
    let fy = _mm256_sub_ps(_mm256_set1_ps(o.y), ld(&b.c[1]));
    let fz = _mm256_sub_ps(_mm256_set1_ps(o.z), ld(&b.c[2]));
    let dot = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(fx, dx), _mm256_mul_ps(fy, dy)), _mm256_mul_ps(fz, dz));
    // Negation flips the sign bit (as `-x` does, also for zeros).
    let bq = _mm256_xor_ps(dot, _mm256_set1_ps(-0.0));
    let s = _mm256_div_ps(bq, _mm256_set1_ps(a));
    let lx = _mm256_add_ps(fx, _mm256_mul_ps(s, dx));
    let ly = _mm256_add_ps(fy, _mm256_mul_ps(s, dy));
    let lz = _mm256_add_ps(fz, _mm256_mul_ps(s, dz));
    let r = ld(&b.r);
    let ll = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(lx, lx), _mm256_mul_ps(ly, ly)), _mm256_mul_ps(lz, lz));
    let disc = _mm256_mul_ps(_mm256_set1_ps(a), _mm256_sub_ps(_mm256_mul_ps(r, r), ll));
    _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_NLT_UQ>(disc, _mm256_setzero_ps())) as u32
}

#[inline(always)]
fn sphere_candidates(b: &SphereBlock, ray: &Ray, a: f32) -> u32 {
    let (o, d) = (ray.origin, ray.dir);
    let mut keep = [0u32; LANES];
    for (l, k) in keep.iter_mut().enumerate() {
        // f = o - c; b = -f·d; l = f + (b / a) d; disc = a (r² - l·l), as glam's scalar
        // Vec3 evaluates them: dot products summed x, y, then z.
        let (fx, fy, fz) = (o.x - b.c[0][l], o.y - b.c[1][l], o.z - b.c[2][l]);
        let bq = -(fx * d.x + fy * d.y + fz * d.z);
        let s = bq / a;
        let (lx, ly, lz) = (fx + s * d.x, fy + s * d.y, fz + s * d.z);
        let r = b.r[l];
        let disc = a * (r * r - (lx * lx + ly * ly + lz * lz));
        *k = u32::from(!(disc < 0.0)) << l;
    }
    keep.iter().fold(0, |m, &k| m | k)
}

#[cfg(test)]
pub(super) mod tests;
