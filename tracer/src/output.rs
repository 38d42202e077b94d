//! Writing images: OpenEXR (linear RGBA float32 plus a per-pixel sample count channel)
//! and PNG (an sRGB tone-mapped preview). Chosen by the output path's extension.

use std::path::Path;

use glam::Vec3;

use crate::film::{Image, Pixels};
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

/// [`check_output_path`] for an image and its optional preview, which must be a PNG.
pub fn check_output_paths(output: &Path, preview: Option<&Path>) -> Result<(), OutputError> {
    check_output_path(output)?;
    if let Some(p) = preview
        && check_output_path(p)? != Format::Png
    {
        return Err(OutputError::Write {
            path: p.display().to_string(),
            message: "a preview is a PNG: give a path ending in .png".into(),
        });
    }
    Ok(())
}

/// Writes `image` to `path`: `.exr` for HDR data, `.png` for a tone-mapped preview.
pub fn write_image(image: &Image, path: &Path) -> Result<(), OutputError> {
    write_image_with(image, None, path)
}

/// [`write_image`] from any pixel source, an EXR's header recording `info`. An EXR is
/// encoded straight from the source, block by block, into the file: a render as large
/// as memory allows is written without a second copy of it.
pub fn write_image_with(image: &impl Pixels, info: Option<&RenderInfo>, path: &Path) -> Result<(), OutputError> {
    match Format::of(path)? {
        Format::Exr => write_exr_with(image, info, path),
        Format::Png => write_png(&Image::of(image), path),
    }
}

/// What made an image, recorded in its EXR header.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RenderInfo {
    /// The scene file, as the user named it.
    pub scene: String,
    /// Samples per pixel asked for.
    pub spp: u32,
    pub max_depth: i32,
    pub seed: u64,
    /// The firefly clamp, if one was on (the image is then biased).
    pub clamp: Option<f32>,
    /// Adaptive sampling's noise target, if it was on.
    pub noise: Option<f32>,
    pub integrator: String,
    /// Wall-clock time of the render so far.
    pub seconds: f64,
    /// OpenEXR's `worldToCamera` and `worldToNDC` (see [`crate::camera::Camera`]).
    pub world_to_camera: [f32; 16],
    pub world_to_ndc: [f32; 16],
}

impl RenderInfo {
    /// Everything but the time, from the scene as it is rendered.
    pub fn of(scene: &crate::scene::Scene, name: &str, integrator: &str) -> Self {
        Self::of_view(&scene.camera, &scene.settings, name, integrator)
    }

    /// [`RenderInfo::of`] a scene's camera and settings (a checked scene has no other).
    pub fn of_view(
        camera: &crate::camera::Camera,
        settings: &crate::scene::RenderSettings,
        name: &str,
        integrator: &str,
    ) -> Self {
        Self {
            scene: name.to_string(),
            spp: settings.spp,
            max_depth: settings.max_depth,
            seed: settings.seed,
            clamp: settings.clamp,
            noise: settings.noise,
            integrator: integrator.to_string(),
            seconds: 0.0,
            world_to_camera: camera.world_to_camera().to_cols_array(),
            world_to_ndc: camera.world_to_ndc().to_cols_array(),
        }
    }
}

pub mod views;

/// The header attributes' names for what has no standard one.
pub mod keys {
    pub const SPP: &str = "tilefarm/spp";
    pub const SPP_REACHED: &str = "tilefarm/sppReached";
    pub const MAX_DEPTH: &str = "tilefarm/maxDepth";
    pub const SEED: &str = "tilefarm/seed";
    pub const INTEGRATOR: &str = "tilefarm/integrator";
    pub const RENDER_SECONDS: &str = "tilefarm/renderSeconds";
    pub const SCENE: &str = "tilefarm/scene";
    /// Present only when a clamp was on: its limit.
    pub const CLAMP: &str = "tilefarm/clamp";
    /// Present only when adaptive sampling was on: its noise target (the `samples`
    /// channel shows where the samples went).
    pub const NOISE: &str = "tilefarm/noiseTarget";
    /// Present only when the file holds a denoised layer: the denoiser that made it.
    pub const DENOISER: &str = "tilefarm/denoiser";
}

