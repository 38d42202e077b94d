//! Materials: the MTL description as read, and its interpretation as a BSDF + emission.

use glam::{Vec2, Vec3};

use crate::bsdf::Bsdf;
use crate::texture::Texture;

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

/// How a material scatters light, decided once from its description (see README.md,
/// "How MTL keys are interpreted").
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Material {
    /// The BSDF with the untextured `Kd`; [`Material::bsdf_at`] applies `map_Kd`.
    pub bsdf: Bsdf,
    /// Emitted radiance (`Ke`), one-sided: from the front face only.
    pub emission: Vec3,
    /// Probability that a ray is blocked here (`d` when `Ni == 1`): below 1 the surface
    /// is stochastically transparent.
    pub opacity: f32,
    pub kd_texture: Option<u32>,
}

impl Material {
    pub fn from_desc(desc: &MaterialDesc) -> Self {
        let clamp01 = |v: Vec3| v.clamp(Vec3::ZERO, Vec3::ONE);
        let (kd, ks, tf) = (clamp01(desc.kd), clamp01(desc.ks), clamp01(desc.tf));
        let illum = desc.illum.unwrap_or(2);
        let refracts = desc.d < 1.0 && desc.ni != 1.0;
        let mut opacity = 1.0;
        let bsdf = if matches!(illum, 3 | 5) {
            Bsdf::Mirror { ks }
        } else if matches!(illum, 4 | 6 | 7) || refracts {
            let eta = if desc.ni > 0.0 && desc.ni.is_finite() { desc.ni } else { 1.5 };
            Bsdf::Glass { eta, tint: tf }
        } else {
            if desc.d < 1.0 {
                opacity = desc.d.clamp(0.0, 1.0);
            }
            if ks.max_element() > 0.0 {
                Bsdf::Glossy { kd, ks, exponent: desc.ns.clamp(0.0, 10000.0) }
            } else {
                Bsdf::Diffuse { kd }
            }
        };
        let emission = desc.ke.max(Vec3::ZERO);
        Self { bsdf, emission, opacity, kd_texture: desc.map_kd }
    }

    #[inline]
    pub fn is_emissive(&self) -> bool {
        self.emission.max_element() > 0.0
    }

    /// The BSDF at a surface point with texture coordinates `uv`: `map_Kd` multiplies
    /// `Kd`, as the MTL specification says.
    #[inline]
    pub fn bsdf_at(&self, uv: Vec2, textures: &[Texture]) -> Bsdf {
        let Some(t) = self.kd_texture.and_then(|t| textures.get(t as usize)) else {
            return self.bsdf;
        };
        let tex = t.sample(uv);
        match self.bsdf {
            Bsdf::Diffuse { kd } => Bsdf::Diffuse { kd: kd * tex },
            Bsdf::Glossy { kd, ks, exponent } => Bsdf::Glossy { kd: kd * tex, ks, exponent },
            other => other,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn desc(f: impl FnOnce(&mut MaterialDesc)) -> Material {
        let mut d = MaterialDesc::default();
        f(&mut d);
        Material::from_desc(&d)
    }

    #[test]
    fn mtl_keys_map_to_the_documented_bsdfs() {
        assert!(matches!(desc(|d| d.kd = Vec3::splat(0.5)).bsdf, Bsdf::Diffuse { .. }));
        assert!(matches!(desc(|d| d.ks = Vec3::splat(0.5)).bsdf, Bsdf::Glossy { .. }));
        assert!(matches!(desc(|d| d.illum = Some(3)).bsdf, Bsdf::Mirror { .. }));
        assert!(matches!(desc(|d| d.illum = Some(5)).bsdf, Bsdf::Mirror { .. }));
        for i in [4, 6, 7] {
            assert!(matches!(desc(|d| d.illum = Some(i)).bsdf, Bsdf::Glass { .. }));
        }
        let glass = desc(|d| {
            d.d = 0.2;
            d.ni = 1.33
        });
        assert_eq!(glass.bsdf, Bsdf::Glass { eta: 1.33, tint: Vec3::ONE });
        assert_eq!(glass.opacity, 1.0);
        let cutout = desc(|d| {
            d.d = 0.25;
            d.kd = Vec3::ONE
        });
        assert!(matches!(cutout.bsdf, Bsdf::Diffuse { .. }));
        assert_eq!(cutout.opacity, 0.25);
        assert!(desc(|d| d.ke = Vec3::new(1.0, 0.0, 0.0)).is_emissive());
        assert!(!desc(|_| {}).is_emissive());
    }
}
