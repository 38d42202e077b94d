//! Smooth dielectric interface (glass, water): Fresnel-weighted choice between the
//! mirror reflection and the Snell refraction, both delta lobes.

use super::{BsdfSample, reflect};
use glam::Vec3;

/// Unpolarised Fresnel reflectance of a smooth dielectric interface. `cos_theta_i` is
/// the cosine with the normal, which points to the exterior; `eta` = η_interior /
/// η_exterior. A negative cosine means the light arrives from inside. Returns 1 under
/// total internal reflection.
#[inline]
pub fn fresnel_dielectric(cos_theta_i: f32, eta: f32) -> f32 {
    let (cos_i, eta) = if cos_theta_i < 0.0 { (-cos_theta_i, 1.0 / eta) } else { (cos_theta_i, eta) };
    let cos_i = cos_i.min(1.0);
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let r_parallel = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perpendicular = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (r_parallel * r_parallel + r_perpendicular * r_perpendicular)
}

/// Refracts `wo` (local frame, z = outward normal) through the interface with relative
/// IOR `eta` = η_interior / η_exterior. Returns the transmitted direction and the ratio
/// η_t/η_i seen from `wo`'s side (`eta` outside, 1/`eta` inside), or None under total
/// internal reflection.
#[inline]
pub fn refract(wo: Vec3, eta: f32) -> Option<(Vec3, f32)> {
    let (cos_i, etap, n) = if wo.z < 0.0 { (-wo.z, 1.0 / eta, -Vec3::Z) } else { (wo.z, eta, Vec3::Z) };
    let cos_i = cos_i.min(1.0);
    // Snell: sin θt = sin θi / η'.
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (etap * etap);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some((-wo / etap + (cos_i / etap - cos_t) * n, etap))
}

#[derive(Clone, Copy, Debug)]
pub struct Dielectric {
    /// η_interior / η_exterior; nonsensical values (≤ 0, NaN, ∞) behave as 1.
    pub eta: f32,
    pub tint: Vec3,
}

impl Dielectric {
    /// Reflects with probability F (weight F/F = 1), else refracts (weight T/T = 1 times
    /// the tint and the radiance scaling (η_i/η_t)² = 1/η'²: radiance is compressed into
    /// the smaller solid angle on entering the denser medium, as pbrt's Radiance mode).
    #[inline]
    pub fn sample(&self, wo: Vec3, u_lobe: f32) -> Option<BsdfSample> {
        if wo.z == 0.0 || !wo.is_finite() {
            return None;
        }
        let eta = if self.eta > 0.0 && self.eta.is_finite() { self.eta } else { 1.0 };
        let r = fresnel_dielectric(wo.z, eta);
        let reflection = |pdf| Some(BsdfSample { wi: reflect(wo), weight: Vec3::ONE, pdf, delta: true });
        // r ≥ 1 is total internal reflection (and grazing incidence).
        if u_lobe < r || r >= 1.0 {
            return reflection(r.min(1.0));
        }
        match refract(wo, eta) {
            Some((wi, etap)) => Some(BsdfSample { wi, weight: self.tint / (etap * etap), pdf: 1.0 - r, delta: true }),
            // Only reached if rounding put F just below 1 at the critical angle: all
            // of the energy is reflected there.
            None => reflection(1.0),
        }
    }
}
