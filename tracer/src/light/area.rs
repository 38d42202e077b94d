//! Area lights as Blender has them: a one-sided rectangle or ellipse (a disk is an
//! ellipse with equal axes) of constant radiance that lights the scene but is not a
//! surface — camera rays do not see it and it blocks nothing; rays that scatter off
//! surfaces do meet it, so that it shows in reflections and weighs against light
//! sampling by MIS.
//!
//! Rectangles are sampled uniformly in the solid angle they subtend (the spherical
//! rectangle of Ureña, Fajardo & King 2013), which removes the noise of sampling by
//! area near a large light; a rectangle so far away that its solid angle is lost to
//! rounding is sampled by area. Ellipses are sampled by area (the concentric map).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::math;
use crate::sampling::sample_uniform_disk_concentric;

/// The outline of an area light.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum AreaShape {
    Rectangle,
    /// An ellipse with semi-axes `|ex|`, `|ey|` (a disk when they are equal).
    Ellipse,
}

/// Below this solid angle (sr) a rectangle is sampled by area: the spherical rectangle's
/// solid angle is a sum of four angles minus 2π, and its rounding grows relative to it.
const MIN_SOLID_ANGLE: f32 = 1e-3;

/// An area light's shape and place: centre, the half-axes `ex`, `ey` (orthogonal), and
/// the unit normal of the side it emits to.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Area {
    pub shape: AreaShape,
    pub center: Vec3,
    pub ex: Vec3,
    pub ey: Vec3,
    pub normal: Vec3,
    pub area: f32,
}

/// A point sampled on an area light as seen from `p`.
#[derive(Clone, Copy, Debug)]
pub struct AreaSample {
    pub q: Vec3,
    pub wi: Vec3,
    /// Solid-angle pdf.
    pub pdf: f32,
}

/// The spherical rectangle of a rectangle seen from a point (Ureña et al. 2013, §3):
/// the rectangle's frame, the point's coordinates in it, and the solid angle.
struct SphericalRect {
    x: Vec3,
    y: Vec3,
    z: Vec3,
    x0: f32,
    x1: f32,
    y0: f32,
    y1: f32,
    z0: f32,
    b0: f32,
    b1: f32,
    k: f32,
    solid_angle: f32,
}

impl SphericalRect {
    fn new(a: &Area, p: Vec3) -> Self {
        let (w, h) = (2.0 * a.ex.length(), 2.0 * a.ey.length());
        let (x, y) = (a.ex / (0.5 * w), a.ey / (0.5 * h));
        let mut z = x.cross(y);
        let d = a.center - a.ex - a.ey - p;
        let (x0, y0, mut z0) = (d.dot(x), d.dot(y), d.dot(z));
        if z0 > 0.0 {
            z0 = -z0;
            z = -z;
        }
        let (x1, y1) = (x0 + w, y0 + h);
        let v00 = Vec3::new(x0, y0, z0);
        let v01 = Vec3::new(x0, y1, z0);
        let v10 = Vec3::new(x1, y0, z0);
        let v11 = Vec3::new(x1, y1, z0);
        let n0 = v00.cross(v10).normalize_or_zero();
        let n1 = v10.cross(v11).normalize_or_zero();
        let n2 = v11.cross(v01).normalize_or_zero();
        let n3 = v01.cross(v00).normalize_or_zero();
        let angle = |a: Vec3, b: Vec3| math::acos((-a.dot(b)).clamp(-1.0, 1.0));
        let (g0, g1, g2, g3) = (angle(n0, n1), angle(n1, n2), angle(n2, n3), angle(n3, n0));
        let k = 2.0 * PI - g2 - g3;
        let solid_angle = g0 + g1 - k;
        Self { x, y, z, x0, x1, y0, y1, z0, b0: n0.z, b1: n2.z, k, solid_angle }
    }

