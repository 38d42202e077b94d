//! Lights with a size, as Blender has them, for soft shadows:
//!
//! - a point or spot light with a radius: a disk of that radius at the light, always
//!   facing the point it lights (Cycles' model for Blender's default "Soft Falloff"),
//!   of radiance I / (π r²) for radiant intensity I, so that far away it delivers what
//!   the point light does, I / d²; a spot's cone attenuates it by the sampled
//!   direction;
//! - a sun with an angle: a disc at infinity of angular radius α, radiance
//!   E / (π sin² α) for irradiance E (on a surface facing it, as the hard sun's).
//!
//! Neither is a surface: light sampling finds them, and so do rays scattered by surfaces
//! (seen in reflections, weighted by MIS), but they block nothing and camera rays do not
//! see them.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::geometry::Frame;
use crate::sampling::{sample_uniform_disk_concentric, spherical_direction};

/// A spot light's cone: `smoothstep` between the cosines, of the angle between the
/// spot's axis and the direction from the light.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Cone {
    pub direction: Vec3,
    pub cos_total: f32,
    pub cos_falloff_start: f32,
}

/// A point (or, with a cone, spot) light of radius `radius`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SoftPoint {
    pub position: Vec3,
    pub radius: f32,
    /// I / (π r²).
    pub radiance: Vec3,
    pub cone: Option<Cone>,
}

/// A sun of angular radius α: `one_minus_cos` = 1 − cos α (as 2 sin²(α/2), which keeps
/// its precision for the real sun's quarter of a degree).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sun {
    /// The way the light travels (unit).
    pub direction: Vec3,
    pub radiance: Vec3,
    pub one_minus_cos: f32,
}

impl SoftPoint {
    /// The disk's unit normal as seen from `p` (towards `p`) and `p`'s squared distance.
    #[inline]
    fn facing(&self, p: Vec3) -> Option<(Vec3, f32)> {
        let d = p - self.position;
        let d2 = d.length_squared();
        (d2 > 1e-12 * self.radius * self.radius && d2.is_finite()).then(|| (d / d2.sqrt(), d2))
    }

    /// The cone's attenuation of light leaving along `w` (1 without a cone).
    #[inline]
    pub fn attenuation(&self, w: Vec3) -> f32 {
        self.cone.map_or(1.0, |c| super::smoothstep(w.dot(c.direction), c.cos_total, c.cos_falloff_start))
    }

    /// A point on the disk for `u`, seen from `p`: `(wi, point, solid-angle pdf)`.
    pub fn sample(&self, p: Vec3, u: Vec2) -> Option<(Vec3, Vec3, f32)> {
        let (n, _) = self.facing(p)?;
        let frame = Frame::from_normal(n);
        let o = sample_uniform_disk_concentric(u) * self.radius;
        let q = self.position + frame.to_world(Vec3::new(o.x, o.y, 0.0));
        let d = q - p;
        let d2 = d.length_squared();
        let wi = d / d2.sqrt();
        let cos_l = -wi.dot(n);
        if !(cos_l > 0.0 && d2 > 0.0) {
            return None;
        }
        Some((wi, q, d2 / (cos_l * PI * self.radius * self.radius)))
    }

    /// The solid-angle pdf of [`SoftPoint::sample`] at `p` for `wi` meeting the disk at `q`.
    pub fn pdf(&self, p: Vec3, wi: Vec3, q: Vec3) -> f32 {
        let Some((n, _)) = self.facing(p) else { return 0.0 };
        let cos_l = -wi.dot(n);
        if cos_l <= 0.0 {
            return 0.0;
        }
        (q - p).length_squared() / (cos_l * PI * self.radius * self.radius)
    }

    /// Where a ray from `origin` along `dir` (unit) meets the disk facing `origin`.
    #[inline]
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<(f32, Vec3)> {
        let (n, _) = self.facing(origin)?;
        let denom = dir.dot(n);
        if !(denom < 0.0) {
            return None;
        }
        let t = (self.position - origin).dot(n) / denom;
        let q = origin + t * dir;
        (t > 0.0 && t < tmax && (q - self.position).length_squared() <= self.radius * self.radius).then_some((t, q))
    }
}

