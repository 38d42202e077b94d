//! Unidirectional path tracing with next-event estimation and multiple importance
//! sampling (power heuristic) between light sampling and BSDF sampling.
//!
//! Depth follows Mitsuba 3's `path` integrator: `max_depth` counts path segments from
//! the camera, so 1 shows only emitters seen directly, 2 adds direct lighting, and -1 is
//! unlimited (paths end by Russian roulette, which starts at depth 5 and is unbiased).

use glam::{Vec2, Vec3};

use super::RayCount;
use crate::bsdf::Bsdf;
use crate::geometry::{Frame, Ray, offset_origin};
use crate::light::LightSample;
use crate::sampler::Sampler;
use crate::sampling::{power_heuristic, uniform_sphere_pdf};
use crate::scene::{Scene, SurfaceHit};

/// Which estimators to combine. The default (MIS) is the renderer; the one-sided
/// variants exist to test that all three converge to the same answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Strategy {
    /// Light sampling and BSDF sampling weighted by the power heuristic.
    Mis,
    /// Emitters found only by light sampling (NEE); BSDF-sampled hits on emitters are
    /// ignored after the first segment. Delta BSDFs still see emitters by BSDF sampling.
    LightOnly,
    /// Emitters found only by BSDF sampling (no NEE); delta lights then contribute nothing.
    BsdfOnly,
}

#[derive(Clone, Copy, Debug)]
pub struct Options {
    pub max_depth: i32,
    pub strategy: Strategy,
    /// Russian roulette starts once this many segments have been traced.
    pub rr_depth: u32,
}

impl Options {
    pub fn from_scene(scene: &Scene) -> Self {
        Self { max_depth: scene.settings.max_depth, strategy: Strategy::Mis, rr_depth: 5 }
    }
}

/// Radiance arriving at the camera along `ray`.
#[inline(always)]
pub fn li(scene: &Scene, mut ray: Ray, sampler: &mut Sampler, count: &mut RayCount, opt: &Options) -> Vec3 {
    let mut l = Vec3::ZERO;
    let mut beta = Vec3::ONE;
    // State of the previous scattering event, for MIS weights of emitters hit next.
    let mut prev_pdf = 0.0f32;
    let mut prev_delta = true;
    let mut prev_p = ray.origin;
    let mut depth: u32 = 0;
    let unlimited = opt.max_depth < 0;
    let (use_nee, use_bsdf_hits) = match opt.strategy {
        Strategy::Mis => (true, true),
        Strategy::LightOnly => (true, false),
        Strategy::BsdfOnly => (false, true),
    };

    loop {
        count.rays += 1;
        let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
            if let Some(env) = scene.lights.environment() {
                let w = emitter_weight(depth, prev_delta, opt.strategy, prev_pdf, || {
                    scene.lights.pmf_at(prev_p, env) * uniform_sphere_pdf()
                });
                l += beta * scene.background * w;
            }
            break;
        };
        let si = scene.interaction(&ray, &hit);
        let material = &scene.materials[si.material as usize];

        // Stochastic opacity (`d < 1`, `Ni = 1`): pass straight through with probability
        // 1 - d. Not a scattering event, so depth and the MIS state are unchanged.
        if material.opacity < 1.0 && sampler.next_1d() >= material.opacity {
            ray.origin = offset_origin(si.p, si.ng, ray.dir);
            continue;
        }

        let wo = -ray.dir;
        // One-sided emission: only the front face emits.
        if material.is_emissive() && si.ng.dot(wo) > 0.0 {
            let w = emitter_weight(depth, prev_delta, opt.strategy, prev_pdf, || {
                // What NEE at prev_p would have had for this light (0 if it never could).
                scene.lights.light_of_prim(hit.prim).map_or(0.0, |li| {
                    scene.lights.pmf_at(prev_p, li) * scene.lights.lights[li].pdf_li(prev_p, ray.dir, si.p)
                })
            });
            l += beta * material.emission * w;
        }

        depth += 1;
        if !unlimited && depth >= opt.max_depth as u32 {
            break;
        }

        let bsdf = material.bsdf_at(si.uv, &scene.textures);
        // Reflection-only surfaces are two-sided: shade the side the ray arrives from.
        // Glass keeps its outward normal so it knows whether the ray is inside.
        let two_sided = !matches!(bsdf, Bsdf::Glass { .. });
        let (ng, ns) = if two_sided && si.ng.dot(wo) < 0.0 { (-si.ng, -si.ns) } else { (si.ng, si.ns) };
        let frame = Frame::from_normal(ns);
        let wo_local = frame.to_local(wo);

        // Next-event estimation. One 2D sample both picks the light (x, then rescaled
        // within the light's interval) and the point on it, so the points stay
        // stratified across the lights together.
        if use_nee && !bsdf.is_delta() {
            let u = sampler.next_2d();
            if let Some((light_index, pmf, ux)) = scene.lights.select_at(si.p, u.x) {
                let light = &scene.lights.lights[light_index];
                if let Some(ls) = light.sample_li(si.p, Vec2::new(ux, u.y)) {
                    let reflects_above = !two_sided || ng.dot(ls.wi) > 0.0;
                    if ls.pdf > 0.0 && ls.li.max_element() > 0.0 && reflects_above {
                        let wi_local = frame.to_local(ls.wi);
                        let (f, bsdf_pdf) = bsdf.eval_pdf(wo_local, wi_local);
                        if f.max_element() > 0.0 {
                            let tr = transmittance(scene, &si, ng, &ls, count);
                            if tr > 0.0 {
                                if ls.delta {
                                    l += beta * f * ls.li * (tr / pmf);
                                } else {
                                    let light_pdf = pmf * ls.pdf;
                                    let w = if use_bsdf_hits {
                                        power_heuristic(1.0, light_pdf, 1.0, bsdf_pdf)
                                    } else {
                                        1.0
                                    };
                                    l += beta * f * ls.li * (tr * w / light_pdf);
                                }
                            }
                        }
                    }
                }
            }
        }

        // BSDF sampling: the next segment of the path. Only the dimensions the BSDF uses
        // are drawn (Lambert: a direction; mirror: none; glass: a lobe choice).
        let (u_lobe, u) = match bsdf {
            Bsdf::Diffuse { .. } => (0.0, sampler.next_2d()),
            Bsdf::Glossy { .. } => (sampler.next_1d(), sampler.next_2d()),
            Bsdf::Mirror { .. } => (0.0, Vec2::ZERO),
            Bsdf::Glass { .. } => (sampler.next_1d(), Vec2::ZERO),
        };
        let Some(bs) = bsdf.sample(wo_local, u_lobe, u) else {
            break;
        };
        let wi = frame.to_world(bs.wi);
        // A reflection that dips below the geometric surface (possible with shading
        // normals) would leak light through it.
        if two_sided && ng.dot(wi) <= 0.0 {
            break;
        }
        beta *= bs.weight;
        if !(beta.max_element() > 0.0) || !beta.is_finite() {
            break;
        }
        prev_pdf = bs.pdf;
        prev_delta = bs.delta;
        prev_p = si.p;
        ray = Ray::new(offset_origin(si.p, ng, wi), wi);

        if depth >= opt.rr_depth {
            let q = beta.max_element().min(0.95);
            if sampler.next_1d() >= q {
                break;
            }
            beta /= q;
        }
    }
    l
}

