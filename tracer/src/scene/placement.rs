//! Where a model goes: the transform fields of a `[[mesh]]` table and of each of its
//! `instance` copies, as a linear map and a translation; and the scene's meshes placed,
//! each OBJ read once, stored flat or as instances (`place_meshes`).

use std::collections::HashMap;
use std::path::Path;

use glam::{Affine3A, Mat3, Vec3};

use super::builder::Depth;
use super::file::{InstanceDesc, MeshDesc, RotateDesc, Scale, UpAxis};
use super::obj::ObjModel;
use crate::accel::instances;
use crate::math;

/// `p ↦ linear · p + translate`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub linear: Mat3,
    pub translate: Vec3,
}

/// A field's key within its table (`scale`, `instance[2].matrix`) and what is wrong.
pub type FieldError = (String, String);

impl Placement {
    /// `self`, then `outer`.
    pub fn then(self, outer: Placement) -> Placement {
        Placement { linear: outer.linear * self.linear, translate: outer.linear * self.translate + outer.translate }
    }

    pub fn affine(self) -> Affine3A {
        Affine3A::from_mat3_translation(self.linear, self.translate)
    }
}

/// The transform fields shared by `[[mesh]]` and its copies.
struct Fields<'a> {
    up: Option<UpAxis>,
    translate: Option<[f32; 3]>,
    scale: Option<Scale>,
    rotate_y: Option<f32>,
    rotate: Option<&'a RotateDesc>,
    matrix: Option<&'a [[f32; 4]; 4]>,
}

/// How a `[[mesh]]` table places its model: the up axis, then scale, rotation and
/// translation (or the matrix).
pub fn of_mesh(m: &MeshDesc) -> Result<Placement, FieldError> {
    placement(
        Fields {
            up: m.up,
            translate: m.translate,
            scale: m.scale,
            rotate_y: m.rotate_y,
            rotate: m.rotate.as_ref(),
            matrix: m.matrix.as_ref(),
        },
        "",
    )
}

/// How copy `k` of a mesh moves the placed model.
pub fn of_instance(d: &InstanceDesc, k: usize) -> Result<Placement, FieldError> {
    placement(
        Fields {
            up: None,
            translate: d.translate,
            scale: d.scale,
            rotate_y: d.rotate_y,
            rotate: d.rotate.as_ref(),
            matrix: d.matrix.as_ref(),
        },
        &format!("instance[{k}]."),
    )
}

fn placement(f: Fields, prefix: &str) -> Result<Placement, FieldError> {
    let err = |k: &str, m: &str| (format!("{prefix}{k}"), m.to_string());
    let finite3 = |k: &str, v: [f32; 3]| {
        if v.iter().all(|x| x.is_finite()) { Ok(Vec3::from_array(v)) } else { Err(err(k, "must be finite")) }
    };
    let up = f.up.unwrap_or_default().to_y_up();
    if let Some(m) = f.matrix {
        for (k, present) in
            [("translate", f.translate.is_some()), ("scale", f.scale.is_some()), ("rotate_y", f.rotate_y.is_some())]
                .into_iter()
                .chain([("rotate", f.rotate.is_some())])
        {
            if present {
                return Err(err(k, "give either matrix or scale, rotate and translate, not both"));
            }
        }
        let p = from_rows(m).map_err(|m| err("matrix", &m))?;
        return Ok(Placement { linear: p.linear * up, translate: p.translate });
    }
    let scale = finite3("scale", f.scale.map_or([1.0; 3], |s| s.to_vec()))?;
    if scale.cmpeq(Vec3::ZERO).any() {
        return Err(err("scale", "must not be zero"));
    }
    let rotation = match (f.rotate_y, f.rotate) {
        (Some(_), Some(_)) => return Err(err("rotate", "give rotate_y or rotate, not both")),
        (Some(a), None) if !a.is_finite() => return Err(err("rotate_y", "must be finite")),
        (a, None) => {
            // As glam's `Mat3::from_rotation_y`, with the platform-free sine and cosine.
            let (sin, cos) = math::sin_cos(a.unwrap_or(0.0).to_radians());
            Mat3::from_cols(Vec3::new(cos, 0.0, -sin), Vec3::Y, Vec3::new(sin, 0.0, cos))
        }
        (None, Some(r)) => {
            let axis = finite3("rotate.axis", r.axis)?.normalize_or_zero();
            if axis == Vec3::ZERO {
                return Err(err("rotate.axis", "must not be zero"));
            }
            if !r.degrees.is_finite() {
                return Err(err("rotate.degrees", "must be finite"));
            }
            about_axis(axis, r.degrees)
        }
    };
    let translate = finite3("translate", f.translate.unwrap_or([0.0; 3]))?;
    Ok(Placement { linear: rotation * Mat3::from_diagonal(scale) * up, translate })
}

