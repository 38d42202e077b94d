use glam::{Vec2, Vec3};

use crate::simd::V3w;

/// An orthonormal basis with `n` as the local z axis, used for shading ("local space").
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub s: Vec3,
    pub t: Vec3,
    pub n: Vec3,
}

impl Frame {
    /// Builds a frame around a unit normal (Duff et al. 2017, branchless and robust).
    #[inline]
    pub fn from_normal(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Self { s, t, n }
    }

    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

/// A turn about the local z axis that brings the direction (cos, sin) of the xy plane
/// to x: the frame of lobes that are not symmetric about the normal (sheen's, which
/// faces wo; anisotropic GGX, along the tangent).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Azimuth(pub Vec2);

impl Azimuth {
    pub const X: Azimuth = Azimuth(Vec2::X);

    /// `v` turned so that the direction is x.
    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        let (c, s) = (self.0.x, self.0.y);
        Vec3::new(c * v.x + s * v.y, -s * v.x + c * v.y, v.z)
    }

    /// The inverse of [`Azimuth::to_local`].
    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        let (c, s) = (self.0.x, self.0.y);
        Vec3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z)
    }
}

/// Eight frames, lane by lane [`Frame`]'s (the eight-path integrator's).
#[derive(Clone, Copy, Debug)]
pub(crate) struct FrameW {
    pub s: V3w,
    pub t: V3w,
    pub n: V3w,
}

// `to_local` / `to_world` keep the signatures of their scalar twins on `Frame`.
#[allow(clippy::wrong_self_convention)]
impl FrameW {
    /// [`Frame::from_normal`], lane by lane.
    #[inline(always)]
    pub fn from_normal(n: V3w) -> Self {
        let sign = n.simd().one().copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = V3w::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = V3w::new(b, sign + n.y * n.y * a, -n.y);
        Self { s, t, n }
    }

    #[inline(always)]
    pub fn to_local(&self, v: V3w) -> V3w {
        V3w::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    #[inline(always)]
    pub fn to_world(&self, v: V3w) -> V3w {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal_and_round_trips() {
        for n in
            [Vec3::Z, -Vec3::Z, Vec3::X, Vec3::new(0.3, -0.5, 0.8).normalize(), Vec3::new(1e-8, 0.0, -1.0).normalize()]
        {
            let f = Frame::from_normal(n);
            assert!((f.s.length() - 1.0).abs() < 1e-5 && (f.t.length() - 1.0).abs() < 1e-5);
            assert!(f.s.dot(f.t).abs() < 1e-5 && f.s.dot(n).abs() < 1e-5 && f.t.dot(n).abs() < 1e-5);
            let v = Vec3::new(0.2, 0.7, -0.1);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-5);
        }
    }
}
