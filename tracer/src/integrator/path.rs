//! Unidirectional path tracing with next-event estimation and multiple importance
//! sampling (power heuristic) between light sampling and BSDF sampling.
//!
//! Depth follows Mitsuba 3's `path` integrator: `max_depth` counts path segments from
//! the camera, so 1 shows only emitters seen directly, 2 adds direct lighting, and -1 is
//! unlimited (paths end by Russian roulette, which starts at depth 5 and is unbiased).
//!
//! A path is a [`PathState`] advanced one vertex at a time by [`PathState::scatter`],
//! between two ray queries that the caller answers: the closest hit of the path's next
//! segment, and the visibility of the light sample that next-event estimation took
//! there ([`ShadowQuery`]). [`li`] answers them one path at a time; the eight-lane
//! renderer (`integrator/eight_paths.rs`) answers eight paths' queries at once. Both run the
//! same code per path, so a sample's radiance is the same bits either way.

use glam::{Vec2, Vec3};

use super::{RayCount, aov};
use crate::accel::Hit;
use crate::bsdf::Bsdf;
use crate::bsdf::bump_shadowing;
use crate::film::FirstHit;
use crate::geometry::{Frame, Ray, offset_origin};
use crate::material::Slot;
use crate::material::normals::ensure_valid_specular_reflection;
use crate::sampler::Sampler;
use crate::sampling::{power_heuristic, sin_cos_turns};
use crate::scene::MAX_MIX_DEPTH;
use crate::scene::Scene;

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
    /// The largest channel value a sample may add ([`RenderSettings::clamp`]); infinite
    /// when off, so that [`Options::limit`] changes no bits.
    ///
    /// [`RenderSettings::clamp`]: crate::scene::RenderSettings::clamp
    pub clamp: f32,
}

impl Options {
    pub fn from_scene(scene: &Scene) -> Self {
        let clamp = scene.settings.clamp.unwrap_or(f32::INFINITY);
        Self { max_depth: scene.settings.max_depth, strategy: Strategy::Mis, rr_depth: 5, clamp }
    }

    /// A sample's radiance as the film takes it: scaled down, hue kept, so that its largest
    /// channel is at most the clamp. Non-finite samples pass, for the film to count.
    #[inline(always)]
    pub fn limit(&self, l: Vec3) -> Vec3 {
        let m = l.max_element();
        if m > self.clamp && m.is_finite() { l * (self.clamp / m) } else { l }
    }
}

/// Radiance arriving at the camera along `ray`; with `first`, also what `ray` met first
/// (from the same intersection).
#[inline(always)]
pub fn li(
    scene: &Scene,
    ray: Ray,
    sampler: &mut Sampler,
    count: &mut RayCount,
    opt: &Options,
    mut first: Option<&mut FirstHit>,
) -> Vec3 {
    let mut path = PathState::new(ray);
    loop {
        count.rays += 1;
        let hit = scene.intersect(&path.ray, f32::INFINITY);
        let (shadow, go_on) = path.scatter(scene, hit, sampler, opt, first.take());
        if let Some(q) = shadow {
            path.add_light(&q, transmittance(scene, &q, count));
        }
        if !go_on {
            return path.radiance();
        }
    }
}

/// A light sample of next-event estimation waiting for its shadow ray: its contribution
/// is `unshadowed · (tr · weight / pdf)` for transmittance `tr` along `ray`.
#[derive(Clone, Copy, Debug)]
pub struct ShadowQuery {
    /// The shadow ray and the distance it must get through; `None` when the light
    /// sample lies at the shading point itself (visible without a ray).
    pub ray: Option<(Ray, f32)>,
    pub(crate) unshadowed: Vec3,
    pub(crate) weight: f32,
    pub(crate) pdf: f32,
}

