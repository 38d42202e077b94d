//! The watertight triangle test for eight (AVX2) or sixteen (AVX-512) triangles at once,
//! bit for bit the scalar test's ([`intersect_triangle_corners`]): shared by the
//! brute-force blocks of small scenes ([`super::triangle_blocks`], corners stored lane by lane;
//! with AVX-512 two blocks at a time) and the kd-tree's leaves (eight lanes, corners
//! loaded by index from the scene's triangles).
//!
//! The lane pass repeats the first half of the scalar test with the same IEEE
//! operations in the same order (no fused multiply-adds: Rust does not contract
//! `a * b + c`), so its edge functions `u, v, w`, `det` and `t·det` are the scalar test's
//! bits. It keeps a lane when the scalar test could accept it with the pass's `tmax`, or
//! when an edge function is exactly zero (where the scalar test switches to double
//! precision, so the caller runs the scalar test itself). A kept lane then finishes from
//! the stored values with the caller's current `tmax` ([`Lanes::finish`], the scalar
//! test's own last step): since a smaller `tmax` only rejects more, that is exactly the
//! scalar test.
//!
//! [`intersect_triangle_corners`]: crate::geometry::triangle::intersect_triangle_corners

use glam::Vec3;

use super::PrimHit;
use crate::geometry::triangle::{RayShear, finish_watertight};

/// Lanes of an AVX2 pass (and of a brute-force block).
pub(crate) const LANES: usize = 8;

/// Lanes of an AVX-512 pass.
pub(crate) const WIDE: usize = 16;

/// Which instruction set the lane tests run with, decided once per structure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum InstructionSet {
    Baseline,
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// Sixteen lanes (AVX-512F and VL); the rest of the query is compiled for AVX2 as
    /// well.
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl InstructionSet {
    /// For reports: `portable`, `AVX2` or `AVX-512`.
    pub(crate) fn name(self) -> &'static str {
        match self {
            InstructionSet::Baseline => "portable",
            #[cfg(target_arch = "x86_64")]
            InstructionSet::Avx2 => "AVX2",
            #[cfg(target_arch = "x86_64")]
            InstructionSet::Avx512 => "AVX-512",
        }
    }

    /// The widest the CPU has, unless `TILEFARM_SIMD` (`baseline`, `avx2`) asks for
    /// less: for comparing the paths (their answers are the same bits).
    #[inline]
    pub(crate) fn detect() -> Self {
        let cap = std::env::var("TILEFARM_SIMD").unwrap_or_default();
        #[cfg(target_arch = "x86_64")]
        {
            let avx2 = std::is_x86_feature_detected!("avx2") && cap != "baseline";
            // VL as well: the eight-lane kernels then use its 32 vector registers.
            let avx512 = std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512vl");
            if avx2 && avx512 && cap != "avx2" {
                return InstructionSet::Avx512;
            }
            if avx2 {
                return InstructionSet::Avx2;
            }
        }
        let _ = cap;
        InstructionSet::Baseline
    }
}

/// The first half of the watertight test for up to sixteen lanes: the edge functions,
/// `det` and `t·det`, bit for bit the scalar test's (an AVX2 pass fills the first eight).
#[derive(Clone, Copy, Default)]
#[repr(C, align(64))]
pub(crate) struct Lanes {
    pub(crate) v: [f32; WIDE],
    pub(crate) w: [f32; WIDE],
    pub(crate) det: [f32; WIDE],
    pub(crate) t_scaled: [f32; WIDE],
}

impl Lanes {
    /// The rest of the scalar test for `lane` with `tmax`, from the stored values (the
    /// lane's edge functions are all nonzero and of one sign, `det != 0`).
    #[inline(always)]
    pub(crate) fn finish(&self, lane: usize, tmax: f32) -> Option<PrimHit> {
        finish_watertight(self.v[lane], self.w[lane], self.det[lane], self.t_scaled[lane], tmax).map(|h| PrimHit {
            t: h.t,
            u: h.b1,
            v: h.b2,
            sub: 0,
        })
    }
}

