//! Bounds of a triangle clipped to a box, for the kd-tree's "perfect splits".
//! PLACEHOLDER: conservative (triangle bounds ∩ box), being replaced by exact clipping.

use glam::Vec3;

use super::Aabb;

pub fn clipped_triangle_bounds(p: [Vec3; 3], clip: &Aabb) -> Aabb {
    Aabb::from_points(&p).intersection(*clip)
}