/// One path between two ray queries.
#[derive(Clone, Copy, Debug)]
pub struct PathState {
    /// The segment whose closest hit [`PathState::scatter`] needs next.
    pub ray: Ray,
    pub(crate) l: Vec3,
    pub(crate) beta: Vec3,
    // State of the previous scattering event, for MIS weights of emitters hit next.
    pub(crate) prev_pdf: f32,
    pub(crate) prev_delta: bool,
    pub(crate) prev_p: Vec3,
    pub(crate) depth: u32,
}

impl PathState {
    /// A path starting with the camera ray `ray`.
    #[inline(always)]
    pub fn new(ray: Ray) -> Self {
        Self { ray, l: Vec3::ZERO, beta: Vec3::ONE, prev_pdf: 0.0, prev_delta: true, prev_p: ray.origin, depth: 0 }
    }

    /// The radiance gathered so far (all of it once the path has ended).
    #[inline(always)]
    pub fn radiance(&self) -> Vec3 {
        self.l
    }

    /// Adds a light sample's contribution with transmittance `tr` (0: blocked).
    #[inline(always)]
    pub fn add_light(&mut self, q: &ShadowQuery, tr: f32) {
        if tr > 0.0 {
            self.l += q.unshadowed * (tr * q.weight / q.pdf);
        }
    }