    /// The point for `u` on the rectangle, uniform in solid angle, relative to `p`.
    fn sample(&self, u: Vec2) -> Vec3 {
        let au = u.x * self.solid_angle + self.k;
        let (sin_au, cos_au) = math::sin_cos(au);
        let fu = (cos_au * self.b0 - self.b1) / sin_au;
        let cu = (1.0 / (fu * fu + self.b0 * self.b0).sqrt()).copysign(fu).clamp(-1.0, 1.0);
        let xu = (-(cu * self.z0) / (1.0 - cu * cu).max(0.0).sqrt()).clamp(self.x0, self.x1);
        let xu = if xu.is_finite() { xu } else { self.x0 };
        let d = (xu * xu + self.z0 * self.z0).sqrt();
        let h0 = self.y0 / (d * d + self.y0 * self.y0).sqrt();
        let h1 = self.y1 / (d * d + self.y1 * self.y1).sqrt();
        let hv = h0 + u.y * (h1 - h0);
        let hv2 = hv * hv;
        let yv = if hv2 < 1.0 - 1e-6 { (hv * d / (1.0 - hv2).sqrt()).clamp(self.y0, self.y1) } else { self.y1 };
        xu * self.x + yv * self.y + self.z0 * self.z
    }
}

impl Area {
    /// Whether `p` lies on the emitting side.
    #[inline]
    fn faces(&self, p: Vec3) -> bool {
        (p - self.center).dot(self.normal) > 0.0
    }

    /// A point on the light for `u`, as seen from `p` (None behind the light).
    pub fn sample(&self, p: Vec3, u: Vec2) -> Option<AreaSample> {
        if !self.faces(p) {
            return None;
        }
        if self.shape == AreaShape::Rectangle {
            let r = SphericalRect::new(self, p);
            if r.solid_angle > MIN_SOLID_ANGLE {
                let d = r.sample(u);
                let dist = d.length();
                if !(dist > 0.0) {
                    return None;
                }
                return Some(AreaSample { q: p + d, wi: d / dist, pdf: 1.0 / r.solid_angle });
            }
        }
        let (a, b) = match self.shape {
            AreaShape::Rectangle => (2.0 * u.x - 1.0, 2.0 * u.y - 1.0),
            AreaShape::Ellipse => sample_uniform_disk_concentric(u).into(),
        };
        let q = self.center + a * self.ex + b * self.ey;
        let d = q - p;
        let d2 = d.length_squared();
        let wi = d / d2.sqrt();
        let cos_l = -wi.dot(self.normal);
        if !(d2 > 0.0 && cos_l > 0.0) {
            return None;
        }
        Some(AreaSample { q, wi, pdf: d2 / (cos_l * self.area) })
    }

    /// The solid-angle pdf with which [`Area::sample`] at `p` gives direction `wi`, which
    /// meets the light at `q`.
    pub fn pdf(&self, p: Vec3, wi: Vec3, q: Vec3) -> f32 {
        if !self.faces(p) {
            return 0.0;
        }
        if self.shape == AreaShape::Rectangle {
            let r = SphericalRect::new(self, p);
            if r.solid_angle > MIN_SOLID_ANGLE {
                return 1.0 / r.solid_angle;
            }
        }
        let cos_l = -wi.dot(self.normal);
        if cos_l <= 0.0 {
            return 0.0;
        }
        (q - p).length_squared() / (cos_l * self.area)
    }

