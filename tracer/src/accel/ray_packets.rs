//! Eight rays at once against a small scene's primitives, by brute force: the ray
//! queries of the eight-path renderer (`integrator/eight_paths.rs`).
//!
//! [`PackedTriangles`]' one-ray queries test a ray against eight triangles at a time and
//! then finish the lanes that pass one by one; most of a query's instructions are that
//! per-ray work around the block tests. Here each lane is a ray, and the primitives come
//! one at a time, broadcast to all lanes: the shear, the loop and the finishing step are
//! shared by eight rays, and the whole test stays in vectors. Brute force does not care
//! whether the rays are coherent.
//!
//! Exactness. Lane `l` runs brute force's loop for its own ray: every primitive in index
//! order, tested with the lane's current `tmax`, with the scalar tests' IEEE operations
//! in the same order (for triangles, the corners permuted by the lane's own shear; for
//! spheres, [`intersect_sphere`]'s operations), so each lane's answer is exactly
//! [`brute_force_intersect`] / [`brute_force_occluded`] of its ray, whichever rays share
//! the packet. A lane with an edge function exactly zero runs the scalar test itself (it
//! switches to double precision there). Triangles come in runs of consecutive indices
//! (`triangle_blocks/runs.rs`); a run whose box none of the searching lanes can reach
//! within its `tmax` holds no hit for any of them and is skipped, which keeps the order.
//!
//! [`intersect_sphere`]: crate::geometry::sphere::intersect_sphere
//! [`brute_force_intersect`]: super::brute_force_intersect
//! [`brute_force_occluded`]: super::brute_force_occluded

use core::arch::x86_64::*;

use glam::Vec3;

use super::block_test::{InstructionSet, lane_arithmetic};
use super::triangle_blocks::{MARGIN, PackedTriangles};
use super::{Hit, Primitives, RayPrecomp};
use crate::geometry::{Aabb, Ray};

/// Rays in a packet.
pub const PACKET: usize = 8;

/// Eight rays, structure of arrays, with the distance each query may reach. Lanes not in
/// `active` are ignored (their values need not be rays).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub struct RayPacket {
    pub origin: [[f32; PACKET]; 3],
    pub dir: [[f32; PACKET]; 3],
    pub tmax: [f32; PACKET],
    /// Bit `l` set: lane `l` holds a ray.
    pub active: u32,
}

impl Default for RayPacket {
    fn default() -> Self {
        // Inactive lanes hold a harmless ray, so their arithmetic makes no NaNs.
        Self {
            origin: [[0.0; PACKET]; 3],
            dir: [[0.0; PACKET], [0.0; PACKET], [1.0; PACKET]],
            tmax: [0.0; PACKET],
            active: 0,
        }
    }
}

impl RayPacket {
    /// Puts `ray` with `tmax` in lane `l` and marks it active.
    #[inline(always)]
    pub fn set(&mut self, l: usize, ray: &Ray, tmax: f32) {
        for a in 0..3 {
            self.origin[a][l] = ray.origin[a];
            self.dir[a][l] = ray.dir[a];
        }
        self.tmax[l] = tmax;
        self.active |= 1 << l;
    }

    /// The ray of lane `l`.
    #[inline(always)]
    pub fn ray(&self, l: usize) -> Ray {
        Ray::new(
            Vec3::new(self.origin[0][l], self.origin[1][l], self.origin[2][l]),
            Vec3::new(self.dir[0][l], self.dir[1][l], self.dir[2][l]),
        )
    }
}

/// The closest hits of a packet: lane `l`'s is valid if bit `l` of `found` is set.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub struct PacketHits {
    pub t: [f32; PACKET],
    pub u: [f32; PACKET],
    pub v: [f32; PACKET],
    pub prim: [u32; PACKET],
    pub found: u32,
}

impl PacketHits {
    /// No lane hit.
    pub(crate) fn none() -> Self {
        PacketHits { t: [0.0; PACKET], u: [0.0; PACKET], v: [0.0; PACKET], prim: [0; PACKET], found: 0 }
    }

