//! False-colour views of a render in progress, beside its tone-mapped beauty image:
//! where the noise is (each pixel's relative error against a target) and where the
//! samples went (each pixel's sample count). The dashboard's live image shows them.

use glam::Vec3;

use super::tonemap;
use crate::film::Pixels;

/// What a view shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum View {
    /// The image, tone-mapped.
    Beauty,
    /// Each pixel's relative error ([`crate::film::PixelLayers::relative_error`]) against
    /// a noise target, on a log scale: blue below it, green at it, red above. Needs the
    /// AOV layers (the variance).
    Noise,
    /// Each pixel's sample count, from black (none) through blue to yellow (the most).
    Samples,
}

impl std::str::FromStr for View {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "beauty" => Ok(Self::Beauty),
            "noise" => Ok(Self::Noise),
            "samples" => Ok(Self::Samples),
            _ => Err(format!("no view {s:?} (beauty, noise or samples)")),
        }
    }
}

/// How far the noise view's colours reach either side of the target, in factors of 2:
/// 1/8 of the target is the deepest blue, 8× the deepest red.
pub const NOISE_OCTAVES: f64 = 3.0;

/// The noise view's colours from 1/8 of the target (first) to 8× (last), evenly on a
/// log scale; the middle one is the target.
const NOISE_RAMP: [[f32; 3]; 5] =
    [[0.08, 0.16, 0.47], [0.16, 0.47, 0.78], [0.31, 0.75, 0.31], [0.94, 0.78, 0.16], [0.86, 0.16, 0.12]];
/// Where the variance is unknown (fewer than two samples).
pub const UNKNOWN: [u8; 3] = [96, 96, 96];
/// The samples view's colours from fewest (first) to most (last), evenly in count.
const SAMPLES_RAMP: [[f32; 3]; 5] =
    [[0.27, 0.0, 0.33], [0.23, 0.32, 0.55], [0.13, 0.57, 0.55], [0.37, 0.79, 0.38], [0.99, 0.91, 0.14]];

/// A view as a PNG, with the values its colour scale spans (for a legend).
#[derive(Clone, Debug)]
pub struct ViewImage {
    pub png: Vec<u8>,
    /// The value of the scale's first colour: for the noise view, the relative error of
    /// the deepest blue; for the samples view, the fewest samples of any pixel.
    pub low: f64,
    /// The value of the scale's last colour.
    pub high: f64,
}

/// `image` as `view` shows it. `scale` multiplies radiance (the beauty view's exposure);
/// `target` is the noise view's relative error shown green. The noise view of an image
/// without layers is refused.
pub fn view_png(image: &impl Pixels, view: View, scale: f32, target: f64) -> Result<ViewImage, String> {
    let (w, h) = image.size();
    let mut buf = Vec::with_capacity(w as usize * h as usize * 3);
    let (low, high) = match view {
        View::Beauty => {
            for y in 0..h {
                for x in 0..w {
                    buf.extend_from_slice(&tonemap(image.pixel(x, y).0 * scale));
                }
            }
            (0.0, 1.0 / f64::from(scale))
        }
        View::Noise => {
            if !image.has_layers() {
                return Err("this render keeps no variance: render with --aovs or --adaptive for a noise view".into());
            }
            for y in 0..h {
                for x in 0..w {
                    let e = image.layers(x, y).relative_error(image.pixel(x, y).0);
                    buf.extend_from_slice(&noise_colour(e, target));
                }
            }
            (target / NOISE_OCTAVES.exp2(), target * NOISE_OCTAVES.exp2())
        }
        View::Samples => {
            let (mut fewest, mut most) = (u32::MAX, 0);
            for y in 0..h {
                for x in 0..w {
                    let n = image.count(x, y);
                    (fewest, most) = (fewest.min(n), most.max(n));
                }
            }
            for y in 0..h {
                for x in 0..w {
                    buf.extend_from_slice(&samples_colour(image.count(x, y), fewest, most));
                }
            }
            (f64::from(fewest.min(most)), f64::from(most))
        }
    };
    Ok(ViewImage { png: encode(&buf, w, h)?, low, high })
}

/// The noise view's colour of relative error `e` against `target`.
pub fn noise_colour(e: f64, target: f64) -> [u8; 3] {
    if !e.is_finite() || !(target > 0.0) {
        return UNKNOWN;
    }
    // 0 at 1/8 of the target, 1 at 8×: a pixel with no error at all is the deepest blue.
    let at = if e > 0.0 { ((e / target).log2() / NOISE_OCTAVES + 1.0) / 2.0 } else { 0.0 };
    ramp(&NOISE_RAMP, at as f32)
}

/// The samples view's colour of a pixel with `n` samples, where the image's pixels have
/// `fewest` to `most`; black where there are none.
pub fn samples_colour(n: u32, fewest: u32, most: u32) -> [u8; 3] {
    if n == 0 {
        return [0, 0, 0];
    }
    let span = most.saturating_sub(fewest);
    let at = if span == 0 { 1.0 } else { f64::from(n - fewest.min(n)) / f64::from(span) };
    ramp(&SAMPLES_RAMP, at as f32)
}

