//! The scene's primitives — triangles then spheres in one index space — as the
//! kd-tree sees them.

use glam::Vec3;

use super::TriangleMesh;
use crate::accel::{KdTree, PrimHit, Primitives, RayPrecomp};
use crate::geometry::clip::clipped_triangle_bounds;
use crate::geometry::sphere::intersect_sphere;
use crate::geometry::triangle::intersect_triangle_corners;
use crate::geometry::{Aabb, Ray};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    pub center: Vec3,
    pub radius: f32,
    pub material: u32,
}

impl Sphere {
    pub fn bounds(&self) -> Aabb {
        Aabb::new(self.center - Vec3::splat(self.radius), self.center + Vec3::splat(self.radius))
    }
}

/// All primitives of a scene. Index `i < mesh.tris.len()` is a triangle, the rest are
/// spheres in order.
///
/// Ray queries read each triangle's corners from `corners`, a copy made by
/// [`Geometry::new`] / [`Geometry::prepare`]: one 36-byte load stream per test instead of
/// the dependent chain `Tri` → three positions. Call `prepare` after changing `mesh`.
#[derive(Clone, Debug, Default)]
pub struct Geometry {
    pub mesh: TriangleMesh,
    pub spheres: Vec<Sphere>,
    corners: Vec<[Vec3; 3]>,
}

/// Which primitive an index denotes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PrimRef {
    Triangle(usize),
    Sphere(usize),
}

impl Geometry {
    pub fn new(mesh: TriangleMesh, spheres: Vec<Sphere>) -> Self {
        let mut g = Self { mesh, spheres, corners: Vec::new() };
        g.prepare();
        g
    }

    /// Rebuilds the intersection data from `mesh` (after it was changed).
    pub fn prepare(&mut self) {
        self.corners = (0..self.mesh.tris.len()).map(|i| self.mesh.corners(i)).collect();
    }

    /// Memory of the intersection data beyond the mesh and spheres.
    pub fn accel_bytes(&self) -> usize {
        self.corners.len() * size_of::<[Vec3; 3]>()
    }

    /// Corners of triangle `i` as the intersection test sees them.
    #[inline]
    pub fn triangle(&self, i: usize) -> &[Vec3; 3] {
        &self.corners[i]
    }

    /// Stores the triangles in `tree`'s leaf order ([`KdTree::leaf_order`]) and renames
    /// the tree's indices to match, so that a leaf's triangles are adjacent in memory
    /// (on large meshes nearly every triangle test is a cache miss otherwise). `tree`
    /// must have been built over `self`. Spheres keep their indices. Returns the
    /// permutation applied to the triangles, `order[new] = old`.
    pub fn store_in_leaf_order(&mut self, tree: &mut KdTree) -> Vec<u32> {
        let ntri = self.mesh.tris.len();
        let order: Vec<u32> = tree.leaf_order(self.len()).into_iter().filter(|&i| (i as usize) < ntri).collect();
        let mut new_index: Vec<u32> = (0..self.len() as u32).collect();
        for (new, &old) in order.iter().enumerate() {
            new_index[old as usize] = new as u32;
        }
        tree.remap(&new_index);
        self.permute_triangles(&order);
        order
    }

    /// Reorders the triangles: new triangle `i` is old triangle `order[i]` (`order` is a
    /// permutation of `0..mesh.tris.len()`). Spheres are unchanged.
    pub fn permute_triangles(&mut self, order: &[u32]) {
        assert_eq!(order.len(), self.mesh.tris.len(), "permute_triangles: not a permutation of the triangles");
        assert_eq!(self.corners.len(), self.mesh.tris.len(), "Geometry: call prepare() after changing the mesh");
        self.mesh.tris = order.iter().map(|&i| self.mesh.tris[i as usize]).collect();
        self.corners = order.iter().map(|&i| self.corners[i as usize]).collect();
    }

    #[inline]
    pub fn resolve(&self, i: u32) -> PrimRef {
        let n = self.mesh.tris.len();
        if (i as usize) < n { PrimRef::Triangle(i as usize) } else { PrimRef::Sphere(i as usize - n) }
    }
}

impl Primitives for Geometry {
    fn len(&self) -> usize {
        assert_eq!(self.corners.len(), self.mesh.tris.len(), "Geometry: call prepare() after changing the mesh");
        self.mesh.tris.len() + self.spheres.len()
    }

    fn bounds(&self, i: u32) -> Aabb {
        match self.resolve(i) {
            PrimRef::Triangle(t) => Aabb::from_points(&self.mesh.corners(t)),
            PrimRef::Sphere(s) => self.spheres[s].bounds(),
        }
    }

    fn clipped_bounds(&self, i: u32, clip: &Aabb) -> Aabb {
        match self.resolve(i) {
            PrimRef::Triangle(t) => clipped_triangle_bounds(self.mesh.corners(t), clip),
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
            }),
            PrimRef::Sphere(s) => self.intersect_sphere(s, ray, tmax),
        }
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

/// Hints the cache to load `p`'s line (nothing is dereferenced).
#[inline(always)]
fn prefetch(p: *const u8) {
    // SAFETY: a prefetch is a hint; it never faults, whatever the address (SSE is part
    // of the x86_64 baseline).
    #[cfg(target_arch = "x86_64")]
    unsafe {
        core::arch::x86_64::_mm_prefetch::<{ core::arch::x86_64::_MM_HINT_T0 }>(p.cast())
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

impl Geometry {
    #[inline(never)]
    fn intersect_sphere(&self, s: usize, ray: &Ray, tmax: f32) -> Option<PrimHit> {
        let sp = &self.spheres[s];
        intersect_sphere(ray, sp.center, sp.radius, 0.0, tmax).map(|t| PrimHit { t, u: 0.0, v: 0.0 })
    }
}
