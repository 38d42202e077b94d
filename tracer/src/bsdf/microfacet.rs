//! The GGX (Trowbridge–Reitz) microfacet distribution with Smith's height-correlated
//! masking-shadowing, sampled by its visible normals.
//!
//! In the local frame (z = the surface normal), for roughness α (Blender: α = roughness²):
//!
//! ```text
//!     D(h)   = 1 / (π α² (h_x²/α² + h_y²/α² + h_z²)²)
//!     Λ(w)   = (√(1 + α² (w_x² + w_y²) / w_z²) − 1) / 2
//!     G1(w)  = 1 / (1 + Λ(w)),   G2(wo, wi) = 1 / (1 + Λ(wo) + Λ(wi))
//!     D_wo(h) = G1(wo) max(0, wo·h) D(h) / wo_z       (the visible normals seen from wo)
//! ```
//!
//! `sample_visible` draws h from D_wo exactly, by the spherical-cap construction of
//! Dupuy & Benyoub 2023 ("Sampling visible GGX normals with spherical caps"): in the
//! configuration stretched to α = 1 the visible normals are the sum of wo and a direction
//! uniform on the spherical cap z > −wo_z.

use glam::{Vec2, Vec3};
use std::f32::consts::PI;

use crate::sampling::sin_cos_turns;

/// Roughness below which a GGX lobe is treated as a perfect mirror (a delta lobe), as
/// Cycles does (α_x α_y ≤ 2·10⁻¹⁰): f32 directions do not resolve narrower lobes.
pub const DELTA_ALPHA: f32 = 1.5e-5;

/// A GGX distribution of roughness α (along x; `alpha_y` along y, the same unless
/// anisotropic: then D, Λ and the sampling stretch x and y by their own α, and the
/// isotropic formulas stay as they were, bit for bit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ggx {
    pub alpha: f32,
    pub alpha_y: f32,
}

fn clean_alpha(alpha: f32) -> f32 {
    if alpha.is_finite() { alpha.clamp(DELTA_ALPHA, 1.0) } else { 1.0 }
}

impl Ggx {
    pub fn new(alpha: f32) -> Self {
        let alpha = clean_alpha(alpha);
        Self { alpha, alpha_y: alpha }
    }

    /// An anisotropic distribution: roughness `alpha_x` along the tangent (x), `alpha_y`
    /// along the bitangent (y).
    pub fn anisotropic(alpha_x: f32, alpha_y: f32) -> Self {
        Self { alpha: clean_alpha(alpha_x), alpha_y: clean_alpha(alpha_y) }
    }

    #[inline]
    pub fn is_anisotropic(&self) -> bool {
        self.alpha != self.alpha_y
    }

    /// Whether the lobe is narrower than f32 directions resolve (a mirror).
    pub fn is_delta(alpha: f32) -> bool {
        !(alpha > DELTA_ALPHA)
    }

    /// The density of microfacet normals (all above the surface), per unit projected area.
    #[inline]
    pub fn d(&self, h: Vec3) -> f32 {
        if !(h.z > 0.0) {
            return 0.0;
        }
        if self.is_anisotropic() {
            let (ax, ay) = (self.alpha, self.alpha_y);
            let k = (h.x / ax) * (h.x / ax) + (h.y / ay) * (h.y / ay) + h.z * h.z;
            return if k > 0.0 { 1.0 / (PI * ax * ay * k * k) } else { 0.0 };
        }
        let a2 = self.alpha * self.alpha;
        let cos2 = h.z * h.z;
        let k = (h.x * h.x + h.y * h.y) + a2 * cos2;
        if !(k > 0.0) {
            return 0.0;
        }
        a2 / (PI * k * k)
    }

    /// Smith's Λ for direction `w`.
    #[inline]
    pub fn lambda(&self, w: Vec3) -> f32 {
        let z2 = w.z * w.z;
        if !(z2 > 0.0) {
            return f32::INFINITY;
        }
        let t2 = if self.is_anisotropic() {
            let (ax, ay) = (self.alpha, self.alpha_y);
            (ax * ax * w.x * w.x + ay * ay * w.y * w.y) / z2
        } else {
            self.alpha * self.alpha * (w.x * w.x + w.y * w.y) / z2
        };
        0.5 * ((1.0 + t2).sqrt() - 1.0)
    }

    #[inline]
    pub fn g1(&self, w: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(w))
    }

    /// Height-correlated masking-shadowing of the pair.
    #[inline]
    pub fn g2(&self, wo: Vec3, wi: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(wo) + self.lambda(wi))
    }

    /// A microfacet normal drawn from D_wo (wo above the surface, wo_z > 0).
    #[inline]
    pub fn sample_visible(&self, wo: Vec3, u: Vec2) -> Vec3 {
        let (ax, ay) = (self.alpha, self.alpha_y);
        let v = Vec3::new(ax * wo.x, ay * wo.y, wo.z).normalize();
        let (sin_phi, cos_phi) = sin_cos_turns(u.x);
        let z = (1.0 - u.y) * (1.0 + v.z) - v.z;
        let sin_theta = (1.0 - z * z).max(0.0).sqrt();
        let h = Vec3::new(sin_theta * cos_phi, sin_theta * sin_phi, z) + v;
        Vec3::new(ax * h.x, ay * h.y, h.z.max(0.0)).normalize_or(Vec3::Z)
    }

    /// The density of [`Self::sample_visible`] at `h`.
    #[inline]
    pub fn visible_pdf(&self, wo: Vec3, h: Vec3) -> f32 {
        let cos = wo.dot(h);
        if !(cos > 0.0 && wo.z > 0.0) {
            return 0.0;
        }
        self.g1(wo) * cos * self.d(h) / wo.z
    }
}

