//! Lights: one enum for every kind, and the set that picks one per shading point in
//! proportion to power / distance² (or to power alone in scenes with many lights).
//!
//! Area lights (emissive triangles and spheres) and the environment are sampled with a
//! solid-angle pdf so that the path integrator can weight them against BSDF sampling by
//! multiple importance sampling; point, spot and directional lights are delta lights,
//! reachable by light sampling alone.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::geometry::{offset_origin, offset_origin_wide};
use crate::sampling::{sample_uniform_sphere, sample_uniform_triangle, uniform_sphere_pdf, wide};
use crate::simd::{F8, M8, U8, V2w, V3w, each};

mod area;
pub mod distribution;
mod environment;
mod set;
mod soft;
mod sphere_cone;
#[cfg(test)]
mod tests;
mod tree;

pub use area::{Area, AreaShape};
pub use environment::{EnvironmentMap, EnvironmentSample, Up};
pub use set::{LOCAL_SELECTION_MAX, LightSet};
pub use soft::{Cone, SoftPoint, Sun};
use sphere_cone::{sample_sphere_cone, sample_sphere_cone_wide};

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Light {
    /// Radiant intensity `intensity` (W/sr) in every direction.
    Point { position: Vec3, intensity: Vec3 },
    /// A cone around `direction` (unit): full intensity within `cos_falloff_start`,
    /// smoothstep falloff to zero at `cos_total`.
    Spot { position: Vec3, direction: Vec3, intensity: Vec3, cos_total: f32, cos_falloff_start: f32 },
    /// Parallel light travelling along `direction` (unit).
    Directional { direction: Vec3, irradiance: Vec3 },
    /// An emissive triangle (primitive `prim`), emitting `radiance` from its front face.
    Triangle { prim: u32, p0: Vec3, e1: Vec3, e2: Vec3, normal: Vec3, area: f32, radiance: Vec3 },
    /// An emissive sphere (primitive `prim`), emitting `radiance` outwards.
    Sphere { prim: u32, center: Vec3, radius: f32, radiance: Vec3 },
    /// Constant radiance from every direction (the report's "ambient light").
    Environment { radiance: Vec3 },
    /// A one-sided rectangle or ellipse of constant `radiance` that is not a surface
    /// (Blender's area light): found by light sampling and by scattered rays.
    Area { geometry: Area, radiance: Vec3 },
    /// A point or spot light with a radius (soft shadows; not a surface).
    SoftPoint(SoftPoint),
    /// A sun with an angular size (soft shadows; at infinity).
    Sun(Sun),
}

/// Incident light from one sampled point of a light.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the shading point towards the light.
    pub wi: Vec3,
    /// Incident radiance (area lights), or irradiance-like `I/r²` / `E` (delta lights).
    pub li: Vec3,
    /// Solid-angle pdf of `wi` (1 for delta lights); excludes the light selection pmf.
    pub pdf: f32,
    /// Where the shadow ray ends: the sampled point, or `None` for lights at infinity.
    pub target: Option<Vec3>,
    pub delta: bool,
}

#[inline]
fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