    /// Records lane `l`'s answer to a one-ray query.
    #[inline(always)]
    pub(crate) fn put(&mut self, l: usize, hit: Option<Hit>) {
        if let Some(h) = hit {
            (self.t[l], self.u[l], self.v[l], self.prim[l]) = (h.t, h.u, h.v, h.prim);
            self.found |= 1 << l;
        }
    }

    /// Lane `l`'s hit, as the one-ray query returns it.
    #[inline(always)]
    pub fn get(&self, l: usize) -> Option<Hit> {
        (self.found & (1 << l) != 0).then(|| Hit { t: self.t[l], prim: self.prim[l], u: self.u[l], v: self.v[l] })
    }
}

/// Each lane's ray, as vectors: the world-space origin and direction (spheres), and the
/// watertight test's shear ([`crate::geometry::triangle::RayShear::for_ray`], computed
/// with the same operations) with its axis permutation as `vpermps` indices.
struct Lanes8 {
    o: [__m256; 3],
    d: [__m256; 3],
    k: [__m256i; 3],
    s: [__m256; 3],
    ko: [__m256; 3],
}

/// Picks `v[idx]` per lane for `idx` in 0..3.
#[target_feature(enable = "avx2")]
#[inline]
fn select3(idx: __m256i, v: &[__m256; 3]) -> __m256 {
    let is0 = _mm256_castsi256_ps(_mm256_cmpeq_epi32(idx, _mm256_setzero_si256()));
    let is1 = _mm256_castsi256_ps(_mm256_cmpeq_epi32(idx, _mm256_set1_epi32(1)));
    _mm256_blendv_ps(_mm256_blendv_ps(v[2], v[1], is1), v[0], is0)
}

impl Lanes8 {
    /// `RayShear::for_ray` for every lane: the axis of the largest |direction| component
    /// (first of equals, NaN as its comparisons say) becomes z, the other two follow
    /// cyclically and swap when that component is negative.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn new(rays: &RayPacket) -> Self {
        // SAFETY: `RayPacket` is 32-byte aligned and its rows are [f32; 8] at multiples
        // of 32 bytes.
        let ld = |row: &[f32; PACKET]| unsafe { _mm256_load_ps(row.as_ptr()) };
        let o = [ld(&rays.origin[0]), ld(&rays.origin[1]), ld(&rays.origin[2])];
        let d = [ld(&rays.dir[0]), ld(&rays.dir[1]), ld(&rays.dir[2])];
        let abs = |x| _mm256_andnot_ps(_mm256_set1_ps(-0.0), x);
        let (ax, ay, az) = (abs(d[0]), abs(d[1]), abs(d[2]));
        let ge = |a, b| _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GE_OQ>(a, b));
        let z0 = _mm256_and_si256(ge(ax, ay), ge(ax, az));
        let z1 = _mm256_andnot_si256(z0, ge(ay, az));
        let pick = |a: i32, b: i32, c: i32| {
            let v = _mm256_blendv_epi8(_mm256_set1_epi32(c), _mm256_set1_epi32(b), z1);
            _mm256_blendv_epi8(v, _mm256_set1_epi32(a), z0)
        };
        // kz = 0, 1, 2 gives (kx, ky) = (1, 2), (2, 0), (0, 1).
        let kz = pick(0, 1, 2);
        let (kx, ky) = (pick(1, 2, 0), pick(2, 0, 1));
        let dz = select3(kz, &d);
        let neg = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(dz, _mm256_setzero_ps()));
        let (kx, ky) = (_mm256_blendv_epi8(kx, ky, neg), _mm256_blendv_epi8(ky, kx, neg));
        let sz = _mm256_div_ps(_mm256_set1_ps(1.0), dz);
        let s = [_mm256_mul_ps(select3(kx, &d), sz), _mm256_mul_ps(select3(ky, &d), sz), sz];
        let ko = [select3(kx, &o), select3(ky, &o), select3(kz, &o)];
        Self { o, d, k: [kx, ky, kz], s, ko }
    }
}