/// Linear float32 R, G, B, A (= 1) and `samples` (u32) channels, lossless ZIP.
pub fn write_exr(image: &Image, path: &Path) -> Result<(), OutputError> {
    write_exr_with(image, None, path)
}

/// [`write_exr`] from any pixel source, its header recording `info`.
pub fn write_exr_with(image: &impl Pixels, info: Option<&RenderInfo>, path: &Path) -> Result<(), OutputError> {
    let fail = |message: String| OutputError::Write { path: path.display().to_string(), message };
    let file = std::fs::File::create(path).map_err(|e| fail(e.to_string()))?;
    let mut out = std::io::BufWriter::new(file);
    write_exr_to(image, info, &mut out).map_err(fail)?;
    use std::io::Write;
    out.flush().map_err(|e| fail(e.to_string()))
}

/// The EXR file of [`write_exr_with`] in memory (for sending over the network).
///
/// Channels: `R`, `G`, `B` (linear Rec. 709 radiance, the mean of each pixel's samples),
/// `A` (1), and `samples`, each pixel's sample count (u32; fewer than the header's spp
/// where a render was stopped early). The header: `software`, `chromaticities` (Rec. 709
/// primaries, D65: sRGB's, linear), and with `info` the standard `worldToCamera` and
/// `worldToNDC` and `tilefarm/*` attributes for spp asked and reached (the least count of
/// any pixel), max depth, seed, integrator, render seconds and the scene file.
pub fn exr_bytes(image: &impl Pixels, info: Option<&RenderInfo>) -> Result<Vec<u8>, String> {
    let mut out = std::io::Cursor::new(Vec::new());
    write_exr_to(image, info, &mut out)?;
    Ok(out.into_inner())
}

/// The channels of an EXR with the AOV layers, in order: the beauty pass, the sample
/// count, albedo, normal, depth and variance (named as compositors, Nuke and Blender,
/// and OIDN's tools expect). A macro, since each channel adds to the builder's type.
macro_rules! layer_channels {
    ($builder:expr) => {
        $builder
            .with_channel("R")
            .with_channel("G")
            .with_channel("B")
            .with_channel("A")
            .with_channel("samples")
            .with_channel("albedo.R")
            .with_channel("albedo.G")
            .with_channel("albedo.B")
            .with_channel("N.X")
            .with_channel("N.Y")
            .with_channel("N.Z")
            .with_channel("Z")
            .with_channel("variance.R")
            .with_channel("variance.G")
            .with_channel("variance.B")
    };
}

fn write_exr_to(
    image: &impl Pixels,
    info: Option<&RenderInfo>,
    out: &mut (impl std::io::Write + std::io::Seek),
) -> Result<(), String> {
    use exr::prelude::*;
    let (w, h) = image.size();
    let attributes = exr_attributes(image, info);
    let size = (w as usize, h as usize);
    if !image.has_layers() {
        let channels = SpecificChannels::build()
            .with_channel("R")
            .with_channel("G")
            .with_channel("B")
            .with_channel("A")
            .with_channel("samples")
            .with_pixel_fn(|Vec2(x, y): Vec2<usize>| {
                let (p, n) = image.pixel(x as u32, y as u32);
                (p.x, p.y, p.z, 1.0f32, n)
            });
        let mut exr = Image::from_layer(Layer::new(size, attributes, Encoding::SMALL_LOSSLESS, channels));
        exr.attributes.chromaticities = Some(REC709);
        return exr.write().to_buffered(out).map_err(|e| e.to_string());
    }
    if image.denoised(0, 0).is_some() {
        return write_denoised_exr(image, attributes, out);
    }
    // The AOV layers, named as compositors (Nuke, Blender) and OIDN's tools expect.
    let channels = layer_channels!(SpecificChannels::build()).with_pixel_fn(|Vec2(x, y): Vec2<usize>| {
        let (p, n) = image.pixel(x as u32, y as u32);
        let l = image.layers(x as u32, y as u32);
        let (a, nn, v) = (l.albedo, l.normal, l.variance);
        (p.x, p.y, p.z, 1.0f32, n, a.x, a.y, a.z, nn.x, nn.y, nn.z, l.depth, v.x, v.y, v.z)
    });
    let mut exr = Image::from_layer(Layer::new(size, attributes, Encoding::SMALL_LOSSLESS, channels));
    exr.attributes.chromaticities = Some(REC709);
    exr.write().to_buffered(out).map_err(|e| e.to_string())
}

