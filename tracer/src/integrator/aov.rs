//! Arbitrary output variables at the first visible surface.

use glam::Vec3;

use super::{Integrator, RayCount};
use crate::accel::Hit;
use crate::bsdf::Bsdf;
use crate::film::FirstHit;
use crate::geometry::Ray;
use crate::scene::Scene;

/// The first-hit layers of a sample whose camera ray `ray` found `hit` (its closest hit,
/// which the path traces anyway): the same quantities as the AOV integrators below.
/// Inlined into the render loop's instruction-set variants, like the integrators.
#[inline(always)]
pub fn first_hit(scene: &Scene, ray: &Ray, hit: Option<Hit>) -> FirstHit {
    let Some(hit) = hit else {
        return FirstHit::default();
    };
    let si = scene.interaction(ray, &hit);
    surface(&scene.materials[si.material as usize].bsdf_at(si.uv, &scene.textures), si.ns, hit.t * ray.dir.length())
}

/// The first-hit layers of a surface with BSDF `bsdf` and shading normal `ns`, met at
/// distance `depth` from the camera. The path integrators record these from the surface
/// data they shade with, so the layers cost no second look-up.
#[inline(always)]
pub fn surface(bsdf: &Bsdf, ns: Vec3, depth: f32) -> FirstHit {
    FirstHit { albedo: albedo(bsdf), normal: ns, depth: Some(depth) }
}

/// The albedo layer's value for a surface with BSDF `bsdf`.
#[inline(always)]
pub fn albedo(bsdf: &Bsdf) -> Vec3 {
    bsdf.albedo().clamp(Vec3::ZERO, Vec3::ONE)
}

pub fn li(kind: Integrator, scene: &Scene, ray: Ray, count: &mut RayCount, first: Option<&mut FirstHit>) -> Vec3 {
    count.rays += 1;
    let hit = scene.intersect(&ray, f32::INFINITY);
    if let Some(f) = first {
        *f = first_hit(scene, &ray, hit);
    }
    let Some(hit) = hit else {
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