/// The weight of emission found by BSDF sampling (or seen from the camera), given the
/// pdf with which light sampling would have produced the same direction.
#[inline]
fn emitter_weight(
    depth: u32,
    prev_delta: bool,
    strategy: Strategy,
    bsdf_pdf: f32,
    light_pdf: impl FnOnce() -> f32,
) -> f32 {
    // Seen directly, or through a delta BSDF: light sampling cannot find it.
    if depth == 0 || prev_delta {
        return 1.0;
    }
    match strategy {
        Strategy::LightOnly => 0.0,
        Strategy::BsdfOnly => 1.0,
        Strategy::Mis => power_heuristic(1.0, bsdf_pdf, 1.0, light_pdf()),
    }
}

/// Visibility of a light sample: 1 if unblocked, 0 if blocked; with stochastic-opacity
/// materials in the scene, the product of (1 - d) over the surfaces crossed (the
/// expected value of the opacity coin flips, so the estimate stays unbiased).
#[inline(always)]
fn transmittance(scene: &Scene, si: &SurfaceHit, ng: Vec3, ls: &LightSample, count: &mut RayCount) -> f32 {
    let mut origin = offset_origin(si.p, ng, ls.wi);
    let (dir, mut tmax) = match ls.target {
        Some(q) => {
            let d = q - origin;
            let dist = d.length();
            if dist <= 0.0 {
                return 1.0;
            }
            (d / dist, dist * (1.0 - 1e-5))
        }
        None => (ls.wi, f32::INFINITY),
    };
    if !scene.has_cutouts {
        count.rays += 1;
        return if scene.occluded(&Ray::new(origin, dir), tmax) { 0.0 } else { 1.0 };
    }
    let mut tr = 1.0f32;
    // Bounded: each step moves past one surface; a pathological stack ends as blocked.
    for _ in 0..256 {
        count.rays += 1;
        let ray = Ray::new(origin, dir);
        let Some(hit) = scene.intersect(&ray, tmax) else {
            return tr;
        };
        let h = scene.interaction(&ray, &hit);
        let opacity = scene.materials[h.material as usize].opacity;
        if opacity >= 1.0 {
            return 0.0;
        }
        tr *= 1.0 - opacity;
        origin = offset_origin(h.p, h.ng, dir);
        tmax = (tmax - hit.t).max(0.0);
        if tmax == 0.0 {
            return tr;
        }
    }
    0.0
}
