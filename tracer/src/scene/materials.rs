//! The scene file's `[materials]` table: Principled materials and mixes by name, their
//! textures loaded relative to the scene file (README.md, "Principled materials").

use std::collections::BTreeMap;
use std::path::Path;

use glam::{Vec2, Vec3};

use super::SceneError;
use super::builder::Builder;
use super::file::{MaterialTable, TextureRef};
use super::textures::{Decode, TextureCache};
use crate::material::{Material, MaterialDesc, Mix, PbrDesc, Slot};
use crate::texture::TexMap;

/// Mixes of mixes are followed this deep at most (a loop is an error before that).
pub const MAX_MIX_DEPTH: usize = 8;

type Invalid<'a> = &'a dyn Fn(String, String) -> SceneError;

/// Adds every material of the table to the builder (so that meshes and spheres can use
/// them by name), mixes after the materials they mix. Textures that cannot be read are
/// one warning each and the input's own value.
pub(super) fn add_table(
    b: &mut Builder,
    table: &BTreeMap<String, MaterialTable>,
    base: &Path,
    invalid: Invalid,
) -> Result<(), SceneError> {
    let mut cache = TextureCache::default();
    let tex_base = b.textures.len() as u32;
    let mut descs = Vec::new();
    for (name, t) in table {
        let mut desc = describe(name, t, base, &mut cache, &mut b.warnings, invalid)?;
        desc.map_kd = desc.map_kd.map(|i| i + tex_base);
        desc.maps = desc.maps.shifted(tex_base);
        descs.push(desc);
    }
    b.textures.extend(cache.textures);
    // Plain materials first, then mixes once both their parts have an index.
    for desc in descs.iter().filter(|d| d.mix.is_none()) {
        b.add_named(desc.name.clone(), Material::from_desc(desc));
    }
    let mut pending: Vec<&MaterialDesc> = descs.iter().filter(|d| d.mix.is_some()).collect();
    // How deeply each mix nests (plain materials: 0).
    let mut depth: BTreeMap<&str, usize> = BTreeMap::new();
    while !pending.is_empty() {
        let before = pending.len();
        let mut too_deep = None;
        pending.retain(|d| {
            let Some(m) = &d.mix else { return false };
            let (Some(first), Some(second)) = (b.named(&m.first), b.named(&m.second)) else { return true };
            let nested = 1 + depth.get(m.first.as_str()).max(depth.get(m.second.as_str())).copied().unwrap_or(0);
            if nested > MAX_MIX_DEPTH {
                too_deep.get_or_insert(d.name.clone());
            }
            depth.insert(d.name.as_str(), nested);
            let mut material = Material::from_desc(d);
            material.mix = Some(Mix { first, second, factor: m.factor });
            b.add_named(d.name.clone(), material);
            false
        });
        if let Some(name) = too_deep {
            return Err(invalid(
                format!("materials.{name}.mix"),
                format!("mixes are nested more than {MAX_MIX_DEPTH} deep"),
            ));
        }
        if pending.len() == before {
            let d = pending[0];
            let m = d.mix.as_ref().expect("pending materials are mixes");
            let missing = [&m.first, &m.second].into_iter().find(|n| !table.contains_key(n.as_str()));
            let message = match missing {
                Some(n) => format!("mixes '{n}', which is not in the [materials] table"),
                None => "is a mix that contains itself".to_string(),
            };
            return Err(invalid(format!("materials.{}.mix", d.name), message));
        }
    }
    Ok(())
}

