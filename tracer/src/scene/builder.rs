//! The parts of a scene as its loader gathers them, before the scene is built: the
//! flat triangles, spheres, materials and textures, warnings, and the meshes stored once
//! with their placed copies.

use glam::{Mat3, Vec3};

use super::obj::ObjModel;
use super::{Geometry, NONE, Sphere, TriangleMesh};
use crate::accel::instances::{Instance, InstancedMesh};
use crate::material::{Material, MaterialDesc};
use crate::texture::Texture;

/// How far a load goes: the whole scene, or only what checking it needs (see
/// [`super::check`]): the OBJ files are checked, not built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Depth {
    Build,
    Check,
}

#[derive(Default)]
pub(super) struct Builder {
    pub(super) mesh: TriangleMesh,
    pub(super) spheres: Vec<Sphere>,
    pub(super) materials: Vec<Material>,
    pub(super) material_names: Vec<String>,
    pub(super) textures: Vec<Texture>,
    pub(super) warnings: Vec<String>,
    /// Meshes stored once, and their placed copies.
    pub(super) instanced: Vec<InstancedMesh>,
    pub(super) copies: Vec<Instance>,
    /// Triangles placed flat, and in copies: what the scene will hold, counted while
    /// its files are only checked (the meshes above are then empty).
    pub(super) flat_triangles: u64,
    pub(super) copy_triangles: u64,
    /// The scene's `[materials]` table by name (indices into `materials`): they replace
    /// MTL materials of the same name.
    pub(super) named_materials: std::collections::HashMap<String, u32>,
}

impl Builder {
    /// Appends a model's materials and textures (and its warnings); returns the index of
    /// its first material in the scene's list.
    pub(super) fn add_materials(
        &mut self,
        materials: &[MaterialDesc],
        textures: Vec<Texture>,
        warnings: Vec<String>,
    ) -> u32 {
        let (mat_base, tex_base) = (self.materials.len() as u32, self.textures.len() as u32);
        self.material_names.extend(materials.iter().map(|m| m.name.clone()));
        for m in materials {
            let material = match self.named(&m.name) {
                Some(i) => self.materials[i as usize],
                None => {
                    let mut m = m.clone();
                    m.map_kd = m.map_kd.map(|t| t + tex_base);
                    m.maps = m.maps.shifted(tex_base);
                    Material::from_desc(&m)
                }
            };
            self.materials.push(material);
        }
        self.textures.extend(textures);
        self.warnings.extend(warnings);
        mat_base
    }

    /// Adds a material of the scene's table under its name.
    pub(super) fn add_named(&mut self, name: String, material: Material) {
        self.named_materials.insert(name.clone(), self.materials.len() as u32);
        self.materials.push(material);
        self.material_names.push(name);
    }

    /// The index of the table's material `name`.
    pub(super) fn named(&self, name: &str) -> Option<u32> {
        self.named_materials.get(name).copied()
    }

    /// Stores a model once, in its own coordinates, for copies to place; returns its
    /// index among the instanced meshes.
    pub(super) fn add_instanced(&mut self, model: ObjModel) -> u32 {
        let ObjModel { mut mesh, materials, textures, warnings } = model;
        let mat_base = self.add_materials(&materials, textures, warnings);
        for t in &mut mesh.tris {
            t.material += mat_base;
        }
        self.instanced.push(InstancedMesh::new(Geometry::new(mesh, Vec::new())));
        self.instanced.len() as u32 - 1
    }

    /// Appends a model, placing it with `transform(p)` and its normals with `normal_m`.
    pub(super) fn add_model(&mut self, model: ObjModel, linear: Mat3, translate: Vec3) {
        let ObjModel { mesh, materials, textures, warnings } = model;
        let mat_base = self.add_materials(&materials, textures, warnings);
        let (pos_base, n_base, uv_base) =
            (self.mesh.positions.len() as u32, self.mesh.normals.len() as u32, self.mesh.uvs.len() as u32);
        let normal_m = linear.inverse().transpose();
        // A mirroring transform turns counter-clockwise into clockwise: swap two corners
        // so that front faces (and one-sided emitters) stay on the same side.
        let mirrored = linear.determinant() < 0.0;
        let out = &mut self.mesh;
        out.positions.extend(mesh.positions.iter().map(|&p| linear * p + translate));
        out.normals.extend(mesh.normals.iter().map(|&n| (normal_m * n).normalize_or_zero()));
        out.uvs.extend_from_slice(&mesh.uvs);
        let shift = |idx: [u32; 3], base: u32| idx.map(|i| if i == NONE { NONE } else { i + base });
        out.tris.extend(mesh.tris.iter().map(|t| {
            let mut t = super::Tri {
                v: shift(t.v, pos_base),
                n: shift(t.n, n_base),
                uv: shift(t.uv, uv_base),
                material: t.material + mat_base,
            };
            if mirrored {
                t.v.swap(1, 2);
                t.n.swap(1, 2);
                t.uv.swap(1, 2);
            }
            t
        }));
    }
}