impl PackedTriangles {
    /// Closest hits of the packet's active lanes: lane by lane exactly
    /// [`super::brute_force_intersect`]`(prims, ray, tmax)`. Only where
    /// [`PackedTriangles::packets`] says so (the CPU has AVX2); panics elsewhere.
    #[inline]
    pub fn intersect8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> PacketHits {
        assert!(self.packets(), "packet queries need AVX2");
        let best = self.each8_dispatch(prims, rays, false);
        let mut out = PacketHits { t: [0.0; PACKET], u: [0.0; PACKET], v: [0.0; PACKET], prim: [0; PACKET], found: 0 };
        // SAFETY: as above.
        unsafe { best.store(&mut out) };
        out.found &= rays.active;
        out
    }

    /// Which active lanes hit anything: lane by lane exactly
    /// [`super::brute_force_occluded`]`(prims, ray, tmax)`. As [`Self::intersect8`],
    /// only where [`PackedTriangles::packets`] says so.
    #[inline]
    pub fn occluded8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> u32 {
        assert!(self.packets(), "packet queries need AVX2");
        let best = self.each8_dispatch(prims, rays, true);
        // SAFETY: as above.
        (unsafe { _mm256_movemask_ps(best.found) }) as u32 & rays.active
    }

    /// [`Self::each8`] compiled for this CPU: with AVX-512VL's 32 vector registers where
    /// it has them (the eight-lane arithmetic needs more than AVX2's 16, and spilled;
    /// the operations are the same, so are the bits).
    #[inline]
    fn each8_dispatch<P: Primitives>(&self, prims: &P, rays: &RayPacket, any: bool) -> Best {
        match self.simd {
            // SAFETY: `Avx512` is only chosen when the CPU reports AVX2, AVX-512F and VL.
            InstructionSet::Avx512 => unsafe { self.each8_vl(prims, rays, any) },
            // SAFETY: `packets()` (asserted by the callers) holds only where the CPU
            // reported AVX2.
            _ => unsafe { self.each8(prims, rays, any) },
        }
    }

    #[target_feature(enable = "avx2,avx512f,avx512vl")]
    fn each8_vl<P: Primitives>(&self, prims: &P, rays: &RayPacket, any: bool) -> Best {
        self.each8(prims, rays, any)
    }