/// Rec. 709 / sRGB primaries and D65 white: what the linear RGB values mean.
const REC709: exr::meta::attribute::Chromaticities = exr::meta::attribute::Chromaticities {
    red: exr::math::Vec2(0.64, 0.33),
    green: exr::math::Vec2(0.30, 0.60),
    blue: exr::math::Vec2(0.15, 0.06),
    white: exr::math::Vec2(0.3127, 0.3290),
};

/// [`write_exr_to`] with the AOV layers and a denoised beauty layer (`denoised.R/G/B`)
/// beside the raw one.
fn write_denoised_exr(
    image: &impl Pixels,
    mut attributes: exr::meta::header::LayerAttributes,
    out: &mut (impl std::io::Write + std::io::Seek),
) -> Result<(), String> {
    use exr::prelude::*;
    let (w, h) = image.size();
    attributes.other.insert(Text::from(keys::DENOISER), AttributeValue::Text(Text::from(DENOISER)));
    let channels = layer_channels!(SpecificChannels::build())
        .with_channel("denoised.R")
        .with_channel("denoised.G")
        .with_channel("denoised.B")
        .with_pixel_fn(|Vec2(x, y): Vec2<usize>| {
            let (x, y) = (x as u32, y as u32);
            let (p, n) = image.pixel(x, y);
            let l = image.layers(x, y);
            let d = image.denoised(x, y).unwrap_or(p);
            let (a, nn, v) = (l.albedo, l.normal, l.variance);
            (p.x, p.y, p.z, 1.0f32, n, a.x, a.y, a.z, nn.x, nn.y, nn.z, l.depth, v.x, v.y, v.z, d.x, d.y, d.z)
        });
    let mut exr =
        Image::from_layer(Layer::new((w as usize, h as usize), attributes, Encoding::SMALL_LOSSLESS, channels));
    exr.attributes.chromaticities = Some(REC709);
    exr.write().to_buffered(out).map_err(|e| e.to_string())
}

/// What the `tilefarm/denoiser` attribute says made a denoised layer.
const DENOISER: &str = "Intel Open Image Denoise 2, RT filter, HDR, guided by albedo and N";

/// The EXR file `exr` with `denoised` (its pixels in row order) as the denoised beauty
/// layer `denoised.R/G/B` beside the raw one, and the denoiser recorded: every other
/// channel and header attribute as the file had it (for an image made elsewhere, such as
/// a farm's, and denoised here). A denoised layer the file already had is replaced.
pub fn add_denoised_layer(exr: &[u8], denoised: &[Vec3]) -> Result<Vec<u8>, String> {
    use exr::prelude::*;
    let mut image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(exr))
        .map_err(|e| e.to_string())?;
    let layer = &mut image.layer_data;
    if denoised.len() != layer.size.area() {
        return Err(format!("{} denoised pixels for an image of {}", denoised.len(), layer.size.area()));
    }
    let mut list: Vec<_> =
        layer.channel_data.list.drain(..).filter(|c| !c.name.to_string().starts_with("denoised.")).collect();
    for (k, name) in ["denoised.R", "denoised.G", "denoised.B"].into_iter().enumerate() {
        list.push(AnyChannel::new(name, FlatSamples::F32(denoised.iter().map(|p| p[k]).collect())));
    }
    layer.channel_data = AnyChannels::sort(list.into_iter().collect());
    layer.attributes.other.insert(Text::from(keys::DENOISER), AttributeValue::Text(Text::from(DENOISER)));
    let mut out = std::io::Cursor::new(Vec::new());
    image.write().to_buffered(&mut out).map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

