//! The watertight triangle test for eight triangles at once, bit for bit the scalar
//! test's ([`intersect_triangle_corners`]): shared by the brute-force blocks of small
//! scenes ([`super::packed`], corners stored lane by lane) and the kd-tree's leaves
//! (corners gathered by index from the scene's triangles).
//!
//! The eight-lane pass repeats the first half of the scalar test with the same IEEE
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

pub(crate) const LANES: usize = 8;

/// Which instruction set the eight-lane tests run with, decided once per structure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Simd {
    Baseline,
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl Simd {
    #[inline]
    pub(crate) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            return Simd::Avx2;
        }
        Simd::Baseline
    }
}

/// The first half of the watertight test for eight lanes: the edge functions, `det`
/// and `t·det`, bit for bit the scalar test's.
#[derive(Clone, Copy, Default)]
#[repr(C, align(32))]
pub(crate) struct Lanes {
    pub(crate) v: [f32; LANES],
    pub(crate) w: [f32; LANES],
    pub(crate) det: [f32; LANES],
    pub(crate) t_scaled: [f32; LANES],
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
        })
    }
}

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
    let (_, [sx, sy, sz], [ox, oy, oz]) = shear.parts();
    let (ox, oy, oz) = (_mm256_set1_ps(ox), _mm256_set1_ps(oy), _mm256_set1_ps(oz));
    let (sx, sy, sz) = (_mm256_set1_ps(sx), _mm256_set1_ps(sy), _mm256_set1_ps(sz));
    let (a_x, a_y, a_z) = (_mm256_sub_ps(p[0], ox), _mm256_sub_ps(p[1], oy), _mm256_sub_ps(p[2], oz));
    let (b_x, b_y, b_z) = (_mm256_sub_ps(p[3], ox), _mm256_sub_ps(p[4], oy), _mm256_sub_ps(p[5], oz));
    let (c_x, c_y, c_z) = (_mm256_sub_ps(p[6], ox), _mm256_sub_ps(p[7], oy), _mm256_sub_ps(p[8], oz));
    let ax = _mm256_sub_ps(a_x, _mm256_mul_ps(sx, a_z));
    let ay = _mm256_sub_ps(a_y, _mm256_mul_ps(sy, a_z));
    let bx = _mm256_sub_ps(b_x, _mm256_mul_ps(sx, b_z));
    let by = _mm256_sub_ps(b_y, _mm256_mul_ps(sy, b_z));
    let cx = _mm256_sub_ps(c_x, _mm256_mul_ps(sx, c_z));
    let cy = _mm256_sub_ps(c_y, _mm256_mul_ps(sy, c_z));
    let u = _mm256_sub_ps(_mm256_mul_ps(cx, by), _mm256_mul_ps(cy, bx));
    let v = _mm256_sub_ps(_mm256_mul_ps(ax, cy), _mm256_mul_ps(ay, cx));
    let w = _mm256_sub_ps(_mm256_mul_ps(bx, ay), _mm256_mul_ps(by, ax));
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
    let det = _mm256_add_ps(_mm256_add_ps(u, v), w);
    let t_scaled = _mm256_add_ps(
        _mm256_add_ps(_mm256_mul_ps(u, _mm256_mul_ps(sz, a_z)), _mm256_mul_ps(v, _mm256_mul_ps(sz, b_z))),
        _mm256_mul_ps(w, _mm256_mul_ps(sz, c_z)),
    );
    let limit = _mm256_mul_ps(_mm256_set1_ps(tmax), det);
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
    // SAFETY: `Lanes` is 32-byte aligned and its rows are [f32; 8].
    unsafe {
        _mm256_store_ps(out.v.as_mut_ptr(), v);
        _mm256_store_ps(out.w.as_mut_ptr(), w);
        _mm256_store_ps(out.det.as_mut_ptr(), det);
        _mm256_store_ps(out.t_scaled.as_mut_ptr(), t_scaled);
    }
    (_mm256_movemask_ps(keep) as u32, _mm256_movemask_ps(zero) as u32)
}

/// Most triangles [`gather_test_avx2`] can address: lane offsets `9 i + 8` into the
/// corners' floats must fit an `i32`.
pub(crate) const GATHER_MAX_TRIANGLES: usize = (i32::MAX as usize - 8) / 9;

/// The eight-lane pass over primitives `ids` (at most eight) of a set whose first
/// `corners.len()` primitives are the triangles `corners` (at most
/// [`GATHER_MAX_TRIANGLES`]): their corners are gathered by index. Returns `(keep, zero,
/// other)` by lane (lane `l` is `ids[l]`): `keep` and `zero` as [`watertight_avx2`]'s
/// for the triangles, `other` the lanes the caller tests itself: those whose primitive
/// is not a triangle, or all when fewer than two are.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn gather_test_avx2(
    corners: &[[Vec3; 3]],
    ids: &[u32],
    shear: &RayShear,
    tmax: f32,
    out: &mut Lanes,
) -> (u32, u32, u32) {
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
    // With fewer than two triangles (a leaf of spheres) the pass is not worth its nine
    // gathers: the caller tests them all.
    if (_mm256_movemask_ps(_mm256_castsi256_ps(tri)) as u32).count_ones() < 2 {
        return (0, 0, (1 << ids.len()) - 1);
    }
    // Float offset of each triangle's first corner: 9 i (lanes not gathered: 0).
    let base_off = _mm256_and_si256(tri, _mm256_add_epi32(_mm256_slli_epi32::<3>(idx), idx));
    let ([kx, ky, kz], _, _) = shear.parts();
    let base = corners.as_ptr().cast::<f32>();
    let mask = _mm256_castsi256_ps(tri);
    let gather = |v: usize, k: usize| {
        let off = _mm256_add_epi32(base_off, _mm256_set1_epi32((3 * v + k) as i32));
        // SAFETY: only lanes of `tri` load, at 9 i + 3 v + k < 9 corners.len() floats of
        // `corners` (i < corners.len(), v, k < 3); the offsets fit in i32.
        unsafe { _mm256_mask_i32gather_ps::<4>(_mm256_setzero_ps(), base, off, mask) }
    };
    let p = [
        gather(0, kx),
        gather(0, ky),
        gather(0, kz),
        gather(1, kx),
        gather(1, ky),
        gather(1, kz),
        gather(2, kx),
        gather(2, ky),
        gather(2, kz),
    ];
    let (keep, zero) = watertight_avx2(&p, shear, tmax, out);
    let tri = _mm256_movemask_ps(mask) as u32;
    (keep & tri, zero & tri, other)
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
        if !std::is_x86_feature_detected!("avx2") {
            return;
        }
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
            let (keep, zero, other) = unsafe { gather_test_avx2(&corners, &ids, &shear, tmax, &mut lanes) };
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
