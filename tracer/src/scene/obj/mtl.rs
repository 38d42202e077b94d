//! MTL material libraries and their `map_Kd` textures.
//!
//! A line pass validates numbers (with line numbers), expands one-value colours (`Ks 0.5`)
//! to three, and keeps only the statements used; tobj then parses the result.

use std::collections::HashMap;
use std::io::Cursor;
use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};

use super::ObjError;
use super::pbr::{PbrKeys, pbr_key_name};
use super::scan::shorten;
use crate::material::{MaterialDesc, Slot};
use crate::scene::textures::Decode;
pub(super) use crate::scene::textures::TextureCache;
use crate::texture::{TexMap, Texture};

/// A material as read from an MTL file, its texture not yet loaded.
#[derive(Clone, Debug)]
pub(super) struct RawMaterial {
    /// Everything but `map_kd`.
    pub desc: MaterialDesc,
    /// The `map_Kd` file name (options stripped), relative to `dir`.
    pub map_kd: Option<String>,
    /// Where `map_Kd`'s options place the image.
    pub map_kd_placement: TexMap,
    /// Textures on the other inputs (file names relative to `dir`), in file order.
    pub maps: Vec<(Slot, MapArg)>,
    /// Folder of the MTL file.
    pub dir: PathBuf,
    /// The MTL file, for messages.
    pub mtl: String,
}

/// An MTL file with its textures loaded (see [`load_mtl`]).
#[derive(Clone, Debug, Default)]
pub struct MtlLibrary {
    /// In file order; `map_kd` indexes `textures`.
    pub materials: Vec<MaterialDesc>,
    pub textures: Vec<Texture>,
    pub warnings: Vec<String>,
}

/// Loads an MTL file and its `map_Kd` textures. A missing file or a malformed statement is
/// an error; a texture that cannot be loaded is a warning (the material keeps its `Kd`).
pub fn load_mtl(path: &Path) -> Result<MtlLibrary, ObjError> {
    let display = path.display().to_string();
    let text = read_text(path, &display, crate::scene::files::MAX_MTL_BYTES)?;
    let mut warnings = Vec::new();
    let dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
    let raws = parse_mtl_str(&text, &display, &dir, &mut warnings)?;
    let mut cache = TextureCache::default();
    let materials = raws.iter().map(|raw| resolve_material(raw, &mut cache, &mut warnings)).collect();
    Ok(MtlLibrary { materials, textures: cache.textures, warnings })
}

pub(super) use crate::scene::textures::io_reason;

/// Reads a text file, errors naming it (with the line of invalid UTF-8).
pub(super) fn read_text(path: &Path, display: &str, limit: u64) -> Result<String, ObjError> {
    let bytes = crate::scene::files::read_bounded(path, limit).map_err(|e| ObjError::Io {
        path: display.to_string(),
        message: format!("cannot read file: {}", io_reason(&e)),
    })?;
    decode_utf8(bytes, display)
}

/// UTF-8 check (a leading byte-order mark is dropped).
pub(super) fn decode_utf8(bytes: Vec<u8>, display: &str) -> Result<String, ObjError> {
    match String::from_utf8(bytes) {
        Ok(s) => Ok(s.strip_prefix('\u{feff}').map(str::to_string).unwrap_or(s)),
        Err(e) => {
            let at = e.utf8_error().valid_up_to();
            let bytes = e.as_bytes();
            let line = 1 + bytes[..at].iter().filter(|&&b| b == b'\n').count();
            Err(ObjError::Parse {
                path: display.to_string(),
                line,
                message: format!("invalid UTF-8 (byte offset {at}); not a text OBJ/MTL file?"),
            })
        }
    }
}

fn strip_comment(s: &str) -> &str {
    match s.find('#') {
        Some(i) => &s[..i],
        None => s,
    }
}

fn parse_number(tok: &str, key: &str) -> Result<f32, String> {
    let x: f32 = tok.parse().map_err(|_| format!("bad number '{}' in {key}", shorten(tok)))?;
    if !x.is_finite() {
        return Err(format!("non-finite number '{}' in {key}", shorten(tok)));
    }
    Ok(x)
}

/// Parses "r g b" as written by the line pass.
fn parse_rgb(s: &str) -> Option<Vec3> {
    let v: Vec<f32> = s.split_whitespace().filter_map(|t| t.parse().ok()).collect();
    match v[..] {
        [r, g, b, ..] => Some(Vec3::new(r, g, b)),
        [x] => Some(Vec3::splat(x)),
        _ => None,
    }
}

