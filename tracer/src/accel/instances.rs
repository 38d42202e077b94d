//! Instancing: a mesh stored once, in its own space, with its own BVH, and placed
//! any number of times by affine transforms; a top-level BVH over the placed copies
//! (two levels, as Embree's and pbrt-v4's instances). A ray meets a copy by being moved
//! into the mesh's space: an affine map keeps the ray's parameter, so the mesh's `t` is
//! the scene's.
//!
//! Hits name triangles scene-wide: copy `k`'s triangle `j` is `first(k) + j`, after the
//! scene's own primitives, so the rest of the renderer keeps one index per hit.

use glam::{Affine3A, Mat3, Vec3};
use rayon::prelude::*;

use super::bvh8::{Bvh8, Bvh8Params};
use super::{Hit, PrimHit, Primitives, RayPrecomp};
use crate::geometry::{Aabb, Ray};
use crate::shapes::Geometry;

/// A mesh as instances see it: its triangles (in its tree's leaf order) and its tree.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct InstancedMesh {
    pub geometry: Geometry,
    pub accel: Bvh8,
}

impl InstancedMesh {
    /// Builds the mesh's tree and stores its triangles in the tree's leaf order.
    pub fn new(mut geometry: Geometry) -> Self {
        let mut accel = Bvh8::build(&geometry, &Bvh8Params::default());
        geometry.store_in_leaf_order(&mut accel);
        Self { geometry, accel }
    }

    /// Bytes held by the triangles and the tree.
    pub fn heap_bytes(&self) -> usize {
        self.geometry.bytes().total() + self.accel.heap_bytes()
    }
}

/// One placed copy of a mesh.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct Instance {
    pub mesh: u32,
    pub to_world: Affine3A,
    pub to_object: Affine3A,
    /// The inverse transpose of `to_world`'s linear part: how normals move.
    pub normal_to_world: Mat3,
    /// The transform turns the mesh inside out (negative determinant): front faces are
    /// then on the other side of the world-space winding.
    pub mirrored: bool,
    /// Rays reach the mesh unchanged (the exact identity).
    pub identity: bool,
    /// Scene-wide index of the copy's triangle 0.
    pub first: u32,
}

/// Why a set of instances cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InstanceError {
    #[error("the transform is not invertible (a scale of zero, or a degenerate matrix)")]
    Singular,
    #[error("the scene has more than 4,294,967,295 triangles counting every copy")]
    TooManyTriangles,
}

/// The copies and their meshes, as the top-level tree's primitives.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct InstanceList {
    pub meshes: Vec<InstancedMesh>,
    pub list: Vec<Instance>,
    /// World bounds of each copy (the mesh's box, transformed, slightly padded).
    bounds: Vec<Aabb>,
}

/// The instances of a scene with their top-level tree.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Instances {
    pub set: InstanceList,
    top: Bvh8,
    /// One past the last scene-wide triangle index of the copies.
    end: u32,
    /// The union of the copies' triangles' world bounds.
    world: Aabb,
}

/// The instance of `to_world`, or an error if it has no inverse.
pub fn place(mesh: u32, to_world: Affine3A) -> Result<Instance, InstanceError> {
    let det = to_world.matrix3.determinant();
    if !(det.is_finite() && det != 0.0 && to_world.translation.is_finite()) {
        return Err(InstanceError::Singular);
    }
    let to_object = to_world.inverse();
    if !(to_object.matrix3.is_finite() && to_object.translation.is_finite()) {
        return Err(InstanceError::Singular);
    }
    let linear = Mat3::from(to_world.matrix3);
    Ok(Instance {
        mesh,
        to_world,
        to_object,
        normal_to_world: linear.inverse().transpose(),
        mirrored: det < 0.0,
        identity: to_world == Affine3A::IDENTITY,
        first: 0,
    })
}

impl Instances {
    /// The copies `list` of `meshes` (each `mesh` field an index into `meshes`), their
    /// triangles numbered from `first`, and the top-level tree over them.
    pub fn new(meshes: Vec<InstancedMesh>, mut list: Vec<Instance>, first: u32) -> Result<Self, InstanceError> {
        let mut next = u64::from(first);
        for inst in &mut list {
            inst.first = u32::try_from(next).map_err(|_| InstanceError::TooManyTriangles)?;
            next += meshes[inst.mesh as usize].geometry.triangle_count() as u64;
        }
        let end = u32::try_from(next).map_err(|_| InstanceError::TooManyTriangles)?;
        let tight: Vec<Aabb> = list.par_iter().map(|inst| world_bounds(&meshes[inst.mesh as usize], inst)).collect();
        let world = tight.iter().fold(Aabb::EMPTY, |a, &b| a.union(b));
        let set = InstanceList { meshes, list, bounds: tight.into_iter().map(padded).collect() };
        // A copy's test is a whole walk of its mesh's hierarchy: small leaves pay.
        let params = Bvh8Params { intersection_cost: 4.0, ..Bvh8Params::default() };
        let top = Bvh8::build(&set, &params);
        Ok(Self { set, top, end, world })
    }

