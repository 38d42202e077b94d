//! The scene's light set: the lights, and the distributions that choose one for a
//! shading point — by an estimate of the irradiance each delivers there in scenes of
//! few lights, by power alone in the others — with their eight-lane twins beside them.

use glam::{Vec2, Vec3};

use super::tree::LightTree;
use super::{EnvironmentMap, Light, LightSample};
use crate::sampler::ONE_MINUS_EPSILON;
use crate::sampling::{select, select_bits};
use crate::simd::{F8, M8, U8, V3w};

/// Scenes with at most this many lights choose one per shading point, in proportion to
/// an estimate of the irradiance each delivers there ([`LightSet::select_at`]); larger
/// scenes walk a light hierarchy (`light/tree.rs`), which costs O(log N) instead of O(N).
pub const LOCAL_SELECTION_MAX: usize = 16;

/// What [`LightSet::select_at`] needs of a light, flat and small.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
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
    fn new(light: &Light, power: f32, scene_radius: f32) -> Self {
        let r2 = (scene_radius * scene_radius).max(f32::MIN_POSITIVE);
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
            Light::Area { geometry, .. } => {
                imp.center = geometry.center;
                imp.normal = geometry.normal;
                imp.plane = geometry.normal.dot(geometry.center);
                imp.min_d2 = geometry.area.max(imp.min_d2);
            }
            Light::SoftPoint(s) => {
                imp.center = s.position;
                imp.min_d2 = (s.radius * s.radius).max(imp.min_d2);
            }
            Light::Directional { .. } | Light::Environment { .. } | Light::Sun(_) => {
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

impl Importance {
    /// [`Importance::weight`] at eight points.
    #[inline(always)]
    fn weight_wide(&self, p: V3w) -> F8 {
        let simd = p.simd();
        if self.min_d2 == 0.0 {
            return simd.splat(self.power);
        }
        let behind = if self.normal != Vec3::ZERO { p.dot(simd.v3(self.normal)).le(self.plane) } else { simd.none() };
        let d2 = (p - simd.v3(self.center)).length_squared();
        let w = self.power / d2.max(self.min_d2);
        (behind | d2.le(self.inside_r2) | !w.is_finite()).select(simd.zero(), w)
    }
}

/// The scene's lights and the distributions that choose one for light sampling.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
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
    /// The environment light's radiance by direction, when it is a map (the light's own
    /// `radiance` is then 1).
    map: Option<EnvironmentMap>,
    /// The lights that scattered rays meet though they are not surfaces (area lights,
    /// lights with a size), tested one by one.
    areas: Vec<u32>,
    /// Scenes of more than [`LOCAL_SELECTION_MAX`] lights: the hierarchy that chooses
    /// one per point (`None`: by power alone).
    tree: Option<LightTree>,
}

impl LightSet {
    pub fn new(lights: Vec<Light>, prim_count: usize, scene_radius: f32) -> Self {
        Self::with_environment_map(lights, None, prim_count, scene_radius)
    }

    /// [`LightSet::new`] with the environment light's radiance given by `map`.
    pub fn with_environment_map(
        lights: Vec<Light>,
        map: Option<EnvironmentMap>,
        prim_count: usize,
        scene_radius: f32,
    ) -> Self {
        let power = |l: &Light| match (l, &map) {
            (Light::Environment { radiance }, Some(m)) => {
                Light::Environment { radiance: *radiance * m.mean() }.power(scene_radius)
            }
            _ => l.power(scene_radius),
        };
        let powers: Vec<f32> = lights.iter().map(power).collect();
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
            lights.iter().zip(&powers).map(|(l, &p)| Importance::new(l, p, scene_radius)).collect()
        } else {
            Vec::new()
        };
        let map = map.filter(|_| environment.is_some());
        let met = |l: &Light| matches!(l, Light::Area { .. } | Light::SoftPoint(_) | Light::Sun(_));
        let areas = (0..lights.len() as u32).filter(|&i| met(&lights[i as usize])).collect();
        let tree = (lights.len() > LOCAL_SELECTION_MAX).then(|| LightTree::new(&lights, &powers));
        Self { lights, cdf, pmf, importance, prim_light, environment, map, areas, tree }
    }

    /// Samples incident light from light `light` at `p` ([`Light::sample_li`], or the
    /// environment map's importance sampling).
    #[inline(always)]
    pub fn sample_li(&self, light: usize, p: Vec3, u: Vec2) -> Option<LightSample> {
        match (&self.lights[light], &self.map) {
            (Light::Environment { radiance }, Some(map)) => {
                let s = map.sample(u)?;
                Some(LightSample { wi: s.wi, li: *radiance * s.radiance, pdf: s.pdf, target: None, delta: false })
            }
            (l, _) => l.sample_li(p, u),
        }
    }

    /// The solid-angle pdf with which [`LightSet::sample_li`] of `light` at `p` gives `wi`
    /// reaching it at `q` ([`Light::pdf_li`]).
    #[inline(always)]
    pub fn pdf_li(&self, light: usize, p: Vec3, wi: Vec3, q: Vec3) -> f32 {
        match (&self.lights[light], &self.map) {
            (Light::Environment { .. }, Some(map)) => map.pdf(wi),
            (l, _) => l.pdf_li(p, wi, q),
        }
    }

    /// Radiance from the environment along `dir` (a ray that left the scene); zero
    /// without an environment.
    #[inline(always)]
    pub fn environment_radiance(&self, dir: Vec3) -> Vec3 {
        let Some(env) = self.environment else { return Vec3::ZERO };
        match (&self.lights[env as usize], &self.map) {
            (Light::Environment { radiance }, Some(map)) => *radiance * map.eval(dir),
            (Light::Environment { radiance }, None) => *radiance,
            _ => Vec3::ZERO,
        }
    }

    /// The lights that are not surfaces which a ray from `origin` along `dir` (unit)
    /// meets before `tmax` ([`Light::meet`]): calls `found(light, radiance, point)` for
    /// each, in the lights' order.
    #[inline]
    pub fn area_hits(&self, origin: Vec3, dir: Vec3, tmax: f32, mut found: impl FnMut(usize, Vec3, Vec3)) {
        for &i in &self.areas {
            if let Some((radiance, q)) = self.lights[i as usize].meet(origin, dir, tmax) {
                found(i as usize, radiance, q);
            }
        }
    }

    /// Chooses lights by power alone from now on, as scenes of many lights did before the
    /// hierarchy (for comparisons of the two).
    pub fn use_power_selection(&mut self) {
        self.tree = None;
    }

    /// Heap bytes of the light hierarchy (0 without one).
    pub fn tree_bytes(&self) -> usize {
        self.tree.as_ref().map_or(0, LightTree::bytes)
    }

    /// Whether the scene has lights that scattered rays meet though they are not
    /// surfaces (area lights, lights with a size).
    #[inline]
    pub fn has_areas(&self) -> bool {
        !self.areas.is_empty()
    }

    /// The environment map, if the environment is one.
    pub fn environment_map(&self) -> Option<&EnvironmentMap> {
        self.map.as_ref()
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
        if let Some(tree) = &self.tree {
            return tree.select(p, u);
        }
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
        if let Some(tree) = &self.tree {
            return tree.pmf(p, light);
        }
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

/// The light choice for the eight-path integrator: [`LightSet::select_at`] lane by
/// lane, with the same operations in the same order (see `simd.rs`).
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
        let simd = u.simd();
        let mut w = [simd.zero(); LOCAL_SELECTION_MAX];
        let mut total = simd.zero();
        for (wi, imp) in w.iter_mut().zip(&self.importance) {
            *wi = imp.weight_wide(p);
            total = total + *wi;
        }
        let ok = total.gt(0.0) & total.is_finite();
        let target = u * total;
        let (mut below, mut chosen_below, mut chosen_w, mut last_w) =
            (simd.zero(), simd.zero(), simd.zero(), simd.zero());
        let none = simd.splat_u(u32::MAX);
        let (mut chosen, mut last, mut found) = (none, none, simd.none());
        for (i, &wi) in w[..self.importance.len()].iter().enumerate() {
            let with_weight = wi.gt(0.0);
            let here = with_weight & !found & target.lt(below + wi);
            chosen = here.select_u(simd.splat_u(i as u32), chosen);
            chosen_below = here.select(below, chosen_below);
            chosen_w = here.select(wi, chosen_w);
            found = found | here;
            last = with_weight.select_u(simd.splat_u(i as u32), last);
            last_w = with_weight.select(wi, last_w);
            below = with_weight.select(below + wi, below);
        }
        // Rounding left `target` past the last sum: the last light with weight takes it.
        let light = found.select_u(chosen, last);
        let ux = ((target - chosen_below) / chosen_w).clamp(0.0, ONE_MINUS_EPSILON);
        let ux = found.select(ux, simd.splat(ONE_MINUS_EPSILON));
        (light, found.select(chosen_w, last_w) / total, ux, ok & !light.eq(none))
    }
}