    /// Brute force's loop for every lane. `any`: stop a lane at its first hit (and the
    /// query when every active lane has one); otherwise keep the nearest. (`best` is a
    /// local that never has its address taken: in memory, the compiler turned its blends
    /// into masked stores, which cost a third of the query on AMD Zen 3.)
    #[target_feature(enable = "avx2")]
    #[inline]
    // Long on purpose: The eight-ray triangle kernel in AVX2 intrinsics: one function so the compiler keeps the eight lanes in registers across the test.
    fn each8<P: Primitives>(&self, prims: &P, rays: &RayPacket, any: bool) -> Best {
        let mut best = Best::new(rays);
        let r = Lanes8::new(rays);
        let active = rays.active & ((1 << PACKET) - 1);
        // Lanes still searching; as a vector for the blends.
        let mut open = active;
        let lane_bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        let open_mask = |open: u32| {
            _mm256_castsi256_ps(_mm256_cmpeq_epi32(
                _mm256_and_si256(_mm256_set1_epi32(open as i32), lane_bits),
                lane_bits,
            ))
        };
        let mut open_v = open_mask(open);
        // The sheared corners 0 and 2 of the triangle before, for one that follows it
        // as a fan: the same values from the same operations, so the same bits. (Not
        // after a skipped run: then they are another triangle's.)
        let mut before = [[_mm256_setzero_ps(); 3]; 2];
        let mut before_ok = false;
        let boxes = RunBoxes::new(&r, self.extent());
        let corners = self.corners4();
        for run in self.runs() {
            if let Some(b) = &run.bounds
                && !boxes.reach(b, best.tmax, open_v)
            {
                before_ok = false;
                continue;
            }
            let (start, end) = (run.start as usize, run.end as usize);
            for (i, tri) in (start..end).zip(&corners[start..end]) {
                // SAFETY: each row of `Corners4` is four floats, 16-byte aligned.
                let ld = |v: usize| unsafe { _mm256_broadcast_ps(&*tri.0[v].as_ptr().cast::<__m128>()) };
                let perm = |p| [r.k[0], r.k[1], r.k[2]].map(|k| _mm256_permutevar8x32_ps(p, k));
                let corner = |v: usize| lane_arithmetic!(@corner perm(ld(v)), r.s, r.ko, _mm256_sub_ps, _mm256_mul_ps);
                let [a, b] = if tri.follows_fan() && before_ok { before } else { [corner(0), corner(1)] };
                let c = corner(2);
                before = [a, c];
                before_ok = true;
                let (u, v, w, det, t_scaled, limit) =
                    lane_arithmetic!(@sheared a, b, c, best.tmax, _mm256_sub_ps, _mm256_mul_ps, _mm256_add_ps);
                let z = _mm256_setzero_ps();
                let zero = _mm256_or_ps(
                    _mm256_or_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(u, z), _mm256_cmp_ps::<_CMP_EQ_OQ>(v, z)),
                    _mm256_cmp_ps::<_CMP_EQ_OQ>(w, z),
                );
                let zero = _mm256_and_ps(zero, open_v);
                // Most triangles miss every lane by the signs of the edge functions alone
                // (`verdict`'s first rejection); the rest of the test is skipped for them.
                let mixed = _mm256_castsi256_ps(_mm256_srai_epi32::<31>(_mm256_castps_si256(_mm256_or_ps(
                    _mm256_xor_ps(u, v),
                    _mm256_xor_ps(u, w),
                ))));
                if _mm256_movemask_ps(_mm256_or_ps(_mm256_andnot_ps(mixed, open_v), zero)) == 0 {
                    continue;
                }
                let inv_det = _mm256_div_ps(_mm256_set1_ps(1.0), det);
                let t = _mm256_mul_ps(t_scaled, inv_det);
                let ok =
                    _mm256_andnot_ps(zero, _mm256_and_ps(open_v, verdict(u, v, w, det, t_scaled, limit, t, best.tmax)));
                best.take(ok, t, _mm256_mul_ps(v, inv_det), _mm256_mul_ps(w, inv_det), i as u32);
                let zero = _mm256_movemask_ps(zero) as u32;
                if zero != 0 {
                    best = best.scalar(prims, rays, i as u32, zero);
                }
                if any {
                    open = active & !(_mm256_movemask_ps(best.found) as u32);
                    if open == 0 {
                        return best;
                    }
                    open_v = open_mask(open);
                }
            }
        }
        for (j, &(c, radius)) in self.sphere_list().iter().enumerate() {
            let i = (self.len() + j) as u32;
            // `intersect_sphere(ray, c, radius, 0.0, tmax)`, glam's scalar Vec3 order:
            // dot products summed x, y, then z.
            let f = [
                _mm256_sub_ps(r.o[0], _mm256_set1_ps(c.x)),
                _mm256_sub_ps(r.o[1], _mm256_set1_ps(c.y)),
                _mm256_sub_ps(r.o[2], _mm256_set1_ps(c.z)),
            ];
            let dot = |a: &[__m256; 3], b: &[__m256; 3]| {
                _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(a[0], b[0]), _mm256_mul_ps(a[1], b[1])),
                    _mm256_mul_ps(a[2], b[2]),
                )
            };
            let a = dot(&r.d, &r.d);
            let b = _mm256_xor_ps(dot(&f, &r.d), _mm256_set1_ps(-0.0));
            let s = _mm256_div_ps(b, a);
            let l = [
                _mm256_add_ps(f[0], _mm256_mul_ps(s, r.d[0])),
                _mm256_add_ps(f[1], _mm256_mul_ps(s, r.d[1])),
                _mm256_add_ps(f[2], _mm256_mul_ps(s, r.d[2])),
            ];
            let r2 = _mm256_set1_ps(radius * radius);
            let disc = _mm256_mul_ps(a, _mm256_sub_ps(r2, dot(&l, &l)));
            // `disc < 0` returns None; NaN goes on (and fails every test below).
            let cand = _mm256_and_ps(_mm256_cmp_ps::<_CMP_NLT_UQ>(disc, _mm256_setzero_ps()), open_v);
            if _mm256_movemask_ps(cand) == 0 {
                continue;
            }
            let sq = _mm256_sqrt_ps(disc);
            let q = _mm256_blendv_ps(
                _mm256_sub_ps(b, sq),
                _mm256_add_ps(b, sq),
                _mm256_cmp_ps::<_CMP_GE_OQ>(b, _mm256_setzero_ps()),
            );
            let t0 = _mm256_div_ps(q, a);
            let t1 = _mm256_blendv_ps(
                t0,
                _mm256_div_ps(_mm256_sub_ps(dot(&f, &f), r2), q),
                _mm256_cmp_ps::<_CMP_NEQ_UQ>(q, _mm256_setzero_ps()),
            );
            let swap = _mm256_cmp_ps::<_CMP_GT_OQ>(t0, t1);
            let (t0, t1) = (_mm256_blendv_ps(t0, t1, swap), _mm256_blendv_ps(t1, t0, swap));
            let within = |t| {
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GT_OQ>(t, _mm256_setzero_ps()),
                    _mm256_cmp_ps::<_CMP_LT_OQ>(t, best.tmax),
                )
            };
            let (ok0, ok1) = (within(t0), within(t1));
            let t = _mm256_blendv_ps(t1, t0, ok0);
            let ok = _mm256_and_ps(cand, _mm256_or_ps(ok0, ok1));
            best.take(ok, t, _mm256_setzero_ps(), _mm256_setzero_ps(), i);
            if any {
                open = active & !(_mm256_movemask_ps(best.found) as u32);
                if open == 0 {
                    return best;
                }
                open_v = open_mask(open);
            }
        }
        // Primitives after the packed ones (none in a scene's set): lane by lane.
        let rest = (self.len() + self.sphere_list().len()) as u32..prims.len() as u32;
        for i in rest {
            let open = if any { active & !(_mm256_movemask_ps(best.found) as u32) } else { active };
            best = best.scalar(prims, rays, i, open);
        }
        best
    }
}