#[inline]
fn smoothstep(x: f32, a: f32, b: f32) -> f32 {
    if a == b {
        return if x < a { 0.0 } else { 1.0 };
    }
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// [`smoothstep`] at eight points, with per-lane edges.
#[inline(always)]
fn smoothstep_wide(x: F8, a: F8, b: F8) -> F8 {
    let step = x.lt(a).select(x.simd().zero(), x.simd().one());
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    a.eq(b).select(step, t * t * (3.0 - 2.0 * t))
}

impl Light {
    /// Emitted power (luminance of W), used to choose lights. `scene_radius` bounds the
    /// area that infinite lights illuminate.
    pub fn power(&self, scene_radius: f32) -> f32 {
        let disc = PI * scene_radius * scene_radius;
        let p = match *self {
            Light::Point { intensity, .. } => 4.0 * PI * luminance(intensity),
            Light::Spot { intensity, cos_total, cos_falloff_start, .. } => {
                2.0 * PI * luminance(intensity) * (1.0 - 0.5 * (cos_total + cos_falloff_start))
            }
            Light::Directional { irradiance, .. } => disc * luminance(irradiance),
            Light::Triangle { area, radiance, .. } => PI * area * luminance(radiance),
            Light::Sphere { radius, radiance, .. } => PI * 4.0 * PI * radius * radius * luminance(radiance),
            Light::Environment { radiance } => PI * 4.0 * disc * luminance(radiance),
            Light::Area { geometry, radiance } => PI * geometry.area * luminance(radiance),
            // As the point or spot light of intensity π r² L.
            Light::SoftPoint(s) => {
                let i = PI * s.radius * s.radius * luminance(s.radiance);
                match s.cone {
                    None => 4.0 * PI * i,
                    Some(c) => 2.0 * PI * i * (1.0 - 0.5 * (c.cos_total + c.cos_falloff_start)),
                }
            }
            // As the hard sun of irradiance π sin²α L (sin²α = (1 − cos α)(1 + cos α)).
            Light::Sun(s) => disc * PI * s.one_minus_cos * (2.0 - s.one_minus_cos) * luminance(s.radiance),
        };
        if p.is_finite() { p.max(0.0) } else { 0.0 }
    }

    pub fn is_delta(&self) -> bool {
        matches!(self, Light::Point { .. } | Light::Spot { .. } | Light::Directional { .. })
    }

    /// Samples incident light at `p` (with geometric normal `n` for ray offsets).
    // Inline: see the note on `Bsdf`'s methods (bsdf/mod.rs).
    #[inline(always)]
    pub fn sample_li(&self, p: Vec3, u: Vec2) -> Option<LightSample> {
        match *self {
            Light::Point { position, intensity } => {
                let d = position - p;
                let d2 = d.length_squared();
                let wi = d / d2.sqrt();
                Some(LightSample { wi, li: intensity / d2, pdf: 1.0, target: Some(position), delta: true })
            }
            Light::Spot { position, direction, intensity, cos_total, cos_falloff_start } => {
                let d = position - p;
                let d2 = d.length_squared();
                let wi = d / d2.sqrt();
                let falloff = smoothstep((-wi).dot(direction), cos_total, cos_falloff_start);
                if falloff <= 0.0 {
                    return None;
                }
                Some(LightSample { wi, li: intensity * falloff / d2, pdf: 1.0, target: Some(position), delta: true })
            }
            Light::Directional { direction, irradiance } => {
                Some(LightSample { wi: -direction, li: irradiance, pdf: 1.0, target: None, delta: true })
            }
            Light::Triangle { p0, e1, e2, normal, area, radiance, .. } => {
                let [_, b1, b2] = sample_uniform_triangle(u);
                let q = p0 + b1 * e1 + b2 * e2;
                let d = q - p;
                let d2 = d.length_squared();
                if d2 == 0.0 {
                    return None;
                }
                let wi = d / d2.sqrt();
                // One-sided: only the front (counter-clockwise) face emits.
                let cos_l = -wi.dot(normal);
                if cos_l <= 0.0 {
                    return None;
                }
                let pdf = d2 / (cos_l * area);
                let target = offset_origin(q, normal, -wi);
                Some(LightSample { wi, li: radiance, pdf, target: Some(target), delta: false })
            }
            Light::Sphere { center, radius, radiance, .. } => {
                let (wi, q, pdf) = sample_sphere_cone(p, center, radius, u)?;
                let n = (q - center) / radius;
                let target = offset_origin(q, n, -wi);
                Some(LightSample { wi, li: radiance, pdf, target: Some(target), delta: false })
            }
            Light::Environment { radiance } => {
                let wi = sample_uniform_sphere(u);
                Some(LightSample { wi, li: radiance, pdf: uniform_sphere_pdf(), target: None, delta: false })
            }
            Light::Area { geometry, radiance } => {
                let s = geometry.sample(p, u)?;
                Some(LightSample { wi: s.wi, li: radiance, pdf: s.pdf, target: Some(s.q), delta: false })
            }
            Light::SoftPoint(s) => {
                let (wi, q, pdf) = s.sample(p, u)?;
                let li = s.radiance * s.attenuation(-wi);
                Some(LightSample { wi, li, pdf, target: Some(q), delta: false })
            }
            Light::Sun(s) => {
                let (wi, pdf) = s.sample(u);
                Some(LightSample { wi, li: s.radiance, pdf, target: None, delta: false })
            }
        }
    }

    /// Where a ray scattered from `origin` along `dir` (unit) meets this light before
    /// `tmax` (infinite: the ray left the scene), for the lights that are not surfaces
    /// yet are seen in reflections: `(radiance, point)`.
    #[inline]
    pub fn meet(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<(Vec3, Vec3)> {
        match *self {
            Light::Area { geometry, radiance } => geometry.intersect(origin, dir, tmax).map(|(_, q)| (radiance, q)),
            Light::SoftPoint(s) => s.intersect(origin, dir, tmax).map(|(_, q)| (s.radiance * s.attenuation(-dir), q)),
            Light::Sun(s) if tmax == f32::INFINITY && s.contains(dir) => Some((s.radiance, origin + dir)),
            _ => None,
        }
    }

    /// The solid-angle pdf with which `sample_li` at `p` would produce direction `wi`
    /// reaching this light at `q` (a point on it, for area lights).
    pub fn pdf_li(&self, p: Vec3, wi: Vec3, q: Vec3) -> f32 {
        match *self {
            Light::Triangle { normal, area, .. } => {
                let cos_l = -wi.dot(normal);
                if cos_l <= 0.0 {
                    return 0.0;
                }
                (q - p).length_squared() / (cos_l * area)
            }
            Light::Sphere { center, radius, .. } => {
                let d2 = (center - p).length_squared();
                let r2 = radius * radius;
                if d2 <= r2 {
                    return 0.0;
                }
                let sin2_max = r2 / d2;
                let one_minus_cos_max = sin2_max / (1.0 + (1.0 - sin2_max).sqrt());
                1.0 / (2.0 * PI * one_minus_cos_max)
            }
            Light::Environment { .. } => uniform_sphere_pdf(),
            Light::Area { geometry, .. } => geometry.pdf(p, wi, q),
            Light::SoftPoint(s) => s.pdf(p, wi, q),
            Light::Sun(s) => s.pdf(wi),
            _ => 0.0,
        }
    }
}

/// Light sampling for the eight-path integrator: [`Light::sample_li`] lane by lane,
/// with the same operations in the same order (see `simd.rs`).
impl LightSet {
    /// [`Light::sample_li`] of light `light[l]` at `p[l]` for the lanes of `mask`; lanes
    /// not `some` have no sample.
    #[inline(always)]
    // Long on purpose: The twin of `Light::sample_li`: one arm per light kind as there, gathered per lane, then each arm's math on all lanes.
    pub(crate) fn sample_li_wide(&self, light: U8, p: V3w, u: V2w, mask: M8) -> LightSamplesW {
        let simd = p.simd();
        let zero = simd.v3(Vec3::ZERO);
        let (mut tri, mut sph, mut pnt, mut spt) = (simd.none(), simd.none(), simd.none(), simd.none());
        // Lights at infinity: the environment, directional lights (`dir` in `b`).
        let (mut env, mut dir) = (simd.none(), simd.none());
        // Area lights, lights with a size: the one-path code, lane by lane.
        let mut area = simd.none();
        // Triangles: p0, e1, e2, normal, area; spheres: center (in `a`), radius; points:
        // position (in `a`); spots: position, direction (in `n`), cos_total (in `size`),
        // cos_falloff_start.
        let (mut a, mut b, mut c, mut n) = (zero, zero, zero, zero);
        let (mut size, mut start, mut li) = (simd.one(), simd.one(), zero);
        for l in each(mask.bits()) {
            match self.lights[light.0[l] as usize] {
                Light::Point { position, intensity } => {
                    pnt.0[l] = u32::MAX;
                    a.set(l, position);
                    li.set(l, intensity);
                }
                Light::Spot { position, direction, intensity, cos_total, cos_falloff_start } => {
                    spt.0[l] = u32::MAX;
                    a.set(l, position);
                    n.set(l, direction);
                    size.0[l] = cos_total;
                    start.0[l] = cos_falloff_start;
                    li.set(l, intensity);
                }
                Light::Directional { direction, irradiance } => {
                    dir.0[l] = u32::MAX;
                    b.set(l, direction);
                    li.set(l, irradiance);
                }
                Light::Environment { radiance } => {
                    env.0[l] = u32::MAX;
                    li.set(l, radiance);
                }
                Light::Triangle { p0, e1, e2, normal, area, radiance, .. } => {
                    tri.0[l] = u32::MAX;
                    a.set(l, p0);
                    b.set(l, e1);
                    c.set(l, e2);
                    n.set(l, normal);
                    size.0[l] = area;
                    li.set(l, radiance);
                }
                Light::Sphere { center, radius, radiance, .. } => {
                    sph.0[l] = u32::MAX;
                    a.set(l, center);
                    size.0[l] = radius;
                    li.set(l, radiance);
                }
                Light::Area { .. } | Light::SoftPoint(_) | Light::Sun(_) => area.0[l] = u32::MAX,
            }
        }
        let (mut wi, mut pdf, mut target, mut some, mut delta) = (zero, simd.zero(), zero, simd.none(), simd.none());
        let mut radiance = li;
        let at_point = pnt | spt;
        if at_point.any() {
            // `Light::Point`'s and `Light::Spot`'s arms.
            let d = a - p;
            let d2 = d.length_squared();
            let w = d / d2.sqrt();
            let falloff = smoothstep_wide((-w).dot(n), size, start);
            let ok = pnt | (spt & !falloff.le(0.0));
            wi = ok.select3(w, wi);
            radiance = pnt.select3(li / d2, spt.select3(li * falloff / d2, radiance));
            pdf = ok.select(simd.one(), pdf);
            target = ok.select3(a, target);
            some = some | ok;
            delta = delta | ok;
        }
        if (dir | env).any() {
            // `Light::Directional`'s and `Light::Environment`'s arms.
            wi = dir.select3(-b, env.select3(wide::sample_uniform_sphere(u), wi));
            pdf = dir.select(simd.one(), env.select(simd.splat(uniform_sphere_pdf()), pdf));
            some = some | dir | env;
            delta = delta | dir;
        }
        if let (Some(map), true) = (self.environment_map(), env.any()) {
            // An environment map: [`LightSet::sample_li`]'s arm, lane by lane (a table
            // search per lane; rare next to the surfaces' own work).
            for l in each(env.bits()) {
                match map.sample(Vec2::new(u.x.0[l], u.y.0[l])) {
                    Some(s) => {
                        wi.set(l, s.wi);
                        pdf.0[l] = s.pdf;
                        radiance.set(l, li.get(l) * s.radiance);
                    }
                    None => some.0[l] = 0,
                }
            }
        }
        if tri.any() {
            // `Light::Triangle`'s arm.
            let [_, b1, b2] = wide::sample_uniform_triangle(u);
            let q = a + b1 * b + b2 * c;
            let d = q - p;
            let d2 = d.length_squared();
            let w = d / d2.sqrt();
            let cos_l = -w.dot(n);
            let ok = tri & d2.ne(0.0) & !cos_l.le(0.0);
            wi = ok.select3(w, wi);
            pdf = ok.select(d2 / (cos_l * size), pdf);
            target = ok.select3(offset_origin_wide(q, n, -w), target);
            some = some | ok;
        }
        if sph.any() {
            // `Light::Sphere`'s arm.
            let (w, q, pdf_s, ok) = sample_sphere_cone_wide(p, a, size, u, sph);
            let normal = (q - a) / size;
            wi = ok.select3(w, wi);
            pdf = ok.select(pdf_s, pdf);
            target = ok.select3(offset_origin_wide(q, normal, -w), target);
            some = some | ok;
        }
        let mut at_infinity = dir | env;
        for l in each(area.bits()) {
            let pl = p.get(l);
            if let Some(s) = self.lights[light.0[l] as usize].sample_li(pl, Vec2::new(u.x.0[l], u.y.0[l])) {
                wi.set(l, s.wi);
                pdf.0[l] = s.pdf;
                radiance.set(l, s.li);
                target.set(l, s.target.unwrap_or(pl));
                some.0[l] = u32::MAX;
                at_infinity.0[l] = if s.target.is_none() { u32::MAX } else { 0 };
            }
        }
        LightSamplesW { wi, li: radiance, pdf, target, some, delta, at_infinity }
    }
}

/// Eight [`LightSample`]s ([`LightSet::sample_li_wide`]).
pub(crate) struct LightSamplesW {
    pub wi: V3w,
    pub li: V3w,
    pub pdf: F8,
    /// The point the shadow ray ends at, where not `at_infinity`.
    pub target: V3w,
    /// The lanes with a sample.
    pub some: M8,
    /// Samples of lights at a point or in one direction (no MIS).
    pub delta: M8,
    /// Samples whose shadow rays are unbounded (`LightSample::target` `None`).
    pub at_infinity: M8,
}