    /// Everything the path does at `hit`, the closest hit of [`PathState::ray`]:
    /// emission found there, next-event estimation, BSDF sampling and Russian
    /// roulette. Returns the light sample whose shadow ray the caller must answer (by
    /// [`PathState::add_light`], before the next call) and whether the path goes on,
    /// with [`PathState::ray`] its next segment. With `first` (the camera ray's segment
    /// of a film that keeps layers), also records what the segment met there, from the
    /// same surface data the path shades with.
    #[inline(always)]
    // Long on purpose: The path integrator's step as the math reads (emission, NEE, BSDF sampling, roulette); one inlined function keeps the path state in registers (see eight_paths.rs, its twin, step for step).
    pub fn scatter(
        &mut self,
        scene: &Scene,
        hit: Option<Hit>,
        sampler: &mut Sampler,
        opt: &Options,
        first: Option<&mut FirstHit>,
    ) -> (Option<ShadowQuery>, bool) {
        let (use_nee, use_bsdf_hits) = match opt.strategy {
            Strategy::Mis => (true, true),
            Strategy::LightOnly => (true, false),
            Strategy::BsdfOnly => (false, true),
        };
        let ray = self.ray;
        // Area lights on the segment (they block nothing; camera rays do not see them).
        if self.depth > 0 && scene.lights.has_areas() {
            let tmax = hit.map_or(f32::INFINITY, |h| h.t);
            if let Some(e) =
                area_light_emission(scene, &ray, tmax, (self.depth, self.prev_delta, self.prev_pdf, self.prev_p), opt)
            {
                self.l += self.beta * e;
            }
        }
        let Some(hit) = hit else {
            if let Some(f) = first {
                *f = FirstHit::default();
            }
            if let Some(env) = scene.lights.environment() {
                let prev_p = self.prev_p;
                let w = emitter_weight(self.depth, self.prev_delta, opt.strategy, self.prev_pdf, || {
                    scene.lights.pmf_at(prev_p, env) * scene.lights.pdf_li(env, prev_p, ray.dir, prev_p)
                });
                self.l += self.beta * scene.lights.environment_radiance(ray.dir) * w;
            }
            return (None, false);
        };
        let mut si = scene.interaction(&ray, &hit);
        let mut material = &scene.materials[si.material as usize];
        // A Mix Shader: continue with one of its two materials, chosen by its factor
        // (mixes of mixes, as deep as the loader allows).
        for _ in 0..MAX_MIX_DEPTH {
            let Some(mix) = material.mix else { break };
            let factor = material.maps.scale(Slot::MixFactor, mix.factor, si.uv, &scene.textures);
            let pick = if sampler.next_1d() < factor { mix.second } else { mix.first };
            material = &scene.materials[pick as usize];
        }
        // Normal and bump maps tilt the shading normal (on the front side, as `si.ns` is).
        let perturbed = material.perturbs_normal();
        let anisotropic = material.anisotropy.amount > 0.0 && matches!(material.bsdf, Bsdf::Principled(_));
        let uv_frame = (perturbed || anisotropic).then(|| scene.uv_frame(&hit, &si));
        let smooth_ns = si.ns;
        if let (true, Some(f)) = (perturbed, &uv_frame) {
            si.ns = material.shading_normal(si.ns, si.uv, f, &scene.textures);
        }
        // The first hit's layers, for the paths that end before their BSDF is known.
        let record_first = |first: Option<&mut FirstHit>| {
            if let Some(f) = first {
                *f = aov::surface(&material.bsdf_at(si.uv, &scene.textures), si.ns, hit.t * ray.dir.length());
            }
        };

        // Stochastic opacity (`d < 1`, `Ni = 1`): pass straight through with probability
        // 1 - d. Not a scattering event, so depth and the MIS state are unchanged.
        if material.has_cutout() && sampler.next_1d() >= material.opacity_at(si.uv, &scene.textures) {
            record_first(first);
            self.ray.origin = offset_origin(si.p, si.ng, ray.dir);
            return (None, true);
        }

        let wo = -ray.dir;
        // One-sided emission: only the front face emits.
        if material.is_emissive() && si.ng.dot(wo) > 0.0 {
            let prev_p = self.prev_p;
            let w = emitter_weight(self.depth, self.prev_delta, opt.strategy, self.prev_pdf, || {
                // What NEE at prev_p would have had for this light (0 if it never could).
                scene
                    .lights
                    .light_of_prim(hit.prim)
                    .map_or(0.0, |li| scene.lights.pmf_at(prev_p, li) * scene.lights.pdf_li(li, prev_p, ray.dir, si.p))
            });
            self.l += self.beta * material.emission_at(si.uv, &scene.textures) * w;
        }

        self.depth += 1;
        if opt.max_depth >= 0 && self.depth >= opt.max_depth as u32 {
            record_first(first);
            return (None, false);
        }

        let bsdf = material.bsdf_at(si.uv, &scene.textures);
        if let Some(f) = first {
            *f = aov::surface(&bsdf, si.ns, hit.t * ray.dir.length());
        }
        // Reflection-only surfaces are two-sided: shade the side the ray arrives from.
        // Glass (and a Principled surface that transmits) keeps its outward normal so it
        // knows whether the ray is inside.
        let two_sided = !bsdf.is_oriented();
        let back = two_sided && si.ng.dot(wo) < 0.0;
        let (ng, tilted) = if back { (-si.ng, -si.ns) } else { (si.ng, si.ns) };
        // The surface's own shading normal, for the shadowing of tilted diffuse lobes.
        let smooth = if back { -smooth_ns } else { smooth_ns };
        // As Cycles does for a tilted normal: glossy lobes turn it just enough that the
        // mirror reflection of wo stays above the surface (seen from wo's side); diffuse
        // lobes keep it as the maps made it.
        let valid = |n: Vec3| {
            let side = if ng.dot(wo) < 0.0 { -1.0 } else { 1.0 };
            side * ensure_valid_specular_reflection(side * ng, wo, side * n)
        };
        let mut ns = tilted;
        if perturbed && !matches!(bsdf, Bsdf::Diffuse { .. }) {
            ns = valid(tilted);
        }
        let frame = Frame::from_normal(ns);
        let wo_local = frame.to_local(wo);
        // A Lambertian surface with maps: Cycles' shadowing of its tilted normal.
        let diffuse_tilted = perturbed && matches!(bsdf, Bsdf::Diffuse { .. });
        // Anisotropy: the tangent (MikkTSpace's, or ∂p/∂u) on the shading plane, turned by
        // the material's rotation about the normal, as a direction in the frame's xy plane.
        let tangent = uv_frame.filter(|_| anisotropic).map(|f| {
            let t = f.tangent.map_or(f.dpdu, |(t, _, _)| t);
            let t = (t - ns * ns.dot(t)).normalize_or_zero();
            let (sin, cos) = sin_cos_turns(material.anisotropy.rotation);
            let t = frame.to_local(cos * t + sin * ns.cross(t));
            (material.anisotropy.amount, Vec2::new(t.x, t.y))
        });
        // A Principled BSDF's lobes at wo, set up once for light and BSDF sampling.
        let lobes = match bsdf {
            Bsdf::Principled(p) if perturbed => {
                // Blender's coat keeps the surface's own normal (its Coat Normal, unlinked).
                let coat = (p.coat > 0.0).then(|| frame.to_local(valid(smooth)));
                let lobes = p.at_with(wo_local, coat, tangent);
                Some(lobes.with_tilted_normal(frame.to_local(tilted), frame.to_local(smooth)))
            }
            Bsdf::Principled(p) if tangent.is_some() => Some(p.at_with(wo_local, None, tangent)),
            Bsdf::Principled(p) => Some(p.at(wo_local)),
            _ => None,
        };

        // Next-event estimation. One 2D sample both picks the light (x, then rescaled
        // within the light's interval) and the point on it, so the points stay
        // stratified across the lights together.
        let mut shadow = None;
        if use_nee && !bsdf.is_delta() {
            let u = sampler.next_2d();
            if let Some((light_index, pmf, ux)) = scene.lights.select_at(si.p, u.x)
                && let Some(ls) = scene.lights.sample_li(light_index, si.p, Vec2::new(ux, u.y))
            {
                let reflects_above = !two_sided || ng.dot(ls.wi) > 0.0;
                if ls.pdf > 0.0 && ls.li.max_element() > 0.0 && reflects_above {
                    let wi_local = frame.to_local(ls.wi);
                    let (mut f, bsdf_pdf) = match &lobes {
                        Some(l) => l.eval_pdf(wo_local, wi_local),
                        None => bsdf.eval_pdf(wo_local, wi_local),
                    };
                    if diffuse_tilted {
                        f *= bump_shadowing(smooth, ns, ls.wi);
                    }
                    if f.max_element() > 0.0 {
                        let (weight, pdf) = if ls.delta {
                            (1.0, pmf)
                        } else {
                            let light_pdf = pmf * ls.pdf;
                            let w = if use_bsdf_hits { power_heuristic(1.0, light_pdf, 1.0, bsdf_pdf) } else { 1.0 };
                            (w, light_pdf)
                        };
                        let origin = offset_origin(si.p, ng, ls.wi);
                        let ray = match ls.target {
                            Some(q) => {
                                let d = q - origin;
                                let dist = d.length();
                                if dist <= 0.0 { None } else { Some((Ray::new(origin, d / dist), dist * (1.0 - 1e-5))) }
                            }
                            None => Some((Ray::new(origin, ls.wi), f32::INFINITY)),
                        };
                        shadow = Some(ShadowQuery { ray, unshadowed: self.beta * f * ls.li, weight, pdf });
                    }
                }
            }
        }

        // BSDF sampling: the next segment of the path. Only the dimensions the BSDF uses
        // are drawn (Lambert: a direction; mirror: none; glass: a lobe choice).
        let (u_lobe, u) = match bsdf {
            Bsdf::Diffuse { .. } => (0.0, sampler.next_2d()),
            Bsdf::Glossy { .. } | Bsdf::Principled(_) => (sampler.next_1d(), sampler.next_2d()),
            Bsdf::Mirror { .. } => (0.0, Vec2::ZERO),
            Bsdf::Glass { .. } => (sampler.next_1d(), Vec2::ZERO),
        };
        let sampled = match &lobes {
            Some(l) => l.sample(wo_local, u_lobe, u),
            None => bsdf.sample(wo_local, u_lobe, u),
        };
        let Some(bs) = sampled else {
            return (shadow, false);
        };
        let wi = frame.to_world(bs.wi);
        // A reflection that dips below the geometric surface (possible with shading
        // normals) would leak light through it.
        if two_sided && ng.dot(wi) <= 0.0 {
            return (shadow, false);
        }
        self.beta *= if diffuse_tilted { bs.weight * bump_shadowing(smooth, ns, wi) } else { bs.weight };
        if !(self.beta.max_element() > 0.0) || !self.beta.is_finite() {
            return (shadow, false);
        }
        self.prev_pdf = bs.pdf;
        self.prev_delta = bs.delta;
        self.prev_p = si.p;
        self.ray = Ray::new(offset_origin(si.p, ng, wi), wi);

        if self.depth >= opt.rr_depth {
            let q = self.beta.max_element().min(0.95);
            if sampler.next_1d() >= q {
                return (shadow, false);
            }
            self.beta /= q;
        }
        (shadow, true)
    }
}

