//! BSDFs in the local shading frame (z = shading normal): Lambertian, diffuse plus
//! Blinn-Phong, mirror, smooth dielectric, and Blender's Principled BSDF (GGX microfacet
//! lobes over a Lambertian base).
//!
//! Conventions (pbrt's): `wo` points away from the surface towards where the light goes
//! (the camera side), `wi` towards where it comes from; both unit vectors in local
//! space. `eval` returns f(wo, wi) * |cos θi| so integrators never multiply by the cosine
//! themselves. Radiance transport mode throughout (camera paths).
//!
//! The reflective BSDFs are two-sided: they shade whichever side `wo` is on and are zero
//! for `wi` on the other side. Glass is oriented: z points to the exterior.
//!
//! Robustness: for any finite input (including `wo.z == 0`, grazing directions, exponent
//! 0) `eval`/`pdf` return finite values and `sample` returns None or a finite sample.

pub mod blinn_phong;
mod bump_shadowing;
pub mod dielectric;
pub mod energy;
pub mod fresnel;
pub mod ggx_lobe;
pub mod lambert;
pub mod microfacet;
pub mod mirror;
pub mod principled;
pub mod sheen;
mod sheen_ltc;

#[cfg(test)]
pub(crate) mod chi2;
#[cfg(test)]
mod principled_tests;
#[cfg(test)]
mod tests;

use blinn_phong::BlinnPhong;
pub use bump_shadowing::bump_shadowing;
use dielectric::Dielectric;
use glam::{Vec2, Vec3};
use lambert::Lambert;
use mirror::SpecularReflection;
pub use principled::Principled;

