//! A light hierarchy for scenes of many lights (pbrt-v4's `BVHLightSampler`, after
//! Conty Estevez & Kulla 2018): a binary tree over the bounded lights, each node with the
//! bounds of its lights' positions, their power and a cone of their emitting directions.
//! Choosing a light for a shading point walks from the root, taking each child with
//! probability proportional to an estimate of what it delivers there (power over squared
//! distance, zero where its cone cannot face the point). Lights at infinity are chosen
//! beside the tree, in proportion to their count.
//!
//! The walk is a pure function of the point and the random number, and
//! [`LightTree::pmf`] repeats the same arithmetic along the light's own path from the
//! root, so a light's probability is the same bits in sampling and in MIS weights.

use std::f32::consts::PI;

use glam::Vec3;

use super::Light;
use crate::sampler::ONE_MINUS_EPSILON;

/// The bounds of a set of lights: where they are, how much they emit, and towards which
/// directions (`w`, within `θo` of it, and `θe` beyond that for the falloff of a surface).
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
struct Bounds {
    lo: Vec3,
    hi: Vec3,
    phi: f32,
    w: Vec3,
    cos_o: f32,
    cos_e: f32,
}

#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
struct Node {
    bounds: Bounds,
    /// A leaf: the light's index; an inner node: its second child (the first follows it).
    index: u32,
    leaf: bool,
}

#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct LightTree {
    nodes: Vec<Node>,
    /// The lights at infinity (chosen beside the tree).
    infinite: Vec<u32>,
    /// Per light: its path from the root (bit k: took the second child at depth k) and
    /// its depth; `u32::MAX` depth for lights not in the tree.
    trail: Vec<(u64, u32)>,
}

fn cos_sub_clamped(sin_a: f32, cos_a: f32, sin_b: f32, cos_b: f32) -> f32 {
    // cos(max(0, a − b)).
    if cos_a > cos_b { 1.0 } else { cos_a * cos_b + sin_a * sin_b }
}

fn sin_sub_clamped(sin_a: f32, cos_a: f32, sin_b: f32, cos_b: f32) -> f32 {
    if cos_a > cos_b { 0.0 } else { sin_a * cos_b - cos_a * sin_b }
}

fn safe_sqrt(x: f32) -> f32 {
    x.max(0.0).sqrt()
}

impl Bounds {
    /// What a light offers the tree; `None` for lights at infinity and dark lights.
    fn of(light: &Light, phi: f32) -> Option<Bounds> {
        if !(phi > 0.0 && phi.is_finite()) {
            return None;
        }
        let any = |lo: Vec3, hi: Vec3| Bounds { lo, hi, phi, w: Vec3::Z, cos_o: -1.0, cos_e: 0.0 };
        let facing = |lo: Vec3, hi: Vec3, w: Vec3| Bounds { lo, hi, phi, w, cos_o: 1.0, cos_e: 0.0 };
        let spot = |p: Vec3, w: Vec3, cos_total: f32, cos_start: f32| {
            // Within the falloff's start, then out to the cone's edge.
            let theta_e = (crate::math::acos(cos_total) - crate::math::acos(cos_start)).max(0.0);
            Bounds { lo: p, hi: p, phi, w, cos_o: cos_start, cos_e: crate::math::cos(theta_e) }
        };
        Some(match *light {
            Light::Point { position, .. } => any(position, position),
            Light::Spot { position, direction, cos_total, cos_falloff_start, .. } => {
                spot(position, direction, cos_total, cos_falloff_start)
            }
            Light::Triangle { p0, e1, e2, normal, .. } => {
                let (a, b) = (p0 + e1, p0 + e2);
                facing(p0.min(a).min(b), p0.max(a).max(b), normal)
            }
            Light::Sphere { center, radius, .. } => any(center - radius, center + radius),
            Light::Area { geometry: g, .. } => {
                let r = g.ex.abs() + g.ey.abs();
                facing(g.center - r, g.center + r, g.normal)
            }
            Light::SoftPoint(s) => {
                let b = match s.cone {
                    None => any(s.position, s.position),
                    Some(c) => spot(s.position, c.direction, c.cos_total, c.cos_falloff_start),
                };
                Bounds { lo: s.position - s.radius, hi: s.position + s.radius, ..b }
            }
            Light::Directional { .. } | Light::Environment { .. } | Light::Sun(_) => return None,
        })
    }

