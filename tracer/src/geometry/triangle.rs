//! Watertight ray–triangle intersection (Woop, Benthin and Wald, JCGT 2013): a ray that
//! crosses a shared edge hits at least one of the two triangles, so closed meshes have
//! no cracks for light to leak through.

use glam::Vec3;

use super::Ray;

/// Ray-specific precomputation for the watertight test: the permutation that makes the
/// largest direction component z, and the shear that maps the ray onto +z. The origin's
/// components are stored permuted too, so the test reads each corner's coordinates
/// straight from memory (no per-triangle permutation of vectors).
#[derive(Clone, Copy, Debug)]
pub struct RayShear {
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f32,
    sy: f32,
    sz: f32,
    /// `origin[kx]`, `origin[ky]`, `origin[kz]`.
    ox: f32,
    oy: f32,
    oz: f32,
}

impl RayShear {
    #[inline]
    pub fn new(dir: Vec3) -> Self {
        Self::for_ray(Vec3::ZERO, dir)
    }

    /// The shear of a ray with its origin (what [`intersect_triangle_corners`] needs;
    /// [`intersect_triangle`] works with either).
    #[inline]
    pub fn for_ray(origin: Vec3, dir: Vec3) -> Self {
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
        Self { kx, ky, kz, sx: dir[kx] * sz, sy: dir[ky] * sz, sz, ox: origin[kx], oy: origin[ky], oz: origin[kz] }
    }

    /// The axis permutation (kx, ky, kz), the shear (sx, sy, sz) and the permuted origin:
    /// what a packed test needs to repeat [`intersect_triangle_corners`]'s arithmetic.
    #[inline]
    pub(crate) fn parts(&self) -> ([usize; 3], [f32; 3], [f32; 3]) {
        ([self.kx, self.ky, self.kz], [self.sx, self.sy, self.sz], [self.ox, self.oy, self.oz])
    }

    /// The same shear for another origin.
    #[inline]
    fn with_origin(mut self, origin: Vec3) -> Self {
        self.ox = origin[self.kx];
        self.oy = origin[self.ky];
        self.oz = origin[self.kz];
        self
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
    intersect_triangle_corners(&shear.with_origin(ray.origin), &[p0, p1, p2], tmax)
}

/// [`intersect_triangle`] for a shear made with [`RayShear::for_ray`] (which carries the
/// origin) and corners in memory; bit-identical results.
#[inline(always)]
pub fn intersect_triangle_corners(shear: &RayShear, p: &[Vec3; 3], tmax: f32) -> Option<TriangleHit> {
    let (kx, ky, kz) = (shear.kx, shear.ky, shear.kz);
    debug_assert!(kx < 3 && ky < 3 && kz < 3);
    let (p0, p1, p2): (&[f32; 3], &[f32; 3], &[f32; 3]) = (p[0].as_ref(), p[1].as_ref(), p[2].as_ref());
    // SAFETY: `for_ray` sets kx, ky, kz to a permutation of 0, 1, 2, and they are private.
    // (Unchecked: nine bounds checks were a fifth of this test's instructions.)
    let at = |q: &[f32; 3], k: usize| unsafe { *q.get_unchecked(k) };
    // Corner minus origin, per permuted axis: the same roundings as `(p - o)[k]`.
    let (a_x, a_y, a_z) = (at(p0, kx) - shear.ox, at(p0, ky) - shear.oy, at(p0, kz) - shear.oz);
    let (b_x, b_y, b_z) = (at(p1, kx) - shear.ox, at(p1, ky) - shear.oy, at(p1, kz) - shear.oz);
    let (c_x, c_y, c_z) = (at(p2, kx) - shear.ox, at(p2, ky) - shear.oy, at(p2, kz) - shear.oz);
    let ax = a_x - shear.sx * a_z;
    let ay = a_y - shear.sy * a_z;
    let bx = b_x - shear.sx * b_z;
    let by = b_y - shear.sy * b_z;
    let cx = c_x - shear.sx * c_z;
    let cy = c_y - shear.sy * c_z;

    let mut u = cx * by - cy * bx;
    let mut v = ax * cy - ay * cx;
    let mut w = bx * ay - by * ax;
    // Fall back to double precision on an edge, as the paper prescribes, so that the
    // sign test is exact there.
    if u == 0.0 || v == 0.0 || w == 0.0 {
        (u, v, w) = edge_functions_f64(ax, ay, bx, by, cx, cy);
    }
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return None;
    }
    let det = u + v + w;
    if det == 0.0 {
        return None;
    }
    let az = shear.sz * a_z;
    let bz = shear.sz * b_z;
    let cz = shear.sz * c_z;
    let t_scaled = u * az + v * bz + w * cz;
    finish_watertight(v, w, det, t_scaled, tmax)
}

/// The last step of the watertight test, from the edge functions `v`, `w` (all three of
/// one sign), `det = u + v + w` (nonzero) and `t·det`: the range check against `tmax` and
/// the division. Packed tests that computed the same values call it too.
#[inline(always)]
pub(crate) fn finish_watertight(v: f32, w: f32, det: f32, t_scaled: f32, tmax: f32) -> Option<TriangleHit> {
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

/// The three edge functions in double precision (exact for f32 inputs), rounded to f32:
/// the rare case of a ray on an edge, kept out of the hot test's code.
#[cold]
#[inline(never)]
fn edge_functions_f64(ax: f32, ay: f32, bx: f32, by: f32, cx: f32, cy: f32) -> (f32, f32, f32) {
    let u = (cx as f64 * by as f64 - cy as f64 * bx as f64) as f32;
    let v = (ax as f64 * cy as f64 - ay as f64 * cx as f64) as f32;
    let w = (bx as f64 * ay as f64 - by as f64 * ax as f64) as f32;
    (u, v, w)
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
