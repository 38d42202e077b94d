//! Lights: one enum for every kind, and the set that picks one per shading point in
//! proportion to power / distance² (or to power alone in scenes with many lights).
//!
//! Area lights (emissive triangles and spheres) and the environment are sampled with a
//! solid-angle pdf so that the path integrator can weight them against BSDF sampling by
//! multiple importance sampling; point, spot and directional lights are delta lights,
//! reachable by light sampling alone.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::geometry::{Frame, FrameW, offset_origin, offset_origin_wide};
use crate::sampler::ONE_MINUS_EPSILON;
use crate::sampling::{sample_uniform_sphere, sample_uniform_triangle, select, select_bits, uniform_sphere_pdf, wide};
use crate::wide::{F8, M8, U8, V2w, V3w, each};

#[derive(Clone, Copy, Debug, PartialEq)]
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
    let step = x.lt(a).select(F8::ZERO, F8::ONE);
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
            _ => 0.0,
        }
    }
}

/// Uniform sampling of the cone of directions a sphere subtends from `p` (pbrt-v4's
/// `Sphere::Sample(ctx)`), with the point on the sphere computed analytically so that it
/// exists even for directions at the silhouette. Returns `(wi, point, pdf)`; `None` when
/// `p` is inside the sphere (it emits outwards only, so nothing reaches `p`).
#[inline(always)]
fn sample_sphere_cone(p: Vec3, center: Vec3, radius: f32, u: Vec2) -> Option<(Vec3, Vec3, f32)> {
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

/// Scenes with at most this many lights choose one per shading point, in proportion to
/// an estimate of the irradiance each delivers there ([`LightSet::select_at`]); larger
/// scenes choose by power alone (a CDF), which costs O(log N) instead of O(N).
pub const LOCAL_SELECTION_MAX: usize = 16;

/// What [`LightSet::select_at`] needs of a light, flat and small.
#[derive(Clone, Copy, Debug)]
struct Importance {
    /// Centre of a local light (point, spot, sphere, triangle centroid).
    center: Vec3,
    /// Emitted power (luminance); for infinite lights, power / scene radius².
    power: f32,
    /// Squared distances are clamped below by this; 0 marks an infinite light (no falloff).
    min_d2: f32,
    /// One-sided planar emitters emit only to points with `p · normal > plane`;
    /// `normal` is zero for the others.
    normal: Vec3,
    plane: f32,
    /// Spheres: nothing reaches points within this squared distance of the centre.
    inside_r2: f32,
}

impl Importance {
    fn new(light: &Light, scene_radius: f32) -> Self {
        let r2 = (scene_radius * scene_radius).max(f32::MIN_POSITIVE);
        let power = light.power(scene_radius);
        let mut imp =
            Importance { center: Vec3::ZERO, power, min_d2: 1e-8 * r2, normal: Vec3::ZERO, plane: 0.0, inside_r2: 0.0 };
        match *light {
            Light::Point { position, .. } | Light::Spot { position, .. } => imp.center = position,
            Light::Triangle { p0, e1, e2, normal, area, .. } => {
                imp.center = p0 + (e1 + e2) / 3.0;
                imp.normal = normal;
                imp.plane = normal.dot(p0);
                // Close to a large emitter the irradiance saturates (at pi L), and so
                // does power / area.
                imp.min_d2 = area.max(imp.min_d2);
            }
            Light::Sphere { center, radius, .. } => {
                imp.center = center;
                imp.inside_r2 = radius * radius;
                imp.min_d2 = imp.inside_r2.max(imp.min_d2);
            }
            Light::Directional { .. } | Light::Environment { .. } => {
                imp.power = power / r2;
                imp.min_d2 = 0.0;
            }
        }
        if !imp.power.is_finite() {
            imp.power = 0.0;
        }
        imp
    }

    /// Selection weight at `p`: power / distance², zero exactly where the light cannot
    /// contribute (behind a one-sided emitter, inside an emitting sphere). The zeros are
    /// selects, not early returns: which side of a light a shading point lies on is
    /// random, and a branch on it mispredicted.
    #[inline]
    fn weight(&self, p: Vec3) -> f32 {
        if self.min_d2 == 0.0 {
            return self.power;
        }
        let behind = self.normal != Vec3::ZERO && p.dot(self.normal) <= self.plane;
        let d2 = (p - self.center).length_squared();
        let w = self.power / d2.max(self.min_d2);
        select(behind || d2 <= self.inside_r2 || !w.is_finite(), 0.0, w)
    }
}

/// The scene's lights and the distributions that choose one for light sampling.
#[derive(Clone, Debug, Default)]
pub struct LightSet {
    pub lights: Vec<Light>,
    cdf: Vec<f32>,
    pmf: Vec<f32>,
    /// Per-light data for the per-point selection; empty when there are more than
    /// [`LOCAL_SELECTION_MAX`] lights (selection by power alone).
    importance: Vec<Importance>,
    /// `(primitive, its area light)` for the emissive primitives, sorted by primitive:
    /// 8 bytes per emitter rather than 4 per primitive of the scene (it is looked up only
    /// when a path hits an emitter).
    prim_light: Vec<(u32, u32)>,
    environment: Option<u32>,
}

impl LightSet {
    pub fn new(lights: Vec<Light>, prim_count: usize, scene_radius: f32) -> Self {
        let powers: Vec<f32> = lights.iter().map(|l| l.power(scene_radius)).collect();
        let total: f64 = powers.iter().map(|&p| p as f64).sum();
        let mut pmf = Vec::with_capacity(lights.len());
        let mut cdf = Vec::with_capacity(lights.len());
        let mut acc = 0.0f64;
        for &p in &powers {
            let q = if total > 0.0 { p as f64 / total } else { 0.0 };
            acc += q;
            pmf.push(q as f32);
            cdf.push(acc as f32);
        }
        // The last light with nonzero probability closes the CDF exactly at 1.
        if let Some(last) = pmf.iter().rposition(|&q| q > 0.0) {
            for c in &mut cdf[last..] {
                *c = 1.0;
            }
        }
        let mut prim_light = Vec::new();
        let mut environment = None;
        for (i, l) in lights.iter().enumerate() {
            match *l {
                Light::Triangle { prim, .. } | Light::Sphere { prim, .. } => {
                    assert!((prim as usize) < prim_count, "light {i}: primitive {prim} out of range");
                    prim_light.push((prim, i as u32));
                }
                Light::Environment { .. } => environment = Some(i as u32),
                _ => {}
            }
        }
        // A primitive named by several lights belongs to the last (stable sort, then keep
        // the last of each run).
        prim_light.sort_by_key(|&(prim, _)| prim);
        prim_light.reverse();
        prim_light.dedup_by_key(|&mut (prim, _)| prim);
        prim_light.reverse();
        prim_light.shrink_to_fit();
        let importance = if lights.len() <= LOCAL_SELECTION_MAX {
            lights.iter().map(|l| Importance::new(l, scene_radius)).collect()
        } else {
            Vec::new()
        };
        Self { lights, cdf, pmf, importance, prim_light, environment }
    }

    pub fn is_empty(&self) -> bool {
        self.lights.is_empty() || self.cdf.last().is_none_or(|&c| c <= 0.0)
    }

    /// Picks a light with probability proportional to its power: `(index, pmf)`.
    #[inline]
    pub fn select(&self, u: f32) -> Option<(usize, f32)> {
        if self.is_empty() {
            return None;
        }
        let i = self.cdf.partition_point(|&c| c <= u).min(self.cdf.len() - 1);
        let p = self.pmf[i];
        (p > 0.0).then_some((i, p))
    }

    /// Probability that [`Self::select`] picks `light`.
    #[inline]
    pub fn pmf(&self, light: usize) -> f32 {
        self.pmf[light]
    }

    /// Picks a light for shading point `p`: `(index, pmf, u')`, where `u'` is `u`
    /// rescaled to `[0, 1)` within the chosen light's interval, so that it can serve as
    /// one coordinate of the light's own 2D sample without losing stratification.
    ///
    /// With at most [`LOCAL_SELECTION_MAX`] lights, the probability is proportional to
    /// power / distance² (zero where a light cannot reach `p`); otherwise to power.
    /// [`Self::pmf_at`] gives the same probability, bit for bit, for MIS weights.
    // Inline, as `Light::sample_li`, `pmf_at` and the integrator's `transmittance`: LLVM
    // kept them as calls in the path loop (bench/RESULTS.md).
    #[inline(always)]
    pub fn select_at(&self, p: Vec3, u: f32) -> Option<(usize, f32, f32)> {
        if self.importance.is_empty() {
            let (i, pmf) = self.select(u)?;
            let below = if i == 0 { 0.0 } else { self.cdf[i - 1] };
            return Some((i, pmf, ((u - below) / pmf).clamp(0.0, ONE_MINUS_EPSILON)));
        }
        let mut w = [0.0f32; LOCAL_SELECTION_MAX];
        let total = self.weights_at(p, &mut w);
        if !(total > 0.0 && total.is_finite()) {
            return None;
        }
        let target = u * total;
        // The first light with weight whose interval [below, below + w) holds `target`;
        // if rounding left `target` past the last sum, the last light with weight. By
        // selects over every light rather than an early exit: which interval a random
        // `target` falls in is random, and the exit branch mispredicted.
        let (mut below, mut chosen_below) = (0.0f32, 0.0f32);
        let (mut chosen, mut last) = (u32::MAX, u32::MAX);
        for (i, &wi) in w[..self.importance.len()].iter().enumerate() {
            let with_weight = wi > 0.0;
            let here = with_weight && chosen == u32::MAX && target < below + wi;
            chosen = select_bits(here, i as u32, chosen);
            chosen_below = select(here, below, chosen_below);
            last = select_bits(with_weight, i as u32, last);
            below = select(with_weight, below + wi, below);
        }
        if chosen != u32::MAX {
            let i = chosen as usize;
            return Some((i, w[i] / total, ((target - chosen_below) / w[i]).clamp(0.0, ONE_MINUS_EPSILON)));
        }
        let i = (last != u32::MAX).then_some(last as usize)?;
        Some((i, w[i] / total, ONE_MINUS_EPSILON))
    }

    /// Probability that [`Self::select_at`] at `p` picks `light`.
    #[inline(always)]
    pub fn pmf_at(&self, p: Vec3, light: usize) -> f32 {
        if self.importance.is_empty() {
            return self.pmf[light];
        }
        let mut w = [0.0f32; LOCAL_SELECTION_MAX];
        let total = self.weights_at(p, &mut w);
        if !(total > 0.0 && total.is_finite()) {
            return 0.0;
        }
        w[light] / total
    }

    /// Fills `w` with every light's selection weight at `p`; returns their sum.
    #[inline]
    fn weights_at(&self, p: Vec3, w: &mut [f32; LOCAL_SELECTION_MAX]) -> f32 {
        let mut total = 0.0f32;
        for (wi, imp) in w.iter_mut().zip(&self.importance) {
            *wi = imp.weight(p);
            total += *wi;
        }
        total
    }

    /// The area light that primitive `prim` belongs to.
    #[inline]
    pub fn light_of_prim(&self, prim: u32) -> Option<usize> {
        let i = self.prim_light.binary_search_by_key(&prim, |&(p, _)| p).ok()?;
        Some(self.prim_light[i].1 as usize)
    }

    pub fn environment(&self) -> Option<usize> {
        self.environment.map(|e| e as usize)
    }
}

/// Light sampling for the eight-path integrator: [`LightSet::select_at`] and
/// [`Light::sample_li`], lane by lane with the same operations in the same order (see
/// `wide.rs`).
impl LightSet {
    /// Whether [`LightSet::select_at_wide`] can choose the lights: the selection is per
    /// point (at most [`LOCAL_SELECTION_MAX`] lights). [`LightSet::sample_li_wide`]
    /// samples every kind.
    pub fn wide_ok(&self) -> bool {
        !self.importance.is_empty()
    }

    /// [`LightSet::select_at`] at eight points: `(light, pmf, u', chosen)` per lane
    /// (lanes not `chosen` had no light to choose). Only where [`LightSet::wide_ok`].
    #[inline(always)]
    pub(crate) fn select_at_wide(&self, p: V3w, u: F8) -> (U8, F8, F8, M8) {
        let mut w = [F8::ZERO; LOCAL_SELECTION_MAX];
        let mut total = F8::ZERO;
        for (wi, imp) in w.iter_mut().zip(&self.importance) {
            *wi = imp.weight_wide(p);
            total = total + *wi;
        }
        let ok = total.gt(0.0) & total.is_finite();
        let target = u * total;
        let (mut below, mut chosen_below, mut chosen_w, mut last_w) = (F8::ZERO, F8::ZERO, F8::ZERO, F8::ZERO);
        let none = U8::splat(u32::MAX);
        let (mut chosen, mut last, mut found) = (none, none, M8::NONE);
        for (i, &wi) in w[..self.importance.len()].iter().enumerate() {
            let with_weight = wi.gt(0.0);
            let here = with_weight & !found & target.lt(below + wi);
            chosen = here.select_u(U8::splat(i as u32), chosen);
            chosen_below = here.select(below, chosen_below);
            chosen_w = here.select(wi, chosen_w);
            found = found | here;
            last = with_weight.select_u(U8::splat(i as u32), last);
            last_w = with_weight.select(wi, last_w);
            below = with_weight.select(below + wi, below);
        }
        // Rounding left `target` past the last sum: the last light with weight takes it.
        let light = found.select_u(chosen, last);
        let ux = ((target - chosen_below) / chosen_w).clamp(0.0, ONE_MINUS_EPSILON);
        let ux = found.select(ux, F8::splat(ONE_MINUS_EPSILON));
        (light, found.select(chosen_w, last_w) / total, ux, ok & !light.eq(none))
    }

    /// [`Light::sample_li`] of light `light[l]` at `p[l]` for the lanes of `mask`; lanes
    /// not `some` have no sample.
    #[inline(always)]
    pub(crate) fn sample_li_wide(&self, light: U8, p: V3w, u: V2w, mask: M8) -> LightSamplesW {
        let zero = V3w::splat(Vec3::ZERO);
        let (mut tri, mut sph, mut pnt, mut spt) = (M8::NONE, M8::NONE, M8::NONE, M8::NONE);
        // Lights at infinity: the environment, directional lights (`dir` in `b`).
        let (mut env, mut dir) = (M8::NONE, M8::NONE);
        // Triangles: p0, e1, e2, normal, area; spheres: center (in `a`), radius; points:
        // position (in `a`); spots: position, direction (in `n`), cos_total (in `size`),
        // cos_falloff_start.
        let (mut a, mut b, mut c, mut n) = (zero, zero, zero, zero);
        let (mut size, mut start, mut li) = (F8::ONE, F8::ONE, zero);
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
            }
        }
        let (mut wi, mut pdf, mut target, mut some, mut delta) = (zero, F8::ZERO, zero, M8::NONE, M8::NONE);
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
            pdf = ok.select(F8::ONE, pdf);
            target = ok.select3(a, target);
            some = some | ok;
            delta = delta | ok;
        }
        if (dir | env).any() {
            // `Light::Directional`'s and `Light::Environment`'s arms.
            wi = dir.select3(-b, env.select3(wide::sample_uniform_sphere(u), wi));
            pdf = dir.select(F8::ONE, env.select(F8::splat(uniform_sphere_pdf()), pdf));
            some = some | dir | env;
            delta = delta | dir;
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
        LightSamplesW { wi, li: radiance, pdf, target, some, delta, at_infinity: dir | env }
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

impl Importance {
    /// [`Importance::weight`] at eight points.
    #[inline(always)]
    fn weight_wide(&self, p: V3w) -> F8 {
        if self.min_d2 == 0.0 {
            return F8::splat(self.power);
        }
        let behind = if self.normal != Vec3::ZERO { p.dot(V3w::splat(self.normal)).le(self.plane) } else { M8::NONE };
        let d2 = (p - V3w::splat(self.center)).length_squared();
        let w = self.power / d2.max(self.min_d2);
        (behind | d2.le(self.inside_r2) | !w.is_finite()).select(F8::ZERO, w)
    }
}

/// [`sample_sphere_cone`] lane by lane, for the lanes of `mask`: `(wi, point, pdf, some)`.
#[inline(always)]
fn sample_sphere_cone_wide(p: V3w, center: V3w, radius: F8, u: V2w, mask: M8) -> (V3w, V3w, F8, M8) {
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

#[cfg(test)]
mod tests;