/// The arithmetic of the lane pass, the same for every width: the corners relative to
/// the origin, sheared; the edge functions; `det`, `t·det` and `tmax·det`. `$p` holds the
/// nine permuted coordinate vectors (see [`watertight_avx2`]), the rest name one width's
/// `set1`, `sub`, `mul` and `add`. The `@lanes` form takes the shear `[sx, sy, sz]`, the
/// permuted origin `[ox, oy, oz]` and `tmax` as vectors, one ray per lane (see
/// `accel/ray_packets.rs`); the other broadcasts one ray's.
macro_rules! lane_arithmetic {
    ($p:expr, $shear:expr, $tmax:expr, $set1:ident, $sub:ident, $mul:ident, $add:ident) => {{
        let (_, [sx, sy, sz], [ox, oy, oz]) = $shear.parts();
        lane_arithmetic!(@lanes $p, [$set1(sx), $set1(sy), $set1(sz)], [$set1(ox), $set1(oy), $set1(oz)],
            $set1($tmax), $sub, $mul, $add)
    }};
    (@lanes $p:expr, $s:expr, $o:expr, $tmax:expr, $sub:ident, $mul:ident, $add:ident) => {{
        let p = $p;
        let s = $s;
        let o = $o;
        let a = lane_arithmetic!(@corner [p[0], p[1], p[2]], s, o, $sub, $mul);
        let b = lane_arithmetic!(@corner [p[3], p[4], p[5]], s, o, $sub, $mul);
        let c = lane_arithmetic!(@corner [p[6], p[7], p[8]], s, o, $sub, $mul);
        lane_arithmetic!(@sheared a, b, c, $tmax, $sub, $mul, $add)
    }};
    // One corner relative to the origin and sheared: `[x, y, sz · z]`.
    (@corner $p:expr, $s:expr, $o:expr, $sub:ident, $mul:ident) => {{
        let [px, py, pz] = $p;
        let [sx, sy, sz] = $s;
        let [ox, oy, oz] = $o;
        let (x, y, z) = ($sub(px, ox), $sub(py, oy), $sub(pz, oz));
        [$sub(x, $mul(sx, z)), $sub(y, $mul(sy, z)), $mul(sz, z)]
    }};
    // The rest from the three sheared corners.
    (@sheared $a:expr, $b:expr, $c:expr, $tmax:expr, $sub:ident, $mul:ident, $add:ident) => {{
        let [ax, ay, az] = $a;
        let [bx, by, bz] = $b;
        let [cx, cy, cz] = $c;
        let u = $sub($mul(cx, by), $mul(cy, bx));
        let v = $sub($mul(ax, cy), $mul(ay, cx));
        let w = $sub($mul(bx, ay), $mul(by, ax));
        let det = $add($add(u, v), w);
        let t_scaled = $add($add($mul(u, az), $mul(v, bz)), $mul(w, cz));
        let limit = $mul($tmax, det);
        (u, v, w, det, t_scaled, limit)
    }};
}
pub(crate) use lane_arithmetic;

