//! One GGX lobe with its Fresnel term: rough reflection, or a rough dielectric interface
//! that reflects and refracts (Walter et al. 2007), in a local frame where `wo` is above
//! the surface (the Principled BSDF flips both directions so that it is).
//!
//! For the half vector h of a pair (h = normalize(wo + wi) for reflection,
//! h = −normalize(η wi + wo) for refraction, η the IOR below over the IOR above):
//!
//! ```text
//!     reflection:  f cos θi = R(wo·h) D(h) G2 / (4 cos θo)
//!     refraction:  f cos θi = T(wo·h) D(h) G2 |wo·h| J / (cos θo η²),   J = η² |wi·h| / (η wi·h + wo·h)²
//! ```
//!
//! (the 1/η² is radiance's compression into the denser medium, as in pbrt-v4 and
//! Mitsuba 3's radiance mode, and as [`super::dielectric`]). Sampling draws h from the
//! visible normals seen from wo, then reflects with probability R̄/(R̄ + T̄) (channel
//! averages), else refracts: pdf = D_wo(h)/(4 wo·h) or D_wo(h) J, times that choice.

use glam::{Vec2, Vec3};

use super::fresnel::{f82, fresnel_dielectric, tinted_dielectric};
use super::microfacet::Ggx;

/// How much of the light meeting a microfacet at `cos` = wo·h is reflected (R) and
/// transmitted (T).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fresnel {
    /// Everything is reflected (the energy tables' lobe; a white metal).
    One,
    /// A dielectric interface of IOR `eta` (seen from wo's side), exact.
    Dielectric { eta: f32 },
    /// A dielectric whose F0 is replaced by `f0` ([`tinted_dielectric`]); transmission
    /// `(1 − R) · transmit`.
    Tinted { eta: f32, f0: Vec3, transmit: Vec3 },
    /// A metal: F82-tint with reflectance `f0` and edge factor `b`.
    F82 { f0: Vec3, b: Vec3 },
}

impl Fresnel {
    #[inline]
    pub fn eval(&self, cos: f32) -> (Vec3, Vec3) {
        match *self {
            Fresnel::One => (Vec3::ONE, Vec3::ZERO),
            Fresnel::Dielectric { eta } => {
                let r = fresnel_dielectric(cos, eta);
                (Vec3::splat(r), Vec3::splat(1.0 - r))
            }
            Fresnel::Tinted { eta, f0, transmit } => {
                let r = tinted_dielectric(cos, eta, f0);
                (r, (Vec3::ONE - r) * transmit)
            }
            Fresnel::F82 { f0, b } => (f82(cos, f0, b), Vec3::ZERO),
        }
    }
}

/// A GGX lobe. With `transmits`, it is an interface of relative IOR `eta` (below over
/// above) that also refracts; else it only reflects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GgxLobe {
    pub ggx: Ggx,
    pub fresnel: Fresnel,
    pub eta: f32,
    pub transmits: bool,
    /// Narrower than f32 resolves: a perfect mirror / smooth interface (delta lobes).
    pub delta: bool,
}

/// A direction sampled from a lobe: `value / pdf` is its weight. For delta lobes `value`
/// is the reflectance (or radiance-scaled transmittance) and `pdf` the probability of
/// the choice.
#[derive(Clone, Copy, Debug)]
pub struct LobeSample {
    pub wi: Vec3,
    pub value: Vec3,
    pub pdf: f32,
}

#[inline]
fn average(v: Vec3) -> f32 {
    (v.x + v.y + v.z) * (1.0 / 3.0)
}

/// The probability of reflecting, from the channel averages of R and T.
#[inline]
fn reflect_probability(r: Vec3, t: Vec3, transmits: bool) -> f32 {
    if !transmits {
        return 1.0;
    }
    let (ar, at) = (average(r), average(t));
    if ar + at > 0.0 { ar / (ar + at) } else { 1.0 }
}

/// `wo` refracted through the microfacet `h` (wo·h > 0) into the medium of relative IOR
/// `eta`; None under total internal reflection.
#[inline]
pub fn refract_about(wo: Vec3, h: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = wo.dot(h);
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some(-wo / eta + (cos_i / eta - cos_t) * h)
}