/// Linear interpolation along evenly spaced colour stops, `at` in [0, 1] (clamped).
fn ramp(stops: &[[f32; 3]], at: f32) -> [u8; 3] {
    let pos = at.clamp(0.0, 1.0) * (stops.len() - 1) as f32;
    let i = (pos as usize).min(stops.len() - 2);
    let (a, b) = (Vec3::from_array(stops[i]), Vec3::from_array(stops[i + 1]));
    let c = a.lerp(b, pos - i as f32);
    [c.x, c.y, c.z].map(|v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8)
}

fn encode(rgb: &[u8], w: u32, h: u32) -> Result<Vec<u8>, String> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(rgb, w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| e.to_string())?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::{Accumulation, FirstHit, Image, Tile};

    fn decode(png: &[u8]) -> image::RgbImage {
        image::load_from_memory(png).unwrap().to_rgb8()
    }

    /// A 3×1 image with layers: pixel 0 gets `a`'s samples, pixel 1 `b`'s, pixel 2 one.
    fn image_of(a: &[f32], b: &[f32]) -> Image {
        let tile = Tile { x0: 0, y0: 0, width: 3, height: 1 };
        let mut acc = Accumulation::with_layers(tile, true);
        for (i, vs) in [a, b, &[1.0][..]].into_iter().enumerate() {
            for &v in vs {
                acc.add_sample_at(i, Vec3::splat(v), &FirstHit::default());
            }
        }
        let mut img = Image::new(3, 1);
        img.put(&acc);
        img
    }

    #[test]
    fn the_noise_view_places_each_pixel_against_the_target() {
        // Pixel 0: values 1 and 3, mean 2 per channel, sample variance 2, variance of the
        // mean 1 per channel: relative error √(1 / (2² + 0.01)).
        let img = image_of(&[1.0, 3.0], &[5.0; 8]);
        let e = (1.0 / 4.01f64).sqrt();
        let v = view_png(&img, View::Noise, 1.0, e).unwrap();
        let px = decode(&v.png);
        assert_eq!(px.get_pixel(0, 0).0, ramp(&NOISE_RAMP, 0.5), "at the target: the middle colour");
        assert_eq!(px.get_pixel(1, 0).0, ramp(&NOISE_RAMP, 0.0), "no variance: the deepest blue");
        assert_eq!(px.get_pixel(2, 0).0, UNKNOWN, "one sample: unknown");
        assert!((v.low - e / 8.0).abs() < 1e-12 && (v.high - e * 8.0).abs() < 1e-12);
        // Evenly on a log scale: each octave from 1/8 of the target to 8× one sixth of
        // the way along the colours; beyond, the ends.
        for k in -3..=3 {
            let at = (f64::from(k) / 3.0 + 1.0) / 2.0;
            assert_eq!(noise_colour(e * 2f64.powi(k), e), ramp(&NOISE_RAMP, at as f32), "2^{k} × the target");
        }
        assert_eq!(noise_colour(100.0 * e, e), ramp(&NOISE_RAMP, 1.0));
        assert_eq!(noise_colour(e / 100.0, e), ramp(&NOISE_RAMP, 0.0));
    }

    #[test]
    fn the_noise_view_needs_the_variance() {
        let err = view_png(&Image::new(2, 2), View::Noise, 1.0, 0.01).unwrap_err();
        assert!(err.contains("--aovs"), "{err}");
    }

    #[test]
    fn the_samples_view_spans_the_fewest_to_the_most() {
        let img = image_of(&[1.0; 4], &[1.0; 10]);
        let v = view_png(&img, View::Samples, 1.0, 0.01).unwrap();
        assert_eq!((v.low, v.high), (1.0, 10.0));
        let px = decode(&v.png);
        assert_eq!(px.get_pixel(1, 0).0, ramp(&SAMPLES_RAMP, 1.0), "the most: the last colour");
        assert_eq!(px.get_pixel(2, 0).0, ramp(&SAMPLES_RAMP, 0.0), "the fewest: the first colour");
        assert_eq!(px.get_pixel(0, 0).0, ramp(&SAMPLES_RAMP, 3.0 / 9.0));
        assert_eq!(samples_colour(0, 0, 10), [0, 0, 0], "no samples: black");
        assert_eq!(samples_colour(7, 7, 7), ramp(&SAMPLES_RAMP, 1.0), "all equal: the last colour");
    }

    #[test]
    fn the_beauty_view_is_the_tone_mapped_image() {
        let img = image_of(&[0.25; 2], &[0.5; 2]);
        let px = decode(&view_png(&img, View::Beauty, 2.0, 0.01).unwrap().png);
        assert_eq!(px.get_pixel(0, 0).0, tonemap(Vec3::splat(0.5)));
        assert_eq!(px.get_pixel(1, 0).0, tonemap(Vec3::splat(1.0)));
        assert_eq!("noise".parse::<View>(), Ok(View::Noise));
        assert!("depth".parse::<View>().unwrap_err().contains("beauty, noise or samples"));
    }
}