/// The emission of the area lights that the segment `ray` (up to `tmax`) passes through,
/// each weighted against light sampling from the vertex it left (`prev`: the path's
/// depth, whether that vertex scattered by a delta lobe, its BSDF pdf and its point);
/// `None` if it meets none.
#[inline]
pub(crate) fn area_light_emission(
    scene: &Scene,
    ray: &Ray,
    tmax: f32,
    (depth, prev_delta, prev_pdf, prev_p): (u32, bool, f32, Vec3),
    opt: &Options,
) -> Option<Vec3> {
    let mut sum: Option<Vec3> = None;
    scene.lights.area_hits(ray.origin, ray.dir, tmax, |light, radiance, q| {
        let w = emitter_weight(depth, prev_delta, opt.strategy, prev_pdf, || {
            scene.lights.pmf_at(prev_p, light) * scene.lights.pdf_li(light, prev_p, ray.dir, q)
        });
        let e = radiance * w;
        sum = Some(sum.map_or(e, |s| s + e));
    });
    sum
}

/// The weight of emission found by BSDF sampling (or seen from the camera), given the
/// pdf with which light sampling would have produced the same direction.
#[inline]
pub(crate) fn emitter_weight(
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

/// The probability that a shadow ray is blocked by material `m` at `uv` (a mix: its
/// materials' in proportion).
fn opacity_of(scene: &Scene, m: u32, uv: Vec2) -> f32 {
    mixed_opacity(scene, m, uv, MAX_MIX_DEPTH)
}

fn mixed_opacity(scene: &Scene, m: u32, uv: Vec2, depth: usize) -> f32 {
    let material = &scene.materials[m as usize];
    match material.mix {
        Some(mix) if depth > 0 => {
            let t = material.maps.scale(Slot::MixFactor, mix.factor, uv, &scene.textures).clamp(0.0, 1.0);
            (1.0 - t) * mixed_opacity(scene, mix.first, uv, depth - 1)
                + t * mixed_opacity(scene, mix.second, uv, depth - 1)
        }
        _ => material.opacity_at(uv, &scene.textures),
    }
}

/// Visibility of a light sample: 1 if unblocked, 0 if blocked; with stochastic-opacity
/// materials in the scene, the product of (1 - d) over the surfaces crossed (the
/// expected value of the opacity coin flips, so the estimate stays unbiased).
#[inline(always)]
pub fn transmittance(scene: &Scene, q: &ShadowQuery, count: &mut RayCount) -> f32 {
    let Some((ray, tmax)) = q.ray else {
        return 1.0;
    };
    if !scene.has_cutouts {
        count.rays += 1;
        return if scene.occluded(&ray, tmax) { 0.0 } else { 1.0 };
    }
    let (mut origin, dir, mut tmax) = (ray.origin, ray.dir, tmax);
    let mut tr = 1.0f32;
    // Bounded: each step moves past one surface; a pathological stack ends as blocked.
    for _ in 0..256 {
        count.rays += 1;
        let ray = Ray::new(origin, dir);
        let Some(hit) = scene.intersect(&ray, tmax) else {
            return tr;
        };
        let h = scene.interaction(&ray, &hit);
        let opacity = opacity_of(scene, h.material, h.uv);
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
