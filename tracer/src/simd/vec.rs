//! Eight 2- and 3-vectors of lanes, with glam's operations in glam's order.

use std::ops::{Add, Div, Mul, Neg, Sub};

use glam::Vec3;

use super::{F8, M8, Simd};

/// Eight 2-vectors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct V2w {
    pub x: F8,
    pub y: F8,
}

/// Eight 3-vectors, component by component; operations in glam's `Vec3` order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct V3w {
    pub x: F8,
    pub y: F8,
    pub z: F8,
}

impl Add for V3w {
    type Output = V3w;
    #[inline(always)]
    fn add(self, o: V3w) -> V3w {
        V3w { x: self.x + o.x, y: self.y + o.y, z: self.z + o.z }
    }
}

impl Sub for V3w {
    type Output = V3w;
    #[inline(always)]
    fn sub(self, o: V3w) -> V3w {
        V3w { x: self.x - o.x, y: self.y - o.y, z: self.z - o.z }
    }
}

/// Component by component (glam's `Vec3 * Vec3`).
impl Mul for V3w {
    type Output = V3w;
    #[inline(always)]
    fn mul(self, o: V3w) -> V3w {
        V3w { x: self.x * o.x, y: self.y * o.y, z: self.z * o.z }
    }
}

/// glam's `Vec3 * f32`.
impl Mul<F8> for V3w {
    type Output = V3w;
    #[inline(always)]
    fn mul(self, s: F8) -> V3w {
        V3w { x: self.x * s, y: self.y * s, z: self.z * s }
    }
}

/// glam's `f32 * Vec3`.
impl Mul<V3w> for F8 {
    type Output = V3w;
    #[inline(always)]
    fn mul(self, v: V3w) -> V3w {
        V3w { x: self * v.x, y: self * v.y, z: self * v.z }
    }
}

/// glam's `Vec3 / f32`.
impl Div<F8> for V3w {
    type Output = V3w;
    #[inline(always)]
    fn div(self, s: F8) -> V3w {
        V3w { x: self.x / s, y: self.y / s, z: self.z / s }
    }
}

impl Neg for V3w {
    type Output = V3w;
    #[inline(always)]
    fn neg(self) -> V3w {
        V3w { x: -self.x, y: -self.y, z: -self.z }
    }
}

impl V3w {
    #[inline(always)]
    pub fn simd(self) -> Simd {
        self.x.1
    }

    #[inline(always)]
    pub fn new(x: F8, y: F8, z: F8) -> V3w {
        V3w { x, y, z }
    }

    /// Lane `l`.
    #[inline(always)]
    pub fn get(&self, l: usize) -> Vec3 {
        Vec3::new(self.x.0[l], self.y.0[l], self.z.0[l])
    }

    #[inline(always)]
    pub fn set(&mut self, l: usize, v: Vec3) {
        (self.x.0[l], self.y.0[l], self.z.0[l]) = (v.x, v.y, v.z);
    }

    /// `(x * o.x + y * o.y) + z * o.z`, as glam's `dot`.
    #[inline(always)]
    pub fn dot(self, o: V3w) -> F8 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }

    #[inline(always)]
    pub fn length_squared(self) -> F8 {
        self.dot(self)
    }

    #[inline(always)]
    pub fn length(self) -> F8 {
        self.dot(self).sqrt()
    }

    /// glam's `cross`.
    #[inline(always)]
    pub fn cross(self, o: V3w) -> V3w {
        V3w { x: self.y * o.z - o.y * self.z, y: self.z * o.x - o.z * self.x, z: self.x * o.y - o.x * self.y }
    }

    /// glam's `normalize`: times the reciprocal of the length.
    #[inline(always)]
    pub fn normalize(self) -> V3w {
        self * self.length().recip()
    }

    /// glam's `normalize_or_zero`.
    #[inline(always)]
    pub fn normalize_or_zero(self) -> V3w {
        let rcp = self.length().recip();
        let ok = rcp.is_finite() & rcp.gt(0.0);
        ok.select3(self * rcp, self.simd().v3(Vec3::ZERO))
    }

    /// glam's `max_element`: `max(x, max(y, z))` with `if a > b { a } else { b }`.
    #[inline(always)]
    pub fn max_element(self) -> F8 {
        let max = |a: F8, b: F8| a.gt(b).select(a, b);
        max(self.x, max(self.y, self.z))
    }

    /// glam's `is_finite` (all three components).
    #[inline(always)]
    pub fn is_finite(self) -> M8 {
        self.x.is_finite() & self.y.is_finite() & self.z.is_finite()
    }

    /// glam's `abs`.
    #[inline(always)]
    pub fn abs(self) -> V3w {
        V3w { x: self.x.abs(), y: self.y.abs(), z: self.z.abs() }
    }
}
