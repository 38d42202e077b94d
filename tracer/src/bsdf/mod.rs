//! BSDFs in the local shading frame (z = shading normal). PLACEHOLDER interface: the
//! lobes are being written in lambert.rs, blinn_phong.rs, mirror.rs, dielectric.rs.
//!
//! Conventions (pbrt's): `wo` points away from the surface towards where the light goes
//! (the camera side), `wi` towards where it comes from; both unit vectors in local
//! space. `eval` returns f(wo, wi) * |cos θi| so integrators never multiply by the cosine
//! themselves. Radiance transport mode throughout (camera paths).

use glam::{Vec2, Vec3};

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bsdf {
    /// Lambertian reflection, two-sided.
    Diffuse { kd: Vec3 },
    /// Diffuse base plus normalised Blinn-Phong lobe, two-sided.
    Glossy { kd: Vec3, ks: Vec3, exponent: f32 },
    /// Perfect specular reflection tinted by `ks`, two-sided.
    Mirror { ks: Vec3 },
    /// Smooth dielectric: `eta` is the interior IOR over the exterior one (the normal
    /// points outside); transmission tinted by `tint`.
    Glass { eta: f32, tint: Vec3 },
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BsdfSample {
    pub wi: Vec3,
    /// f * |cos θi| / pdf.
    pub weight: Vec3,
    /// Solid-angle pdf (for a delta lobe: the discrete probability of picking it).
    pub pdf: f32,
    /// The sampled lobe is a delta (mirror or smooth glass): no MIS with light sampling.
    pub delta: bool,
}

impl Bsdf {
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match *self {
            Bsdf::Diffuse { kd } if wo.z * wi.z > 0.0 => kd * (wi.z.abs() / std::f32::consts::PI),
            _ => Vec3::ZERO,
        }
    }

    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Diffuse { .. } if wo.z * wi.z > 0.0 => wi.z.abs() / std::f32::consts::PI,
            _ => 0.0,
        }
    }

    pub fn sample(&self, wo: Vec3, _u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        match *self {
            Bsdf::Diffuse { kd } => {
                let r = u.x.sqrt();
                let phi = 2.0 * std::f32::consts::PI * u.y;
                let mut wi = Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u.x).max(0.0).sqrt());
                if wo.z < 0.0 {
                    wi.z = -wi.z;
                }
                let pdf = wi.z.abs() / std::f32::consts::PI;
                (pdf > 0.0).then_some(BsdfSample { wi, weight: kd, pdf, delta: false })
            }
            _ => None,
        }
    }

    /// True when every lobe is a delta (no point sampling lights).
    pub fn is_delta(&self) -> bool {
        matches!(self, Bsdf::Mirror { .. } | Bsdf::Glass { .. })
    }

    /// The diffuse reflectance (for the albedo AOV and for light-selection heuristics).
    pub fn albedo(&self) -> Vec3 {
        match *self {
            Bsdf::Diffuse { kd } => kd,
            Bsdf::Glossy { kd, ks, .. } => kd + ks,
            Bsdf::Mirror { ks } => ks,
            Bsdf::Glass { tint, .. } => tint,
        }
    }
}
