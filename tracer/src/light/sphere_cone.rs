//! Sampling the cone of directions a sphere subtends, and its eight-lane twin.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::geometry::{Frame, FrameW};
use crate::sampling::wide;
use crate::simd::{F8, M8, V2w, V3w};

/// Uniform sampling of the cone of directions a sphere subtends from `p` (pbrt-v4's
/// `Sphere::Sample(ctx)`), with the point on the sphere computed analytically so that it
/// exists even for directions at the silhouette. Returns `(wi, point, pdf)`; `None` when
/// `p` is inside the sphere (it emits outwards only, so nothing reaches `p`).
#[inline(always)]
pub(super) fn sample_sphere_cone(p: Vec3, center: Vec3, radius: f32, u: Vec2) -> Option<(Vec3, Vec3, f32)> {
    let to_center = center - p;
    let d2 = to_center.length_squared();
    let r2 = radius * radius;
    if d2 <= r2 {
        return None;
    }
    // Two independent divisions up front; the rest multiplies by them.
    let dist = d2.sqrt();
    let inv_dist = 1.0 / dist;
    let inv_sin_max = dist / radius;
    let sin_max = radius * inv_dist;
    let sin2_max = sin_max * sin_max;
    let cos_max = (1.0 - sin2_max).max(0.0).sqrt();
    let mut one_minus_cos_max = 1.0 - cos_max;
    let mut cos_t = (cos_max - 1.0) * u.x + 1.0;
    let mut sin2_t = (1.0 - cos_t * cos_t).max(0.0);
    if sin2_max < 0.00068523 {
        // Small cones: Taylor expansion keeps precision (sin² ≈ 1 - cos²).
        sin2_t = sin2_max * u.x;
        cos_t = (1.0 - sin2_t).sqrt();
        one_minus_cos_max = sin2_max / 2.0;
    }
    // Angle alpha at the sphere's centre between the sampled point and the direction to p.
    let s = sin2_t * inv_sin_max; // sin2_t / sin_max
    let cos_alpha = s + cos_t * (1.0 - s * inv_sin_max).max(0.0).sqrt();
    let sin_alpha = (1.0 - cos_alpha * cos_alpha).max(0.0).sqrt();
    let frame = Frame::from_normal(to_center * inv_dist);
    let (sin_phi, cos_phi) = crate::sampling::sin_cos_turns(u.y);
    let w = Vec3::new(sin_alpha * cos_phi, sin_alpha * sin_phi, cos_alpha);
    let n = frame.to_world(-w);
    let q = center + radius * n;
    let wi = (q - p).normalize();
    Some((wi, q, 1.0 / (2.0 * PI * one_minus_cos_max)))
}

/// [`sample_sphere_cone`] lane by lane, for the lanes of `mask`: `(wi, point, pdf, some)`.
#[inline(always)]
pub(super) fn sample_sphere_cone_wide(p: V3w, center: V3w, radius: F8, u: V2w, mask: M8) -> (V3w, V3w, F8, M8) {
    let to_center = center - p;
    let d2 = to_center.length_squared();
    let r2 = radius * radius;
    let some = mask & !d2.le(r2);
    let dist = d2.sqrt();
    let inv_dist = 1.0 / dist;
    let inv_sin_max = dist / radius;
    let sin_max = radius * inv_dist;
    let sin2_max = sin_max * sin_max;
    let cos_max = (1.0 - sin2_max).max(0.0).sqrt();
    let cos_t = (cos_max - 1.0) * u.x + 1.0;
    let sin2_t = (1.0 - cos_t * cos_t).max(0.0);
    // Small cones: Taylor expansion keeps precision (sin² ≈ 1 - cos²).
    let small = sin2_max.lt(0.00068523);
    let sin2_t = small.select(sin2_max * u.x, sin2_t);
    let cos_t = small.select((1.0 - sin2_t).sqrt(), cos_t);
    let one_minus_cos_max = small.select(sin2_max / 2.0, 1.0 - cos_max);
    let s = sin2_t * inv_sin_max;
    let cos_alpha = s + cos_t * (1.0 - s * inv_sin_max).max(0.0).sqrt();
    let sin_alpha = (1.0 - cos_alpha * cos_alpha).max(0.0).sqrt();
    let frame = FrameW::from_normal(to_center * inv_dist);
    let (sin_phi, cos_phi) = wide::sin_cos_turns(u.y);
    let w = V3w::new(sin_alpha * cos_phi, sin_alpha * sin_phi, cos_alpha);
    let n = frame.to_world(-w);
    let q = center + radius * n;
    let wi = (q - p).normalize();
    (wi, q, 1.0 / (2.0 * PI * one_minus_cos_max), some)
}
