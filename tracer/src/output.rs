//! Writing images: OpenEXR (linear RGBA float32 plus a per-pixel sample count channel)
//! and PNG (an sRGB tone-mapped preview). Chosen by the output path's extension.

use std::path::Path;

use glam::Vec3;

use crate::film::Image;
use crate::math;

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("{path}: unsupported output format (use .exr or .png)")]
    Format { path: String },
    #[error("{path}: {message}")]
    Write { path: String, message: String },
    #[error("{path}: {message}")]
    Read { path: String, message: String },
}

/// The output formats, by the path's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Exr,
    Png,
}

impl Format {
    pub fn of(path: &Path) -> Result<Self, OutputError> {
        match path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
            Some("exr") => Ok(Self::Exr),
            Some("png") => Ok(Self::Png),
            _ => Err(OutputError::Format { path: path.display().to_string() }),
        }
    }
}

/// Checks before a render that `path` can be written — a known extension, an existing
/// folder that accepts a new file, not a folder itself — so that a typo in `-o` fails at
/// once instead of throwing the finished render away.
pub fn check_output_path(path: &Path) -> Result<Format, OutputError> {
    let format = Format::of(path)?;
    let shown = path.display().to_string();
    let fail = |message: String| OutputError::Write { path: shown.clone(), message };
    if path.is_dir() {
        return Err(fail("is a folder; give a file name ending in .exr or .png".into()));
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !parent.is_dir() {
        return Err(fail(format!("the folder {} does not exist", parent.display())));
    }
    // Only creating a file proves that the folder takes one (permissions, a read-only
    // mount, ACLs): a probe beside the output, removed at once.
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let probe = parent.join(format!(".{name}.{}.probe", std::process::id()));
    match std::fs::OpenOptions::new().write(true).create_new(true).open(&probe) {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
            Ok(format)
        }
        Err(e) => Err(fail(format!("cannot write in {}: {e}", parent.display()))),
    }
}

/// Writes `image` to `path`: `.exr` for HDR data, `.png` for a tone-mapped preview.
pub fn write_image(image: &Image, path: &Path) -> Result<(), OutputError> {
    match Format::of(path)? {
        Format::Exr => write_exr(image, path),
        Format::Png => write_png(image, path),
    }
}

/// Linear float32 R, G, B, A (= 1) and `samples` (u32) channels, lossless ZIP.
pub fn write_exr(image: &Image, path: &Path) -> Result<(), OutputError> {
    let bytes = exr_bytes(image).map_err(|message| OutputError::Write { path: path.display().to_string(), message })?;
    std::fs::write(path, bytes)
        .map_err(|e| OutputError::Write { path: path.display().to_string(), message: e.to_string() })
}

/// The EXR file of [`write_exr`] in memory (for sending over the network).
pub fn exr_bytes(image: &Image) -> Result<Vec<u8>, String> {
    use exr::prelude::*;
    let size = (image.width as usize, image.height as usize);
    let channel = |name: &str, f: &dyn Fn(&Vec3) -> f32| {
        AnyChannel::new(name, FlatSamples::F32(image.pixels.iter().map(f).collect()))
    };
    let channels = vec![
        channel("R", &|p| p.x),
        channel("G", &|p| p.y),
        channel("B", &|p| p.z),
        channel("A", &|_| 1.0),
        AnyChannel::new("samples", FlatSamples::U32(image.counts.clone())),
    ];
    let layer = Layer::new(
        size,
        LayerAttributes::named("tilefarm"),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(channels.into()),
    );
    let mut out = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer).write().to_buffered(&mut out).map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

/// Reads back what [`write_exr`] wrote (RGB and the sample counts, if present).
pub fn read_exr(path: &Path) -> Result<Image, OutputError> {
    use exr::prelude::*;
    let err = |e: exr::error::Error| OutputError::Read { path: path.display().to_string(), message: e.to_string() };
    let img = read_first_flat_layer_from_file(path).map_err(err)?;
    let layer = &img.layer_data;
    let (w, h) = (layer.size.width() as u32, layer.size.height() as u32);
    let mut out = crate::film::Image::new(w, h);
    for ch in &layer.channel_data.list {
        let name = ch.name.to_string();
        let values: Vec<f32> = ch.sample_data.values_as_f32().collect();
        for (i, v) in values.into_iter().enumerate() {
            match name.as_str() {
                "R" => out.pixels[i].x = v,
                "G" => out.pixels[i].y = v,
                "B" => out.pixels[i].z = v,
                "samples" => out.counts[i] = v as u32,
                _ => {}
            }
        }
    }
    Ok(out)
}

/// sRGB opto-electronic transfer function.
#[inline]
fn srgb_encode(linear: f32) -> f32 {
    if linear <= 0.0031308 { 12.92 * linear } else { 1.055 * math::powf(linear, 1.0 / 2.4) - 0.055 }
}

/// Tone maps linear radiance to 8-bit sRGB: clamp to [0, 1] at exposure 1, then the sRGB
/// curve — what a viewer shows for an EXR at default exposure.
pub fn tonemap(p: Vec3) -> [u8; 3] {
    let q = |v: f32| {
        let v = if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
        (srgb_encode(v) * 255.0 + 0.5) as u8
    };
    [q(p.x), q(p.y), q(p.z)]
}

pub fn write_png(image: &Image, path: &Path) -> Result<(), OutputError> {
    let mut buf = Vec::with_capacity(image.pixels.len() * 3);
    for p in &image.pixels {
        buf.extend_from_slice(&tonemap(*p));
    }
    image::save_buffer(path, &buf, image.width, image.height, image::ColorType::Rgb8)
        .map_err(|e| OutputError::Write { path: path.display().to_string(), message: e.to_string() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exr_round_trips_bits_and_counts() {
        let mut img = crate::film::Image::new(3, 2);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = Vec3::new(i as f32 * 0.1 + 1e-8, 1234.5678, 1.0 / 3.0);
        }
        img.counts = vec![1, 2, 3, 4, 5, 6];
        let dir = std::env::temp_dir().join(format!("tilefarm-exr-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.exr");
        write_image(&img, &path).unwrap();
        let back = read_exr(&path).unwrap();
        assert_eq!(back, img);
        write_image(&img, &dir.join("t.png")).unwrap();
        assert!(write_image(&img, &dir.join("t.bmpx")).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn output_paths_are_checked_before_rendering() {
        let dir = std::env::temp_dir().join(format!("tilefarm-outcheck-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert_eq!(check_output_path(&dir.join("a.EXR")).unwrap(), Format::Exr);
        assert_eq!(check_output_path(&dir.join("a.png")).unwrap(), Format::Png);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "the probe file is removed");
        let e = check_output_path(&dir.join("a.jpg")).unwrap_err().to_string();
        assert!(e.contains("a.jpg") && e.contains(".exr or .png"), "{e}");
        let e = check_output_path(&dir.join("no-such-folder/a.exr")).unwrap_err().to_string();
        assert!(e.contains("no-such-folder") && e.contains("does not exist"), "{e}");
        std::fs::create_dir_all(dir.join("d.exr")).unwrap();
        assert!(check_output_path(&dir.join("d.exr")).unwrap_err().to_string().contains("is a folder"));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn tonemap_is_srgb_and_safe() {
        assert_eq!(tonemap(Vec3::new(0.0, 1.0, 5.0)), [0, 255, 255]);
        assert_eq!(tonemap(Vec3::splat(0.5))[0], 188);
        assert_eq!(tonemap(Vec3::new(f32::NAN, -1.0, f32::INFINITY)), [0, 0, 0]);
    }
}
