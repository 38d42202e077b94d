//! Integrators: estimate the radiance arriving along a camera ray. `Path` is the physically
//! based estimator; the others are the AOVs a user (and a denoiser) needs.

pub mod aov;
#[cfg(target_arch = "x86_64")]
pub(crate) mod eight_paths;
pub mod path;

use glam::Vec3;

use crate::film::FirstHit;
use crate::geometry::Ray;
use crate::sampler::Sampler;
use crate::scene::Scene;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Integrator {
    /// Unidirectional path tracing with next-event estimation and MIS.
    #[default]
    Path,
    /// Path tracing with light sampling only (no MIS): for comparing estimators.
    PathLightOnly,
    /// Path tracing with BSDF sampling only (no next-event estimation).
    PathBsdfOnly,
    /// World-space shading normal at the first hit (components in [-1, 1]).
    Normals,
    /// Diffuse (or specular tint) reflectance at the first hit.
    Albedo,
    /// Distance from the camera to the first hit.
    Depth,
}

impl Integrator {
    pub const NAMES: [&'static str; 6] = ["path", "path-light", "path-bsdf", "normals", "albedo", "depth"];

    pub fn name(self) -> &'static str {
        match self {
            Integrator::Path => "path",
            Integrator::PathLightOnly => "path-light",
            Integrator::PathBsdfOnly => "path-bsdf",
            Integrator::Normals => "normals",
            Integrator::Albedo => "albedo",
            Integrator::Depth => "depth",
        }
    }
}

impl std::str::FromStr for Integrator {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "path" => Ok(Integrator::Path),
            "path-light" => Ok(Integrator::PathLightOnly),
            "path-bsdf" => Ok(Integrator::PathBsdfOnly),
            "normals" => Ok(Integrator::Normals),
            "albedo" => Ok(Integrator::Albedo),
            "depth" => Ok(Integrator::Depth),
            _ => Err(format!("unknown integrator '{s}' (expected one of: {})", Integrator::NAMES.join(", "))),
        }
    }
}

/// Counts rays traced, for the rays/s figure.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayCount {
    pub rays: u64,
}

/// The estimate for one camera ray; with `first`, also what the ray met first (for the
/// film's layers), from the same intersection. (Inlined into the render loop's variants,
/// so that the sampler's code is compiled for each instruction set; see `render.rs`.)
#[inline(always)]
pub fn li(
    integrator: Integrator,
    scene: &Scene,
    ray: Ray,
    sampler: &mut Sampler,
    count: &mut RayCount,
    first: Option<&mut FirstHit>,
) -> Vec3 {
    match path_options(integrator, scene) {
        Some(options) => options.limit(path::li(scene, ray, sampler, count, &options, first)),
        None => aov::li(integrator, scene, ray, count, first),
    }
}

/// The path integrator's options for `integrator`, or `None` for an AOV.
#[inline(always)]
pub(crate) fn path_options(integrator: Integrator, scene: &Scene) -> Option<path::Options> {
    let strategy = match integrator {
        Integrator::Path => path::Strategy::Mis,
        Integrator::PathLightOnly => path::Strategy::LightOnly,
        Integrator::PathBsdfOnly => path::Strategy::BsdfOnly,
        Integrator::Normals | Integrator::Albedo | Integrator::Depth => return None,
    };
    Some(path::Options { strategy, ..path::Options::from_scene(scene) })
}