// Long on purpose: One table's keys checked and read in the README's order, each a line; split, the key list would be harder to hold against the documentation.
fn describe(
    name: &str,
    t: &MaterialTable,
    base: &Path,
    cache: &mut TextureCache,
    warnings: &mut Vec<String>,
    invalid: Invalid,
) -> Result<MaterialDesc, SceneError> {
    let field = |k: &str| format!("materials.{name}.{k}");
    let unit = |k: &str, v: Option<f32>, default: f32| match v {
        None => Ok(default),
        Some(x) if (0.0..=1.0).contains(&x) => Ok(x),
        Some(x) => Err(invalid(field(k), format!("must be in [0, 1], got {x}"))),
    };
    let positive = |k: &str, v: Option<f32>, default: f32| match v {
        None => Ok(default),
        Some(x) if x >= 0.0 && x.is_finite() => Ok(x),
        Some(x) => Err(invalid(field(k), format!("must be finite and ≥ 0, got {x}"))),
    };
    let colour = |k: &str, v: Option<[f32; 3]>, default: Vec3| match v {
        None => Ok(default),
        Some(c) if c.iter().all(|x| x.is_finite() && *x >= 0.0) => Ok(Vec3::from_array(c)),
        Some(_) => Err(invalid(field(k), "must be finite and ≥ 0".into())),
    };
    let mut desc = MaterialDesc { name: name.to_string(), ..MaterialDesc::default() };
    if let Some([first, second]) = &t.mix {
        let principled_keys = MaterialTable { mix: None, factor: None, factor_map: None, ..t.clone() };
        if principled_keys != MaterialTable::default() {
            return Err(invalid(field("mix"), "a mix takes only `factor` or `factor_map` beside it".into()));
        }
        let factor = if t.factor_map.is_some() { 1.0 } else { unit("factor", t.factor, 0.5)? };
        desc.mix = Some(crate::material::MixDesc { first: first.clone(), second: second.clone(), factor });
        let map =
            load(t.factor_map.as_ref(), Some(Slot::MixFactor), "factor_map", &field, base, cache, warnings, invalid)?;
        desc.maps.set(Slot::MixFactor, map);
        return Ok(desc);
    }
    if t.factor.is_some() || t.factor_map.is_some() {
        return Err(invalid(field("factor"), "only a mix (`mix = [first, second]`) has a factor".into()));
    }
    let mut pbr = PbrDesc::default();
    let p = &mut pbr.inputs;
    // Given a map, an input's own value is not used (Blender: a linked socket's value
    // is hidden): it becomes 1 and the texture is the value.
    let base_map = load(t.base_color_map.as_ref(), None, "base_color_map", &field, base, cache, warnings, invalid)?;
    let mut slot = |s: Slot, k: &str, r: &Option<TextureRef>| -> Result<bool, SceneError> {
        let map = load(r.as_ref(), Some(s), k, &field, base, cache, warnings, invalid)?;
        desc.maps.set(s, map);
        Ok(map.is_some())
    };
    let textured = |given: bool, value: f32| if given { 1.0 } else { value };
    p.metallic = textured(slot(Slot::Metallic, "metallic_map", &t.metallic_map)?, unit("metallic", t.metallic, 0.0)?);
    p.roughness =
        textured(slot(Slot::Roughness, "roughness_map", &t.roughness_map)?, unit("roughness", t.roughness, 0.5)?);
    p.transmission = textured(
        slot(Slot::Transmission, "transmission_map", &t.transmission_map)?,
        unit("transmission", t.transmission, 0.0)?,
    );
    p.coat = textured(slot(Slot::Coat, "coat_map", &t.coat_map)?, positive("coat", t.coat, 0.0)?);
    pbr.inputs.sheen = textured(slot(Slot::Sheen, "sheen_map", &t.sheen_map)?, positive("sheen", t.sheen, 0.0)?);
    pbr.alpha = textured(slot(Slot::Alpha, "alpha_map", &t.alpha_map)?, unit("alpha", t.alpha, 1.0)?);
    let emission_map = slot(Slot::Emission, "emission_map", &t.emission_map)?;
    let normal = slot(Slot::Normal, "normal_map", &t.normal_map)?;
    let bump = slot(Slot::Bump, "bump_map", &t.bump_map)?;
    desc.map_kd = base_map;
    let p = &mut pbr.inputs;
    desc.kd = if base_map.is_some() { Vec3::ONE } else { colour("base_color", t.base_color, Vec3::splat(0.8))? };
    p.ior = match t.ior {
        None => 1.5,
        Some(x) if x > 0.0 && x.is_finite() => x,
        Some(x) => Err(invalid(field("ior"), format!("must be > 0, got {x}")))?,
    };
    p.specular_ior_level = positive("specular_ior_level", t.specular_ior_level, 0.5)?;
    p.specular_tint = colour("specular_tint", t.specular_tint, Vec3::ONE)?;
    p.coat_roughness = unit("coat_roughness", t.coat_roughness, 0.03)?;
    p.coat_ior = match t.coat_ior {
        None => 1.5,
        Some(x) if x >= 1.0 && x.is_finite() => x,
        Some(x) => Err(invalid(field("coat_ior"), format!("must be ≥ 1, got {x}")))?,
    };
    p.coat_tint = colour("coat_tint", t.coat_tint, Vec3::ONE)?;
    p.multiscatter = match t.distribution.as_deref() {
        None | Some("multiscatter_ggx") => true,
        Some("ggx") => false,
        Some(other) => Err(invalid(
            field("distribution"),
            format!("unknown distribution '{other}' (expected multiscatter_ggx or ggx)"),
        ))?,
    };
    pbr.inputs.sheen_roughness = unit("sheen_roughness", t.sheen_roughness, 0.5)?;
    pbr.inputs.sheen_tint = colour("sheen_tint", t.sheen_tint, Vec3::ONE)?;
    pbr.anisotropy.amount = unit("anisotropic", t.anisotropic, 0.0)?;
    if let Some(r) = t.anisotropic_rotation {
        if !r.is_finite() {
            return Err(invalid(field("anisotropic_rotation"), "must be finite".into()));
        }
        pbr.anisotropy.rotation = r;
    }
    let emission = if emission_map { Vec3::ONE } else { colour("emission_color", t.emission_color, Vec3::ONE)? };
    desc.ke = emission * positive("emission_strength", t.emission_strength, 0.0)?;
    if let (true, Some(n)) = (normal, &t.normal_map) {
        desc.bumps.normal_strength = n.strength.unwrap_or(1.0);
    }
    if let (true, Some(m)) = (bump, &t.bump_map) {
        desc.bumps.bump_strength = m.strength.unwrap_or(1.0);
        desc.bumps.bump_distance = m.distance.unwrap_or(1.0);
    }
    desc.pbr = Some(pbr);
    Ok(desc)
}