fn to_vec3(c: Option<[f32; 3]>) -> Option<Vec3> {
    c.map(Vec3::from_array)
}

/// Parses MTL text into materials. `dir` is the folder texture paths are relative to.
// Long on purpose: One arm per MTL keyword, in one loop over the lines: a lexer reads best as one match.
pub(super) fn parse_mtl_str(
    text: &str,
    display: &str,
    dir: &Path,
    warnings: &mut Vec<String>,
) -> Result<Vec<RawMaterial>, ObjError> {
    let mut clean = String::with_capacity(text.len());
    let mut ignored: Vec<String> = Vec::new();
    // The material being defined, the placement of each material's map_Kd, its PBR
    // keys and the textures on its other inputs.
    let mut current: Option<String> = None;
    let mut placements: HashMap<String, TexMap> = HashMap::new();
    let mut pbr_keys: HashMap<String, PbrKeys> = HashMap::new();
    let mut maps: HashMap<String, Vec<(Slot, MapArg)>> = HashMap::new();
    for (i, raw) in text.split('\n').enumerate() {
        let line_no = i + 1;
        let err = |message: String| ObjError::Parse { path: display.to_string(), line: line_no, message };
        let trimmed = raw.trim();
        let keyword = trimmed.split_whitespace().next().unwrap_or("");
        let rest = trimmed[keyword.len()..].trim();
        let lower = keyword.to_ascii_lowercase();
        match lower.as_str() {
            "" => {}
            k if k.starts_with('#') => {}
            "newmtl" => {
                if rest.is_empty() {
                    return Err(err("newmtl without a material name".into()));
                }
                clean.push_str("newmtl ");
                clean.push_str(rest);
                current = Some(rest.to_string());
            }
            "ka" | "kd" | "ks" | "ke" | "tf" => {
                let key = match lower.as_str() {
                    "ka" => "Ka",
                    "kd" => "Kd",
                    "ks" => "Ks",
                    "ke" => "Ke",
                    _ => "Tf",
                };
                let toks: Vec<&str> = strip_comment(rest).split_whitespace().collect();
                if toks.first().is_some_and(|t| t.eq_ignore_ascii_case("spectral") || t.eq_ignore_ascii_case("xyz")) {
                    warnings.push(format!("{display}:{line_no}: {key} {} colours are not supported, ignored", toks[0]));
                } else {
                    for tok in toks.iter().take(3) {
                        parse_number(tok, key).map_err(&err)?;
                    }
                    match toks.len() {
                        1 => clean.push_str(&format!("{key} {0} {0} {0}", toks[0])),
                        n if n >= 3 => clean.push_str(&format!("{key} {} {} {}", toks[0], toks[1], toks[2])),
                        n => return Err(err(format!("{key} needs 1 or 3 numbers, found {n}"))),
                    }
                }
            }
            "ns" | "ni" | "d" | "tr" => {
                let key = match lower.as_str() {
                    "ns" => "Ns",
                    "ni" => "Ni",
                    "d" => "d",
                    _ => "Tr",
                };
                let tok = strip_comment(rest)
                    .split_whitespace()
                    .find(|t| !t.eq_ignore_ascii_case("-halo"))
                    .ok_or_else(|| err(format!("{key} needs a number")))?;
                parse_number(tok, key).map_err(&err)?;
                clean.push_str(&format!("{key} {tok}"));
            }
            "illum" => {
                let tok = strip_comment(rest).split_whitespace().next().unwrap_or("");
                let model: u8 =
                    tok.parse().map_err(|_| err(format!("illum needs an integer 0-255, found '{}'", shorten(tok))))?;
                clean.push_str(&format!("illum {model}"));
            }
            "pr" | "pm" | "ps" | "pc" | "pcr" | "aniso" | "anisor" | "pt" => {
                let key = pbr_key_name(&lower);
                let tok = strip_comment(rest)
                    .split_whitespace()
                    .next()
                    .ok_or_else(|| err(format!("{key} needs a number")))?;
                let x = parse_number(tok, key).map_err(&err)?;
                if let Some(material) = &current {
                    pbr_keys.entry(material.clone()).or_default().set(&lower, x);
                }
            }
            "map_pr" | "map_pm" | "map_ps" | "map_pc" | "map_pt" | "map_d" | "map_ke" | "norm" | "map_bump"
            | "bump" => {
                let slot = match lower.as_str() {
                    "map_pr" => Slot::Roughness,
                    "map_pm" => Slot::Metallic,
                    "map_ps" => Slot::Sheen,
                    "map_pc" => Slot::Coat,
                    "map_pt" => Slot::Transmission,
                    "map_d" => Slot::Alpha,
                    "map_ke" => Slot::Emission,
                    "norm" => Slot::Normal,
                    _ => Slot::Bump,
                };
                match parse_map_arg(rest) {
                    None => warnings.push(format!("{display}:{line_no}: {keyword} without a file name, ignored")),
                    Some(arg) => {
                        let skipped = skipped_options(&arg, matches!(slot, Slot::Normal | Slot::Bump));
                        if !skipped.is_empty() {
                            warnings.push(format!(
                                "{display}:{line_no}: {keyword} options {} are not supported and were skipped",
                                skipped.join(", ")
                            ));
                        }
                        if let Some(material) = &current {
                            maps.entry(material.clone()).or_default().push((slot, arg));
                        }
                    }
                }
            }
            "map_kd" => match parse_map_arg(rest) {
                None => warnings.push(format!("{display}:{line_no}: map_Kd without a file name, ignored")),
                Some(arg) => {
                    let skipped = skipped_options(&arg, false);
                    if !skipped.is_empty() {
                        warnings.push(format!(
                            "{display}:{line_no}: map_Kd options {} are not supported and were skipped",
                            skipped.join(", ")
                        ));
                    }
                    clean.push_str("map_Kd ");
                    clean.push_str(&arg.name);
                    if let Some(material) = &current {
                        placements.insert(material.clone(), arg.map);
                    }
                }
            },
            _ => {
                let key = shorten(keyword);
                if !ignored.contains(&key) && ignored.len() < 16 {
                    ignored.push(key);
                }
            }
        }
        clean.push('\n');
    }
    if !ignored.is_empty() {
        warnings.push(format!("{display}: ignored unsupported statements: {}", ignored.join(", ")));
    }

    let (materials, _) = tobj::load_mtl_buf(&mut Cursor::new(clean.as_bytes()))
        .map_err(|e| ObjError::Io { path: display.to_string(), message: format!("MTL parser (tobj): {e}") })?;
    Ok(materials
        .into_iter()
        .map(|m| {
            let param = |k: &str| m.unknown_param.get(k).and_then(|s| parse_rgb(s));
            let d = m.dissolve.or_else(|| param("Tr").map(|tr| 1.0 - tr.x));
            let keys = pbr_keys.get(&m.name).copied().unwrap_or_default();
            let maps = maps.get(&m.name).cloned().unwrap_or_default();
            let mut desc = MaterialDesc {
                name: m.name.clone(),
                ka: to_vec3(m.ambient).unwrap_or(Vec3::ZERO),
                kd: to_vec3(m.diffuse).unwrap_or(Vec3::ZERO),
                ks: to_vec3(m.specular).unwrap_or(Vec3::ZERO),
                ke: to_vec3(m.emissive).or_else(|| param("Ke")).unwrap_or(Vec3::ZERO),
                tf: param("Tf").unwrap_or(Vec3::ONE),
                ns: m.shininess.unwrap_or(0.0),
                ni: m.optical_density.unwrap_or(1.0),
                d: d.unwrap_or(1.0),
                illum: m.illumination_model.map(u32::from),
                ..MaterialDesc::default()
            };
            if keys.principled() {
                desc.pbr = Some(keys.pbr_desc(&desc, m.optical_density));
            }
            // `-bm` on a normal or bump map is its strength.
            for (slot, arg) in &maps {
                match slot {
                    Slot::Normal => desc.bumps.normal_strength = arg.bm.unwrap_or(1.0),
                    Slot::Bump => desc.bumps.bump_strength = arg.bm.unwrap_or(1.0),
                    _ => {}
                }
            }
            let map_kd = m.diffuse_texture.as_deref().map(|t| t.trim().to_string()).filter(|t| !t.is_empty());
            let map_kd_placement = placements.get(&m.name).copied().unwrap_or_default();
            RawMaterial { desc, map_kd, map_kd_placement, maps, dir: dir.to_path_buf(), mtl: display.to_string() }
        })
        .collect())
}

