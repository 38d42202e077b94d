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

/// Writes `image` to `path`: `.exr` for HDR data, `.png` for a tone-mapped preview.
pub fn write_image(image: &Image, path: &Path) -> Result<(), OutputError> {
    match path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
        Some("exr") => write_exr(image, path),
        Some("png") => write_png(image, path),
        _ => Err(OutputError::Format { path: path.display().to_string() }),
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
    fn tonemap_is_srgb_and_safe() {
        assert_eq!(tonemap(Vec3::new(0.0, 1.0, 5.0)), [0, 255, 255]);
        assert_eq!(tonemap(Vec3::splat(0.5))[0], 188);
        assert_eq!(tonemap(Vec3::new(f32::NAN, -1.0, f32::INFINITY)), [0, 0, 0]);
    }
}