/// The layer's header attributes: the software, and with `info` what made the image.
fn exr_attributes(image: &impl Pixels, info: Option<&RenderInfo>) -> exr::meta::header::LayerAttributes {
    use exr::prelude::*;
    let (w, h) = image.size();
    let mut attributes = LayerAttributes::named("tilefarm");
    attributes.software_name = Some(Text::from(concat!("tilefarm ", env!("CARGO_PKG_VERSION"))));
    if let Some(info) = info {
        attributes.world_to_camera = Some(info.world_to_camera);
        attributes.world_to_normalized_device = Some(info.world_to_ndc);
        let reached = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| image.count(x, y)).min();
        let clamp = |v: u64| AttributeValue::I32(i32::try_from(v).unwrap_or(i32::MAX));
        let text = |s: &str| AttributeValue::Text(Text::new_or_none(s).unwrap_or_default());
        for (name, value) in [
            (keys::SPP, clamp(info.spp.into())),
            (keys::SPP_REACHED, clamp(reached.unwrap_or(0).into())),
            (keys::MAX_DEPTH, AttributeValue::I32(info.max_depth)),
            // Seeds are 64-bit; OpenEXR has no 64-bit integer attribute.
            (keys::SEED, text(&info.seed.to_string())),
            (keys::INTEGRATOR, text(&info.integrator)),
            (keys::RENDER_SECONDS, AttributeValue::F64(info.seconds)),
            (keys::SCENE, text(&info.scene)),
        ] {
            attributes.other.insert(Text::from(name), value);
        }
        if let Some(c) = info.clamp {
            attributes.other.insert(Text::from(keys::CLAMP), AttributeValue::F32(c));
        }
        if let Some(n) = info.noise {
            attributes.other.insert(Text::from(keys::NOISE), AttributeValue::F32(n));
        }
    }
    attributes
}

