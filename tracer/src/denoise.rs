//! Denoising with Intel Open Image Denoise (OIDN 2.x): its `RT` filter on the beauty
//! pass, guided by the albedo and normal layers of the same samples
//! ([`crate::film::layers`]). Only with the `denoise` cargo feature, which links
//! `libOpenImageDenoise` (found through `OIDN_DIR` or pkg-config); without it,
//! [`denoise`] says how to get it. The denoised image is an addition to the render,
//! never a replacement: the raw beauty pass stays what the samples say.

use glam::Vec3;

use crate::film::Image;

/// Whether this build can denoise.
pub const AVAILABLE: bool = cfg!(feature = "denoise");

/// Why this build cannot denoise, and what to do about it.
const UNAVAILABLE: &str = "this build has no denoiser: build with `--features denoise` and Intel Open Image \
     Denoise 2.x installed (OIDN_DIR pointing at it, or found by pkg-config; README.md, Denoising)";

/// Ok if this build can denoise; else why not, for a command to refuse `--denoise` before
/// it renders anything.
pub fn check_available() -> Result<(), String> {
    if AVAILABLE { Ok(()) } else { Err(UNAVAILABLE.into()) }
}

/// The denoised beauty pass of `image`, which must carry the AOV layers (its albedo and
/// normals guide the filter). Pixels in row order, as [`Image::pixels`].
pub fn denoise(image: &Image) -> Result<Vec<Vec3>, String> {
    if image.layers.len() != image.pixels.len() {
        return Err("denoising needs the albedo and normal layers: render with --aovs".into());
    }
    run(image)
}

#[cfg(feature = "denoise")]
fn run(image: &Image) -> Result<Vec<Vec3>, String> {
    let flat =
        |f: &dyn Fn(usize) -> Vec3| -> Vec<f32> { (0..image.pixels.len()).flat_map(|i| f(i).to_array()).collect() };
    // OIDN wants finite colour; the film already replaces non-finite samples by zero.
    let color = flat(&|i| image.pixels[i]);
    let albedo = flat(&|i| image.layers[i].albedo);
    let normal = flat(&|i| image.layers[i].normal);
    let device = oidn::Device::new().map_err(|e| format!("Open Image Denoise: no device: {e:?}"))?;
    let mut filter =
        oidn::RayTracing::try_new(&device).map_err(|e| format!("Open Image Denoise: no RT filter: {e:?}"))?;
    filter
        .srgb(false)
        .hdr(true)
        .image_dimensions(image.width as usize, image.height as usize)
        .albedo_normal(&albedo, &normal);
    let mut out = vec![0.0f32; color.len()];
    filter.filter(&color, &mut out).map_err(|e| format!("Open Image Denoise: {e:?}"))?;
    device.get_error().map_err(|e| format!("Open Image Denoise: {e:?}"))?;
    Ok(out.chunks_exact(3).map(Vec3::from_slice).collect())
}

#[cfg(not(feature = "denoise"))]
fn run(_: &Image) -> Result<Vec<Vec3>, String> {
    Err(UNAVAILABLE.into())
}