impl Sun {
    /// The direction towards the sun's centre.
    #[inline]
    fn axis(&self) -> Vec3 {
        -self.direction
    }

    /// A direction within the disc, uniform in solid angle: `(wi, pdf)`.
    pub fn sample(&self, u: Vec2) -> (Vec3, f32) {
        let one_minus = u.x * self.one_minus_cos;
        let cos_theta = 1.0 - one_minus;
        let sin_theta = (one_minus * (2.0 - one_minus)).max(0.0).sqrt();
        let local = spherical_direction(sin_theta, cos_theta, u.y);
        (Frame::from_normal(self.axis()).to_world(local).normalize(), self.pdf_inside())
    }

    #[inline]
    fn pdf_inside(&self) -> f32 {
        1.0 / (2.0 * PI * self.one_minus_cos)
    }

    /// Whether direction `wi` (unit) looks into the disc: 1 − cos θ from the axis as
    /// |wi − axis|² / 2, precise for small angles.
    #[inline]
    pub fn contains(&self, wi: Vec3) -> bool {
        0.5 * (wi - self.axis()).length_squared() <= self.one_minus_cos
    }

    /// The solid-angle pdf of [`Sun::sample`] for `wi`.
    pub fn pdf(&self, wi: Vec3) -> f32 {
        if self.contains(wi) { self.pdf_inside() } else { 0.0 }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::disallowed_methods)] // values checked, not platform-free bits
    use super::*;

    #[test]
    fn a_disk_light_far_away_is_the_point_light() {
        // E at distance d facing the disk: π L r² / (d² + r²) = I / (d² + r²).
        let (i, r) = (5.0f32, 0.3f32);
        let light = SoftPoint { position: Vec3::ZERO, radius: r, radiance: Vec3::splat(i / (PI * r * r)), cone: None };
        for d in [0.5f32, 2.0, 20.0] {
            let p = Vec3::new(0.0, 0.0, d);
            let n = 1 << 14;
            let mut e = 0.0f64;
            for k in 0..n {
                let mut s = crate::sampler::Sampler::new(2, 0, 0, k);
                let (wi, q, pdf) = light.sample(p, s.next_2d()).unwrap();
                assert!((light.pdf(p, wi, q) - pdf).abs() <= 1e-4 * pdf);
                let (_, hit) = light.intersect(p, wi, f32::INFINITY).expect("the sample is on the disk");
                assert!((hit - q).length() < 1e-4 * d);
                e += f64::from(light.radiance.x * (-wi.z) / pdf);
            }
            e /= f64::from(n);
            let exact = f64::from(i / (d * d + r * r));
            assert!((e / exact - 1.0).abs() < 2e-3, "at {d}: {e} against {exact}");
        }
    }

    #[test]
    fn the_sun_delivers_its_irradiance_whatever_its_size() {
        for angle_deg in [0.526f32, 5.0, 30.0] {
            let a = 0.5 * angle_deg.to_radians();
            let e = 3.0f32;
            let sun = Sun {
                direction: Vec3::new(0.3, -1.0, 0.2).normalize(),
                radiance: Vec3::splat(e / (PI * a.sin() * a.sin())),
                one_minus_cos: 2.0 * (0.5 * a).sin().powi(2),
            };
            // A surface facing the sun.
            let n = -sun.direction;
            let count = 1 << 14;
            let mut sum = 0.0f64;
            for k in 0..count {
                let mut s = crate::sampler::Sampler::new(8, 0, 0, k);
                let (wi, pdf) = sun.sample(s.next_2d());
                assert!(sun.contains(wi) || (wi + sun.direction).length() > 0.999 * (2.0 * sun.one_minus_cos).sqrt());
                assert_eq!(sun.pdf(-sun.direction), pdf);
                sum += f64::from(sun.radiance.x * wi.dot(n) / pdf);
            }
            let got = sum / f64::from(count);
            assert!((got / f64::from(e) - 1.0).abs() < 2e-3, "{angle_deg}°: {got} against {e}");
            assert!(!sun.contains(Vec3::new(1.0, 0.0, 0.0)));
        }
    }
}
