//! SAH kd-tree. PLACEHOLDER being replaced by the real build: a single leaf.

use super::{Hit, Primitives, Ray, RayPrecomp};
use crate::geometry::Aabb;

/// Build parameters (documented in README.md).
#[derive(Clone, Debug)]
pub struct BuildParams {
    pub traversal_cost: f32,
    pub intersection_cost: f32,
    pub empty_bonus: f32,
    pub max_depth: Option<u32>,
    pub max_leaf_prims: usize,
}

impl Default for BuildParams {
    fn default() -> Self {
        Self { traversal_cost: 1.0, intersection_cost: 1.5, empty_bonus: 0.2, max_depth: None, max_leaf_prims: 2 }
    }
}

#[derive(Clone, Debug, Default)]
pub struct KdTreeStats {
    pub nodes: usize,
    pub leaves: usize,
    pub max_depth: usize,
    pub prim_refs: usize,
    pub bytes: usize,
}

pub struct KdTree {
    bounds: Aabb,
    prims: Vec<u32>,
}

impl KdTree {
    pub fn build<P: Primitives>(prims: &P, _params: &BuildParams) -> Self {
        let bounds = (0..prims.len() as u32).fold(Aabb::EMPTY, |b, i| b.union(prims.bounds(i)));
        Self { bounds, prims: (0..prims.len() as u32).collect() }
    }

    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    pub fn stats(&self) -> KdTreeStats {
        KdTreeStats { nodes: 1, leaves: 1, max_depth: 0, prim_refs: self.prims.len(), bytes: self.prims.len() * 4 }
    }

    pub fn intersect<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        let pre = RayPrecomp::new(ray);
        let mut best = None;
        let mut tmax = tmax;
        for &i in &self.prims {
            if let Some(h) = prims.intersect(i, ray, &pre, tmax) {
                tmax = h.t;
                best = Some(Hit { t: h.t, prim: i, u: h.u, v: h.v });
            }
        }
        best
    }

    pub fn occluded<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        let pre = RayPrecomp::new(ray);
        self.prims.iter().any(|&i| prims.intersect(i, ray, &pre, tmax).is_some())
    }
}
