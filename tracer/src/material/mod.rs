//! Materials: the MTL description as read (or the scene's material table), and its
//! interpretation as a BSDF + emission, with the textures on its inputs.

pub mod normals;
pub mod slots;

use glam::{Vec2, Vec3};

use crate::bsdf::{Bsdf, Principled};
use crate::texture::Texture;
use normals::{Bumps, UvFrame};
pub use slots::{Maps, Slot};

/// The Principled inputs a material has beyond MTL's classic keys (MTL's PBR extension,
/// or the scene's `[materials]` table). Its base colour is `Kd`, its emission `Ke`.
#[derive(Clone, Debug, PartialEq)]
pub struct PbrDesc {
    /// The inputs; `base_color` is taken from `Kd`.
    pub inputs: Principled,
    /// Opacity: a stochastic cut-out below 1 (MTL's `d`, unless `d` made it glass).
    pub alpha: f32,
    pub anisotropy: Anisotropy,
}

/// Blender's Anisotropic (0–1) and Anisotropic Rotation (in turns) of a Principled
/// material: its metal and specular lobes stretch along the surface's tangent (the
/// direction of its texture coordinates' u), turned by the rotation.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Anisotropy {
    pub amount: f32,
    pub rotation: f32,
}

impl Default for PbrDesc {
    fn default() -> Self {
        Self { inputs: Principled::default(), alpha: 1.0, anisotropy: Anisotropy::default() }
    }
}

/// Blender's Mix Shader: `(1 − factor) · first + factor · second`, by material name.
#[derive(Clone, Debug, PartialEq)]
pub struct MixDesc {
    pub first: String,
    pub second: String,
    pub factor: f32,
}

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
    /// Index into the model's texture list: the base colour's texture.
    pub map_kd: Option<u32>,
    /// Textures on the other inputs (indices into the same list).
    pub maps: Maps,
    /// The strengths of the normal and bump maps in `maps`.
    pub bumps: Bumps,
    /// `Some`: a Principled material.
    pub pbr: Option<PbrDesc>,
    /// `Some`: a mix of two other materials (the fields above are unused).
    pub mix: Option<MixDesc>,
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
            maps: Maps::default(),
            bumps: Bumps::default(),
            pbr: None,
            mix: None,
        }
    }
}

impl MaterialDesc {
    /// The material used where one is missing: grey diffuse.
    pub fn default_grey(name: &str) -> Self {
        Self { name: name.to_string(), kd: Vec3::splat(0.5), ..Self::default() }
    }
}

/// Blender's Mix Shader between two materials of the scene (indices into its list).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Mix {
    pub first: u32,
    pub second: u32,
    pub factor: f32,
}

/// How a material scatters light, decided once from its description (see README.md,
/// "How MTL keys are interpreted" and "Principled materials").
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Material {
    /// The BSDF with the untextured inputs; [`Material::bsdf_at`] applies the textures.
    pub bsdf: Bsdf,
    /// Emitted radiance (`Ke`), one-sided: from the front face only.
    pub emission: Vec3,
    /// Probability that a ray is blocked here (`d` when `Ni == 1`): below 1 the surface
    /// is stochastically transparent.
    pub opacity: f32,
    /// The base colour's texture (`map_Kd`).
    pub kd_texture: Option<u32>,
    /// Textures on the other inputs.
    pub maps: Maps,
    /// A mix of two materials: a path meeting it continues with one of them, chosen with
    /// the factor's probability (the mixture's unbiased one-sample estimate).
    pub mix: Option<Mix>,
    /// The strengths of the normal and bump maps in `maps`.
    pub bumps: Bumps,
    /// A Principled material's anisotropy (zero amount: none).
    pub anisotropy: Anisotropy,
}