/// The options of `arg` that have no effect: those [`parse_map_arg`] skipped, and `-bm`
/// unless the map is a normal or bump map.
fn skipped_options(arg: &MapArg, bumps: bool) -> Vec<String> {
    let mut skipped = arg.skipped.clone();
    if let (Some(bm), false) = (arg.bm, bumps) {
        skipped.push(format!("-bm {bm}"));
    }
    skipped
}

/// A `map_Kd` argument: the file name, the options that place the image, and the options
/// that are read past without effect (named in a warning).
#[derive(Clone, Debug, PartialEq)]
pub(super) struct MapArg {
    pub name: String,
    pub map: TexMap,
    /// `-bm`: a bump or normal map's strength.
    pub bm: Option<f32>,
    pub skipped: Vec<String>,
}

/// Parses a `map_Kd` argument: `-s u [v [w]]` and `-o u [v [w]]` (uv scale and offset)
/// and `-clamp on|off` are honoured; the other MTL options (`-bm`, `-mm`, `-blendu`, ...)
/// are skipped with their values and listed in `skipped`. `None` when no file name is left.
pub(super) fn parse_map_arg(arg: &str) -> Option<MapArg> {
    let mut rest = arg.trim();
    let mut map = TexMap::default();
    let mut skipped = Vec::new();
    let mut bm = None;
    loop {
        let opt = rest.split_whitespace().next()?;
        let (min, max) = match opt {
            "-blendu" | "-blendv" | "-cc" | "-clamp" | "-bm" | "-boost" | "-texres" | "-imfchan" | "-type" => (1, 1),
            "-mm" => (2, 2),
            "-o" | "-s" | "-t" => (1, 3),
            _ => break,
        };
        rest = rest[opt.len()..].trim_start();
        let mut values: Vec<&str> = Vec::new();
        while values.len() < max {
            let Some(tok) = rest.split_whitespace().next() else { break };
            // -o/-s/-t take 1 to 3 numbers; stop at the first non-number after the first.
            if values.len() >= min && tok.parse::<f32>().is_err() {
                break;
            }
            values.push(tok);
            rest = rest[tok.len()..].trim_start();
        }
        let numbers: Vec<f32> = values.iter().filter_map(|v| v.parse().ok()).filter(|x: &f32| x.is_finite()).collect();
        let uv = |default: f32| {
            let u = numbers.first().copied().unwrap_or(default);
            Vec2::new(u, numbers.get(1).copied().unwrap_or(default))
        };
        match opt {
            "-s" if numbers.len() == values.len() => map.scale = uv(1.0),
            "-o" if numbers.len() == values.len() => map.offset = uv(0.0),
            "-clamp" if values.first().is_some_and(|v| v.eq_ignore_ascii_case("on")) => map.clamp = true,
            "-clamp" if values.first().is_some_and(|v| v.eq_ignore_ascii_case("off")) => {}
            "-bm" if numbers.len() == 1 => bm = numbers.first().copied(),
            _ => skipped.push(format!("{opt} {}", values.join(" ")).trim().to_string()),
        }
    }
    let name = rest.trim();
    (!name.is_empty()).then(|| MapArg { name: name.to_string(), map, bm, skipped })
}

