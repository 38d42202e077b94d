//! Decoding image textures, once per file: the MTL loader and the scene's material
//! table both go through a [`TextureCache`], so materials that use the same file share
//! its decoding.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::Vec3;

use crate::math;
use crate::texture::{TexMap, Texture};

/// How an image's values become texels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Decode {
    /// Colour data: 8- and 16-bit images are sRGB-encoded (floating-point images are
    /// linear either way). Off: non-colour data, read as stored.
    pub srgb: bool,
    /// Read the image's alpha channel (into all three channels) instead of its colour.
    pub alpha: bool,
}

/// Decoded textures, one per distinct file, decoding and placement.
#[derive(Default)]
pub struct TextureCache {
    pub textures: Vec<Texture>,
    by_path: HashMap<(PathBuf, Decode), Result<Vec<u32>, String>>,
}

impl TextureCache {
    /// The index of `path` decoded as `decode` and placed by `map` (decoded on first use).
    pub fn get(&mut self, path: &Path, map: TexMap, decode: Decode) -> Result<u32, String> {
        let key = (std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()), decode);
        let known = match self.by_path.get(&key) {
            Some(Err(e)) => return Err(e.clone()),
            Some(Ok(known)) => known.clone(),
            None => match decode_texture(path, decode) {
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

/// An I/O error in plain words, without the OS's error number.
pub fn io_reason(e: &std::io::Error) -> String {
    match e.kind() {
        std::io::ErrorKind::NotFound => "no such file".into(),
        std::io::ErrorKind::PermissionDenied => "permission denied".into(),
        _ => {
            let s = e.to_string();
            s.split(" (os error").next().unwrap_or(&s).to_string()
        }
    }
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { math::powf((c + 0.055) / 1.055, 2.4) }
}

fn clean(x: f32) -> f32 {
    if x.is_finite() { x.max(0.0) } else { 0.0 }
}

fn clean_texel(c: Vec3) -> Vec3 {
    Vec3::new(clean(c.x), clean(c.y), clean(c.z))
}

/// Decodes an image into linear RGB texels (see [`Decode`]).
pub fn decode_texture(path: &Path, decode: Decode) -> Result<Texture, String> {
    decode_image(path, decode, crate::scene::files::MAX_TEXTURE_BYTES, None)
}

/// [`decode_texture`] within `max_bytes` of file and of decoding memory, and, with
/// `max_size`, at most that many texels wide and high.
pub fn decode_image(
    path: &Path,
    decode: Decode,
    max_bytes: u64,
    max_size: Option<(u32, u32)>,
) -> Result<Texture, String> {
    use crate::scene::files::check_regular;
    use image::DynamicImage;
    check_regular(path, max_bytes).map_err(|e| io_reason(&e))?;
    let mut reader =
        image::ImageReader::open(path).map_err(|e| io_reason(&e))?.with_guessed_format().map_err(|e| e.to_string())?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(max_bytes);
    if let Some((w, h)) = max_size {
        (limits.max_image_width, limits.max_image_height) = (Some(w), Some(h));
    }
    reader.limits(limits);
    let img = reader.decode().map_err(|e| e.to_string())?;
    let (width, height) = (img.width(), img.height());
    let float = matches!(img, DynamicImage::ImageRgb32F(_) | DynamicImage::ImageRgba32F(_));
    let texels: Vec<Vec3> = if decode.alpha {
        // Alpha is linear coverage in every format.
        img.to_rgba32f().pixels().map(|p| Vec3::splat(clean(p[3]).min(1.0))).collect()
    } else if float || !decode.srgb {
        img.to_rgb32f().pixels().map(|p| clean_texel(Vec3::new(p[0], p[1], p[2]))).collect()
    } else if matches!(
        img,
        DynamicImage::ImageLuma8(_)
            | DynamicImage::ImageLumaA8(_)
            | DynamicImage::ImageRgb8(_)
            | DynamicImage::ImageRgba8(_)
    ) {
        let lut: Vec<f32> = (0..=255u8).map(|b| srgb_to_linear(f32::from(b) / 255.0)).collect();
        let f = |b: u8| lut[usize::from(b)];
        img.to_rgb8().pixels().map(|p| Vec3::new(f(p[0]), f(p[1]), f(p[2]))).collect()
    } else {
        img.to_rgb32f()
            .pixels()
            .map(|p| clean_texel(Vec3::new(srgb_to_linear(p[0]), srgb_to_linear(p[1]), srgb_to_linear(p[2]))))
            .collect()
    };
    if width == 0 || height == 0 || texels.len() != width as usize * height as usize {
        return Err("empty image".into());
    }
    Ok(Texture { width, height, texels, map: TexMap::default() })
}