#[cfg(test)]
// Tests may use the C library's functions: they check values, not platform-free bits.
#[allow(clippy::disallowed_methods)]
mod tests {
    use super::*;
    use crate::bsdf::chi2::{Rng, chi2_sphere, integrate_sphere, sidak_alpha};

    fn dir(theta_deg: f32, phi: f32) -> Vec3 {
        let t = theta_deg.to_radians();
        Vec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), t.cos())
    }

    #[test]
    fn projected_normals_cover_the_surface_once() {
        // ∫ D(h) h_z dh = 1 for every α.
        for alpha in [0.05, 0.2, 0.5, 1.0] {
            let g = Ggx::new(alpha);
            let total = integrate_sphere(&|h: Vec3| (g.d(h) * h.z.max(0.0)) as f64, 96, 64, 0.0);
            assert!((total - 1.0).abs() < 2e-3, "α {alpha}: {total}");
        }
    }

    /// ∫ f over the upper hemisphere by the midpoint rule in (θ, φ), fine enough for
    /// lobes down to α = 0.05.
    fn hemisphere(f: impl Fn(Vec3) -> f64) -> f64 {
        let (nt, np) = (2000, 400);
        let (dt, dp) = (std::f64::consts::FRAC_PI_2 / nt as f64, std::f64::consts::TAU / np as f64);
        let mut sum = 0.0;
        for i in 0..nt {
            let t = (i as f64 + 0.5) * dt;
            for j in 0..np {
                let p = (j as f64 + 0.5) * dp;
                let h = Vec3::new((t.sin() * p.cos()) as f32, (t.sin() * p.sin()) as f32, t.cos() as f32);
                sum += f(h) * t.sin() * dt * dp;
            }
        }
        sum
    }

    #[test]
    fn visible_normals_integrate_to_one() {
        for alpha in [0.05, 0.3, 1.0] {
            for theta in [0.0, 40.0, 80.0] {
                let g = Ggx::new(alpha);
                let wo = dir(theta, 0.4);
                let total = hemisphere(|h| g.visible_pdf(wo, h) as f64);
                assert!((total - 1.0).abs() < 1e-3, "α {alpha} θ {theta}: {total}");
            }
        }
    }

    /// Anisotropic: the projected normals still cover the surface once, the visible
    /// normals integrate to one, and sampling follows their density (χ²).
    #[test]
    fn anisotropic_normals_integrate_and_sample_as_their_density() {
        let cases = [(0.6f32, 0.15f32, 0.0f32), (0.15, 0.6, 50.0), (0.9, 0.3, 75.0), (0.4, 0.8, 30.0)];
        let alpha_level = sidak_alpha(cases.len());
        for (k, &(ax, ay, theta)) in cases.iter().enumerate() {
            let g = Ggx::anisotropic(ax, ay);
            assert!(g.is_anisotropic());
            let covered = hemisphere(|h| (g.d(h) * h.z) as f64);
            assert!((covered - 1.0).abs() < 1e-3, "α ({ax}, {ay}): ∫D cos = {covered}");
            let wo = dir(theta, 0.7);
            let visible = hemisphere(|h| g.visible_pdf(wo, h) as f64);
            assert!((visible - 1.0).abs() < 1e-3, "α ({ax}, {ay}) θ {theta}: ∫D_wo = {visible}");
            let r = chi2_sphere(
                |rng: &mut Rng| Some(g.sample_visible(wo, rng.vec2())),
                |h| g.visible_pdf(wo, h) as f64,
                32,
                64,
                400_000,
                177 + k as u64,
                None,
            );
            assert!(
                r.p_value > alpha_level,
                "α ({ax}, {ay}) θ {theta}: χ² {:.1} / {} dof, p {:.2e}",
                r.statistic,
                r.dof,
                r.p_value
            );
        }
    }

    #[test]
    fn visible_normal_sampling_matches_its_pdf_chi2() {
        let cases: Vec<(f32, f32)> =
            [0.2f32, 0.4, 0.7, 1.0].iter().flat_map(|&a| [0.0f32, 45.0, 75.0].map(|t| (a, t))).collect();
        let alpha_level = sidak_alpha(cases.len());
        for (k, &(alpha, theta)) in cases.iter().enumerate() {
            let g = Ggx::new(alpha);
            let wo = dir(theta, 1.1);
            // Cells equal in cos θ are wide near the pole: a zoom there for the narrower
            // distributions (what falls outside it is tested as one category).
            let cap = (alpha < 0.5).then_some((Vec3::Z, (5.0 * alpha as f64).atan().cos()));
            let r = chi2_sphere(
                |rng: &mut Rng| Some(g.sample_visible(wo, rng.vec2())),
                |h| g.visible_pdf(wo, h) as f64,
                32,
                64,
                400_000,
                77 + k as u64,
                cap,
            );
            assert!(
                r.p_value > alpha_level,
                "α {alpha} θ {theta}: χ² {:.1} / {} dof, p {:.2e}",
                r.statistic,
                r.dof,
                r.p_value
            );
        }
    }
}