/// The eight-lane pass in AVX2 from the corners' coordinates on the shear's permuted
/// axes: `p[3 v + j]` holds corner `v`'s coordinate on axis `k_j` (`(kx, ky, kz)` of
/// [`RayShear::parts`]) for each lane. Returns the bit masks `(keep, zero)` (see the
/// module comment; `zero` is a subset of `keep`) and fills `out` for the other kept
/// lanes. Comparisons use the predicates of Rust's operators: ordered for `<`, `>`,
/// `<=`, `>=`, `==`; unordered for `!=`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn watertight_avx2(
    p: &[core::arch::x86_64::__m256; 9],
    shear: &RayShear,
    tmax: f32,
    out: &mut Lanes,
) -> (u32, u32) {
    use core::arch::x86_64::*;
    let (u, v, w, det, t_scaled, limit) =
        lane_arithmetic!(p, shear, tmax, _mm256_set1_ps, _mm256_sub_ps, _mm256_mul_ps, _mm256_add_ps);
    let (keep, zero) = watertight_masks_avx2(u, v, w, det, t_scaled, limit);
    // SAFETY: `Lanes` is 64-byte aligned and its rows are [f32; 16] (the first eight
    // are written).
    unsafe {
        _mm256_store_ps(out.v.as_mut_ptr(), v);
        _mm256_store_ps(out.w.as_mut_ptr(), w);
        _mm256_store_ps(out.det.as_mut_ptr(), det);
        _mm256_store_ps(out.t_scaled.as_mut_ptr(), t_scaled);
    }
    (_mm256_movemask_ps(keep) as u32, _mm256_movemask_ps(zero) as u32)
}

/// The verdicts of the lane pass from its arithmetic, as lane masks: `keep`, the lanes
/// whose triangle the scalar test may accept with the pass's `tmax` or that have an edge
/// function exactly zero, and `zero`, the latter (a subset of `keep`). Comparisons use
/// the predicates of Rust's operators: ordered for `<`, `>`, `<=`, `>=`, `==`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn watertight_masks_avx2(
    u: core::arch::x86_64::__m256,
    v: core::arch::x86_64::__m256,
    w: core::arch::x86_64::__m256,
    det: core::arch::x86_64::__m256,
    t_scaled: core::arch::x86_64::__m256,
    limit: core::arch::x86_64::__m256,
) -> (core::arch::x86_64::__m256, core::arch::x86_64::__m256) {
    use core::arch::x86_64::*;
    let z = _mm256_setzero_ps();
    let or = |a, b| _mm256_or_ps(a, b);
    let and = |a, b| _mm256_and_ps(a, b);
    let zero =
        or(or(_mm256_cmp_ps::<_CMP_EQ_OQ>(u, z), _mm256_cmp_ps::<_CMP_EQ_OQ>(v, z)), _mm256_cmp_ps::<_CMP_EQ_OQ>(w, z));
    let neg =
        or(or(_mm256_cmp_ps::<_CMP_LT_OQ>(u, z), _mm256_cmp_ps::<_CMP_LT_OQ>(v, z)), _mm256_cmp_ps::<_CMP_LT_OQ>(w, z));
    let pos =
        or(or(_mm256_cmp_ps::<_CMP_GT_OQ>(u, z), _mm256_cmp_ps::<_CMP_GT_OQ>(v, z)), _mm256_cmp_ps::<_CMP_GT_OQ>(w, z));
    let mixed = and(neg, pos);
    let out_neg = and(
        _mm256_cmp_ps::<_CMP_LT_OQ>(det, z),
        or(_mm256_cmp_ps::<_CMP_GE_OQ>(t_scaled, z), _mm256_cmp_ps::<_CMP_LT_OQ>(t_scaled, limit)),
    );
    let out_pos = and(
        _mm256_cmp_ps::<_CMP_GT_OQ>(det, z),
        or(_mm256_cmp_ps::<_CMP_LE_OQ>(t_scaled, z), _mm256_cmp_ps::<_CMP_GT_OQ>(t_scaled, limit)),
    );
    // !mixed & det != 0 & !out_neg & !out_pos, as and-nots of the rejections.
    let rejected = or(or(mixed, _mm256_cmp_ps::<_CMP_EQ_OQ>(det, z)), or(out_neg, out_pos));
    let keep = or(zero, _mm256_andnot_ps(rejected, _mm256_castsi256_ps(_mm256_set1_epi32(-1))));
    (keep, zero)
}