use crate::simd::V3w;

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Bsdf {
    /// Lambertian reflection, two-sided.
    Diffuse { kd: Vec3 },
    /// Diffuse base plus normalised Blinn-Phong lobe (`exponent` = MTL Ns ≥ 0), two-sided.
    /// If kd + ks > 1 in a channel both are scaled down so that it is 1 (see
    /// [`blinn_phong`] for the energy bound).
    Glossy { kd: Vec3, ks: Vec3, exponent: f32 },
    /// Perfect specular reflection tinted by `ks`, two-sided.
    Mirror { ks: Vec3 },
    /// Smooth dielectric: `eta` is the interior IOR over the exterior one (the normal
    /// points outside); transmission tinted by `tint`.
    Glass { eta: f32, tint: Vec3 },
    /// Blender's Principled BSDF ([`principled`]): two-sided unless it transmits, then
    /// oriented as glass is.
    Principled(Principled),
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BsdfSample {
    pub wi: Vec3,
    /// f * |cos θi| / pdf.
    pub weight: Vec3,
    /// Solid-angle pdf (for a delta lobe: the discrete probability of picking it).
    pub pdf: f32,
    /// The sampled lobe is a delta (mirror or smooth glass): no MIS with light sampling.
    pub delta: bool,
}

// `eval`, `pdf` and `sample` are forced inline into the path loop, like
// `Light::sample_li` and `Scene::interaction`: LLVM kept them as calls, which cost the
// path loop several per cent (bench/RESULTS.md).
impl Bsdf {
    /// f(wo, wi) |cos θi| (0 for delta BSDFs).
    #[inline(always)]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match *self {
            Bsdf::Diffuse { kd } => Lambert { kd }.eval(wo, wi),
            Bsdf::Glossy { kd, ks, exponent } => BlinnPhong::new(kd, ks, exponent).eval(wo, wi),
            Bsdf::Mirror { .. } | Bsdf::Glass { .. } => Vec3::ZERO,
            Bsdf::Principled(p) => p.at(wo).eval_pdf(wo, wi).0,
        }
    }

    /// [`Self::eval`] and [`Self::pdf`] at once: the same values, with the work they
    /// share done once (for light sampling, which needs both).
    #[inline(always)]
    pub fn eval_pdf(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        match *self {
            Bsdf::Diffuse { kd } => {
                let l = Lambert { kd };
                (l.eval(wo, wi), l.pdf(wo, wi))
            }
            Bsdf::Glossy { kd, ks, exponent } => BlinnPhong::new(kd, ks, exponent).eval_pdf(wo, wi),
            Bsdf::Mirror { .. } | Bsdf::Glass { .. } => (Vec3::ZERO, 0.0),
            Bsdf::Principled(p) => p.at(wo).eval_pdf(wo, wi),
        }
    }

    /// Solid-angle density with which `sample` produces `wi` (0 for delta BSDFs).
    #[inline(always)]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Diffuse { kd } => Lambert { kd }.pdf(wo, wi),
            Bsdf::Glossy { kd, ks, exponent } => BlinnPhong::new(kd, ks, exponent).pdf(wo, wi),
            Bsdf::Mirror { .. } | Bsdf::Glass { .. } => 0.0,
            Bsdf::Principled(p) => p.at(wo).eval_pdf(wo, wi).1,
        }
    }

    /// Samples wi given wo: `u_lobe` chooses the lobe (Glossy: diffuse or specular;
    /// Glass: reflection or transmission), `u` the direction within it. None when the
    /// sample carries no energy (below the horizon, degenerate wo).
    #[inline(always)]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        match *self {
            Bsdf::Diffuse { kd } => Lambert { kd }.sample(wo, u),
            Bsdf::Glossy { kd, ks, exponent } => BlinnPhong::new(kd, ks, exponent).sample(wo, u_lobe, u),
            Bsdf::Mirror { ks } => SpecularReflection { ks }.sample(wo),
            Bsdf::Glass { eta, tint } => Dielectric { eta, tint }.sample(wo, u_lobe),
            Bsdf::Principled(p) => p.at(wo).sample(wo, u_lobe, u),
        }
    }

    /// True when every lobe is a delta (no point sampling lights).
    pub fn is_delta(&self) -> bool {
        match self {
            Bsdf::Mirror { .. } | Bsdf::Glass { .. } => true,
            Bsdf::Principled(p) => p.is_delta(),
            Bsdf::Diffuse { .. } | Bsdf::Glossy { .. } => false,
        }
    }

    /// Whether the surface is oriented (knows inside from outside: it refracts) rather
    /// than two-sided.
    #[inline]
    pub fn is_oriented(&self) -> bool {
        match self {
            Bsdf::Glass { .. } => true,
            Bsdf::Principled(p) => p.transmits(),
            _ => false,
        }
    }

    /// The reflectance for the albedo AOV and light-selection heuristics: kd, the
    /// (energy-clamped) kd + ks bound for Glossy, ks for mirrors, the tint for glass.
    pub fn albedo(&self) -> Vec3 {
        match *self {
            Bsdf::Diffuse { kd } => kd,
            Bsdf::Glossy { kd, ks, exponent } => {
                let (kd, ks) = BlinnPhong::new(kd, ks, exponent).reflectances();
                kd + ks
            }
            Bsdf::Mirror { ks } => ks,
            Bsdf::Glass { tint, .. } => tint,
            Bsdf::Principled(p) => p.albedo(),
        }
    }
}

/// Both directions on the same side of the surface (strictly).
#[inline]
pub(crate) fn same_hemisphere(a: Vec3, b: Vec3) -> bool {
    a.z * b.z > 0.0
}

/// `w` (given in the upper hemisphere) moved to the side of the surface `wo` is on.
#[inline]
pub(crate) fn to_side_of(wo: Vec3, w: Vec3) -> Vec3 {
    if wo.z < 0.0 { Vec3::new(w.x, w.y, -w.z) } else { w }
}

/// Mirror reflection about the shading normal.
/// [`to_side_of`] lane by lane.
#[inline(always)]
pub(crate) fn to_side_of_wide(wo: V3w, w: V3w) -> V3w {
    V3w::new(w.x, w.y, wo.z.lt(0.0).select(-w.z, w.z))
}

/// [`reflect_about`] lane by lane.
#[inline(always)]
pub(crate) fn reflect_about_wide(wo: V3w, h: V3w) -> V3w {
    2.0 * wo.dot(h) * h - wo
}

#[inline]
pub(crate) fn reflect(wo: Vec3) -> Vec3 {
    Vec3::new(-wo.x, -wo.y, wo.z)
}

/// Mirror reflection of `wo` about the unit vector `h`.
#[inline]
pub(crate) fn reflect_about(wo: Vec3, h: Vec3) -> Vec3 {
    2.0 * wo.dot(h) * h - wo
}
