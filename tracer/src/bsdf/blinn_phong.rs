//! Diffuse base plus a normalised, energy-conserving Blinn-Phong lobe (the `Glossy`
//! material: MTL Kd, Ks, Ns).
//!
//! The specular lobe is the isotropic Ashikhmin–Shirley form without its Fresnel term:
//!
//! ```text
//!     f_s(wo, wi) = ks · D(h) / (4 |wo·h| max(|cos θo|, |cos θi|)),
//!     D(h)        = (n + 1)/(2π) · cos^n θh,
//! ```
//!
//! with h the half vector. D is normalised as a density of h over the hemisphere
//! (∫ D dωh = 1), which is exactly the distribution the sampler draws h from.
//!
//! Energy conservation, for every wo and every n ≥ 0: with dωi = 4 |wo·h| dωh,
//!
//! ```text
//!     ∫ f_s |cos θi| dωi = ks ∫ D(h) · cos θi / max(cos θo, cos θi) dωh ≤ ks ∫ D(h) dωh = ks,
//! ```
//!
//! the integral running over the h whose reflection of wo is above the horizon. The
//! Lambertian base reflects exactly kd, so the directional albedo is at most kd + ks,
//! and kd, ks are scaled per channel so that kd + ks ≤ 1. Unlike the classic
//! (n + 8)/(8π) normalisation this bound holds exactly (also at grazing angles and
//! small n), f is symmetric in (wo, wi) (reciprocal), and the sampled specular weight
//! ks · cos θi / max(cos θo, cos θi) is bounded by ks, so the lobe has no fireflies.

use super::{BsdfSample, reflect_about, reflect_about_wide, same_hemisphere, to_side_of, to_side_of_wide};
use crate::sampling::{cosine_hemisphere_pdf, power_cosine_pdf, sample_cosine_hemisphere, sample_power_cosine, wide};
use crate::simd::{F8, M8, Simd, V2w, V3w, W};
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

/// Exponents are clamped to this; MTL's Ns range is 0..1000 and beyond 1e4 the lobe is
/// narrower than f32 directions resolve well.
pub const MAX_EXPONENT: f32 = 1e4;

#[derive(Clone, Copy, Debug)]
pub struct BlinnPhong {
    kd: Vec3,
    ks: Vec3,
    exponent: f32,
    /// Probability of sampling the specular lobe (one-sample mixture with the diffuse one).
    spec_prob: f32,
}

/// Negative, NaN and infinite reflectances are treated as 0.
fn sanitize(v: Vec3) -> Vec3 {
    let f = |x: f32| if x > 0.0 && x.is_finite() { x } else { 0.0 };
    Vec3::new(f(v.x), f(v.y), f(v.z))
}

impl BlinnPhong {
    /// Scales kd and ks per channel by 1/max(1, kd + ks), so the albedo bound kd + ks
    /// never exceeds 1 (MTL files routinely have Kd + Ks > 1); NaN/negative exponents
    /// become 0.
    pub fn new(kd: Vec3, ks: Vec3, exponent: f32) -> Self {
        let (kd, ks) = (sanitize(kd), sanitize(ks));
        let scale = (kd + ks).max(Vec3::ONE).recip();
        let (kd, ks) = (kd * scale, ks * scale);
        let exponent = if exponent > 0.0 { exponent.min(MAX_EXPONENT) } else { 0.0 };
        // Choose lobes in proportion to their albedo bounds (channel sums).
        let (wd, ws) = (kd.element_sum(), ks.element_sum());
        let spec_prob = if ws > 0.0 { ws / (wd + ws) } else { 0.0 };
        Self { kd, ks, exponent, spec_prob }
    }

    /// The effective (energy-conserving) diffuse and specular reflectances.
    pub fn reflectances(&self) -> (Vec3, Vec3) {
        (self.kd, self.ks)
    }

    /// For wo, wi both above the horizon: (pdf of sampling wi through the half vector,
    /// D(h)/(4 wo·h), and cos θi / max(cos θo, cos θi)), so that
    /// f_s |cos θi| = ks · pdf_s · ratio. Zero when the half vector is degenerate.
    #[inline]
    fn specular(&self, wo: Vec3, wi: Vec3) -> (f32, f32) {
        // For unit wo, wi: wo·h = wi·h = |wo + wi|/2. Computed this way it is symmetric
        // in (wo, wi) to the last bit (reciprocity) and avoids the cancellation of a dot
        // product when wo and wi are nearly opposite.
        let sum = wo + wi;
        let len = sum.length();
        if len.is_nan() || len <= 0.0 {
            return (0.0, 0.0);
        }
        let h = sum / len;
        let wo_dot_h = 0.5 * len;
        let pdf = power_cosine_pdf(h.z, self.exponent) / (4.0 * wo_dot_h);
        if !pdf.is_finite() {
            return (0.0, 0.0);
        }
        (pdf, wi.z / wo.z.max(wi.z))
    }

    /// Mirrors the pair into the upper hemisphere (two-sided shading) or None if wi is
    /// on the other side of the surface from wo.
    #[inline]
    fn upper(wo: Vec3, wi: Vec3) -> Option<(Vec3, Vec3)> {
        if !same_hemisphere(wo, wi) {
            return None;
        }
        let flip = Vec3::new(1.0, 1.0, wo.z.signum());
        Some((wo * flip, wi * flip))
    }

