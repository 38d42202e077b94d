//! The scene's primitive store ([`Geometry`]) as the aggregates' primitives: its ray
//! tests, bounds and prefetches, and its storage in a tree's leaf order.

use glam::Vec3;

use super::{LeafOrdered, PrimHit, Primitives, RayPrecomp, prefetch};
use crate::geometry::clip::clipped_triangle_bounds;
use crate::geometry::sphere::intersect_sphere;
use crate::geometry::triangle::intersect_triangle_corners;
use crate::geometry::{Aabb, Ray};
use crate::shapes::{Geometry, PrimRef};

impl Geometry {
    /// Stores the triangles in `tree`'s leaf order ([`LeafOrdered::leaf_order`]) and renames
    /// the tree's indices to match, so that a leaf's triangles are adjacent in memory
    /// (on large meshes nearly every triangle test is a cache miss otherwise). `tree`
    /// must have been built over `self`. Spheres keep their indices. Returns the
    /// permutation applied to the triangles, `order[new] = old`.
    pub fn store_in_leaf_order(&mut self, tree: &mut impl LeafOrdered) -> Vec<u32> {
        let ntri = self.triangle_count();
        let order: Vec<u32> = tree.leaf_order(self.prim_count()).into_iter().filter(|&i| (i as usize) < ntri).collect();
        let mut new_index: Vec<u32> = (0..self.prim_count() as u32).collect();
        for (new, &old) in order.iter().enumerate() {
            new_index[old as usize] = new as u32;
        }
        tree.remap(&new_index);
        self.permute_triangles(&order);
        order
    }

    #[inline(never)]
    fn intersect_sphere(&self, s: usize, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        let sp = &self.spheres[s];
        intersect_sphere(ray, sp.center, sp.radius, 0.0, tmax).map(|t| PrimHit { t, u: 0.0, v: 0.0, sub: 0 })
    }
}

impl Primitives for Geometry {
    fn len(&self) -> usize {
        self.prim_count()
    }

    fn bounds(&self, i: u32) -> Aabb {
        match self.resolve(i) {
            PrimRef::Triangle(t) => Aabb::from_points(&self.corners[t]),
            PrimRef::Sphere(s) => self.spheres[s].bounds(),
        }
    }

    fn clipped_bounds(&self, i: u32, clip: &Aabb) -> Aabb {
        match self.resolve(i) {
            PrimRef::Triangle(t) => clipped_triangle_bounds(self.corners[t], clip),
            PrimRef::Sphere(s) => self.spheres[s].bounds().intersection(*clip),
        }
    }

    // Inlined into the kd-tree's leaf loop (the triangle test then keeps the ray's
    // shear in registers across a leaf's primitives); the rarer sphere test stays out of
    // line so the loop stays small.
    #[inline(always)]
    fn intersect(&self, i: u32, ray: &Ray, pre: &RayPrecomp, tmax: f32) -> Option<PrimHit> {
        match self.resolve(i) {
            PrimRef::Triangle(t) => intersect_triangle_corners(&pre.shear, &self.corners[t], tmax).map(|h| PrimHit {
                t: h.t,
                u: h.b1,
                v: h.b2,
                sub: 0,
            }),
            PrimRef::Sphere(s) => self.intersect_sphere(s, ray, tmax),
        }
    }

    #[inline(always)]
    fn triangle_corners(&self) -> &[[Vec3; 3]] {
        &self.corners
    }

    #[inline(always)]
    fn prefetch(&self, i: u32) {
        // The 36 corner bytes may straddle two cache lines.
        if let Some(c) = self.corners.get(i as usize) {
            let p: *const u8 = (c as *const [Vec3; 3]).cast();
            prefetch(p);
            prefetch(p.wrapping_add(size_of::<[Vec3; 3]>() - 1));
        }
    }
}
