//! The inputs of a material that a texture can drive, and the textures a material
//! has on them.

use glam::{Vec2, Vec3};

use crate::texture::{Texture, luminance};

/// A textured input (besides the base colour, which is `map_Kd`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Slot {
    Roughness,
    Metallic,
    Sheen,
    Coat,
    Transmission,
    /// Opacity (MTL `d`, Blender's Alpha).
    Alpha,
    Emission,
    /// A tangent-space normal map.
    Normal,
    /// A height map (bump).
    Bump,
    /// A Mix Shader's factor.
    MixFactor,
}

impl Slot {
    pub const ALL: [Slot; 10] = [
        Slot::Roughness,
        Slot::Metallic,
        Slot::Sheen,
        Slot::Coat,
        Slot::Transmission,
        Slot::Alpha,
        Slot::Emission,
        Slot::Normal,
        Slot::Bump,
        Slot::MixFactor,
    ];

    /// Whether the input is a colour (textures then default to sRGB) rather than data.
    pub fn is_colour(self) -> bool {
        matches!(self, Slot::Emission)
    }

    /// The name of the input in MTL (its map statement) and in the scene's material table.
    pub fn names(self) -> (&'static str, &'static str) {
        match self {
            Slot::Roughness => ("map_Pr", "roughness_map"),
            Slot::Metallic => ("map_Pm", "metallic_map"),
            Slot::Sheen => ("map_Ps", "sheen_map"),
            Slot::Coat => ("map_Pc", "coat_map"),
            Slot::Transmission => ("map_Pt", "transmission_map"),
            Slot::Alpha => ("map_d", "alpha_map"),
            Slot::Emission => ("map_Ke", "emission_map"),
            Slot::Normal => ("norm", "normal_map"),
            Slot::Bump => ("map_Bump", "bump_map"),
            Slot::MixFactor => ("", "factor_map"),
        }
    }
}

const NONE: u32 = u32::MAX;

/// The texture (an index into the scene's list) on each [`Slot`], if any.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Maps([u32; 10]);

impl Default for Maps {
    fn default() -> Self {
        Self([NONE; 10])
    }
}

impl Maps {
    #[inline]
    pub fn get(&self, slot: Slot) -> Option<u32> {
        let t = self.0[slot as usize];
        (t != NONE).then_some(t)
    }

    pub fn set(&mut self, slot: Slot, texture: Option<u32>) {
        self.0[slot as usize] = texture.unwrap_or(NONE);
    }

    pub fn is_empty(&self) -> bool {
        self.0.iter().all(|&t| t == NONE)
    }

    /// Every texture index shifted by `base` (a model's textures joining the scene's).
    pub fn shifted(mut self, base: u32) -> Self {
        for t in &mut self.0 {
            if *t != NONE {
                *t += base;
            }
        }
        self
    }

    /// The slot's colour at `uv`, or None without a texture.
    #[inline]
    pub fn colour(&self, slot: Slot, uv: Vec2, textures: &[Texture]) -> Option<Vec3> {
        let t = self.get(slot)?;
        textures.get(t as usize).map(|t| t.sample(uv))
    }

    /// `value` times the slot's texture's luminance at `uv` (the value alone without one).
    #[inline]
    pub fn scale(&self, slot: Slot, value: f32, uv: Vec2, textures: &[Texture]) -> f32 {
        match self.colour(slot, uv, textures) {
            Some(c) => value * luminance(c),
            None => value,
        }
    }
}