/// The lanes where the scalar watertight test (`intersect_triangle_corners`) returns a
/// hit at `t = t_scaled · (1 / det)`, given that no edge function is zero (those lanes
/// run the scalar test). It is the scalar test's sequence of rejections, shortened:
///
/// * Mixed signs of `u, v, w` reject. With all three nonzero and finite, that is their
///   sign bits differing. A NaN or infinite edge function makes `det` NaN or infinite,
///   and then `t` is NaN or ±0 (or ±inf for a subnormal `det`, which the `t` range
///   fails too), so the `t` test below rejects whatever the signs say.
/// * `det == 0` cannot happen for nonzero edge functions of one sign.
/// * `t·det` outside `(0, tmax·det]` (signs following `det`) rejects: with `det`'s sign
///   bit flipped into both sides, that is `!(t_scaled' > limit')` (unordered, as the
///   scalar `>` rejects only when ordered), plus `t_scaled' <= 0`, which implies
///   `!(t > 0)` as `1 / det` has `det`'s sign.
/// * Then `0 < t < tmax`.
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2")]
#[inline]
fn verdict(
    u: __m256,
    v: __m256,
    w: __m256,
    det: __m256,
    t_scaled: __m256,
    limit: __m256,
    t: __m256,
    tmax: __m256,
) -> __m256 {
    let mixed = _mm256_castsi256_ps(_mm256_srai_epi32::<31>(_mm256_castps_si256(_mm256_or_ps(
        _mm256_xor_ps(u, v),
        _mm256_xor_ps(u, w),
    ))));
    let sign = _mm256_and_ps(det, _mm256_set1_ps(-0.0));
    let within = _mm256_cmp_ps::<_CMP_NGT_UQ>(_mm256_xor_ps(t_scaled, sign), _mm256_xor_ps(limit, sign));
    let t_ok = _mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(t, _mm256_setzero_ps()), _mm256_cmp_ps::<_CMP_LT_OQ>(t, tmax));
    _mm256_andnot_ps(mixed, _mm256_and_ps(within, t_ok))
}

