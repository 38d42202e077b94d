//! The scene's primitives — triangles then spheres in one index space — as the
//! aggregates (`accel`) see them: their ray tests are in `accel/store.rs`.

use glam::{Vec2, Vec3, Vec4};

use super::{NONE, TriangleMesh};
use crate::geometry::Aabb;

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
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

/// All primitives of a scene. Index `i < triangle_count()` is a triangle, the rest are
/// spheres in order.
///
/// The runtime form of a [`TriangleMesh`] (the loaders' format), made by
/// [`Geometry::new`]: per triangle only what rendering reads.
/// - `corners`: the three positions, the only position storage. Ray queries read them
///   as one 36-byte load stream per test instead of the dependent chain index →
///   three positions; hit points, normals and area lights are computed from them too.
/// - `materials`: the material index (4 bytes).
/// - `normal_idx` / `uv_idx`: shading-normal and texture-coordinate indices into
///   `normals` / `uvs`, only when some face has them (empty otherwise; faces without
///   them hold [`NONE`]).
///
/// For the 1M-triangle displaced sphere (no normals, no uvs) that is 40 bytes per
/// triangle, where the mesh (positions + 40-byte index records) and a copy of the
/// corners took ~82.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Geometry {
    pub spheres: Vec<Sphere>,
    pub(crate) corners: Vec<[Vec3; 3]>,
    materials: Vec<u32>,
    normal_idx: Vec<[u32; 3]>,
    uv_idx: Vec<[u32; 3]>,
    normals: Vec<Vec3>,
    uvs: Vec<Vec2>,
    /// Per triangle, MikkTSpace tangents at its corners (xyz, bitangent sign in w; zero
    /// where it has none): only when the scene has normal maps ([`Geometry::add_tangents`]).
    tangents: Vec<[Vec4; 3]>,
}

/// Bytes held by a [`Geometry`], by kind (allocated capacity, not just length).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GeometryBytes {
    /// Triangle corners (36 per triangle).
    pub corners: usize,
    /// Material indices, shading-normal and uv index arrays, the normals and uvs, and the
    /// tangents (48 per triangle, with normal maps only).
    pub mesh: usize,
    pub spheres: usize,
}

impl GeometryBytes {
    pub fn total(&self) -> usize {
        self.corners + self.mesh + self.spheres
    }
}

/// Which primitive an index denotes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PrimRef {
    Triangle(usize),
    Sphere(usize),
}

impl Geometry {
    /// The runtime form of `mesh` (consumed: its positions and index records are not kept).
    pub fn new(mesh: TriangleMesh, spheres: Vec<Sphere>) -> Self {
        let TriangleMesh { positions, mut normals, mut uvs, tris } = mesh;
        let corners = tris.iter().map(|t| t.v.map(|v| positions[v as usize])).collect();
        drop(positions);
        let materials = tris.iter().map(|t| t.material).collect();
        let normal_idx =
            if tris.iter().any(|t| t.n != [NONE; 3]) { tris.iter().map(|t| t.n).collect() } else { Vec::new() };
        let uv_idx =
            if tris.iter().any(|t| t.uv != [NONE; 3]) { tris.iter().map(|t| t.uv).collect() } else { Vec::new() };
        if normal_idx.is_empty() {
            normals = Vec::new();
        }
        if uv_idx.is_empty() {
            uvs = Vec::new();
        }
        normals.shrink_to_fit();
        uvs.shrink_to_fit();
        let mut spheres = spheres;
        spheres.shrink_to_fit();
        Self { spheres, corners, materials, normal_idx, uv_idx, normals, uvs, tangents: Vec::new() }
    }

    pub fn triangle_count(&self) -> usize {
        self.corners.len()
    }

    /// Corners of triangle `i`, counter-clockwise seen from the front face.
    #[inline]
    pub fn triangle(&self, i: usize) -> &[Vec3; 3] {
        &self.corners[i]
    }

    /// Material index of triangle `i`.
    #[inline]
    pub fn material(&self, i: usize) -> u32 {
        self.materials[i]
    }

