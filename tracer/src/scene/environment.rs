//! The scene file's `[background]`: a constant radiance, or an environment map read from
//! an image beside the scene (README.md, "Environment maps").

use std::path::Path;

use glam::Vec3;

use super::error::SceneError;
use super::file::{BackgroundDesc, UpDesc};
use super::files::{MAX_ENVIRONMENT_BYTES, MAX_ENVIRONMENT_SIZE};
use super::textures::{Decode, decode_image};
use crate::light::{EnvironmentMap, Up};

/// What lights a scene from infinitely far away.
pub(super) struct Background {
    /// Constant radiance (zero when there is a map or nothing).
    pub radiance: Vec3,
    pub map: Option<EnvironmentMap>,
}

/// Reads `[background]`; `invalid` makes an error about a field, relative paths resolve
/// against `base`. An image that cannot be read is an error: the scene's lighting would
/// be wrong without it.
pub(super) fn background(
    desc: &BackgroundDesc,
    base: &Path,
    invalid: &dyn Fn(String, String) -> SceneError,
) -> Result<Background, SceneError> {
    let field = |k: &str| format!("background.{k}");
    let radiance = match desc.radiance {
        Some(v) if !v.iter().all(|x| x.is_finite() && *x >= 0.0) => {
            return Err(invalid(field("radiance"), "must be finite and ≥ 0".into()));
        }
        Some(v) => Vec3::from_array(v),
        None => Vec3::ZERO,
    };
    let Some(file) = &desc.map else {
        for (k, given) in
            [("strength", desc.strength.is_some()), ("rotate", desc.rotate.is_some()), ("up", desc.up.is_some())]
        {
            if given {
                return Err(invalid(field(k), "applies to an environment map: give `map` too".into()));
            }
        }
        return Ok(Background { radiance, map: None });
    };
    if desc.radiance.is_some() {
        return Err(invalid(field("radiance"), "give either a constant `radiance` or a `map`, not both".into()));
    }
    let strength = desc.strength.unwrap_or(1.0);
    if !(strength.is_finite() && strength >= 0.0) {
        return Err(invalid(field("strength"), format!("must be finite and ≥ 0, got {strength}")));
    }
    let rotate = desc.rotate.unwrap_or(0.0);
    if !(rotate.is_finite() && rotate.abs() <= 1e6) {
        return Err(invalid(field("rotate"), format!("must be a finite angle in degrees, got {rotate}")));
    }
    let up = match desc.up {
        None | Some(UpDesc::Y) => Up::Y,
        Some(UpDesc::Z) => Up::Z,
    };
    let (w, h) = MAX_ENVIRONMENT_SIZE;
    let decode = Decode { srgb: true, alpha: false };
    let image =
        decode_image(&base.join(file), decode, MAX_ENVIRONMENT_BYTES, Some(MAX_ENVIRONMENT_SIZE)).map_err(|e| {
            let limits =
                format!(" (an environment map may be at most {w} × {h} texels, {} GiB)", MAX_ENVIRONMENT_BYTES >> 30);
            let why = if e.contains("limit") { limits } else { String::new() };
            invalid(field("map"), format!("{file}: {e}{why}"))
        })?;
    let map = EnvironmentMap::new(image.width, image.height, image.texels, strength, rotate, up);
    Ok(Background { radiance: Vec3::ZERO, map: Some(map) })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::disallowed_methods)] // values checked, not platform-free bits
    use crate::scene::scene_from_toml;

    const CAMERA: &str = "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nwidth = 8\nheight = 8\n";

    fn error(background: &str, dir: &std::path::Path) -> String {
        let toml = format!("{CAMERA}[background]\n{background}");
        scene_from_toml(&toml, "s.toml", dir).err().map(|e| e.to_string()).unwrap_or_default()
    }

    #[test]
    fn bad_backgrounds_are_errors_naming_the_line_and_key() {
        let dir = std::env::temp_dir().join(format!("tilefarm-env-errors-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        image::RgbImage::from_pixel(4, 2, image::Rgb([10, 20, 30])).save(dir.join("sky.png")).unwrap();
        std::fs::write(dir.join("junk.exr"), b"not an image").unwrap();
        let cases = [
            ("map = \"sky.png\"\nradiance = [1, 1, 1]\n", "s.toml:8: background.radiance: give either"),
            ("map = \"gone.exr\"\n", "s.toml:7: background.map: gone.exr: no such file"),
            ("map = \"junk.exr\"\n", "s.toml:7: background.map: junk.exr: "),
            ("map = \"sky.png\"\nstrength = -1\n", "s.toml:8: background.strength: must be finite and ≥ 0"),
            ("strength = 2\n", "s.toml:7: background.strength: applies to an environment map"),
            ("map = \"sky.png\"\nup = \"x\"\n", "unknown variant `x`"),
            ("radiance = [1, -1, 0]\n", "s.toml:7: background.radiance: must be finite and ≥ 0"),
        ];
        for (background, expected) in cases {
            let e = error(background, &dir);
            assert!(e.contains(expected), "{background:?}: {e}");
        }
        let ok = scene_from_toml(&format!("{CAMERA}[background]\nmap = \"sky.png\"\nrotate = 45\n"), "s.toml", &dir);
        let scene = ok.unwrap();
        let map = scene.lights.environment_map().expect("a map");
        let srgb = |b: f32| ((b / 255.0 + 0.055) / 1.055).powf(2.4);
        assert!((map.mean().x - srgb(10.0)).abs() < 1e-4, "8-bit maps are sRGB: {}", map.mean());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