/// The packet's rays for box tests of triangle runs: each lane's origin and reciprocal
/// direction, and the margin by which boxes widen for it (`PackedTriangles::margin`'s,
/// from [`MARGIN`]: far above the rounding of either test, so a skipped run holds no hit).
struct RunBoxes {
    o: [__m256; 3],
    inv: [__m256; 3],
    pad: __m256,
}

impl RunBoxes {
    #[target_feature(enable = "avx2")]
    #[inline]
    fn new(r: &Lanes8, extent: f32) -> Self {
        let one = _mm256_set1_ps(1.0);
        let inv = r.d.map(|d| _mm256_div_ps(one, d));
        let abs = |x| _mm256_andnot_ps(_mm256_set1_ps(-0.0), x);
        let far = _mm256_max_ps(_mm256_max_ps(abs(r.o[0]), abs(r.o[1])), abs(r.o[2]));
        let pad = _mm256_mul_ps(_mm256_set1_ps(MARGIN), _mm256_add_ps(_mm256_set1_ps(extent), far));
        Self { o: r.o, inv, pad }
    }

    /// Whether any lane of `open` can reach box `b`, widened by its margin, within its
    /// `tmax`. A NaN slab distance (0 · inf: a ray in a slab's plane) leaves that axis
    /// unbounded, so it never excludes.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn reach(&self, b: &Aabb, tmax: __m256, open: __m256) -> bool {
        let (mut near, mut far) = (_mm256_setzero_ps(), tmax);
        for a in 0..3 {
            let lo = _mm256_sub_ps(_mm256_set1_ps(b.min[a]), self.pad);
            let hi = _mm256_add_ps(_mm256_set1_ps(b.max[a]), self.pad);
            let t0 = _mm256_mul_ps(_mm256_sub_ps(lo, self.o[a]), self.inv[a]);
            let t1 = _mm256_mul_ps(_mm256_sub_ps(hi, self.o[a]), self.inv[a]);
            let nan = _mm256_cmp_ps::<_CMP_UNORD_Q>(t0, t1);
            let tn = _mm256_blendv_ps(_mm256_min_ps(t0, t1), _mm256_set1_ps(f32::NEG_INFINITY), nan);
            let tf = _mm256_blendv_ps(_mm256_max_ps(t0, t1), _mm256_set1_ps(f32::INFINITY), nan);
            near = _mm256_max_ps(near, tn);
            far = _mm256_min_ps(far, tf);
        }
        // `near <= far` fails only when ordered; a NaN tmax (never passed) would test.
        let miss = _mm256_cmp_ps::<_CMP_GT_OQ>(near, far);
        _mm256_movemask_ps(_mm256_andnot_ps(miss, open)) != 0
    }
}

/// Each lane's nearest hit so far.
struct Best {
    tmax: __m256,
    u: __m256,
    v: __m256,
    prim: __m256i,
    found: __m256,
}