    /// Shading-normal indices of triangle `i` (`[NONE; 3]` for flat shading).
    #[inline]
    pub fn normal_indices(&self, i: usize) -> [u32; 3] {
        self.normal_idx.get(i).copied().unwrap_or([NONE; 3])
    }

    /// Texture-coordinate indices of triangle `i` (`[NONE; 3]` when it has none).
    #[inline]
    pub fn uv_indices(&self, i: usize) -> [u32; 3] {
        self.uv_idx.get(i).copied().unwrap_or([NONE; 3])
    }

    /// The shading normals at the corners of triangle `i`, if it has them.
    #[inline]
    pub fn shading_normals(&self, i: usize) -> Option<[Vec3; 3]> {
        let n = self.normal_indices(i);
        (n[0] != NONE).then(|| n.map(|k| self.normals[k as usize]))
    }

    /// Interpolated texture coordinates of triangle `i` at barycentrics `b`, or
    /// `(b.y, b.z)` when the triangle has none.
    #[inline]
    pub fn uv(&self, i: usize, b: Vec3) -> Vec2 {
        let idx = self.uv_indices(i);
        if idx[0] == NONE || idx[1] == NONE || idx[2] == NONE {
            return Vec2::new(b.y, b.z);
        }
        b.x * self.uvs[idx[0] as usize] + b.y * self.uvs[idx[1] as usize] + b.z * self.uvs[idx[2] as usize]
    }

    /// The texture coordinates at the corners of triangle `i`, if it has them.
    #[inline]
    pub fn corner_uvs(&self, i: usize) -> Option<[Vec2; 3]> {
        let idx = self.uv_indices(i);
        (idx[0] != NONE && idx[1] != NONE && idx[2] != NONE).then(|| idx.map(|k| self.uvs[k as usize]))
    }

    /// Computes the MikkTSpace tangents that normal maps need (see `shapes/tangents.rs`).
    pub fn add_tangents(&mut self) {
        self.tangents = super::tangents::mikk_tangents(self);
        self.tangents.shrink_to_fit();
    }

    /// The interpolated tangent of triangle `i` at barycentrics `b` and its bitangent
    /// sign, if the triangle has one (unnormalized, as MikkTSpace intends).
    #[inline]
    pub fn tangent(&self, i: usize, b: Vec3) -> Option<(Vec3, f32)> {
        let [t0, t1, t2] = self.tangents.get(i)?;
        if t0.w == 0.0 {
            return None;
        }
        Some(((b.x * *t0 + b.y * *t1 + b.z * *t2).truncate(), t0.w))
    }

    /// Memory held, by kind.
    pub fn bytes(&self) -> GeometryBytes {
        GeometryBytes {
            corners: self.corners.capacity() * size_of::<[Vec3; 3]>(),
            mesh: self.materials.capacity() * size_of::<u32>()
                + (self.normal_idx.capacity() + self.uv_idx.capacity()) * size_of::<[u32; 3]>()
                + self.normals.capacity() * size_of::<Vec3>()
                + self.uvs.capacity() * size_of::<Vec2>()
                + self.tangents.capacity() * size_of::<[Vec4; 3]>(),
            spheres: self.spheres.capacity() * size_of::<Sphere>(),
        }
    }

    /// Reorders the triangles: new triangle `i` is old triangle `order[i]` (`order` is a
    /// permutation of `0..triangle_count()`). Every per-triangle array moves; spheres are
    /// unchanged.
    pub fn permute_triangles(&mut self, order: &[u32]) {
        assert_eq!(order.len(), self.triangle_count(), "permute_triangles: not a permutation of the triangles");
        fn permute<T: Copy>(v: &mut Vec<T>, order: &[u32]) {
            if !v.is_empty() {
                *v = order.iter().map(|&i| v[i as usize]).collect();
            }
        }
        permute(&mut self.corners, order);
        permute(&mut self.materials, order);
        permute(&mut self.normal_idx, order);
        permute(&mut self.uv_idx, order);
        permute(&mut self.tangents, order);
        self.advise_huge_pages();
    }

    /// Ray queries read the corners in the tree's leaf order but jump between distant
    /// leaves: on 4 KiB pages most of those reads also miss the TLB.
    pub(crate) fn advise_huge_pages(&self) {
        crate::memory::advise_huge_pages(&self.corners);
    }