    /// Where a ray from `origin` along `dir` (unit) meets the light's emitting face
    /// before `tmax`: `(t, point)`.
    #[inline]
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<(f32, Vec3)> {
        let denom = dir.dot(self.normal);
        // Only from the front: the ray travels against the normal.
        if !(denom < 0.0) {
            return None;
        }
        let t = (self.center - origin).dot(self.normal) / denom;
        if !(t > 0.0 && t < tmax) {
            return None;
        }
        let q = origin + t * dir;
        let r = q - self.center;
        let (a, b) = (r.dot(self.ex) / self.ex.length_squared(), r.dot(self.ey) / self.ey.length_squared());
        let inside = match self.shape {
            AreaShape::Rectangle => a.abs() <= 1.0 && b.abs() <= 1.0,
            AreaShape::Ellipse => a * a + b * b <= 1.0,
        };
        inside.then_some((t, q))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::disallowed_methods)] // values checked, not platform-free bits
    use super::*;

    fn rect(w: f32, h: f32, center: Vec3) -> Area {
        // Facing down (−Y), axes along X and Z.
        Area {
            shape: AreaShape::Rectangle,
            center,
            ex: Vec3::X * 0.5 * w,
            ey: Vec3::Z * 0.5 * h,
            normal: -Vec3::Y,
            area: w * h,
        }
    }

    /// Irradiance at `p` on a surface with normal `n`, by `n` samples of the light.
    fn irradiance(a: &Area, p: Vec3, n: Vec3, count: u32) -> f64 {
        let mut sum = 0.0f64;
        for i in 0..count {
            let mut sampler = crate::sampler::Sampler::new(11, 0, 0, i);
            if let Some(s) = a.sample(p, sampler.next_2d()) {
                let hit = a.intersect(p, s.wi, f32::INFINITY).expect("the sample lies on the light");
                assert!((hit.1 - s.q).length() < 1e-3 * (s.q - p).length(), "{:?} vs {:?}", hit.1, s.q);
                let pdf = a.pdf(p, s.wi, s.q);
                assert!((pdf - s.pdf).abs() <= 1e-4 * s.pdf, "pdf {pdf} vs {}", s.pdf);
                sum += f64::from(s.wi.dot(n).max(0.0) / s.pdf);
            }
        }
        sum / f64::from(count)
    }

    #[test]
    fn a_rectangle_delivers_its_form_factor() {
        // A point under the corner of a w × h rectangle at height c, facing it: E / L = π F
        // for the classic corner form factor F = [X/√(1+X²) atan(Y/√(1+X²)) + (X ↔ Y)] / 2π.
        let corner = |a: f64, b: f64, c: f64| {
            let (x, y) = (a / c, b / c);
            let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
            0.5 * (x / sx * (y / sx).atan() + y / sy * (x / sy).atan())
        };
        for (w, h, c) in [(2.0f32, 1.0f32, 1.0f32), (0.3, 0.2, 2.0), (6.0, 4.0, 0.5)] {
            let a = rect(w, h, Vec3::new(0.5 * w, c, 0.5 * h));
            let e = irradiance(&a, Vec3::ZERO, Vec3::Y, 1 << 14);
            let exact = corner(w as f64, h as f64, c as f64);
            assert!((e / exact - 1.0).abs() < 2e-3, "{w}×{h} at {c}: {e} against {exact}");
        }
    }

    #[test]
    fn solid_angle_sampling_is_exact_for_a_constant_integrand() {
        // Facing away from the light's normal the cosine is not in the pdf; the estimate
        // of the solid angle itself (1/pdf) has no variance at all.
        let a = rect(1.0, 3.0, Vec3::new(0.2, 1.5, -0.4));
        let r = SphericalRect::new(&a, Vec3::ZERO);
        assert!(r.solid_angle > MIN_SOLID_ANGLE);
        let s = a.sample(Vec3::ZERO, Vec2::new(0.3, 0.8)).unwrap();
        assert_eq!(s.pdf, 1.0 / r.solid_angle);
    }

    #[test]
    fn a_disk_delivers_pi_l_r2_over_h2_plus_r2() {
        let (r, h) = (0.8f32, 1.5f32);
        let disk = Area {
            shape: AreaShape::Ellipse,
            center: Vec3::new(0.0, h, 0.0),
            ex: Vec3::X * r,
            ey: Vec3::Z * r,
            normal: -Vec3::Y,
            area: PI * r * r,
        };
        let e = irradiance(&disk, Vec3::ZERO, Vec3::Y, 1 << 16);
        let exact = std::f64::consts::PI * f64::from(r * r / (h * h + r * r));
        assert!((e / exact - 1.0).abs() < 4e-3, "{e} against {exact}");
    }

    #[test]
    fn only_the_front_emits_and_rays_miss_outside_the_outline() {
        let a = rect(2.0, 2.0, Vec3::new(0.0, 1.0, 0.0));
        assert!(a.sample(Vec3::new(0.0, 2.0, 0.0), Vec2::splat(0.5)).is_none(), "behind");
        assert!(a.intersect(Vec3::new(0.0, 2.0, 0.0), -Vec3::Y, 10.0).is_none(), "from behind");
        assert!(a.intersect(Vec3::ZERO, Vec3::Y, 10.0).is_some());
        assert!(a.intersect(Vec3::ZERO, Vec3::Y, 0.5).is_none(), "beyond tmax");
        assert!(a.intersect(Vec3::new(1.2, 0.0, 0.0), Vec3::Y, 10.0).is_none(), "outside");
        let e = Area { shape: AreaShape::Ellipse, ..a };
        assert!(e.intersect(Vec3::new(0.9, 0.0, 0.9), Vec3::Y, 10.0).is_none(), "outside the ellipse");
        assert!(a.intersect(Vec3::new(0.9, 0.0, 0.9), Vec3::Y, 10.0).is_some(), "inside the rectangle");
    }
}