/// Loads a texture reference for input `slot` (None: the base colour; `key` names it),
/// or None without one. A file that cannot be read is a warning and None.
#[allow(clippy::too_many_arguments)]
fn load(
    r: Option<&TextureRef>,
    slot: Option<Slot>,
    key: &str,
    field: &dyn Fn(&str) -> String,
    base: &Path,
    cache: &mut TextureCache,
    warnings: &mut Vec<String>,
    invalid: Invalid,
) -> Result<Option<u32>, SceneError> {
    let Some(r) = r else { return Ok(None) };
    let bad = |k: &str, message: String| invalid(field(key), format!("{k}: {message}"));
    let finite2 = |k: &str, v: Option<[f32; 2]>, default: Vec2| match v {
        None => Ok(default),
        Some(v) if v.iter().all(|x| x.is_finite()) => Ok(Vec2::from_array(v)),
        Some(_) => Err(bad(k, "must be finite".into())),
    };
    let scale = finite2("scale", r.scale, Vec2::ONE)?;
    let offset = finite2("offset", r.offset, Vec2::ZERO)?;
    let degrees = r.rotation.unwrap_or(0.0);
    if !degrees.is_finite() {
        return Err(bad("rotation", "must be finite".into()));
    }
    let (sin, cos) = crate::math::sin_cos(degrees.to_radians());
    let srgb = match r.colorspace.as_deref() {
        None => slot.is_none_or(Slot::is_colour),
        Some("srgb") => true,
        Some("non-color") => false,
        Some(other) => {
            return Err(bad("colorspace", format!("unknown colour space '{other}' (expected srgb or non-color)")));
        }
    };
    let closest = match r.interpolation.as_deref() {
        None | Some("linear") => false,
        Some("closest") => true,
        Some(other) => {
            return Err(bad("interpolation", format!("unknown interpolation '{other}' (expected linear or closest)")));
        }
    };
    let alpha = match r.channel.as_deref() {
        None | Some("rgb") | Some("luminance") => false,
        Some("alpha") => true,
        Some(other) => {
            return Err(bad("channel", format!("unknown channel '{other}' (expected rgb, luminance or alpha)")));
        }
    };
    let bumps = matches!(slot, Some(Slot::Normal | Slot::Bump));
    if r.strength.is_some_and(|s| !s.is_finite()) || (r.strength.is_some() && !bumps) {
        return Err(bad("strength", "only normal and bump maps have a finite strength".into()));
    }
    if r.distance.is_some_and(|d| !(d.is_finite() && d >= 0.0)) || (r.distance.is_some() && slot != Some(Slot::Bump)) {
        return Err(bad("distance", "only bump maps have a distance (finite, ≥ 0)".into()));
    }
    let map = TexMap { scale, offset, rotation: Vec2::new(cos, sin), clamp: r.clamp.unwrap_or(false), closest };
    let path = base.join(&r.file);
    match cache.get(&path, map, Decode { srgb, alpha }) {
        Ok(i) => Ok(Some(i)),
        Err(e) => {
            warnings.push(format!(
                "{}: texture '{}' could not be loaded ({e}); using the input's value without a texture",
                field(key),
                path.display()
            ));
            Ok(None)
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::bsdf::Bsdf;
    use crate::scene::{Scene, scene_from_toml};
    use glam::Vec3;

    const CAMERA: &str = "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nwidth = 8\nheight = 8\n";

    fn load(body: &str) -> Result<Scene, String> {
        let dir = std::env::temp_dir();
        scene_from_toml(&format!("{CAMERA}{body}"), "s.toml", &dir).map_err(|e| e.to_string())
    }

    #[test]
    fn table_materials_are_principled_and_spheres_use_them_by_name() {
        let scene = load(
            "[[sphere]]\ncenter = [0, 0, 0]\nradius = 1\nmaterial = \"Gold\"\n\
             [[sphere]]\ncenter = [2, 0, 0]\nradius = 1\nmaterial = \"Half\"\n\
             [materials.Gold]\nbase_color = [1.0, 0.78, 0.34]\nmetallic = 1\nroughness = 0.3\ndistribution = \"ggx\"\n\
             [materials.Red]\nbase_color = [0.8, 0.1, 0.1]\n\
             [materials.Half]\nmix = [\"Gold\", \"Red\"]\nfactor = 0.25\n",
        )
        .expect("loads");
        let gold = scene.materials[scene.geometry.spheres[0].material as usize];
        let Bsdf::Principled(p) = gold.bsdf else { panic!("{gold:?}") };
        assert_eq!(
            (p.base_color, p.metallic, p.roughness, p.multiscatter),
            (Vec3::new(1.0, 0.78, 0.34), 1.0, 0.3, false)
        );
        let half = scene.materials[scene.geometry.spheres[1].material as usize];
        let mix = half.mix.expect("a mix");
        assert_eq!(mix.factor, 0.25);
        assert_eq!(scene.materials[mix.first as usize], gold);
        assert!(matches!(scene.materials[mix.second as usize].bsdf, Bsdf::Principled(p) if p.base_color.x == 0.8));
    }

    #[test]
    fn bad_tables_are_errors_naming_line_and_key() {
        let cases = [
            ("[materials.A]\nroughness = 1.5\n", "s.toml:7: materials.A.roughness: must be in [0, 1], got 1.5"),
            ("[materials.A]\nroughnes = 0.5\n", "roughnes"),
            (
                "[materials.A]\nmix = [\"A\", \"B\"]\n",
                "materials.A.mix: mixes 'B', which is not in the [materials] table",
            ),
            ("[materials.A]\nmix = [\"B\", \"B\"]\n[materials.B]\nmix = [\"A\", \"A\"]\n", "contains itself"),
            ("[materials.A]\nmix = [\"B\", \"B\"]\nmetallic = 1\n[materials.B]\n", "a mix takes only"),
            (
                "[materials.A]\ndistribution = \"beckmann\"\n",
                "s.toml:7: materials.A.distribution: unknown distribution",
            ),
            (
                "[materials.A]\nroughness_map = { file = \"r.png\", strength = 2 }\n",
                "s.toml:7: materials.A.roughness_map: strength: only normal and bump maps",
            ),
            (
                "[materials.A]\nbase_color_map = { file = \"r.png\", colorspace = \"acescg\" }\n",
                "unknown colour space 'acescg'",
            ),
            (
                "[[sphere]]\ncenter = [0, 0, 0]\nradius = 1\nmaterial = \"Nope\"\n",
                "'Nope' is not in the [materials] table",
            ),
        ];
        for (body, expected) in cases {
            let err = load(body).err().unwrap_or_else(|| panic!("{body}: loaded"));
            assert!(err.contains(expected), "{body}:\n{err}\nexpected: {expected}");
        }
    }

    #[test]
    fn a_texture_that_cannot_be_read_is_one_warning_and_the_value() {
        let scene = load(
            "[[sphere]]\ncenter = [0, 0, 0]\nradius = 1\nmaterial = \"A\"\n\
             [materials.A]\nroughness = 0.2\nbase_color_map = { file = \"no_such_texture.png\" }\n",
        )
        .expect("loads");
        let warnings: Vec<_> = scene.warnings.iter().filter(|w| w.contains("no_such_texture.png")).collect();
        assert_eq!(warnings.len(), 1, "{:?}", scene.warnings);
        assert!(warnings[0].contains("materials.A.base_color_map"), "{}", warnings[0]);
        let m = scene.materials[scene.geometry.spheres[0].material as usize];
        assert!(m.kd_texture.is_none());
    }
}

#[cfg(test)]
mod render_tests {
    use crate::film::SampleRange;
    use crate::integrator::Integrator;
    use crate::render::render_image;
    use crate::scene::scene_from_toml;

    /// The image mean of a sphere of `material` filling the view under a white sky.
    fn mean_of(materials: &str, material: &str) -> f32 {
        let text = format!(
            "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 20\nwidth = 16\nheight = 16\n\
             [render]\nspp = 64\nmax_depth = 3\n[background]\nradiance = [1, 1, 1]\n\
             [[sphere]]\ncenter = [0, 0, 0]\nradius = 1\nmaterial = \"{material}\"\n{materials}"
        );
        let scene = scene_from_toml(&text, "mix.toml", &std::env::temp_dir()).expect("loads");
        let (image, _) = render_image(&scene, Integrator::Path, SampleRange::new(0, 64), 8, &|_| {});
        let n = image.pixels.len() as f32;
        image.pixels.iter().map(|p| p.x).sum::<f32>() / n
    }

    #[test]
    fn a_mix_renders_between_its_parts() {
        let table = "[materials.Dark]\nbase_color = [0.1, 0.1, 0.1]\nspecular_ior_level = 0\n\
                     [materials.Light]\nbase_color = [0.9, 0.9, 0.9]\nspecular_ior_level = 0\n\
                     [materials.Half]\nmix = [\"Dark\", \"Light\"]\nfactor = 0.5\n";
        let (dark, light, half) = (mean_of(table, "Dark"), mean_of(table, "Light"), mean_of(table, "Half"));
        // A diffuse sphere under a white sky: the mix's mean is the parts' mean, up to noise.
        let expected = 0.5 * (dark + light);
        assert!((half - expected).abs() < 0.05 * expected, "dark {dark} light {light} half {half}");
    }
}