    fn centroid(&self) -> Vec3 {
        0.5 * (self.lo + self.hi)
    }

    /// The union: the boxes', the power's sum, a cone holding both cones.
    fn union(a: &Bounds, b: &Bounds) -> Bounds {
        let (w, cos_o) = cone_union((a.w, a.cos_o), (b.w, b.cos_o));
        Bounds { lo: a.lo.min(b.lo), hi: a.hi.max(b.hi), phi: a.phi + b.phi, w, cos_o, cos_e: a.cos_e.min(b.cos_e) }
    }

    /// pbrt-v4's `LightBounds::Importance` at `p` (without a surface normal).
    fn importance(&self, p: Vec3) -> f32 {
        let pc = self.centroid();
        let half_diag = 0.5 * (self.hi - self.lo).length();
        let d2 = (p - pc).length_squared().max(half_diag);
        let to_p = (p - pc).normalize_or_zero();
        let cos_w = if to_p == Vec3::ZERO { 1.0 } else { self.w.dot(to_p) };
        let sin_w = safe_sqrt(1.0 - cos_w * cos_w);
        // The angle the box subtends from p (all directions from inside it).
        let r2 = half_diag * half_diag;
        let dist2 = (p - pc).length_squared();
        let cos_b = if dist2 < r2 { -1.0 } else { safe_sqrt(1.0 - r2 / dist2) };
        let sin_b = safe_sqrt(1.0 - cos_b * cos_b);
        let sin_o = safe_sqrt(1.0 - self.cos_o * self.cos_o);
        let cos_x = cos_sub_clamped(sin_w, cos_w, sin_o, self.cos_o);
        let sin_x = sin_sub_clamped(sin_w, cos_w, sin_o, self.cos_o);
        let cos_p = cos_sub_clamped(sin_x, cos_x, sin_b, cos_b);
        if cos_p <= self.cos_e {
            return 0.0;
        }
        let v = self.phi * cos_p / d2;
        if v.is_finite() { v.max(0.0) } else { 0.0 }
    }
}

/// The smallest cone (axis, cos of its half-angle) holding two cones.
fn cone_union(a: (Vec3, f32), b: (Vec3, f32)) -> (Vec3, f32) {
    let angle = |c: f32| crate::math::acos(c.clamp(-1.0, 1.0));
    let (theta_a, theta_b) = (angle(a.1), angle(b.1));
    let theta_d = angle(a.0.dot(b.0));
    if (theta_d + theta_b).min(PI) <= theta_a {
        return a;
    }
    if (theta_d + theta_a).min(PI) <= theta_b {
        return b;
    }
    let theta_o = 0.5 * (theta_a + theta_d + theta_b);
    if theta_o >= PI {
        return (a.0, -1.0);
    }
    // Turn a's axis towards b's by θo − θa.
    let axis = a.0.cross(b.0);
    if axis.length_squared() < 1e-12 {
        return (a.0, -1.0);
    }
    // Rodrigues' rotation of a's axis about a × b.
    let (k, v) = (axis.normalize(), a.0);
    let (sin, cos) = crate::math::sin_cos(theta_o - theta_a);
    let turned = v * cos + k.cross(v) * sin + k * k.dot(v) * (1.0 - cos);
    (turned.normalize_or(v), crate::math::cos(theta_o))
}

impl LightTree {
    /// The tree over `lights` with powers `phi`.
    pub fn new(lights: &[Light], phi: &[f32]) -> Self {
        let mut infinite = Vec::new();
        let mut items = Vec::new();
        for (i, l) in lights.iter().enumerate() {
            match Bounds::of(l, phi[i]) {
                Some(b) => items.push((i as u32, b)),
                None if matches!(l, Light::Directional { .. } | Light::Environment { .. } | Light::Sun(_))
                    && phi[i] > 0.0 =>
                {
                    infinite.push(i as u32)
                }
                None => {}
            }
        }
        let mut tree = LightTree { nodes: Vec::new(), infinite, trail: vec![(0, u32::MAX); lights.len()] };
        if !items.is_empty() {
            tree.build(&mut items, 0, 0);
        }
        tree
    }