impl GgxLobe {
    /// f cos θi and the pdf of [`Self::sample`] (both 0 for delta lobes). `wo.z > 0`.
    #[inline]
    pub fn eval_pdf(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        if self.delta || !(wo.z > 0.0) {
            return (Vec3::ZERO, 0.0);
        }
        let g = &self.ggx;
        if wi.z > 0.0 {
            let h = (wo + wi).normalize_or_zero();
            let cos = wo.dot(h);
            if !(cos > 0.0) {
                return (Vec3::ZERO, 0.0);
            }
            let (r, t) = self.fresnel.eval(cos);
            let d = g.d(h);
            let f = r * (d * g.g2(wo, wi) / (4.0 * wo.z));
            let pdf = reflect_probability(r, t, self.transmits) * d * g.g1(wo) / (4.0 * wo.z);
            return (f, pdf);
        }
        if !(wi.z < 0.0) || !self.transmits {
            return (Vec3::ZERO, 0.0);
        }
        let eta = self.eta;
        let mut h = -(eta * wi + wo);
        if h.z < 0.0 {
            h = -h;
        }
        let h = h.normalize_or_zero();
        let (cos_o, cos_i) = (wo.dot(h), wi.dot(h));
        // Microfacets seen from behind transmit nothing.
        if !(cos_o > 0.0 && cos_i < 0.0) {
            return (Vec3::ZERO, 0.0);
        }
        let (r, t) = self.fresnel.eval(cos_o);
        let denom = eta * cos_i + cos_o;
        let jacobian = eta * eta * (-cos_i) / (denom * denom);
        let d = g.d(h);
        let common = d * cos_o * jacobian / wo.z;
        let f = t * (common * g.g2(wo, wi) / (eta * eta));
        let pdf = (1.0 - reflect_probability(r, t, true)) * common * g.g1(wo);
        if !(pdf.is_finite() && f.is_finite()) {
            return (Vec3::ZERO, 0.0);
        }
        (f, pdf)
    }

    /// Draws wi: `u` the visible normal, `u_choice` reflection or refraction. None when
    /// the direction is on the wrong side or carries nothing.
    #[inline]
    pub fn sample(&self, wo: Vec3, u_choice: f32, u: Vec2) -> Option<LobeSample> {
        let (wi, value, choice) = self.sample_direction(wo, u_choice, u)?;
        if self.delta {
            return (choice > 0.0 && value.max_element() > 0.0).then_some(LobeSample { wi, value, pdf: choice });
        }
        let (value, pdf) = self.eval_pdf(wo, wi);
        (pdf > 0.0 && pdf.is_finite()).then_some(LobeSample { wi, value, pdf })
    }

    /// [`Self::sample`]'s direction alone, with the Fresnel weight of the branch taken
    /// (reflectance, or radiance-scaled transmittance) and that branch's probability: for
    /// callers that evaluate the BSDF at wi themselves (the Principled mixture does).
    #[inline]
    pub fn sample_direction(&self, wo: Vec3, u_choice: f32, u: Vec2) -> Option<(Vec3, Vec3, f32)> {
        if !(wo.z > 0.0) {
            return None;
        }
        let h = if self.delta { Vec3::Z } else { self.ggx.sample_visible(wo, u) };
        let cos = wo.dot(h);
        if !(cos > 0.0) {
            return None;
        }
        let (r, t) = self.fresnel.eval(cos);
        let pr = reflect_probability(r, t, self.transmits);
        let (wi, value, choice) = if u_choice < pr {
            let wi = 2.0 * cos * h - wo;
            if !(wi.z > 0.0) {
                return None;
            }
            (wi, r, pr)
        } else {
            let wi = refract_about(wo, h, self.eta)?;
            if !(wi.z < 0.0) {
                return None;
            }
            (wi, t / (self.eta * self.eta), 1.0 - pr)
        };
        Some((wi, value, choice))
    }

    /// The weight G2/G1 of a sampled pair without Fresnel, summed over reflection and
    /// refraction in proportion to an exact dielectric Fresnel at h (the energy tables'
    /// integrand; no radiance scaling: energy, not radiance).
    pub(crate) fn table_weight(&self, wo: Vec3, h: Vec3) -> f64 {
        let g = &self.ggx;
        let cos = wo.dot(h);
        if !(cos > 0.0) {
            return 0.0;
        }
        let r = if self.transmits { fresnel_dielectric(cos, self.eta) } else { 1.0 };
        let g1 = g.g1(wo);
        let mut sum = 0.0f64;
        let wr = 2.0 * cos * h - wo;
        if wr.z > 0.0 {
            sum += f64::from(r * g.g2(wo, wr) / g1);
        }
        if self.transmits
            && let Some(wt) = refract_about(wo, h, self.eta)
            && wt.z < 0.0
        {
            sum += f64::from((1.0 - r) * g.g2(wo, wt) / g1);
        }
        sum
    }
}
