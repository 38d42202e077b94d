//! Triangle meshes as the loaders produce them. The scene keeps the compact runtime form
//! made from one by [`super::Geometry::new`].

use glam::{Vec2, Vec3};

/// Marks an absent normal or texture-coordinate index.
pub const NONE: u32 = u32::MAX;

/// One triangle: indices into the mesh's vertex arrays, and a material index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tri {
    /// Position indices, counter-clockwise seen from the front face.
    pub v: [u32; 3],
    /// Shading-normal indices (`[NONE; 3]` for flat shading).
    pub n: [u32; 3],
    /// Texture-coordinate indices (`[NONE; 3]` when the face has none).
    pub uv: [u32; 3],
    pub material: u32,
}

/// An indexed triangle mesh. `material` indices refer to the material list that comes
/// with the mesh (the loader's, or the scene's once merged).
#[derive(Clone, Debug, Default)]
pub struct TriangleMesh {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub uvs: Vec<Vec2>,
    pub tris: Vec<Tri>,
}

impl TriangleMesh {
    #[inline]
    pub fn corners(&self, i: usize) -> [Vec3; 3] {
        let t = &self.tris[i];
        [self.positions[t.v[0] as usize], self.positions[t.v[1] as usize], self.positions[t.v[2] as usize]]
    }
}