impl Material {
    pub fn from_desc(desc: &MaterialDesc) -> Self {
        let clamp01 = |v: Vec3| v.clamp(Vec3::ZERO, Vec3::ONE);
        let (kd, ks, tf) = (clamp01(desc.kd), clamp01(desc.ks), clamp01(desc.tf));
        let illum = desc.illum.unwrap_or(2);
        let refracts = desc.d < 1.0 && desc.ni != 1.0;
        let mut opacity = 1.0;
        let bsdf = if let Some(pbr) = &desc.pbr {
            opacity = if pbr.alpha.is_finite() { pbr.alpha.clamp(0.0, 1.0) } else { 1.0 };
            Bsdf::Principled(Principled { base_color: desc.kd.max(Vec3::ZERO), ..pbr.inputs }.sanitized())
        } else if matches!(illum, 3 | 5) {
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
        let anisotropy = desc.pbr.as_ref().map_or(Anisotropy::default(), |p| Anisotropy {
            amount: if p.anisotropy.amount.is_finite() { p.anisotropy.amount.clamp(0.0, 1.0) } else { 0.0 },
            rotation: if p.anisotropy.rotation.is_finite() { p.anisotropy.rotation } else { 0.0 },
        });
        Self {
            bsdf,
            emission,
            opacity,
            kd_texture: desc.map_kd,
            maps: desc.maps,
            mix: None,
            bumps: desc.bumps,
            anisotropy,
        }
    }

    #[inline]
    pub fn is_emissive(&self) -> bool {
        self.emission.max_element() > 0.0
    }

    /// Whether the surface may let rays pass (stochastic opacity, constant or textured).
    pub fn has_cutout(&self) -> bool {
        self.opacity < 1.0 || self.maps.get(Slot::Alpha).is_some()
    }

    /// The BSDF at a surface point with texture coordinates `uv`: textures multiply the
    /// values they drive (`map_Kd` multiplies `Kd`, as the MTL specification says; a
    /// scene's material table sets the value to 1 where it gives a texture).
    #[inline]
    pub fn bsdf_at(&self, uv: Vec2, textures: &[Texture]) -> Bsdf {
        let tex = self.kd_texture.and_then(|t| textures.get(t as usize)).map(|t| t.sample(uv));
        match self.bsdf {
            Bsdf::Diffuse { kd } => Bsdf::Diffuse { kd: tex.map_or(kd, |t| kd * t) },
            Bsdf::Glossy { kd, ks, exponent } => Bsdf::Glossy { kd: tex.map_or(kd, |t| kd * t), ks, exponent },
            Bsdf::Principled(p) => {
                if tex.is_none() && self.maps.is_empty() {
                    return self.bsdf;
                }
                let m = &self.maps;
                let p = Principled {
                    base_color: tex.map_or(p.base_color, |t| p.base_color * t),
                    roughness: m.scale(Slot::Roughness, p.roughness, uv, textures),
                    metallic: m.scale(Slot::Metallic, p.metallic, uv, textures),
                    coat: m.scale(Slot::Coat, p.coat, uv, textures),
                    sheen: m.scale(Slot::Sheen, p.sheen, uv, textures),
                    transmission: m.scale(Slot::Transmission, p.transmission, uv, textures),
                    ..p
                };
                Bsdf::Principled(p.sanitized())
            }
            other => other,
        }
    }

    /// Whether a normal or bump map tilts the shading normal.
    #[inline]
    pub fn perturbs_normal(&self) -> bool {
        self.maps.get(Slot::Normal).is_some() || self.maps.get(Slot::Bump).is_some()
    }

    /// The shading normal `ns` (front side) tilted by the normal map, then by the bump map
    /// (Blender's usual chain: the Normal Map node into the Bump node's Normal).
    pub fn shading_normal(&self, ns: Vec3, uv: Vec2, frame: &UvFrame, textures: &[Texture]) -> Vec3 {
        let mut n = ns;
        if let Some(rgb) = self.maps.colour(Slot::Normal, uv, textures)
            && let Some(mapped) = normals::normal_map(rgb, self.bumps.normal_strength, frame)
        {
            n = mapped;
        }
        if let Some(t) = self.maps.get(Slot::Bump).and_then(|t| textures.get(t as usize)) {
            let b = &self.bumps;
            n = normals::bump(n, t.luminance_gradient(uv), b.bump_distance, b.bump_strength, frame);
        }
        if n == Vec3::ZERO || !n.is_finite() { ns } else { n }
    }

    /// The probability that a ray is blocked at `uv`.
    #[inline]
    pub fn opacity_at(&self, uv: Vec2, textures: &[Texture]) -> f32 {
        self.maps.scale(Slot::Alpha, self.opacity, uv, textures).clamp(0.0, 1.0)
    }

    /// The emitted radiance at `uv`.
    #[inline]
    pub fn emission_at(&self, uv: Vec2, textures: &[Texture]) -> Vec3 {
        match self.maps.colour(Slot::Emission, uv, textures) {
            Some(c) => self.emission * c,
            None => self.emission,
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
