use glam::Vec3;

use crate::wide::{F8, V3w};

/// A ray `origin + t * dir`. `dir` need not be normalised for intersection, but the
/// integrators always pass unit directions so that `t` is a distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
}

impl Ray {
    #[inline]
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Self { origin, dir }
    }

    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + t * self.dir
    }
}

/// Moves a surface point off its surface, to the side `dir` leaves towards, so that a
/// ray spawned there does not hit the surface it starts on. The offset scales with the
/// magnitude of the coordinates because f32 rounding error does.
#[inline]
pub fn offset_origin(p: Vec3, geometric_normal: Vec3, dir: Vec3) -> Vec3 {
    let eps = 2e-5 * p.abs().max_element().max(1.0);
    let side = if geometric_normal.dot(dir) >= 0.0 { 1.0 } else { -1.0 };
    p + geometric_normal * (eps * side)
}

/// [`offset_origin`] lane by lane.
#[inline(always)]
pub(crate) fn offset_origin_wide(p: V3w, geometric_normal: V3w, dir: V3w) -> V3w {
    let eps = 2e-5 * p.abs().max_element().max(1.0);
    let side = geometric_normal.dot(dir).ge(0.0).select(F8::ONE, F8::splat(-1.0));
    p + geometric_normal * (eps * side)
}
