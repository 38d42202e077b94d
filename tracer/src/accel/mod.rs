//! Acceleration structures. The kd-tree is generic over a [`Primitives`] set so that it
//! can be tested against brute force on any shapes, and is monomorphised (no `dyn`) for
//! the scene's triangles and spheres.

pub mod kdtree;

pub use kdtree::{BuildParams, KdTree, KdTreeStats};

use crate::geometry::{Aabb, Ray};

/// A hit reported by a primitive: distance and two surface parameters (barycentrics
/// `b1, b2` for triangles; unused for spheres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrimHit {
    pub t: f32,
    pub u: f32,
    pub v: f32,
}

/// A hit found by a query over a whole primitive set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub prim: u32,
    pub u: f32,
    pub v: f32,
}

/// Per-ray data computed once per query and shared by every primitive test.
#[derive(Clone, Copy, Debug)]
pub struct RayPrecomp {
    pub inv_dir: glam::Vec3,
    pub shear: crate::geometry::triangle::RayShear,
}

impl RayPrecomp {
    #[inline]
    pub fn new(ray: &Ray) -> Self {
        Self { inv_dir: ray.dir.recip(), shear: crate::geometry::triangle::RayShear::new(ray.dir) }
    }
}

/// A set of primitives addressed by index `0..len()`.
pub trait Primitives: Sync {
    fn len(&self) -> usize;

    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bounds of primitive `i`.
    fn bounds(&self, i: u32) -> Aabb;

    /// Bounds of the part of primitive `i` that lies inside `clip` ("perfect splits").
    /// The default is conservative; triangles override it with exact polygon clipping.
    fn clipped_bounds(&self, i: u32, clip: &Aabb) -> Aabb {
        self.bounds(i).intersection(*clip)
    }

    /// Nearest hit of primitive `i` with `0 < t < tmax`.
    fn intersect(&self, i: u32, ray: &Ray, pre: &RayPrecomp, tmax: f32) -> Option<PrimHit>;
}

/// The O(N) reference query: the kd-tree must give exactly this answer.
pub fn brute_force_intersect<P: Primitives>(prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
    let pre = RayPrecomp::new(ray);
    let mut best: Option<Hit> = None;
    let mut tmax = tmax;
    for i in 0..prims.len() as u32 {
        if let Some(h) = prims.intersect(i, ray, &pre, tmax) {
            tmax = h.t;
            best = Some(Hit { t: h.t, prim: i, u: h.u, v: h.v });
        }
    }
    best
}

/// The O(N) reference any-hit query.
pub fn brute_force_occluded<P: Primitives>(prims: &P, ray: &Ray, tmax: f32) -> bool {
    let pre = RayPrecomp::new(ray);
    (0..prims.len() as u32).any(|i| prims.intersect(i, ray, &pre, tmax).is_some())
}