    /// Builds the subtree over `items` (at `depth`, reached by `bits`); returns its bounds.
    fn build(&mut self, items: &mut [(u32, Bounds)], bits: u64, depth: u32) -> Bounds {
        let at = self.nodes.len();
        // Median splits: the depth is ⌈log₂ n⌉, far below the trail's 64 bits.
        if items.len() == 1 {
            let (light, b) = items[0];
            self.nodes.push(Node { bounds: b, index: light, leaf: true });
            self.trail[light as usize] = (bits, depth);
            return b;
        }
        // Split at the median of the centroids along the widest axis of their box.
        let (lo, hi) = items.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), (_, b)| {
            (lo.min(b.centroid()), hi.max(b.centroid()))
        });
        let axis = (hi - lo).max_position();
        let mid = items.len() / 2;
        items.select_nth_unstable_by(mid, |a, b| {
            a.1.centroid()[axis].total_cmp(&b.1.centroid()[axis]).then(a.0.cmp(&b.0))
        });
        self.nodes.push(Node { bounds: items[0].1, index: 0, leaf: false });
        let (first, second) = items.split_at_mut(mid);
        let a = self.build(first, bits, depth + 1);
        self.nodes[at].index = self.nodes.len() as u32;
        let b = self.build(second, bits | (1 << depth), depth + 1);
        let bounds = Bounds::union(&a, &b);
        self.nodes[at].bounds = bounds;
        bounds
    }

    /// The probability of choosing a light at infinity rather than the tree.
    fn p_infinite(&self) -> f32 {
        let n = self.infinite.len() as f32;
        if self.nodes.is_empty() { 1.0 } else { n / (n + 1.0) }
    }

    /// A light for point `p` and random number `u`: `(light, pmf, u')` with `u'` rescaled
    /// to `[0, 1)` within the choice, as [`super::LightSet::select_at`] returns.
    #[inline]
    pub fn select(&self, p: Vec3, u: f32) -> Option<(usize, f32, f32)> {
        let p_inf = self.p_infinite();
        if u < p_inf {
            let n = self.infinite.len();
            let k = ((u / p_inf * n as f32) as usize).min(n - 1);
            let ux = (u / p_inf * n as f32 - k as f32).clamp(0.0, ONE_MINUS_EPSILON);
            return Some((self.infinite[k] as usize, p_inf / n as f32, ux));
        }
        let mut u = ((u - p_inf) / (1.0 - p_inf)).clamp(0.0, ONE_MINUS_EPSILON);
        let mut pmf = 1.0 - p_inf;
        let mut node = 0usize;
        if self.nodes.is_empty() || self.nodes[0].bounds.importance(p) <= 0.0 {
            return None;
        }
        loop {
            let n = self.nodes[node];
            if n.leaf {
                return Some((n.index as usize, pmf, u));
            }
            let (a, b) = (node + 1, n.index as usize);
            let (ia, ib) = (self.nodes[a].bounds.importance(p), self.nodes[b].bounds.importance(p));
            if !(ia + ib > 0.0) {
                return None;
            }
            let pa = ia / (ia + ib);
            if u < pa {
                u = (u / pa).min(ONE_MINUS_EPSILON);
                pmf *= pa;
                node = a;
            } else {
                u = ((u - pa) / (1.0 - pa)).clamp(0.0, ONE_MINUS_EPSILON);
                pmf *= 1.0 - pa;
                node = b;
            }
        }
    }

    /// The probability that [`LightTree::select`] at `p` chooses `light`.
    #[inline]
    pub fn pmf(&self, p: Vec3, light: usize) -> f32 {
        let p_inf = self.p_infinite();
        if let Some(_k) = self.infinite.iter().position(|&i| i as usize == light) {
            return p_inf / self.infinite.len() as f32;
        }
        let (bits, depth) = self.trail[light];
        if depth == u32::MAX || self.nodes.is_empty() || self.nodes[0].bounds.importance(p) <= 0.0 {
            return 0.0;
        }
        let mut pmf = 1.0 - p_inf;
        let mut node = 0usize;
        for k in 0..depth {
            let n = self.nodes[node];
            let (a, b) = (node + 1, n.index as usize);
            let (ia, ib) = (self.nodes[a].bounds.importance(p), self.nodes[b].bounds.importance(p));
            if !(ia + ib > 0.0) {
                return 0.0;
            }
            let pa = ia / (ia + ib);
            if bits >> k & 1 == 0 {
                pmf *= pa;
                node = a;
            } else {
                pmf *= 1.0 - pa;
                node = b;
            }
        }
        pmf
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        std::mem::size_of::<Node>() * self.nodes.len() + 4 * self.infinite.len() + 12 * self.trail.len()
    }
}
