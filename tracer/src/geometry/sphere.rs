use glam::Vec3;

use super::Ray;

/// Intersects a ray (unit direction) with a sphere; returns the nearest `t` in
/// `(tmin, tmax)`. Uses the numerically careful form of the quadratic from pbrt-v4 /
/// Ray Tracing Gems ch. 7, so hits stay accurate far from the sphere.
#[inline]
pub fn intersect_sphere(ray: &Ray, center: Vec3, radius: f32, tmin: f32, tmax: f32) -> Option<f32> {
    let f = ray.origin - center;
    let a = ray.dir.length_squared();
    let b = -f.dot(ray.dir);
    // discriminant / 4 computed as r² - |f - (f·d/|d|²) d|², which avoids cancellation.
    let l = f + (b / a) * ray.dir;
    let disc = a * (radius * radius - l.length_squared());
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    let q = if b >= 0.0 { b + sq } else { b - sq };
    let mut t0 = q / a;
    let mut t1 = if q != 0.0 { (f.length_squared() - radius * radius) / q } else { t0 };
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    if t0 > tmin && t0 < tmax {
        Some(t0)
    } else if t1 > tmin && t1 < tmax {
        Some(t1)
    } else {
        None
    }
}

/// The distance below which a ray leaving a sphere's surface is taken to hit its own
/// starting point again (rounding), relative to the radius and the center's magnitude.
#[inline]
pub fn sphere_self_hit_epsilon(center: Vec3, radius: f32) -> f32 {
    1e-4 * radius + 2e-6 * center.abs().max_element()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn front_and_inside_hits() {
        let r = Ray::new(Vec3::new(0.0, 0.0, -5.0), Vec3::Z);
        assert!((intersect_sphere(&r, Vec3::ZERO, 1.0, 0.0, f32::INFINITY).unwrap() - 4.0).abs() < 1e-5);
        let r = Ray::new(Vec3::ZERO, Vec3::Z);
        assert!((intersect_sphere(&r, Vec3::ZERO, 1.0, 0.0, f32::INFINITY).unwrap() - 1.0).abs() < 1e-6);
        let r = Ray::new(Vec3::new(0.0, 2.0, -5.0), Vec3::Z);
        assert!(intersect_sphere(&r, Vec3::ZERO, 1.0, 0.0, f32::INFINITY).is_none());
        // Far away: still accurate.
        let r = Ray::new(Vec3::new(0.0, 0.0, -1e5), Vec3::Z);
        let t = intersect_sphere(&r, Vec3::ZERO, 1.0, 0.0, f32::INFINITY).unwrap();
        assert!((t - (1e5 - 1.0)).abs() < 0.02);
    }
}