/// The right-handed rotation by `degrees` about the unit `axis` (Rodrigues' formula),
/// with the platform-free sine and cosine.
pub fn about_axis(axis: Vec3, degrees: f32) -> Mat3 {
    let (s, c) = math::sin_cos(degrees.to_radians());
    let t = 1.0 - c;
    let Vec3 { x, y, z } = axis;
    Mat3::from_cols(
        Vec3::new(t * x * x + c, t * x * y + s * z, t * x * z - s * y),
        Vec3::new(t * x * y - s * z, t * y * y + c, t * y * z + s * x),
        Vec3::new(t * x * z + s * y, t * y * z - s * x, t * z * z + c),
    )
}

/// A row-major 4×4 affine matrix: finite, last row `[0, 0, 0, 1]`, invertible.
pub(super) fn from_rows(m: &[[f32; 4]; 4]) -> Result<Placement, String> {
    if m.iter().flatten().any(|x| !x.is_finite()) {
        return Err("must be finite".into());
    }
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(format!("the last row must be [0, 0, 0, 1] (an affine transform), got {:?}", m[3]));
    }
    let linear = Mat3::from_cols(
        Vec3::new(m[0][0], m[1][0], m[2][0]),
        Vec3::new(m[0][1], m[1][1], m[2][1]),
        Vec3::new(m[0][2], m[1][2], m[2][2]),
    );
    let det = linear.determinant();
    if !(det.is_finite() && det != 0.0) {
        return Err("is not invertible (its 3×3 part has determinant 0)".into());
    }
    Ok(Placement { linear, translate: Vec3::new(m[0][3], m[1][3], m[2][3]) })
}

/// The most meshes a scene may place, copies included: each costs a transform pair and
/// a box before the first ray (about 200 bytes), and a scene file is at most 16 MiB.
pub const MAX_COPIES: usize = 1_000_000;

