//! Environment maps against analytic answers (issue 50): a band of sky over a plane, the
//! white furnace, and what importance sampling buys over cosine sampling alone. On an
//! unoccluded plane under an environment every point receives the same irradiance, so
//! the pixels are independent estimates of one value: their spread is the noise.

// Tests may use the C library's functions: they check values, not platform-free bits.
#![allow(clippy::disallowed_methods)]

mod common;

use std::f64::consts::PI;

use common::{TempDir, mean_stderr, render};
use tracer::integrator::Integrator;
use tracer::scene::{Scene, scene_from_toml};

/// Writes a `w × h` float EXR of `texel(row, col)` (grey) to `dir/name`.
fn write_map(dir: &TempDir, name: &str, w: u32, h: u32, texel: impl Fn(u32, u32) -> [f32; 3]) {
    let img = image::Rgb32FImage::from_fn(w, h, |c, r| image::Rgb(texel(r, c)));
    img.save(dir.0.join(name)).unwrap();
}

/// A white-ish Lambertian floor (`kd`) seen from above, lit by `background` alone.
fn floor_scene(dir: &TempDir, kd: f32, background: &str, max_depth: i32) -> Scene {
    dir.write("m.mtl", &format!("newmtl floor\nKd {kd} {kd} {kd}\n"));
    dir.write("floor.obj", "mtllib m.mtl\nv -60 0 -60\nv 60 0 -60\nv 60 0 60\nv -60 0 60\nusemtl floor\nf 1 4 3 2\n");
    let toml = format!(
        "[camera]\nposition = [0.3, 4.0, 0.2]\nlook_at = [0.3, 0.0, 0.0]\nup = [0, 0, 1]\nfov = 40\nwidth = 24\n\
         height = 18\n[render]\nmax_depth = {max_depth}\nseed = 3\n[[mesh]]\nobj = \"floor.obj\"\n[background]\n{background}"
    );
    scene_from_toml(&toml, "floor.toml", &dir.0).unwrap()
}

/// The irradiance on an upward plane under radiance `l(θ)` (θ from the zenith, constant
/// in azimuth): 2π ∫ l(θ) cos θ sin θ dθ over [0, π/2], by Simpson's rule.
fn irradiance(l: impl Fn(f64) -> f64) -> f64 {
    let n = 200_000;
    let h = 0.5 * PI / n as f64;
    let f = |t: f64| l(t) * t.cos() * t.sin();
    let mut s = f(0.0) + f(0.5 * PI);
    for i in 1..n {
        s += f(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    2.0 * PI * s * h / 3.0
}

#[test]
fn a_band_of_sky_lights_a_plane_as_the_integral_says() {
    // Radiance 2 between 30° and 60° from the zenith, zero elsewhere: 181 rows, row i at
    // i degrees, so the band's rows are exactly 30..=60 and the bilinear image ramps to
    // zero over the degree on either side.
    let (kd, l) = (0.5, 2.0);
    let dir = TempDir::new("env-band");
    write_map(&dir, "band.exr", 8, 181, |r, _| if (30..=60).contains(&r) { [l; 3] } else { [0.0; 3] });
    let exact = irradiance(|t| {
        let deg = t.to_degrees();
        let ramp = if deg < 30.0 {
            deg - 29.0
        } else if deg > 60.0 {
            61.0 - deg
        } else {
            1.0
        };
        l as f64 * ramp.clamp(0.0, 1.0)
    }) * kd as f64
        / PI;
    // Without the ramps the answer is π L (sin² 60° − sin² 30°) = π L / 2.
    assert!((exact - kd as f64 * l as f64 / 2.0).abs() < 0.03 * exact);
    let scene = floor_scene(&dir, kd, "map = \"band.exr\"\nrotate = 37\n", 2);
    for (integrator, spp) in
        [(Integrator::Path, 256), (Integrator::PathLightOnly, 256), (Integrator::PathBsdfOnly, 1024)]
    {
        let img = render(&scene, integrator, spp);
        for channel in 0..3 {
            let px: Vec<f64> = img.pixels.iter().map(|p| p[channel] as f64).collect();
            let (mean, se) = mean_stderr(&px);
            assert!(4.0 * se < 0.01 * exact, "{integrator:?}: too weak to see a 1% bias: se {se}");
            assert!((mean - exact).abs() < 4.0 * se, "{integrator:?}: {mean} ± {se} against {exact}");
        }
    }
}

#[test]
fn a_white_sphere_in_a_constant_map_is_the_map() {
    // The white furnace: an albedo-1 Lambertian sphere under constant radiance L reflects
    // exactly L, at any depth of interreflection (a convex sphere has none).
    let l = 0.7f32;
    let dir = TempDir::new("env-furnace");
    write_map(&dir, "grey.exr", 16, 9, |_, _| [l; 3]);
    let toml = "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 25\nwidth = 16\nheight = 16\n\
                [render]\nmax_depth = -1\nseed = 9\n[[sphere]]\ncenter = [0, 0, 0]\nradius = 1\nkd = [1, 1, 1]\n\
                [background]\nmap = \"grey.exr\"\nrotate = -20\nup = \"z\"\n";
    let scene = scene_from_toml(toml, "furnace.toml", &dir.0).unwrap();
    let img = render(&scene, Integrator::Path, 256);
    let px: Vec<f64> = img.pixels.iter().map(|p| p.x as f64).collect();
    let (mean, se) = mean_stderr(&px);
    assert!(4.0 * se < 0.01 * l as f64, "too weak: se {se}");
    assert!((mean - l as f64).abs() < 4.0 * se, "furnace {mean} ± {se}, expected {l}");
}

#[test]
fn importance_sampling_finds_a_small_sun() {
    // A dim sky and a sun of a few texels (about 1/2000 of the sphere, 5,000 times as
    // bright): at equal samples, MIS with the map's importance sampling must have at
    // least 10× lower relative MSE than cosine-weighted BSDF sampling alone.
    let dir = TempDir::new("env-sun");
    write_map(&dir, "sun.exr", 128, 65, |r, c| {
        if (20..23).contains(&r) && (40..43).contains(&c) {
            [5000.0, 4500.0, 4000.0]
        } else if r < 32 {
            [0.3, 0.5, 1.0]
        } else {
            [0.1, 0.08, 0.05]
        }
    });
    let scene = floor_scene(&dir, 0.8, "map = \"sun.exr\"\n", 2);
    let rel_mse = |integrator| {
        let img = render(&scene, integrator, 16);
        let px: Vec<f64> = img.pixels.iter().map(|p| (p.x + p.y + p.z) as f64).collect();
        let (mean, se) = mean_stderr(&px);
        (mean, se, se * se * px.len() as f64 / (mean * mean))
    };
    let (m_is, se_is, is) = rel_mse(Integrator::Path);
    let (m_cos, se_cos, cos) = rel_mse(Integrator::PathBsdfOnly);
    println!("relative MSE at 16 spp: map sampling + MIS {is:.3e}, cosine sampling alone {cos:.3e} ({:.0}×)", cos / is);
    let se = (se_is * se_is + se_cos * se_cos).sqrt();
    assert!((m_is - m_cos).abs() < 4.0 * se, "the two disagree: {m_is} and {m_cos} (± {se})");
    assert!(cos > 10.0 * is, "importance sampling {is:.3e} is not 10× better than cosine sampling {cos:.3e}");
}
