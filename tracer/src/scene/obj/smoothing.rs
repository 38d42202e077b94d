//! Smoothing-group shading normals: angle-weighted averages of polygon normals per
//! (smoothing group, position), so vertices are split between groups and creases survive.

use std::collections::HashMap;

use glam::Vec3;

use crate::math;

/// The polygon's normal scaled by twice its area (sum of its fan triangles' cross products;
/// exact for planar polygons, a sensible average otherwise). Counter-clockwise = front.
pub(super) fn polygon_normal(pts: &[Vec3]) -> Vec3 {
    let Some(&p0) = pts.first() else { return Vec3::ZERO };
    pts.windows(2).skip(1).fold(Vec3::ZERO, |acc, w| acc + (w[0] - p0).cross(w[1] - p0))
}

/// Interior angle at `cur` between the edges to `prev` and `next` (0 for degenerate edges).
fn corner_angle(prev: Vec3, cur: Vec3, next: Vec3) -> f32 {
    let (a, b) = ((prev - cur).normalize_or_zero(), (next - cur).normalize_or_zero());
    if a == Vec3::ZERO || b == Vec3::ZERO {
        return 0.0;
    }
    math::acos(a.dot(b).clamp(-1.0, 1.0))
}

/// Accumulated vertex normals, keyed by (smoothing group, output position index).
#[derive(Default)]
pub(super) struct SmoothNormals {
    acc: HashMap<(u32, u32), Vec3>,
}

impl SmoothNormals {
    /// Adds a polygon (position indices `idx`, coordinates `pts`) of smoothing `group`.
    pub fn add_polygon(&mut self, group: u32, idx: &[u32], pts: &[Vec3]) {
        let n = polygon_normal(pts).normalize_or_zero();
        if n == Vec3::ZERO || !n.is_finite() {
            return;
        }
        let count = pts.len();
        for (k, &v) in idx.iter().enumerate() {
            let angle = corner_angle(pts[(k + count - 1) % count], pts[k], pts[(k + 1) % count]);
            if angle > 0.0 && angle.is_finite() {
                *self.acc.entry((group, v)).or_insert(Vec3::ZERO) += n * angle;
            }
        }
    }

    /// The unit smooth normal at position `v` in `group`, or `None` when the contributions
    /// cancel out (e.g. the two sides of a sheet in one group).
    pub fn get(&self, group: u32, v: u32) -> Option<Vec3> {
        let n = self.acc.get(&(group, v))?.normalize_or_zero();
        (n != Vec3::ZERO && n.is_finite()).then_some(n)
    }
}
