//! MTL material libraries and their `map_Kd` textures.
//!
//! A line pass validates numbers (with line numbers), expands one-value colours (`Ks 0.5`)
//! to three, and keeps only the statements used; tobj then parses the result.

use std::collections::HashMap;
use std::io::Cursor;
use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};

use super::ObjError;
use super::scan::shorten;
use crate::material::MaterialDesc;
use crate::math;
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

/// An I/O error in plain words, without the OS's error number.
pub(super) fn io_reason(e: &std::io::Error) -> String {
    match e.kind() {
        std::io::ErrorKind::NotFound => "no such file".into(),
        std::io::ErrorKind::PermissionDenied => "permission denied".into(),
        _ => {
            let s = e.to_string();
            s.split(" (os error").next().unwrap_or(&s).to_string()
        }
    }
}

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
    // The material being defined, and the placement of each material's map_Kd.
    let mut current: Option<String> = None;
    let mut placements: HashMap<String, TexMap> = HashMap::new();
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
            "map_kd" => match parse_map_arg(rest) {
                None => warnings.push(format!("{display}:{line_no}: map_Kd without a file name, ignored")),
                Some(arg) => {
                    if !arg.skipped.is_empty() {
                        warnings.push(format!(
                            "{display}:{line_no}: map_Kd options {} are not supported and were skipped",
                            arg.skipped.join(", ")
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
            let desc = MaterialDesc {
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
                map_kd: None,
            };
            let map_kd = m.diffuse_texture.as_deref().map(|t| t.trim().to_string()).filter(|t| !t.is_empty());
            let map_kd_placement = placements.get(&m.name).copied().unwrap_or_default();
            RawMaterial { desc, map_kd, map_kd_placement, dir: dir.to_path_buf(), mtl: display.to_string() }
        })
        .collect())
}

/// A `map_Kd` argument: the file name, the options that place the image, and the options
/// that are read past without effect (named in a warning).
#[derive(Clone, Debug, PartialEq)]
pub(super) struct MapArg {
    pub name: String,
    pub map: TexMap,
    pub skipped: Vec<String>,
}

/// Parses a `map_Kd` argument: `-s u [v [w]]` and `-o u [v [w]]` (uv scale and offset)
/// and `-clamp on|off` are honoured; the other MTL options (`-bm`, `-mm`, `-blendu`, ...)
/// are skipped with their values and listed in `skipped`. `None` when no file name is left.
pub(super) fn parse_map_arg(arg: &str) -> Option<MapArg> {
    let mut rest = arg.trim();
    let mut map = TexMap::default();
    let mut skipped = Vec::new();
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
            _ => skipped.push(format!("{opt} {}", values.join(" ")).trim().to_string()),
        }
    }
    let name = rest.trim();
    (!name.is_empty()).then(|| MapArg { name: name.to_string(), map, skipped })
}

/// Decoded textures, one per distinct path and placement (an image is decoded once).
#[derive(Default)]
pub(super) struct TextureCache {
    pub textures: Vec<Texture>,
    by_path: HashMap<PathBuf, Result<Vec<u32>, String>>,
}

impl TextureCache {
    fn get(&mut self, path: &Path, map: TexMap) -> Result<u32, String> {
        let key = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
        let known = match self.by_path.get(&key) {
            Some(Err(e)) => return Err(e.clone()),
            Some(Ok(known)) => known.clone(),
            None => match decode_texture(path) {
                Ok(tex) => {
                    self.textures.push(tex);
                    vec![self.textures.len() as u32 - 1]
                }
                Err(e) => {
                    self.by_path.insert(key, Err(e.clone()));
                    return Err(e);
                }
            },
        };
        let index = match known.iter().find(|&&i| self.textures[i as usize].map == map) {
            Some(&i) => i,
            None => {
                let placed = Texture { map, ..self.textures[known[0] as usize].clone() };
                self.textures.push(placed);
                self.textures.len() as u32 - 1
            }
        };
        let mut known = known;
        if !known.contains(&index) {
            known.push(index);
        }
        self.by_path.insert(key, Ok(known));
        Ok(index)
    }
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
        match cache.get(&path, raw.map_kd_placement) {
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
    desc
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { math::powf((c + 0.055) / 1.055, 2.4) }
}

fn clean_texel(c: Vec3) -> Vec3 {
    Vec3::new(
        if c.x.is_finite() { c.x.max(0.0) } else { 0.0 },
        if c.y.is_finite() { c.y.max(0.0) } else { 0.0 },
        if c.z.is_finite() { c.z.max(0.0) } else { 0.0 },
    )
}

/// Decodes an image into linear RGB (8/16-bit images are sRGB-encoded; float images such
/// as `.hdr` are already linear). Alpha is ignored.
pub(super) fn decode_texture(path: &Path) -> Result<Texture, String> {
    use crate::scene::files::{MAX_TEXTURE_BYTES, check_regular};
    use image::DynamicImage;
    check_regular(path, MAX_TEXTURE_BYTES).map_err(|e| io_reason(&e))?;
    let mut reader =
        image::ImageReader::open(path).map_err(|e| io_reason(&e))?.with_guessed_format().map_err(|e| e.to_string())?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_TEXTURE_BYTES);
    reader.limits(limits);
    let img = reader.decode().map_err(|e| e.to_string())?;
    let (width, height) = (img.width(), img.height());
    let texels: Vec<Vec3> = match &img {
        DynamicImage::ImageRgb32F(_) | DynamicImage::ImageRgba32F(_) => {
            img.to_rgb32f().pixels().map(|p| clean_texel(Vec3::new(p[0], p[1], p[2]))).collect()
        }
        DynamicImage::ImageLuma8(_)
        | DynamicImage::ImageLumaA8(_)
        | DynamicImage::ImageRgb8(_)
        | DynamicImage::ImageRgba8(_) => {
            let lut: Vec<f32> = (0..=255u8).map(|b| srgb_to_linear(f32::from(b) / 255.0)).collect();
            let f = |b: u8| lut[usize::from(b)];
            img.to_rgb8().pixels().map(|p| Vec3::new(f(p[0]), f(p[1]), f(p[2]))).collect()
        }
        _ => img
            .to_rgb32f()
            .pixels()
            .map(|p| clean_texel(Vec3::new(srgb_to_linear(p[0]), srgb_to_linear(p[1]), srgb_to_linear(p[2]))))
            .collect(),
    };
    if width == 0 || height == 0 || texels.len() != width as usize * height as usize {
        return Err("empty image".into());
    }
    Ok(Texture { width, height, texels, map: TexMap::default() })
}