impl Best {
    /// No hits yet, within the packet's `tmax`.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn new(rays: &RayPacket) -> Self {
        Best {
            // SAFETY: `RayPacket` is 32-byte aligned and `tmax` is at a multiple of 32 bytes.
            tmax: unsafe { _mm256_load_ps(rays.tmax.as_ptr()) },
            u: _mm256_setzero_ps(),
            v: _mm256_setzero_ps(),
            prim: _mm256_setzero_si256(),
            found: _mm256_setzero_ps(),
        }
    }

    /// Takes the hits of lanes `ok`.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn take(&mut self, ok: __m256, t: __m256, u: __m256, v: __m256, prim: u32) {
        self.tmax = _mm256_blendv_ps(self.tmax, t, ok);
        self.u = _mm256_blendv_ps(self.u, u, ok);
        self.v = _mm256_blendv_ps(self.v, v, ok);
        self.prim = _mm256_blendv_epi8(self.prim, _mm256_set1_epi32(prim as i32), _mm256_castps_si256(ok));
        self.found = _mm256_or_ps(self.found, ok);
    }

    #[target_feature(enable = "avx2")]
    #[inline]
    fn store(&self, out: &mut PacketHits) {
        // SAFETY: `PacketHits` is 32-byte aligned and its rows are eight lanes at
        // multiples of 32 bytes.
        unsafe {
            _mm256_store_ps(out.t.as_mut_ptr(), self.tmax);
            _mm256_store_ps(out.u.as_mut_ptr(), self.u);
            _mm256_store_ps(out.v.as_mut_ptr(), self.v);
            _mm256_store_si256(out.prim.as_mut_ptr().cast(), self.prim);
        }
        out.found = _mm256_movemask_ps(self.found) as u32;
    }

    /// The scalar test of primitive `i` for each lane of `lanes`, with its current tmax.
    /// (By value: a reference would keep the caller's `Best` in memory.)
    #[cold]
    #[inline(never)]
    #[target_feature(enable = "avx2")]
    fn scalar<P: Primitives>(mut self, prims: &P, rays: &RayPacket, i: u32, mut lanes: u32) -> Self {
        let mut out = PacketHits { t: [0.0; PACKET], u: [0.0; PACKET], v: [0.0; PACKET], prim: [0; PACKET], found: 0 };
        self.store(&mut out);
        while lanes != 0 {
            let l = lanes.trailing_zeros() as usize;
            lanes &= lanes - 1;
            let ray = rays.ray(l);
            if let Some(h) = prims.intersect(i, &ray, &RayPrecomp::new(&ray), out.t[l]) {
                (out.t[l], out.u[l], out.v[l], out.prim[l]) = (h.t, h.u, h.v, i);
                out.found |= 1 << l;
            }
        }
        let bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        // SAFETY: as in `store`.
        unsafe {
            self.tmax = _mm256_load_ps(out.t.as_ptr());
            self.u = _mm256_load_ps(out.u.as_ptr());
            self.v = _mm256_load_ps(out.v.as_ptr());
            self.prim = _mm256_load_si256(out.prim.as_ptr().cast());
        }
        self.found =
            _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(out.found as i32), bits), bits));
        self
    }
}

#[cfg(test)]
mod tests {
    use std::io::Write;

    use super::*;
    use crate::accel::triangle_blocks::tests::{Rng, scaled_scene};
    use crate::accel::{brute_force_intersect, brute_force_occluded};

