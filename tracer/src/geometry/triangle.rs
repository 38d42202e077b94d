//! Watertight ray–triangle intersection (Woop, Benthin and Wald, JCGT 2013): a ray that
//! crosses a shared edge hits at least one of the two triangles, so closed meshes have
//! no cracks for light to leak through.

use glam::Vec3;

use super::Ray;

/// Ray-specific precomputation for the watertight test: the permutation that makes the
/// largest direction component z, and the shear that maps the ray onto +z.
#[derive(Clone, Copy, Debug)]
pub struct RayShear {
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f32,
    sy: f32,
    sz: f32,
}

impl RayShear {
    #[inline]
    pub fn new(dir: Vec3) -> Self {
        let a = dir.abs();
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let sz = 1.0 / dir[kz];
        Self { kx, ky, kz, sx: dir[kx] * sz, sy: dir[ky] * sz, sz }
    }
}

/// A hit on a triangle: distance and the barycentric weights of vertices 1 and 2
/// (vertex 0 has `1 - b1 - b2`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    pub t: f32,
    pub b1: f32,
    pub b2: f32,
}

/// Intersects the ray with triangle (p0, p1, p2) for `0 < t < tmax`.
#[inline]
pub fn intersect_triangle(ray: &Ray, shear: &RayShear, p0: Vec3, p1: Vec3, p2: Vec3, tmax: f32) -> Option<TriangleHit> {
    let (kx, ky, kz) = (shear.kx, shear.ky, shear.kz);
    let a = p0 - ray.origin;
    let b = p1 - ray.origin;
    let c = p2 - ray.origin;
    let ax = a[kx] - shear.sx * a[kz];
    let ay = a[ky] - shear.sy * a[kz];
    let bx = b[kx] - shear.sx * b[kz];
    let by = b[ky] - shear.sy * b[kz];
    let cx = c[kx] - shear.sx * c[kz];
    let cy = c[ky] - shear.sy * c[kz];

    let mut u = cx * by - cy * bx;
    let mut v = ax * cy - ay * cx;
    let mut w = bx * ay - by * ax;
    // Fall back to double precision on an edge, as the paper prescribes, so that the
    // sign test is exact there.
    if u == 0.0 || v == 0.0 || w == 0.0 {
        u = (cx as f64 * by as f64 - cy as f64 * bx as f64) as f32;
        v = (ax as f64 * cy as f64 - ay as f64 * cx as f64) as f32;
        w = (bx as f64 * ay as f64 - by as f64 * ax as f64) as f32;
    }
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return None;
    }
    let det = u + v + w;
    if det == 0.0 {
        return None;
    }
    let az = shear.sz * a[kz];
    let bz = shear.sz * b[kz];
    let cz = shear.sz * c[kz];
    let t_scaled = u * az + v * bz + w * cz;
    // Compare t * det against [0, tmax * det] without dividing; signs follow det.
    if det < 0.0 && (t_scaled >= 0.0 || t_scaled < tmax * det) {
        return None;
    }
    if det > 0.0 && (t_scaled <= 0.0 || t_scaled > tmax * det) {
        return None;
    }
    let inv_det = 1.0 / det;
    let t = t_scaled * inv_det;
    if !(t > 0.0 && t < tmax) {
        return None;
    }
    Some(TriangleHit { t, b1: v * inv_det, b2: w * inv_det })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(o: Vec3, d: Vec3) -> Option<TriangleHit> {
        let ray = Ray::new(o, d);
        intersect_triangle(&ray, &RayShear::new(d), Vec3::ZERO, Vec3::X, Vec3::Y, f32::INFINITY)
    }

    #[test]
    fn hits_inside_with_barycentrics() {
        let h = hit(Vec3::new(0.25, 0.5, 2.0), -Vec3::Z).unwrap();
        assert!((h.t - 2.0).abs() < 1e-6);
        assert!((h.b1 - 0.25).abs() < 1e-6 && (h.b2 - 0.5).abs() < 1e-6);
        // Both faces are hit (culling is the material's business).
        assert!(hit(Vec3::new(0.25, 0.25, -1.0), Vec3::Z).is_some());
    }

    #[test]
    fn misses_outside_behind_and_beyond_tmax() {
        assert!(hit(Vec3::new(0.8, 0.8, 1.0), -Vec3::Z).is_none());
        assert!(hit(Vec3::new(0.2, 0.2, 1.0), Vec3::Z).is_none());
        let ray = Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z);
        assert!(intersect_triangle(&ray, &RayShear::new(ray.dir), Vec3::ZERO, Vec3::X, Vec3::Y, 0.5).is_none());
    }

    #[test]
    fn shared_edge_is_watertight() {
        // Two triangles sharing the diagonal of the unit square; rays exactly on it.
        let (a, b, c, d) = (Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y);
        for i in 0..=100 {
            let s = i as f32 / 100.0;
            let ray = Ray::new(Vec3::new(s, s, 1.0), Vec3::new(0.0, 0.0, -1.0));
            let sh = RayShear::new(ray.dir);
            let h1 = intersect_triangle(&ray, &sh, a, b, c, f32::INFINITY);
            let h2 = intersect_triangle(&ray, &sh, a, c, d, f32::INFINITY);
            assert!(h1.is_some() || h2.is_some(), "crack at s = {s}");
        }
    }
}