    /// Union of the copies' world bounds.
    pub fn bounds(&self) -> Aabb {
        self.world
    }

    /// Whether `prim` is one of the copies' triangles.
    #[inline]
    pub fn holds(&self, prim: u32) -> bool {
        self.set.list.first().is_some_and(|i| prim >= i.first) && prim < self.end
    }

    /// The copy and its mesh's triangle that scene-wide index `prim` names ([`Self::holds`]).
    #[inline]
    pub fn resolve(&self, prim: u32) -> (&Instance, &InstancedMesh, usize) {
        let k = self.set.list.partition_point(|i| i.first <= prim) - 1;
        let inst = &self.set.list[k];
        (inst, &self.set.meshes[inst.mesh as usize], (prim - inst.first) as usize)
    }

    #[inline]
    pub fn intersect(&self, ray: &Ray, tmax: f32) -> Option<Hit> {
        self.top.intersect(&self.set, ray, tmax)
    }

    #[inline]
    pub fn occluded(&self, ray: &Ray, tmax: f32) -> bool {
        self.top.occluded(&self.set, ray, tmax)
    }

    /// Triangles counting every copy.
    pub fn triangles_seen(&self) -> u64 {
        u64::from(self.end) - self.set.list.first().map_or(u64::from(self.end), |i| u64::from(i.first))
    }

    /// Bytes held by the meshes, the copies and the top-level tree.
    pub fn heap_bytes(&self) -> usize {
        self.set.meshes.iter().map(InstancedMesh::heap_bytes).sum::<usize>()
            + self.set.list.capacity() * size_of::<Instance>()
            + self.set.bounds.capacity() * size_of::<Aabb>()
            + self.top.heap_bytes()
    }

    pub(crate) fn advise_huge_pages(&self) {
        for m in &self.set.meshes {
            m.geometry.advise_huge_pages();
            m.accel.advise_huge_pages();
        }
    }
}

/// The copy's world box: its triangles' corners moved to the world (as tight as the
/// flattened triangles' box, so that framing and light importance do not depend on how
/// the copies are stored).
fn world_bounds(mesh: &InstancedMesh, inst: &Instance) -> Aabb {
    let g = &mesh.geometry;
    (0..g.triangle_count())
        .fold(Aabb::EMPTY, |b, i| g.triangle(i).iter().fold(b, |b, &p| b.grow(inst.to_world.transform_point3(p))))
}

/// `b` padded by a relative 2⁻¹⁶ of its size and place, against the rounding of the
/// transform and of the ray's: the top tree's box of a copy.
fn padded(b: Aabb) -> Aabb {
    if b.is_empty() {
        return b;
    }
    let pad = Vec3::splat((b.diagonal().max_element() + b.min.abs().max(b.max.abs()).max_element()) / 65536.0);
    Aabb::new(b.min - pad, b.max + pad)
}

impl InstanceList {
    /// The ray in copy `inst`'s mesh space (the same parameter `t` along it).
    #[inline(always)]
    fn local(inst: &Instance, ray: &Ray) -> Ray {
        if inst.identity {
            *ray
        } else {
            Ray::new(inst.to_object.transform_point3(ray.origin), inst.to_object.transform_vector3(ray.dir))
        }
    }
}

impl Primitives for InstanceList {
    fn len(&self) -> usize {
        self.list.len()
    }

    fn bounds(&self, i: u32) -> Aabb {
        self.bounds[i as usize]
    }

    #[inline]
    fn intersect(&self, i: u32, ray: &Ray, _pre: &RayPrecomp, tmax: f32) -> Option<PrimHit> {
        let inst = &self.list[i as usize];
        let m = &self.meshes[inst.mesh as usize];
        let h = m.accel.intersect(&m.geometry, &Self::local(inst, ray), tmax)?;
        Some(PrimHit { t: h.t, u: h.u, v: h.v, sub: h.prim })
    }

    #[inline]
    fn occludes(&self, i: u32, ray: &Ray, _pre: &RayPrecomp, tmax: f32) -> bool {
        let inst = &self.list[i as usize];
        let m = &self.meshes[inst.mesh as usize];
        m.accel.occluded(&m.geometry, &Self::local(inst, ray), tmax)
    }

    #[inline(always)]
    fn hit_prim(&self, i: u32, h: &PrimHit) -> u32 {
        self.list[i as usize].first + h.sub
    }
}

#[cfg(test)]
mod tests;
