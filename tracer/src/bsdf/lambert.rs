//! Lambertian reflection: f = kd/π on the side of the surface `wo` is on.

use super::{BsdfSample, same_hemisphere, to_side_of, to_side_of_wide};
use crate::sampling::{cosine_hemisphere_pdf, sample_cosine_hemisphere, wide};
use crate::simd::{F8, M8, V2w, V3w};
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

#[derive(Clone, Copy, Debug)]
pub struct Lambert {
    pub kd: Vec3,
}

impl Lambert {
    /// f(wo, wi) |cos θi| = kd/π |cos θi| for `wi` on the side of `wo`, else 0.
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if !same_hemisphere(wo, wi) {
            return Vec3::ZERO;
        }
        self.kd * (FRAC_1_PI * wi.z.abs())
    }

    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if !same_hemisphere(wo, wi) {
            return 0.0;
        }
        cosine_hemisphere_pdf(wi.z.abs())
    }

    /// Cosine-weighted sampling: f |cos θi| / pdf = kd exactly.
    #[inline]
    pub fn sample(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        if wo.z == 0.0 {
            return None;
        }
        let wi = to_side_of(wo, sample_cosine_hemisphere(u));
        let pdf = cosine_hemisphere_pdf(wi.z.abs());
        // wi.z = 0 only on the disk's rim: a zero-probability event with pdf 0.
        (pdf > 0.0).then_some(BsdfSample { wi, weight: self.kd, pdf, delta: false })
    }
}

/// Eight Lambertian BSDFs, lane by lane [`Lambert`]'s (the eight-path integrator's).
#[derive(Clone, Copy, Debug)]
pub(crate) struct LambertW {
    pub kd: V3w,
}

impl LambertW {
    #[inline(always)]
    pub fn eval(&self, wo: V3w, wi: V3w) -> V3w {
        let same = (wo.z * wi.z).gt(0.0);
        same.select3(self.kd * (FRAC_1_PI * wi.z.abs()), wi.simd().v3(Vec3::ZERO))
    }

    #[inline(always)]
    pub fn pdf(&self, wo: V3w, wi: V3w) -> F8 {
        let same = (wo.z * wi.z).gt(0.0);
        same.select(wide::cosine_hemisphere_pdf(wi.z.abs()), wi.simd().zero())
    }

    /// For the lanes of `mask`: `(wi, pdf, valid)`; the weight is `kd`.
    #[inline(always)]
    pub fn sample(&self, wo: V3w, u: V2w, mask: M8) -> (V3w, F8, M8) {
        let wi = to_side_of_wide(wo, wide::sample_cosine_hemisphere(u));
        let pdf = wide::cosine_hemisphere_pdf(wi.z.abs());
        (wi, pdf, mask & wo.z.ne(0.0) & pdf.gt(0.0))
    }
}