/// [`watertight_avx2`] for sixteen lanes in AVX-512: the same predicates, as mask
/// registers; returns `(keep, zero)` and fills all sixteen lanes of `out`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f")]
#[inline]
pub(crate) fn watertight_avx512(
    p: &[core::arch::x86_64::__m512; 9],
    shear: &RayShear,
    tmax: f32,
    out: &mut Lanes,
) -> (u32, u32) {
    use core::arch::x86_64::*;
    let (u, v, w, det, t_scaled, limit) =
        lane_arithmetic!(p, shear, tmax, _mm512_set1_ps, _mm512_sub_ps, _mm512_mul_ps, _mm512_add_ps);
    let z = _mm512_setzero_ps();
    let eq = |a, b| _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(a, b);
    let lt = |a, b| _mm512_cmp_ps_mask::<_CMP_LT_OQ>(a, b);
    let gt = |a, b| _mm512_cmp_ps_mask::<_CMP_GT_OQ>(a, b);
    let zero = eq(u, z) | eq(v, z) | eq(w, z);
    let mixed = (lt(u, z) | lt(v, z) | lt(w, z)) & (gt(u, z) | gt(v, z) | gt(w, z));
    let out_neg = lt(det, z) & (_mm512_cmp_ps_mask::<_CMP_GE_OQ>(t_scaled, z) | lt(t_scaled, limit));
    let out_pos = gt(det, z) & (_mm512_cmp_ps_mask::<_CMP_LE_OQ>(t_scaled, z) | gt(t_scaled, limit));
    let rejected = mixed | eq(det, z) | out_neg | out_pos;
    let keep = zero | !rejected;
    // SAFETY: `Lanes` is 64-byte aligned and its rows are [f32; 16].
    unsafe {
        _mm512_store_ps(out.v.as_mut_ptr(), v);
        _mm512_store_ps(out.w.as_mut_ptr(), w);
        _mm512_store_ps(out.det.as_mut_ptr(), det);
        _mm512_store_ps(out.t_scaled.as_mut_ptr(), t_scaled);
    }
    (keep as u32, zero as u32)
}

/// Most triangles [`gather_avx2`] can address: indices are compared as `i32`s.
pub(crate) const GATHER_MAX_TRIANGLES: usize = i32::MAX as usize;

// `load_corners` reads a triangle as nine contiguous floats.
const _: () = assert!(size_of::<[Vec3; 3]>() == 9 * size_of::<f32>());

/// Up to eight primitives loaded for the eight-lane pass ([`gather_avx2`]): once for a
/// leaf that several rays of a packet test.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct Gathered {
    /// The triangles' corners, `[corner][axis]`, lane by lane (other lanes: the first
    /// triangle's, or zeros when `tri` is empty).
    c: [[core::arch::x86_64::__m256; 3]; 3],
    /// The lanes holding triangles; empty when fewer than two do.
    tri: u32,
    /// The lanes the caller tests itself.
    other: u32,
}

/// Loads primitives `ids` (at most eight) of a set whose first `corners.len()` are the
/// triangles `corners` (at most [`GATHER_MAX_TRIANGLES`]): the triangles' corners by
/// index ([`load_corners`]), unless fewer than two are triangles (a leaf of spheres),
/// which are then all left to the caller.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn gather_avx2(corners: &[[Vec3; 3]], ids: &[u32]) -> Gathered {
    use core::arch::x86_64::*;
    assert!(ids.len() <= LANES && corners.len() <= GATHER_MAX_TRIANGLES);
    let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let valid = _mm256_cmpgt_epi32(_mm256_set1_epi32(ids.len() as i32), lane);
    // SAFETY: the masked load reads only lanes `< ids.len()`, inside `ids`.
    let idx = unsafe { _mm256_maskload_epi32(ids.as_ptr().cast(), valid) };
    // Indices are below 2^32; those at or above 2^31 compare negative, so they also
    // need `idx >= 0` to count as triangles.
    let ntri = _mm256_set1_epi32(corners.len() as i32);
    let below = _mm256_andnot_si256(_mm256_cmpgt_epi32(_mm256_setzero_si256(), idx), _mm256_cmpgt_epi32(ntri, idx));
    let tri = _mm256_and_si256(valid, below);
    let other = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_andnot_si256(tri, valid))) as u32;
    let tri_lanes = _mm256_movemask_ps(_mm256_castsi256_ps(tri)) as u32;
    // With fewer than two triangles the pass is not worth its loads and transposes.
    if tri_lanes.count_ones() < 2 {
        return Gathered { c: [[_mm256_setzero_ps(); 3]; 3], tri: 0, other: (1 << ids.len()) - 1 };
    }
    // The triangles' indices (lanes not tested: 0, the first triangle).
    let mut tris = [0u32; LANES];
    // SAFETY: `tris` is 32 bytes.
    unsafe { _mm256_storeu_si256(tris.as_mut_ptr().cast(), _mm256_and_si256(tri, idx)) };
    // SAFETY: every index is below `corners.len()` (`tri`, or 0 with `corners` not
    // empty: `tri` has lanes).
    let c = unsafe { load_corners(corners, &tris) };
    Gathered { c, tri: tri_lanes, other }
}

