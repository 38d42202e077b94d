use glam::Vec3;

use super::Ray;

/// An axis-aligned bounding box. The empty box has `min = +inf`, `max = -inf`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Default for Aabb {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb { min: Vec3::splat(f32::INFINITY), max: Vec3::splat(f32::NEG_INFINITY) };

    #[inline]
    pub fn new(min: Vec3, max: Vec3) -> Self {
        Self { min, max }
    }

    #[inline]
    pub fn from_points(points: &[Vec3]) -> Self {
        points.iter().fold(Self::EMPTY, |b, &p| b.grow(p))
    }

    #[inline]
    pub fn grow(self, p: Vec3) -> Self {
        Self { min: self.min.min(p), max: self.max.max(p) }
    }

    #[inline]
    pub fn union(self, o: Aabb) -> Self {
        Self { min: self.min.min(o.min), max: self.max.max(o.max) }
    }

    #[inline]
    pub fn intersection(self, o: Aabb) -> Self {
        Self { min: self.min.max(o.min), max: self.max.min(o.max) }
    }

    /// True when the box contains no point (any axis with min > max).
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    #[inline]
    pub fn diagonal(&self) -> Vec3 {
        (self.max - self.min).max(Vec3::ZERO)
    }

    #[inline]
    pub fn center(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }

    #[inline]
    pub fn surface_area(&self) -> f32 {
        if self.is_empty() {
            return 0.0;
        }
        let d = self.diagonal();
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }

    /// Index of the longest axis.
    #[inline]
    pub fn max_axis(&self) -> usize {
        let d = self.diagonal();
        if d.x >= d.y && d.x >= d.z {
            0
        } else if d.y >= d.z {
            1
        } else {
            2
        }
    }

    /// Slab test. Returns the parametric interval `[t0, t1]` of the ray inside the box,
    /// clipped to `[0, tmax]`, or `None` if it misses. `inv_dir` is `1 / ray.dir`
    /// (infinities for zero components are fine: IEEE arithmetic does the right thing,
    /// and `max`/`min` drop the NaN of `0 * inf` in favour of the other operand).
    #[inline]
    pub fn intersect(&self, ray: &Ray, inv_dir: Vec3, tmax: f32) -> Option<(f32, f32)> {
        let t0 = (self.min - ray.origin) * inv_dir;
        let t1 = (self.max - ray.origin) * inv_dir;
        let tnear = t0.min(t1).max_element().max(0.0);
        // Robust traversal (Ize 2013): widen the far distance by 2 ulp-ish so rays that
        // graze an edge are not lost to rounding.
        let tfar = t0.max(t1).min_element().min(tmax) * (1.0 + 2.0 * gamma(3));
        if tnear <= tfar { Some((tnear, tfar)) } else { None }
    }
}

/// pbrt's error bound factor gamma(n) = n*eps / (1 - n*eps) for f32.
#[inline]
pub const fn gamma(n: i32) -> f32 {
    let e = f32::EPSILON * 0.5 * n as f32;
    e / (1.0 - e)
}
