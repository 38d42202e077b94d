//! Blender 4.x's sheen: the microfiber sheen of Zeltner, Burley and Chiang (2022), a
//! linearly transformed cosine (LTC) whose matrix and albedo are tabulated over the
//! roughness and cos θo ([`super::sheen_ltc`]).
//!
//! In a frame whose x axis points towards wo's side, M = [[a, 0, b], [0, a, 0], [0, 0, 1]]
//! takes a lobe direction ω to a cosine-distributed ω' = Mω / |Mω|, so the lobe's density
//! is D(ω) = (1/π) ω'_z · |det M| / |Mω|³ = (1/π) z · (a / L²)² with L² = |Mω|² =
//! (a x + b z)² + (a y)² + z² (the form Cycles evaluates). M keeps z, so the lobe stays
//! in the upper hemisphere and integrates to 1 there.
//! The BSDF times cos θi *is* that density scaled by the albedo, so sampling it is exact.

use glam::{Vec2, Vec3};

use super::sheen_ltc::SHEEN_LTC;
use crate::geometry::Azimuth;
use crate::sampling::sample_uniform_disk_concentric;

/// The sheen lobe seen from one wo.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SheenLobe {
    a: f32,
    b: f32,
    /// wo's azimuth in the shading frame (cos, sin): the LTC's frame is turned to it.
    azimuth: Azimuth,
}

/// Cycles' `lookup_table_read`: linear interpolation over `size` samples spanning [0, 1].
fn read_1d(row: &[f32], x: f32) -> f32 {
    let size = row.len();
    let x = x.clamp(0.0, 1.0) * (size - 1) as f32;
    let i = (x as usize).min(size - 1);
    let j = (i + 1).min(size - 1);
    let t = x - i as f32;
    if t == 0.0 { row[i] } else { (1.0 - t) * row[i] + t * row[j] }
}

/// `lookup_table_read_2D` over a 32 × 32 table: x = cos θo (columns), y = roughness (rows).
fn read_2d(table: &[f32; 1024], x: f32, y: f32) -> f32 {
    let y = y.clamp(0.0, 1.0) * 31.0;
    let i = (y as usize).min(31);
    let j = (i + 1).min(31);
    let t = y - i as f32;
    let r0 = read_1d(&table[32 * i..32 * i + 32], x);
    if t == 0.0 {
        return r0;
    }
    (1.0 - t) * r0 + t * read_1d(&table[32 * j..32 * j + 32], x)
}

impl SheenLobe {
    /// The lobe for `roughness` seen from `wo` (wo.z > 0), and its albedo; `None` where
    /// the fit has no valid transform (Cycles then drops the closure).
    pub fn at(roughness: f32, wo: Vec3) -> Option<(Self, f32)> {
        let r = roughness.clamp(1e-3, 1.0);
        let mu = wo.z.clamp(0.0, 1.0);
        let a = read_2d(&SHEEN_LTC[0], mu, r);
        let b = read_2d(&SHEEN_LTC[1], mu, r);
        let albedo = read_2d(&SHEEN_LTC[2], mu, r);
        if a.abs() < 1e-5 || albedo < 1e-5 {
            return None;
        }
        let planar = Vec2::new(wo.x, wo.y);
        let len = planar.length();
        // Straight above, the azimuth is arbitrary (and the fit is symmetric there).
        let azimuth = Azimuth(if len > 1e-7 { planar / len } else { Vec2::X });
        Some((Self { a, b, azimuth }, albedo))
    }

    /// The density at `wi` (shading frame): the BSDF times cos θi over the albedo, and
    /// the pdf of [`Self::sample`].
    #[inline]
    pub fn density(&self, wi: Vec3) -> f32 {
        let o = self.azimuth.to_local(wi);
        if o.z <= 0.0 {
            return 0.0;
        }
        let (a, b) = (self.a, self.b);
        let len2 = (a * o.x + b * o.z) * (a * o.x + b * o.z) + (a * o.y) * (a * o.y) + o.z * o.z;
        let d = std::f32::consts::FRAC_1_PI * o.z * (a / len2) * (a / len2);
        if d.is_finite() { d } else { 0.0 }
    }

    /// A direction distributed by [`Self::density`].
    #[inline]
    pub fn sample(&self, u: Vec2) -> Option<Vec3> {
        let disk = sample_uniform_disk_concentric(u);
        let z = (1.0 - disk.length_squared()).max(0.0).sqrt();
        let o = Vec3::new(disk.x - z * self.b, disk.y, z * self.a).normalize_or_zero();
        let wi = self.azimuth.to_world(o);
        (wi.z > 0.0 && wi.is_finite()).then_some(wi)
    }
}

#[cfg(test)]
#[allow(clippy::disallowed_methods)]
mod tests {
    use super::*;

    #[test]
    fn the_table_reads_its_corners_and_interpolates_between() {
        let t = &SHEEN_LTC[2];
        assert_eq!(read_2d(t, 0.0, 0.0), t[0]);
        assert_eq!(read_2d(t, 1.0, 1.0), t[1023]);
        assert_eq!(read_2d(t, 1.0, 0.0), t[31]);
        let mid = read_2d(t, 0.5 / 31.0, 0.0);
        assert!((mid - 0.5 * (t[0] + t[1])).abs() < 1e-6);
    }

    #[test]
    fn the_density_integrates_to_one_over_the_hemisphere() {
        for (r, mu) in [(0.5, 0.8), (0.2, 0.3), (1.0, 0.05), (0.7, 1.0)] {
            let wo = Vec3::new((1.0f32 - mu * mu).sqrt() * 0.6, (1.0f32 - mu * mu).sqrt() * 0.8, mu);
            let Some((lobe, albedo)) = SheenLobe::at(r, wo) else {
                panic!("no lobe at roughness {r}, μ {mu}");
            };
            assert!(albedo > 0.0 && albedo <= 1.0);
            // Midpoint rule over (cos θ, φ).
            let (n_t, n_p) = (400, 400);
            let mut sum = 0.0f64;
            for i in 0..n_t {
                let c = (i as f32 + 0.5) / n_t as f32;
                let s = (1.0 - c * c).sqrt();
                for j in 0..n_p {
                    let (sp, cp) = (std::f32::consts::TAU * (j as f32 + 0.5) / n_p as f32).sin_cos();
                    sum += f64::from(lobe.density(Vec3::new(s * cp, s * sp, c)));
                }
            }
            let integral = sum * std::f64::consts::TAU / (n_t * n_p) as f64;
            assert!((integral - 1.0).abs() < 2e-3, "roughness {r}, μ {mu}: {integral}");
        }
    }
}