    /// Triangles and spheres.
    #[inline]
    pub fn prim_count(&self) -> usize {
        self.corners.len() + self.spheres.len()
    }

    #[inline]
    pub fn resolve(&self, i: u32) -> PrimRef {
        let n = self.corners.len();
        if (i as usize) < n { PrimRef::Triangle(i as usize) } else { PrimRef::Sphere(i as usize - n) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::Tri;

    /// Four triangles over six positions: one with normals and uvs, one with normals
    /// only, one with uvs only, one with neither.
    fn mixed_mesh() -> TriangleMesh {
        let positions = (0..6).map(|i| Vec3::new(i as f32, (i * i) as f32, 1.0)).collect();
        let normals = vec![Vec3::X, Vec3::Y, Vec3::Z];
        let uvs = vec![Vec2::ZERO, Vec2::X, Vec2::Y, Vec2::ONE];
        let tris = vec![
            Tri { v: [0, 1, 2], n: [0, 1, 2], uv: [0, 1, 2], material: 3 },
            Tri { v: [1, 3, 2], n: [2, 1, 0], uv: [NONE; 3], material: 1 },
            Tri { v: [3, 4, 5], n: [NONE; 3], uv: [3, 2, 1], material: 0 },
            Tri { v: [5, 4, 0], n: [NONE; 3], uv: [NONE; 3], material: 2 },
        ];
        TriangleMesh { positions, normals, uvs, tris }
    }

    #[test]
    fn keeps_what_the_mesh_says_per_triangle() {
        let mesh = mixed_mesh();
        let g = Geometry::new(mesh.clone(), vec![]);
        assert_eq!(g.triangle_count(), 4);
        for (i, t) in mesh.tris.iter().enumerate() {
            assert_eq!(*g.triangle(i), mesh.corners(i));
            assert_eq!(g.material(i), t.material);
            assert_eq!(g.normal_indices(i), t.n);
            assert_eq!(g.uv_indices(i), t.uv);
            let expect = (t.n[0] != NONE).then(|| t.n.map(|k| mesh.normals[k as usize]));
            assert_eq!(g.shading_normals(i), expect);
        }
        let b = Vec3::new(0.25, 0.5, 0.25);
        assert_eq!(g.uv(0, b), 0.25 * Vec2::ZERO + 0.5 * Vec2::X + 0.25 * Vec2::Y);
        assert_eq!(g.uv(1, b), Vec2::new(0.5, 0.25), "no uvs: the barycentrics");
    }

    #[test]
    fn a_plain_mesh_costs_corners_and_a_material_index() {
        let mut mesh = mixed_mesh();
        for t in &mut mesh.tris {
            (t.n, t.uv) = ([NONE; 3], [NONE; 3]);
        }
        let g = Geometry::new(mesh, vec![]);
        assert_eq!(g.bytes(), GeometryBytes { corners: 4 * 36, mesh: 4 * 4, spheres: 0 });
        assert_eq!(g.shading_normals(0), None);
        let full = Geometry::new(mixed_mesh(), vec![Sphere { center: Vec3::ZERO, radius: 1.0, material: 0 }]);
        let b = full.bytes();
        assert_eq!(b.mesh, 4 * 4 + 2 * 4 * 12 + 3 * 12 + 4 * 8);
        assert_eq!(b.spheres, size_of::<Sphere>());
        assert_eq!(b.total(), 4 * 36 + b.mesh + b.spheres);
    }

    #[test]
    fn permuting_moves_every_per_triangle_array() {
        let mesh = mixed_mesh();
        let g = Geometry::new(mesh.clone(), vec![]);
        let mut p = g.clone();
        let order = [2u32, 0, 3, 1];
        p.permute_triangles(&order);
        for (new, &old) in order.iter().enumerate() {
            let old = old as usize;
            assert_eq!(p.triangle(new), g.triangle(old));
            assert_eq!(p.material(new), g.material(old));
            assert_eq!(p.normal_indices(new), g.normal_indices(old));
            assert_eq!(p.uv_indices(new), g.uv_indices(old));
            assert_eq!(p.shading_normals(new), g.shading_normals(old));
        }
    }
}