    /// Every active lane's answer is brute force's for its ray, bit for bit, whatever
    /// the other lanes hold: random rays, rays aimed exactly at the grid's vertices and
    /// edges (edge functions exactly zero), tmax at and around hit distances, partly
    /// active packets; and scenes so large that `t·det` overflows (2e13) or so small
    /// that it is subnormal (1e-13) or the edge functions underflow to zero (1e-20).
    #[test]
    fn every_lane_is_brute_force() {
        let mut r = Rng(17);
        let (mut hits, mut sphere_hits, mut blocked, mut compared) = (0, 0, 0, 0);
        let cases = [(0, 11, 1.0), (1, 3, 1.0), (9, 0, 1.0), (40, 11, 1.0), (100, 5, 1.0)];
        let extreme = [(40, 11, 2e13), (40, 11, 1e-13), (40, 11, 1e-20)];
        for (n, spheres, scale) in cases.into_iter().chain(extreme) {
            let geo = scaled_scene(&mut r, n, spheres, scale);
            let packed = PackedTriangles::for_small_scene(&geo).expect("small");
            if !packed.packets() {
                // On stderr itself: the harness hides a passing test's println!.
                let _ = writeln!(std::io::stderr(), "SKIPPED: packet queries need AVX2, which this CPU lacks");
                return;
            }
            // The grid's quads are fans: their second triangles reuse two corners.
            assert_eq!(packed.corners4().iter().filter(|c| c.follows_fan()).count(), 16);
            // The grid's quads are small beside the scene: runs of them get boxes, which
            // packets skip (fans cut at a skipped run included).
            if n == 0 {
                assert!(packed.runs().iter().any(|r| r.bounds.is_some()), "{:?}", packed.runs());
            }
            // The AVX2 build of the kernel too, where the CPU would take AVX-512VL's.
            let mut avx2 = packed.clone();
            avx2.simd = InstructionSet::Avx2;
            for k in 0..1500 {
                let mut rays = RayPacket::default();
                let mut expected = [None; PACKET];
                for (l, expected) in expected.iter_mut().enumerate() {
                    // Some lanes inactive, holding garbage that must not matter.
                    if (k + l) % 7 == 3 {
                        let o = r.v();
                        rays.set(l, &Ray::new(o, Vec3::new(f32::NAN, 0.0, 1.0)), 1.0);
                        rays.active &= !(1 << l);
                        continue;
                    }
                    let o = r.v() * 2.0 * scale;
                    let m = k * PACKET + l;
                    let target = if m.is_multiple_of(4) {
                        Vec3::new((m / 4 % 9) as f32 * 0.25 - 1.0, (m / 36 % 9) as f32 * 0.25 - 1.0, 0.25) * scale
                    } else {
                        r.v() * scale
                    };
                    let ray = Ray::new(o, (target - o).normalize());
                    let mut tmax =
                        if m.is_multiple_of(3) { f32::INFINITY } else { (target - o).length() * (0.5 + r.f()) };
                    // Every fifth lane: tmax at or next to its own nearest hit.
                    if m % 5 == 1
                        && let Some(h) = brute_force_intersect(&geo, &ray, tmax)
                    {
                        tmax = [h.t, h.t.next_up(), h.t.next_down()][m / 5 % 3];
                    }
                    rays.set(l, &ray, tmax);
                    *expected = Some((brute_force_intersect(&geo, &ray, tmax), brute_force_occluded(&geo, &ray, tmax)));
                }
                let (got, occluded) = (packed.intersect8(&geo, &rays), packed.occluded8(&geo, &rays));
                let (got2, occluded2) = (avx2.intersect8(&geo, &rays), avx2.occluded8(&geo, &rays));
                assert_eq!((got.found, occluded), (got2.found, occluded2), "n {n} scale {scale} packet {k}");
                for (l, e) in expected.iter().enumerate() {
                    let Some((hit, occ)) = *e else {
                        assert_eq!(got.found & (1 << l), 0, "inactive lane {l} reported");
                        assert_eq!(occluded & (1 << l), 0, "inactive lane {l} reported");
                        continue;
                    };
                    assert_eq!(got.get(l), hit, "n {n} scale {scale} packet {k} lane {l}");
                    assert_eq!(got2.get(l), hit, "AVX2: n {n} scale {scale} packet {k} lane {l}");
                    assert_eq!(occluded & (1 << l) != 0, occ, "n {n} scale {scale} packet {k} lane {l}");
                    if scale != 1.0 {
                        continue;
                    }
                    compared += 1;
                    hits += usize::from(hit.is_some());
                    sphere_hits += usize::from(hit.is_some_and(|h| h.prim as usize >= geo.triangle_count()));
                    blocked += usize::from(occ);
                }
            }
        }
        // Hits and misses, triangles and spheres, blocked and free all covered.
        assert!(compared > 30000, "{compared}");
        assert!(hits > compared / 4 && hits < compared * 9 / 10, "{hits} of {compared}");
        assert!(sphere_hits > 1000, "{sphere_hits}");
        assert!(blocked > compared / 4 && blocked < compared * 9 / 10, "{blocked} of {compared}");
    }
}
