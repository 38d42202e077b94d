//! Arbitrary output variables at the first visible surface.

use glam::Vec3;

use super::{Integrator, RayCount};
use crate::geometry::Ray;
use crate::scene::Scene;

pub fn li(kind: Integrator, scene: &Scene, ray: Ray, count: &mut RayCount) -> Vec3 {
    count.rays += 1;
    let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
        return Vec3::ZERO;
    };
    let si = scene.interaction(&ray, &hit);
    match kind {
        Integrator::Normals => si.ns,
        Integrator::Albedo => scene.materials[si.material as usize].bsdf_at(si.uv, &scene.textures).albedo(),
        Integrator::Depth => Vec3::splat(hit.t * ray.dir.length()),
        Integrator::Path | Integrator::PathLightOnly | Integrator::PathBsdfOnly => {
            unreachable!("path integrators are not AOVs")
        }
    }
}
