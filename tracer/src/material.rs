//! Materials: the MTL description as read, and its interpretation as a BSDF + emission.

use glam::Vec3;

/// A material as written in an MTL file or inline on a sphere (field names are MTL's).
/// Absent colours are black; `d` and `ni` default to 1, `tf` to white.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialDesc {
    pub name: String,
    pub ka: Vec3,
    pub kd: Vec3,
    pub ks: Vec3,
    pub ke: Vec3,
    pub tf: Vec3,
    pub ns: f32,
    pub ni: f32,
    pub d: f32,
    pub illum: Option<u32>,
    /// Index into the model's texture list.
    pub map_kd: Option<u32>,
}

impl Default for MaterialDesc {
    fn default() -> Self {
        Self {
            name: String::new(),
            ka: Vec3::ZERO,
            kd: Vec3::ZERO,
            ks: Vec3::ZERO,
            ke: Vec3::ZERO,
            tf: Vec3::ONE,
            ns: 0.0,
            ni: 1.0,
            d: 1.0,
            illum: None,
            map_kd: None,
        }
    }
}

impl MaterialDesc {
    /// The material used where one is missing: grey diffuse.
    pub fn default_grey(name: &str) -> Self {
        Self { name: name.to_string(), kd: Vec3::splat(0.5), ..Self::default() }
    }
}
