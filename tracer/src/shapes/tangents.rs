//! Per-corner tangents by MikkTSpace (the `mikktspace` crate), the tangent space that
//! Blender, Substance and glTF tools bake tangent-space normal maps in. Without the same
//! tangents a baked normal map shows seams and tilts where it should be flat.

use glam::{Vec3, Vec4};

use super::{Geometry, NONE};

/// The triangles of a [`Geometry`] that have texture coordinates, as MikkTSpace sees
/// them: faces of three corners with positions, normals (the shading normals, or the
/// face's for a flat triangle) and texture coordinates.
struct Faces<'a> {
    geometry: &'a Geometry,
    /// Triangle index of each face.
    faces: Vec<u32>,
    /// Per triangle: the tangent (xyz) and bitangent sign (w) of each corner.
    out: Vec<[Vec4; 3]>,
}

impl Faces<'_> {
    fn tri(&self, face: usize) -> usize {
        self.faces[face] as usize
    }
}

impl mikktspace::Geometry for Faces<'_> {
    fn num_faces(&self) -> usize {
        self.faces.len()
    }

    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }

    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.geometry.triangle(self.tri(face))[vert].to_array()
    }

    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        let i = self.tri(face);
        match self.geometry.shading_normals(i) {
            Some(n) => n[vert].to_array(),
            None => {
                let [p0, p1, p2] = *self.geometry.triangle(i);
                (p1 - p0).cross(p2 - p0).normalize_or_zero().to_array()
            }
        }
    }

    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        let i = self.tri(face);
        self.geometry.corner_uvs(i).map_or([0.0; 2], |uv| uv[vert].to_array())
    }

    fn set_tangent_encoded(&mut self, tangent: [f32; 4], face: usize, vert: usize) {
        let i = self.tri(face);
        self.out[i][vert] = Vec4::from_array(tangent);
    }
}

/// Tangents for every triangle of `geometry` with texture coordinates (zero, "none", for
/// the others); empty when no triangle has any.
pub fn mikk_tangents(geometry: &Geometry) -> Vec<[Vec4; 3]> {
    let n = geometry.triangle_count();
    let faces: Vec<u32> = (0..n as u32).filter(|&i| geometry.uv_indices(i as usize)[0] != NONE).collect();
    if faces.is_empty() {
        return Vec::new();
    }
    let mut f = Faces { geometry, faces, out: vec![[Vec4::ZERO; 3]; n] };
    if !mikktspace::generate_tangents(&mut f) {
        tracing::warn!("tangents for normal maps could not be computed: normal maps are ignored");
        return Vec::new();
    }
    // A corner MikkTSpace could not give a finite tangent is "none" (its normal map is
    // then ignored there) rather than a NaN in the shading.
    for t in &mut f.out {
        for c in t.iter_mut() {
            if !c.is_finite() || c.truncate() == Vec3::ZERO {
                *c = Vec4::ZERO;
            }
        }
    }
    f.out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::{Tri, TriangleMesh};
    use glam::Vec2;

    /// A unit quad in the xy plane facing +z, as two triangles, with uvs = (x, y) or
    /// mirrored in u.
    fn quad(mirror_u: bool) -> Geometry {
        let positions = vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
        let u = |x: f32| if mirror_u { 1.0 - x } else { x };
        let uvs = positions.iter().map(|p| Vec2::new(u(p.x), p.y)).collect();
        let tris = vec![
            Tri { v: [0, 1, 2], n: [NONE; 3], uv: [0, 1, 2], material: 0 },
            Tri { v: [0, 2, 3], n: [NONE; 3], uv: [0, 2, 3], material: 0 },
        ];
        Geometry::new(TriangleMesh { positions, normals: vec![], uvs, tris }, vec![])
    }

    #[test]
    fn a_quad_mapped_along_x_has_tangent_x_and_a_positive_sign() {
        let t = mikk_tangents(&quad(false));
        for tri in &t {
            for c in tri {
                assert!((c.truncate() - Vec3::X).length() < 1e-5, "{c}");
                assert_eq!(c.w, 1.0);
            }
        }
    }

    #[test]
    fn mirrored_texture_coordinates_flip_the_tangent() {
        for tri in &mikk_tangents(&quad(true)) {
            for c in tri {
                assert!((c.truncate() + Vec3::X).length() < 1e-5, "{c}");
                // The bitangent (sign · n × t) still points along +v = +y.
                let b = c.w * Vec3::Z.cross(c.truncate());
                assert!((b - Vec3::Y).length() < 1e-5, "{b}");
            }
        }
    }

    #[test]
    fn no_texture_coordinates_no_tangents() {
        let mut g = quad(false);
        g = Geometry::new(
            TriangleMesh {
                positions: g.corners.iter().flatten().copied().collect(),
                normals: vec![],
                uvs: vec![],
                tris: vec![Tri { v: [0, 1, 2], n: [NONE; 3], uv: [NONE; 3], material: 0 }],
            },
            vec![],
        );
        assert!(mikk_tangents(&g).is_empty());
    }
}