/// The eight-lane pass over primitives loaded by [`gather_avx2`], for one ray. Returns
/// `(keep, zero, other)` by lane (lane `l` is the `l`-th primitive loaded): `keep` and
/// `zero` as [`watertight_avx2`]'s for the triangles, `other` the lanes the caller tests
/// itself: those whose primitive is not a triangle, or all when fewer than two are.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn gathered_test_avx2(g: &Gathered, shear: &RayShear, tmax: f32, out: &mut Lanes) -> (u32, u32, u32) {
    if g.tri == 0 {
        return (0, 0, g.other);
    }
    let c = &g.c;
    let ([kx, ky, kz], _, _) = shear.parts();
    let p = [c[0][kx], c[0][ky], c[0][kz], c[1][kx], c[1][ky], c[1][kz], c[2][kx], c[2][ky], c[2][kz]];
    let (keep, zero) = watertight_avx2(&p, shear, tmax, out);
    (keep & g.tri, zero & g.tri, g.other)
}

/// The corners of triangles `tris` as `[corner][axis]` vectors of the eight lanes:
/// sixteen-byte loads put together by a 4×4 transpose in each half. Eight-lane gathers
/// (nine of them) did the same at 39 micro-ops each on Zen 3: `KDTREE_AB` with gathers
/// as A, 1M mesh, medians of 200 slice pairs: closest-hit 1.14 and 1.11, any-hit 1.10
/// and 1.06; 100k mesh 1.21 and 1.19.
///
/// # Safety
/// Every index is below `corners.len()`; AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn load_corners(corners: &[[Vec3; 3]], tris: &[u32; LANES]) -> [[core::arch::x86_64::__m256; 3]; 3] {
    use core::arch::x86_64::*;
    // Loops, not closures: a closure does not inherit `target_feature`, and these were
    // not inlined.
    let mut out = [[_mm256_setzero_ps(); 3]; 3];
    for (c, out) in out.iter_mut().enumerate() {
        // Corner 2 is read from the triangle's float 5 on, so that no load runs past its
        // nine floats: its coordinates are then columns 1 to 3.
        let start = 3 * c - usize::from(c == 2);
        let mut r = [_mm256_setzero_ps(); 4];
        for (j, r) in r.iter_mut().enumerate() {
            // SAFETY: `tris[j]` indexes `corners` (the caller's promise), whose elements
            // are nine contiguous floats; the loads read floats `start .. start + 4 <= 9`
            // of one element.
            *r = unsafe {
                let lo = _mm_loadu_ps(corners.as_ptr().add(tris[j] as usize).cast::<f32>().add(start));
                let hi = _mm_loadu_ps(corners.as_ptr().add(tris[j + 4] as usize).cast::<f32>().add(start));
                _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(lo), hi)
            };
        }
        let (t0, t1) = (_mm256_unpacklo_ps(r[0], r[1]), _mm256_unpackhi_ps(r[0], r[1]));
        let (t2, t3) = (_mm256_unpacklo_ps(r[2], r[3]), _mm256_unpackhi_ps(r[2], r[3]));
        let col = [
            _mm256_shuffle_ps::<0x44>(t0, t2),
            _mm256_shuffle_ps::<0xee>(t0, t2),
            _mm256_shuffle_ps::<0x44>(t1, t3),
            _mm256_shuffle_ps::<0xee>(t1, t3),
        ];
        let k = usize::from(c == 2);
        *out = [col[k], col[k + 1], col[k + 2]];
    }
    out
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::geometry::triangle::intersect_triangle_corners;

    struct Rng(u64);

    impl Rng {
        fn f(&mut self) -> f32 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (self.0 >> 40) as f32 / (1u64 << 24) as f32
        }
        fn v(&mut self) -> Vec3 {
            Vec3::new(self.f(), self.f(), self.f()) * 2.0 - 1.0
        }
    }

    /// Lane by lane, the gathered pass and its finish give the scalar test's bits; lanes
    /// past the ids or not triangles are never kept, and the latter are reported.
    #[test]
    fn gathered_lanes_are_the_scalar_test() {
        crate::simd::tests::require_avx2();
        let mut r = Rng(3);
        // Small triangles around the origin, some sharing corners (edges: zero lanes).
        let corners: Vec<[Vec3; 3]> = (0..64)
            .map(|i| {
                let a = r.v() * 0.5;
                if i % 7 == 0 { [a, Vec3::ZERO, Vec3::X * 0.5] } else { [a, a + r.v() * 0.6, a + r.v() * 0.6] }
            })
            .collect();
        let (mut kept, mut hits, mut zeros) = (0, 0, 0);
        for q in 0..4000 {
            let o = r.v() * 3.0;
            let d = if q % 5 == 0 { -o } else { (r.v() * 0.5 - o).normalize() };
            let shear = RayShear::for_ray(o, d);
            let tmax = if q % 3 == 0 { f32::INFINITY } else { 1.0 + 4.0 * r.f() };
            let n = 1 + q % LANES;
            // Ids past the triangles stand for other primitives.
            let ids: Vec<u32> = (0..n).map(|_| (r.f() * 72.0) as u32).collect();
            let mut lanes = Lanes::default();
            // SAFETY: AVX2 was detected above.
            let (keep, zero, other) =
                unsafe { gathered_test_avx2(&gather_avx2(&corners, &ids), &shear, tmax, &mut lanes) };
            assert_eq!((keep | zero | other) >> n, 0, "lanes past the ids");
            assert_eq!(zero & !keep, 0);
            for (l, &id) in ids.iter().enumerate() {
                let bit = 1 << l;
                if other & bit != 0 {
                    // Not a triangle, or the group had too few to be worth the pass.
                    let tris = ids.iter().filter(|&&i| (i as usize) < corners.len()).count();
                    assert!(keep & bit == 0 && (id as usize >= corners.len() || tris < 2));
                    continue;
                }
                assert!((id as usize) < corners.len());
                let scalar = intersect_triangle_corners(&shear, &corners[id as usize], tmax);
                if keep & bit == 0 {
                    assert!(scalar.is_none(), "dropped a hit: ray {q} lane {l}");
                    continue;
                }
                kept += 1;
                if zero & bit != 0 {
                    zeros += 1;
                    continue;
                }
                let got = lanes.finish(l, tmax).map(|h| (h.t.to_bits(), h.u.to_bits(), h.v.to_bits()));
                let want = scalar.map(|h| (h.t.to_bits(), h.b1.to_bits(), h.b2.to_bits()));
                assert_eq!(got, want, "ray {q} lane {l}");
                hits += usize::from(got.is_some());
            }
        }
        // The test means something: lanes were kept, hit, and some on an edge.
        assert!(kept > 500 && hits > 300 && zeros > 0, "kept {kept}, hits {hits}, zero {zeros}");
    }
}