    /// f(wo, wi) |cos θi|.
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        self.eval_pdf(wo, wi).0
    }

    /// Density of [`Self::sample`]: the mixture of both lobes' densities.
    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        self.eval_pdf(wo, wi).1
    }

    /// [`Self::eval`] and [`Self::pdf`] together, sharing the half vector and the power
    /// of cos θh (light sampling and `sample` need both).
    #[inline(always)]
    pub fn eval_pdf(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        let Some((wo, wi)) = Self::upper(wo, wi) else { return (Vec3::ZERO, 0.0) };
        let (pdf_s, ratio) = self.specular(wo, wi);
        let f = self.kd * (FRAC_1_PI * wi.z) + self.ks * (pdf_s * ratio);
        (f, (1.0 - self.spec_prob) * cosine_hemisphere_pdf(wi.z) + self.spec_prob * pdf_s)
    }

    /// Picks a lobe with `u_lobe`, samples it with `u` (h ~ D for the specular lobe,
    /// then wi = reflect(wo, h)), and weights by the whole BSDF over the mixture pdf.
    /// None when the reflected direction falls below the horizon (that mass is simply
    /// lost; `pdf` integrates to less than 1 accordingly).
    #[inline(always)]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wo.z == 0.0 || !wo.is_finite() || (self.kd + self.ks).max_element() <= 0.0 {
            return None;
        }
        let wo_up = Vec3::new(wo.x, wo.y, wo.z.abs());
        let wi_up = if u_lobe < self.spec_prob {
            reflect_about(wo_up, sample_power_cosine(u, self.exponent)).normalize_or_zero()
        } else {
            sample_cosine_hemisphere(u)
        };
        if wi_up.z <= 0.0 {
            return None;
        }
        let wi = to_side_of(wo, wi_up);
        let (f, pdf) = self.eval_pdf(wo, wi);
        if !(pdf > 0.0 && pdf.is_finite()) {
            return None;
        }
        let weight = f / pdf;
        weight.is_finite().then_some(BsdfSample { wi, weight, pdf, delta: false })
    }
}

/// Eight normalised Blinn-Phong BSDFs, lane by lane [`BlinnPhong`]'s (the eight-path
/// integrator's), from [`BlinnPhong::new`]'s values.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BlinnPhongW {
    kd: V3w,
    ks: V3w,
    exponent: F8,
    spec_prob: F8,
}

impl BlinnPhongW {
    /// Lane `l` is `of(l)`.
    #[inline(always)]
    pub fn from_fn(simd: Simd, of: impl Fn(usize) -> BlinnPhong) -> Self {
        let b: [BlinnPhong; W] = std::array::from_fn(of);
        Self {
            kd: simd.v3_from_fn(|l| b[l].kd),
            ks: simd.v3_from_fn(|l| b[l].ks),
            exponent: simd.f8(std::array::from_fn(|l| b[l].exponent)),
            spec_prob: simd.f8(std::array::from_fn(|l| b[l].spec_prob)),
        }
    }

    /// [`BlinnPhong::specular`] for the lanes of `mask`.
    #[inline(always)]
    fn specular(&self, wo: V3w, wi: V3w, mask: M8) -> (F8, F8) {
        let sum = wo + wi;
        let len = sum.length();
        let h = sum / len;
        let wo_dot_h = 0.5 * len;
        let pdf = wide::power_cosine_pdf(h.z, self.exponent, mask) / (4.0 * wo_dot_h);
        let none = len.is_nan() | len.le(0.0) | !pdf.is_finite();
        let zero = len.simd().zero();
        (none.select(zero, pdf), none.select(zero, wi.z / wo.z.max(wi.z)))
    }

    /// [`BlinnPhong::eval_pdf`] for the lanes of `mask`.
    #[inline(always)]
    pub fn eval_pdf(&self, wo: V3w, wi: V3w, mask: M8) -> (V3w, F8) {
        let same = (wo.z * wi.z).gt(0.0);
        let flip = wo.z.signum();
        let (wo, wi) = (V3w::new(wo.x * 1.0, wo.y * 1.0, wo.z * flip), V3w::new(wi.x * 1.0, wi.y * 1.0, wi.z * flip));
        let (pdf_s, ratio) = self.specular(wo, wi, mask & same);
        let f = self.kd * (FRAC_1_PI * wi.z) + self.ks * (pdf_s * ratio);
        let pdf = (1.0 - self.spec_prob) * wide::cosine_hemisphere_pdf(wi.z) + self.spec_prob * pdf_s;
        let simd = pdf.simd();
        (same.select3(f, simd.v3(Vec3::ZERO)), same.select(pdf, simd.zero()))
    }

    /// [`BlinnPhong::sample`] for the lanes of `mask`: `(wi, weight, pdf, valid)`.
    #[inline(always)]
    pub fn sample(&self, wo: V3w, u_lobe: F8, u: V2w, mask: M8) -> (V3w, V3w, F8, M8) {
        let none = wo.z.eq(0.0) | !wo.is_finite() | (self.kd + self.ks).max_element().le(0.0);
        let wo_up = V3w::new(wo.x, wo.y, wo.z.abs());
        let spec = u_lobe.lt(self.spec_prob);
        let (on_spec, on_diffuse) = (mask & spec, mask & !spec);
        let mut wi_up = wo.simd().v3(Vec3::ZERO);
        if on_spec.any() {
            let h = wide::sample_power_cosine(u, self.exponent, on_spec);
            wi_up = on_spec.select3(reflect_about_wide(wo_up, h).normalize_or_zero(), wi_up);
        }
        if on_diffuse.any() {
            wi_up = on_diffuse.select3(wide::sample_cosine_hemisphere(u), wi_up);
        }
        let none = none | wi_up.z.le(0.0);
        let wi = to_side_of_wide(wo, wi_up);
        let (f, pdf) = self.eval_pdf(wo, wi, mask & !none);
        let none = none | !(pdf.gt(0.0) & pdf.is_finite());
        let weight = f / pdf;
        (wi, weight, pdf, mask & !(none | !weight.is_finite()))
    }
}