/// Reads back what [`write_exr`] wrote (RGB, the sample counts and the AOV layers, where
/// present).
pub fn read_exr(path: &Path) -> Result<Image, OutputError> {
    use exr::prelude::*;
    let err = |e: exr::error::Error| OutputError::Read { path: path.display().to_string(), message: e.to_string() };
    let img = read_first_flat_layer_from_file(path).map_err(err)?;
    let layer = &img.layer_data;
    let (w, h) = (layer.size.width() as u32, layer.size.height() as u32);
    let mut out = crate::film::Image::new(w, h);
    if layer.channel_data.list.iter().any(|c| c.name.to_string() == "albedo.R") {
        out.layers = vec![crate::film::PixelLayers::default(); out.pixels.len()];
    }
    if layer.channel_data.list.iter().any(|c| c.name.to_string() == "denoised.R") {
        out.denoised = vec![Vec3::ZERO; out.pixels.len()];
    }
    for ch in &layer.channel_data.list {
        let name = ch.name.to_string();
        let values: Vec<f32> = ch.sample_data.values_as_f32().collect();
        for (i, v) in values.into_iter().enumerate() {
            let l = out.layers.get_mut(i);
            match (name.as_str(), l) {
                ("R", _) => out.pixels[i].x = v,
                ("G", _) => out.pixels[i].y = v,
                ("B", _) => out.pixels[i].z = v,
                ("samples", _) => out.counts[i] = v as u32,
                ("albedo.R", Some(l)) => l.albedo.x = v,
                ("albedo.G", Some(l)) => l.albedo.y = v,
                ("albedo.B", Some(l)) => l.albedo.z = v,
                ("N.X", Some(l)) => l.normal.x = v,
                ("N.Y", Some(l)) => l.normal.y = v,
                ("N.Z", Some(l)) => l.normal.z = v,
                ("Z", Some(l)) => l.depth = v,
                ("variance.R", Some(l)) => l.variance.x = v,
                ("variance.G", Some(l)) => l.variance.y = v,
                ("variance.B", Some(l)) => l.variance.z = v,
                ("denoised.R", _) if !out.denoised.is_empty() => out.denoised[i].x = v,
                ("denoised.G", _) if !out.denoised.is_empty() => out.denoised[i].y = v,
                ("denoised.B", _) if !out.denoised.is_empty() => out.denoised[i].z = v,
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

/// A tone-mapped PNG of `image` (each radiance scaled by `scale` first: 2^stops of
/// exposure), in memory: the dashboard's live image.
pub fn png_bytes(image: &impl Pixels, scale: f32) -> Result<Vec<u8>, String> {
    views::view_png(image, views::View::Beauty, scale, 0.0).map(|v| v.png)
}

/// A tone-mapped PNG of `image`: its denoised pixels where it has them, else the raw.
pub fn write_png(image: &Image, path: &Path) -> Result<(), OutputError> {
    let mut buf = Vec::with_capacity(image.pixels.len() * 3);
    let shown = if image.denoised.len() == image.pixels.len() { &image.denoised } else { &image.pixels };
    for p in shown {
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
        img.layers = (0..6)
            .map(|i| crate::film::PixelLayers {
                albedo: Vec3::new(0.5, 0.25, i as f32 / 8.0),
                normal: Vec3::new(0.0, -1.0, i as f32 / 6.0),
                depth: if i == 5 { f32::INFINITY } else { 1.5 * i as f32 },
                variance: Vec3::new(1e-4, 2e-4, i as f32),
            })
            .collect();
        write_image(&img, &path).unwrap();
        assert_eq!(read_exr(&path).unwrap(), img, "the AOV layers round-trip");
        img.denoised = (0..6).map(|i| Vec3::new(0.25, i as f32, 2.0)).collect();
        write_image(&img, &path).unwrap();
        assert_eq!(read_exr(&path).unwrap(), img, "a denoised layer round-trips beside the raw one");
        write_image(&img, &dir.join("t.png")).unwrap();
        assert!(write_image(&img, &dir.join("t.bmpx")).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A denoised layer added to a file made elsewhere keeps every channel and header
    /// attribute of it, and adding one again replaces it.
    #[test]
    fn a_denoised_layer_joins_a_file_as_it_was() {
        let mut img = crate::film::Image::new(4, 3);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = Vec3::new(i as f32 * 0.1, 2.5, 1.0 / 7.0);
        }
        img.counts = (1..=12).collect();
        img.layers = (0..12)
            .map(|i| crate::film::PixelLayers {
                albedo: Vec3::splat(i as f32 / 12.0),
                normal: Vec3::Y,
                depth: i as f32,
                variance: Vec3::splat(1e-3),
            })
            .collect();
        let cam = crate::camera::Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::Y, 40.0, 4, 3).unwrap();
        let info = RenderInfo::of_view(&cam, &crate::scene::RenderSettings::default(), "s.toml", "path");
        let raw = exr_bytes(&img, Some(&info)).unwrap();
        let d1: Vec<Vec3> = (0..12).map(|i| Vec3::new(i as f32, 0.5, 0.25)).collect();
        let d2: Vec<Vec3> = (0..12).map(|i| Vec3::new(0.125, i as f32, 1.0)).collect();
        let once = add_denoised_layer(&raw, &d1).unwrap();
        let twice = add_denoised_layer(&once, &d2).unwrap();
        let dir = std::env::temp_dir().join(format!("tilefarm-adddenoised-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.exr");
        for (bytes, denoised) in [(&once, &d1), (&twice, &d2)] {
            std::fs::write(&path, bytes).unwrap();
            let back = read_exr(&path).unwrap();
            let expected = crate::film::Image { denoised: denoised.clone(), ..img.clone() };
            assert_eq!(back, expected);
            let attrs = |b: &[u8]| {
                let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(b), false).unwrap();
                meta.headers[0].own_attributes.clone()
            };
            let (before, after) = (attrs(&raw), attrs(bytes));
            let key = exr::meta::attribute::Text::from(keys::DENOISER);
            assert!(after.other.contains_key(&key));
            let mut without = after.clone();
            without.other.remove(&key);
            assert_eq!(without, before, "every other attribute is kept");
        }
        assert!(add_denoised_layer(&raw, &d1[..11]).is_err(), "a wrong pixel count is refused");
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
