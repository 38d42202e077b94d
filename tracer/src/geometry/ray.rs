use glam::Vec3;

use crate::simd::V3w;

/// A ray `origin + t * dir`. `dir` need not be normalised for intersection, but the
/// integrators always pass unit directions so that `t` is a distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
}

impl Ray {
    #[inline]
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Self { origin, dir }
    }

    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + t * self.dir
    }
}

/// Moves a surface point off its surface, to the side `dir` leaves towards, so that a
/// ray spawned there does not hit the surface it starts on. The offset scales with the
/// magnitude of the coordinates because f32 rounding error does.
#[inline]
pub fn offset_origin(p: Vec3, geometric_normal: Vec3, dir: Vec3) -> Vec3 {
    let eps = 2e-5 * p.abs().max_element().max(1.0);
    let side = if geometric_normal.dot(dir) >= 0.0 { 1.0 } else { -1.0 };
    p + geometric_normal * (eps * side)
}

/// [`offset_origin`] lane by lane.
#[inline(always)]
pub(crate) fn offset_origin_wide(p: V3w, geometric_normal: V3w, dir: V3w) -> V3w {
    let eps = 2e-5 * p.abs().max_element().max(1.0);
    let simd = p.simd();
    let side = geometric_normal.dot(dir).ge(0.0).select(simd.one(), simd.splat(-1.0));
    p + geometric_normal * (eps * side)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`offset_origin_wide`] gives [`offset_origin`]'s bits, on both sides of the
    /// surface and at large coordinates.
    #[test]
    fn the_wide_offset_is_the_offset() {
        let simd = crate::simd::tests::require_avx2();
        let mut h = 5u64;
        let mut next = || {
            h = h.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((h >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        };
        for k in 0..5000 {
            let scale = [1.0, 10.0, 1e4][k % 3];
            let p: [Vec3; 8] = std::array::from_fn(|_| Vec3::new(next(), next(), next()) * scale);
            let n: [Vec3; 8] = std::array::from_fn(|_| Vec3::new(next(), next(), next()).normalize_or(Vec3::Z));
            let d: [Vec3; 8] = std::array::from_fn(|_| Vec3::new(next(), next(), next()));
            let w = offset_origin_wide(simd.v3_from_fn(|l| p[l]), simd.v3_from_fn(|l| n[l]), simd.v3_from_fn(|l| d[l]));
            for l in 0..8 {
                let e = offset_origin(p[l], n[l], d[l]);
                assert_eq!(w.get(l).to_array().map(f32::to_bits), e.to_array().map(f32::to_bits), "lane {l}");
            }
        }
    }
}