/// Reads each `[[mesh]]` table's OBJ once and places its copies: an OBJ placed once is
/// added to the scene's own triangles (as before instancing existed, bit for bit); one
/// placed more than once (several tables, or `instance` lists) is stored once and its
/// copies are instances, unless it emits light (its triangles are then lights, one per
/// copy, so each copy is added).
pub(super) fn place_meshes<E: From<super::obj::ObjError>>(
    b: &mut super::builder::Builder,
    meshes: &[MeshDesc],
    name: &str,
    base: &Path,
    depth: Depth,
    invalid: &dyn Fn(String, String) -> E,
) -> Result<(), E> {
    let mut uses: HashMap<&str, usize> = HashMap::new();
    let mut total = 0usize;
    for (i, m) in meshes.iter().enumerate() {
        *uses.entry(m.obj.as_str()).or_default() += m.instance.len().max(1);
        total += m.instance.len().max(1);
        if total > MAX_COPIES {
            let message = format!("more than {MAX_COPIES} placed meshes in one scene");
            return Err(invalid(format!("mesh[{i}].instance"), message));
        }
    }
    let mut loaded: HashMap<&str, ObjModel> = HashMap::new();
    let mut triangles: HashMap<&str, u64> = HashMap::new();
    let mut instanced: HashMap<&str, u32> = HashMap::new();
    for (i, m) in meshes.iter().enumerate() {
        let field = |k: &str| format!("mesh[{i}].{k}");
        let bad = |(k, message): (String, String)| invalid(field(&k), message);
        let own = of_mesh(m).map_err(bad)?;
        let copies: Vec<Placement> = if m.instance.is_empty() {
            vec![own]
        } else {
            let each = m.instance.iter().enumerate().map(|(k, d)| of_instance(d, k));
            each.map(|p| p.map(|p| own.then(p)).map_err(bad)).collect::<Result<_, _>>()?
        };
        let obj = m.obj.as_str();
        if !loaded.contains_key(obj) && !instanced.contains_key(obj) {
            let (path, shown) = (base.join(obj), super::obj::shown_beside(name, obj));
            let model = match depth {
                Depth::Build => super::obj::load_obj_as(&path, &shown)?,
                Depth::Check => {
                    let checked = super::obj::check_obj_as(&path, &shown)?;
                    triangles.insert(obj, checked.triangles as u64);
                    checked.model
                }
            };
            triangles.entry(obj).or_insert(model.mesh.tris.len() as u64);
            let times = uses[obj];
            if times > 1 && model.materials.iter().any(|d| d.ke.max_element() > 0.0) {
                b.warnings.push(format!(
                    "{obj}: placed {times} times, but it emits light, so each copy is stored (emitting triangles are lights)"
                ));
            }
            loaded.insert(obj, model);
        }
        let remaining = uses.get_mut(obj).expect("counted above");
        if let Some(model) = loaded.get(obj)
            && !model.materials.iter().any(|d| d.ke.max_element() > 0.0)
            && *remaining > 1
            && !instanced.contains_key(obj)
        {
            let model = loaded.remove(obj).expect("just found");
            instanced.insert(obj, b.add_instanced(model));
        }
        match instanced.get(obj) {
            Some(&mesh) => {
                for (k, p) in copies.into_iter().enumerate() {
                    let copy = instances::place(mesh, p.affine()).map_err(|e| {
                        let table =
                            if m.instance.is_empty() { format!("mesh[{i}]") } else { field(&format!("instance[{k}]")) };
                        invalid(table, e.to_string())
                    })?;
                    b.copies.push(copy);
                    b.copy_triangles += triangles[obj];
                }
            }
            None => {
                for p in copies {
                    *remaining -= 1;
                    b.flat_triangles += triangles[obj];
                    let model = if *remaining == 0 {
                        loaded.remove(obj).expect("kept until its last use")
                    } else {
                        loaded[obj].clone()
                    };
                    b.add_model(model, p.linear, p.translate);
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).abs().max_element() < 1e-5
    }

    #[test]
    fn axis_rotation_is_right_handed_and_matches_rotate_y() {
        let r = about_axis(Vec3::Z, 90.0);
        assert!(close(r * Vec3::X, Vec3::Y), "{:?}", r * Vec3::X);
        let by_axis = about_axis(Vec3::Y, 30.0);
        let d = InstanceDesc { rotate_y: Some(30.0), ..InstanceDesc::default() };
        let by_y = of_instance(&d, 0).unwrap().linear;
        for v in [Vec3::X, Vec3::Y, Vec3::Z] {
            assert!(close(by_axis * v, by_y * v));
        }
        assert!((about_axis(Vec3::new(1.0, 2.0, 3.0).normalize(), 47.0).determinant() - 1.0).abs() < 1e-5);
    }

    #[test]
    fn a_matrix_is_read_row_by_row() {
        let m = [[0.0, -2.0, 0.0, 5.0], [2.0, 0.0, 0.0, 6.0], [0.0, 0.0, 2.0, 7.0], [0.0, 0.0, 0.0, 1.0]];
        let d = InstanceDesc { matrix: Some(m), ..InstanceDesc::default() };
        let p = of_instance(&d, 0).unwrap();
        assert_eq!(p.linear * Vec3::X + p.translate, Vec3::new(5.0, 8.0, 7.0));
        let affine = p.affine();
        assert_eq!(affine.transform_point3(Vec3::Y), Vec3::new(3.0, 6.0, 7.0));
    }

    #[test]
    fn composing_applies_the_inner_placement_first() {
        let inner = Placement { linear: Mat3::from_diagonal(Vec3::splat(2.0)), translate: Vec3::X };
        let outer = Placement { linear: about_axis(Vec3::Z, 90.0), translate: Vec3::Z };
        let both = inner.then(outer);
        let p = Vec3::new(1.0, 1.0, 1.0);
        let step = outer.linear * (inner.linear * p + inner.translate) + outer.translate;
        assert!(close(both.linear * p + both.translate, step));
    }

    #[test]
    fn bad_transforms_name_their_field() {
        let row = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 1.0, 1.0]];
        let flat = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
        let rot = |axis: [f32; 3]| Some(RotateDesc { axis, degrees: 10.0 });
        let cases = [
            (InstanceDesc { matrix: Some(row), ..Default::default() }, "instance[3].matrix", "last row"),
            (InstanceDesc { matrix: Some(flat), ..Default::default() }, "instance[3].matrix", "not invertible"),
            (
                InstanceDesc { matrix: Some(flat), translate: Some([1.0; 3]), ..Default::default() },
                "instance[3].translate",
                "not both",
            ),
            (InstanceDesc { rotate: rot([0.0; 3]), ..Default::default() }, "instance[3].rotate.axis", "zero"),
            (
                InstanceDesc { rotate: rot([1.0; 3]), rotate_y: Some(3.0), ..Default::default() },
                "instance[3].rotate",
                "not both",
            ),
            (
                InstanceDesc { scale: Some(Scale::PerAxis([1.0, 0.0, 1.0])), ..Default::default() },
                "instance[3].scale",
                "zero",
            ),
            (
                InstanceDesc { translate: Some([f32::NAN, 0.0, 0.0]), ..Default::default() },
                "instance[3].translate",
                "finite",
            ),
        ];
        for (d, key, words) in cases {
            let (k, m) = of_instance(&d, 3).unwrap_err();
            assert_eq!(k, key);
            assert!(m.contains(words), "{key}: {m}");
        }
    }
}
