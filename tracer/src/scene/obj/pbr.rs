//! MTL's PBR extension (as Blender's OBJ exporter and tinyobjloader write it): the keys
//! that make a material a Principled one (README.md, "Principled materials").

use crate::material::{MaterialDesc, PbrDesc};

/// The PBR keys of one material as written (absent: None).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct PbrKeys {
    pub pr: Option<f32>,
    pub pm: Option<f32>,
    pub ps: Option<f32>,
    pub pc: Option<f32>,
    pub pcr: Option<f32>,
    pub pt: Option<f32>,
    pub aniso: Option<f32>,
    pub anisor: Option<f32>,
}

/// The key as MTL spells it, for messages.
pub(crate) fn pbr_key_name(lower: &str) -> &'static str {
    match lower {
        "pr" => "Pr",
        "pm" => "Pm",
        "ps" => "Ps",
        "pc" => "Pc",
        "pcr" => "Pcr",
        "pt" => "Pt",
        "aniso" => "aniso",
        _ => "anisor",
    }
}

impl PbrKeys {
    pub fn set(&mut self, lower: &str, x: f32) {
        let slot = match lower {
            "pr" => &mut self.pr,
            "pm" => &mut self.pm,
            "ps" => &mut self.ps,
            "pc" => &mut self.pc,
            "pcr" => &mut self.pcr,
            "pt" => &mut self.pt,
            "aniso" => &mut self.aniso,
            _ => &mut self.anisor,
        };
        *slot = Some(x);
    }

    /// `Pr` or `Pm` makes a material Principled.
    pub fn principled(&self) -> bool {
        self.pr.is_some() || self.pm.is_some()
    }

    /// The Principled inputs of `desc` (its `Kd`, `Ke`, `d` and `illum` already read;
    /// `ni` is `Ni` as written). Glass (`illum 4/6/7`, or `d < 1` with `Ni ≠ 1`) becomes
    /// transmission 1 with alpha 1, else alpha is `d`.
    pub fn pbr_desc(self, desc: &MaterialDesc, ni: Option<f32>) -> PbrDesc {
        let mut pbr = PbrDesc::default();
        let p = &mut pbr.inputs;
        p.roughness = self.pr.unwrap_or(p.roughness);
        p.metallic = self.pm.unwrap_or(0.0);
        p.coat = self.pc.unwrap_or(0.0);
        p.coat_roughness = self.pcr.unwrap_or(p.coat_roughness);
        p.ior = ni.filter(|n| *n > 0.0).unwrap_or(p.ior);
        let glass = matches!(desc.illum, Some(4 | 6 | 7)) || (desc.d < 1.0 && ni.is_some_and(|n| n != 1.0));
        p.transmission = if glass { 1.0 } else { self.pt.unwrap_or(0.0) };
        pbr.alpha = if glass { 1.0 } else { desc.d };
        p.sheen = self.ps.unwrap_or(0.0);
        pbr.anisotropy.amount = self.aniso.unwrap_or(0.0);
        pbr.anisotropy.rotation = self.anisor.unwrap_or(0.0);
        pbr
    }
}