/// `dir/name`, tolerating Windows separators in `name` when the file is not found as written.
pub(super) fn resolve_path(dir: &Path, name: &str) -> PathBuf {
    let direct = dir.join(name);
    if !direct.exists() && name.contains('\\') {
        let alt = dir.join(name.replace('\\', "/"));
        if alt.exists() {
            return alt;
        }
    }
    direct
}

/// The final material: its texture loaded (or, when that fails, a warning, and the
/// material keeps its own `Kd`).
pub(super) fn resolve_material(
    raw: &RawMaterial,
    cache: &mut TextureCache,
    warnings: &mut Vec<String>,
) -> MaterialDesc {
    let mut desc = raw.desc.clone();
    if let Some(name) = &raw.map_kd {
        let path = resolve_path(&raw.dir, name);
        match cache.get(&path, raw.map_kd_placement, Decode { srgb: true, alpha: false }) {
            Ok(i) => desc.map_kd = Some(i),
            Err(e) => {
                warnings.push(format!(
                    "{}: material '{}': map_Kd texture '{}' could not be loaded ({e}); using its Kd without a texture",
                    raw.mtl,
                    desc.name,
                    super::shown_beside(&raw.mtl, name)
                ));
                desc.map_kd = None;
            }
        }
    }
    for (slot, arg) in &raw.maps {
        let path = resolve_path(&raw.dir, &arg.name);
        match cache.get(&path, arg.map, Decode { srgb: slot.is_colour(), alpha: false }) {
            Ok(i) => desc.maps.set(*slot, Some(i)),
            Err(e) => warnings.push(format!(
                "{}: material '{}': {} texture '{}' could not be loaded ({e}); using the value without a texture",
                raw.mtl,
                desc.name,
                slot.names().0,
                super::shown_beside(&raw.mtl, &arg.name)
            )),
        }
    }
    desc
}
