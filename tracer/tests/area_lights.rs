//! Area lights (issue 50): a rectangle and a disk over a floor against the irradiance
//! formulas, by light sampling, BSDF sampling and MIS; unseen by the camera; blocking
//! nothing.

// Tests may use the C library's functions: they check values, not platform-free bits.
#![allow(clippy::disallowed_methods)]

mod common;

use std::f64::consts::PI;

use common::{TempDir, mean_stderr, render};
use glam::Vec2;
use tracer::film::Image;
use tracer::integrator::Integrator;
use tracer::scene::{Scene, scene_from_toml};

/// E / L at a point under the corner of an `a × b` rectangle at height `c` (parallel,
/// facing it): π times the corner form factor.
fn corner(a: f64, b: f64, c: f64) -> f64 {
    let (x, y) = (a / c, b / c);
    let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
    0.5 * (x / sx * (y / sx).atan() + y / sy * (x / sy).atan())
}

/// E / L at `(px, pz)` on the floor under the rectangle `[x0, x1] × [z0, z1]` at height
/// `c`: four signed corner rectangles.
fn under_rectangle(px: f64, pz: f64, (x0, x1, z0, z1): (f64, f64, f64, f64), c: f64) -> f64 {
    let part = |dx: f64, dz: f64| dx.signum() * dz.signum() * corner(dx.abs(), dz.abs(), c);
    part(x1 - px, z1 - pz) - part(x0 - px, z1 - pz) - part(x1 - px, z0 - pz) + part(x0 - px, z0 - pz)
}

const FLOOR: &str = "mtllib m.mtl\nv -30 0 -30\nv 30 0 -30\nv 30 0 30\nv -30 0 30\nusemtl floor\nf 1 4 3 2\n";

fn scene(dir: &TempDir, light: &str) -> Scene {
    dir.write("m.mtl", "newmtl floor\nKd 0.6 0.6 0.6\n");
    dir.write("floor.obj", FLOOR);
    let toml = format!(
        "[camera]\nposition = [0.2, 3.0, 0.1]\nlook_at = [0.2, 0.0, 0.0]\nup = [0, 0, 1]\nfov = 60\nwidth = 24\n\
         height = 18\n[render]\nmax_depth = 2\nseed = 5\n[[mesh]]\nobj = \"floor.obj\"\n[[light]]\n{light}"
    );
    scene_from_toml(&toml, "area.toml", &dir.0).unwrap()
}

/// Ratios of each pixel to its analytic value (`exact(x, z)` at floor points averaged
/// over the pixel), which are independent with mean 1: their mean and standard error.
fn ratios(s: &Scene, img: &Image, exact: &dyn Fn(f64, f64) -> f64) -> (f64, f64) {
    ratios_above(s, img, exact, 0.0)
}

#[test]
fn a_rectangle_light_lights_the_floor_as_the_form_factor_says() {
    // 2 × 1 at height 1.5 facing down, 40 W: L = 40 / (π · 2).
    let dir = TempDir::new("area-rect");
    let s = scene(
        &dir,
        "type = \"area\"\nsize = [2.0, 1.0]\nposition = [0.5, 1.5, -0.2]\ndirection = [0, -1, 0]\nup = [0, 0, 1]\npower = 40\n",
    );
    let l = 40.0 / (PI * 2.0);
    let exact = |x: f64, z: f64| 0.6 / PI * l * under_rectangle(x, z, (-0.5, 1.5, -0.7, 0.3), 1.5);
    for (integrator, spp, power) in
        [(Integrator::Path, 64, 0.01), (Integrator::PathLightOnly, 64, 0.01), (Integrator::PathBsdfOnly, 512, 0.02)]
    {
        let img = render(&s, integrator, spp);
        let (mean, se) = ratios(&s, &img, &exact);
        assert!(4.0 * se < power, "{integrator:?}: too weak, se {se}");
        assert!((mean - 1.0).abs() < 4.0 * se + 5e-4, "{integrator:?}: ratio {mean} ± {se}");
    }
}

#[test]
fn a_disk_light_lights_the_floor_below_as_pi_l_r2_over_h2_plus_r2() {
    // A disk of radius 0.6 at height 2 (by its matrix: Blender's light looks down its −Z,
    // so the identity with a translation faces down the world's −Z; turned to face −Y).
    let dir = TempDir::new("area-disk");
    let s = scene(
        &dir,
        "type = \"area\"\nshape = \"disk\"\nsize = 1.2\nmatrix = [[1, 0, 0, 0.2], [0, 0, 1, 2], [0, -1, 0, 0], [0, 0, 0, 1]]\n\
         radiance = [3, 3, 3]\n",
    );
    // On the axis of a disk: E = π L r² / (h² + r²); off the axis by the disk's own
    // numerical integral over its area.
    let (r, h, l) = (0.6f64, 2.0f64, 3.0f64);
    let exact = |x: f64, z: f64| {
        let n = 64;
        let mut e = 0.0;
        for i in 0..n {
            for j in 0..n {
                let rho = r * ((i as f64 + 0.5) / n as f64).sqrt();
                let phi = 2.0 * PI * (j as f64 + 0.5) / n as f64;
                let (dx, dz) = (0.2 + rho * phi.cos() - x, rho * phi.sin() - z);
                let d2 = dx * dx + dz * dz + h * h;
                e += h * h / (d2 * d2);
            }
        }
        0.6 / PI * l * e * PI * r * r / (n * n) as f64
    };
    assert!((exact(0.2, 0.0) * PI / 0.6 / l - PI * r * r / (h * h + r * r)).abs() < 1e-3);
    for integrator in [Integrator::Path, Integrator::PathLightOnly] {
        let img = render(&s, integrator, 64);
        let (mean, se) = ratios(&s, &img, &exact);
        assert!(4.0 * se < 0.01, "{integrator:?}: too weak, se {se}");
        assert!((mean - 1.0).abs() < 4.0 * se + 5e-4, "{integrator:?}: ratio {mean} ± {se}");
    }
}

#[test]
fn an_area_light_is_not_seen_by_the_camera_and_blocks_nothing() {
    let dir = TempDir::new("area-unseen");
    dir.write("m.mtl", "newmtl floor\nKd 0.6 0.6 0.6\n");
    dir.write("floor.obj", FLOOR);
    // Looking straight up at a bright light from below it: black.
    let up = "[camera]\nposition = [0, 0.5, 0]\nlook_at = [0, 3, 0]\nup = [0, 0, 1]\nfov = 30\nwidth = 8\nheight = 8\n\
              [[light]]\ntype = \"area\"\nsize = 4\nposition = [0, 2, 0]\ndirection = [0, -1, 0]\nradiance = [50, 50, 50]\n";
    let img = render(&scene_from_toml(up, "up.toml", &dir.0).unwrap(), Integrator::Path, 4);
    assert!(img.pixels.iter().all(|p| p.max_element() == 0.0), "the camera saw the light");
    // The same light with `visible = true` is a surface the camera sees.
    let visible = format!("{up}visible = true\n");
    let img = render(&scene_from_toml(&visible, "up.toml", &dir.0).unwrap(), Integrator::Path, 4);
    assert!(img.pixels.iter().all(|p| (p.x - 50.0).abs() < 1e-3), "the visible light is a surface");
    // A sun above a dark area light: the floor below gets the sun's full irradiance.
    let sun = "[camera]\nposition = [0, 3, 0.01]\nlook_at = [0, 0, 0]\nup = [0, 0, 1]\nfov = 20\nwidth = 8\nheight = 8\n\
               [render]\nmax_depth = 2\n[[mesh]]\nobj = \"floor.obj\"\n[[light]]\ntype = \"directional\"\n\
               direction = [0, -1, 0]\nirradiance = [2, 2, 2]\n[[light]]\ntype = \"area\"\nsize = 10\n\
               position = [0, 1, 0]\ndirection = [0, 1, 0]\nradiance = [1, 1, 1]\n";
    let img = render(&scene_from_toml(sun, "sun.toml", &dir.0).unwrap(), Integrator::Path, 4);
    let expected = 0.6 / std::f32::consts::PI * 2.0;
    assert!(img.pixels.iter().all(|p| (p.x - expected).abs() < 1e-4), "{:?} against {expected}", img.pixels[0]);
}

/// A floor under `light` (a `[[light]]` table's keys) and, with `occluder`, a
/// half-plane x < 0 at height 1 that casts a shadow edge along z.
fn soft_scene(dir: &TempDir, light: &str, occluder: bool) -> Scene {
    dir.write("m.mtl", "newmtl floor\nKd 0.6 0.6 0.6\n");
    dir.write("floor.obj", FLOOR);
    dir.write("half.obj", "mtllib m.mtl\nv -30 1 -30\nv 0 1 -30\nv 0 1 30\nv -30 1 30\nusemtl floor\nf 1 2 3 4\n");
    let extra = if occluder { "[[mesh]]\nobj = \"half.obj\"\n" } else { "" };
    // The camera under the half-plane's level, looking down across the shadow's edge.
    let toml = format!(
        "[camera]\nposition = [0.0, 0.8, 0.0]\nlook_at = [0.0, 0.0, 0.0]\nup = [0, 0, 1]\nfov = 50\nwidth = 24\n\
         height = 18\n[render]\nmax_depth = 2\nseed = 6\n[[mesh]]\nobj = \"floor.obj\"\n{extra}[[light]]\n{light}"
    );
    scene_from_toml(&toml, "soft.toml", &dir.0).unwrap()
}

#[test]
fn a_sun_with_an_angle_gives_its_irradiance_and_a_penumbra_of_its_width() {
    // A 12° sun straight down: E on the open floor; under the half-plane's edge a
    // penumbra whose profile is the visible part of the sun's disc (integrated here over
    // the disc's solid angle, independently of the renderer).
    let (e, angle) = (2.0f64, 12.0f64);
    let light =
        format!("type = \"directional\"\ndirection = [0, -1, 0]\nirradiance = [{e}, {e}, {e}]\nangle = {angle}\n");
    let dir = TempDir::new("soft-sun");
    let a = (0.5 * angle).to_radians();
    let l = e / (PI * a.sin() * a.sin());
    // The floor point x sees the sun's direction (sin θ cos φ, cos θ, ·) past the edge when
    // x + 1·tan(θ) cos φ ≥ 0 (the ray reaches height 1 at x + tanθ cosφ).
    let exact = |x: f64, _z: f64| {
        let (nt, np) = (200, 200);
        let mut sum = 0.0;
        for i in 0..nt {
            let cos_t = 1.0 - (1.0 - a.cos()) * (i as f64 + 0.5) / nt as f64;
            let tan_t = (1.0 - cos_t * cos_t).sqrt() / cos_t;
            for j in 0..np {
                let phi = 2.0 * PI * (j as f64 + 0.5) / np as f64;
                if x + tan_t * phi.cos() >= 0.0 {
                    sum += cos_t;
                }
            }
        }
        0.6 / PI * l * sum * 2.0 * PI * (1.0 - a.cos()) / (nt * np) as f64
    };
    let open = soft_scene(&dir, &light, false);
    let shadowed = soft_scene(&dir, &light, true);
    for (integrator, spp) in [(Integrator::Path, 64), (Integrator::PathLightOnly, 64), (Integrator::PathBsdfOnly, 4096)]
    {
        let img = render(&open, integrator, spp);
        let px: Vec<f64> = img.pixels.iter().map(|p| p.x as f64).collect();
        let (mean, se) = mean_stderr(&px);
        let flat = 0.6 / PI * e;
        assert!((mean - flat).abs() < 4.0 * se + 1e-4 * flat, "{integrator:?}: open floor {mean} ± {se} vs {flat}");
    }
    // The penumbra is 2·tan 6° ≈ 0.21 wide on a view 0.75 wide: most pixels are in it.
    let img = render(&shadowed, Integrator::Path, 256);
    let (mean, se) = ratios_above(&shadowed, &img, &exact, 0.05);
    assert!(4.0 * se < 0.01, "too weak: se {se}");
    assert!((mean - 1.0).abs() < 4.0 * se + 5e-4, "penumbra ratio {mean} ± {se}");
}

#[test]
fn a_point_light_with_a_radius_is_a_disk_facing_what_it_lights() {
    // I = 3 W/sr, radius 0.4, 1 m above the floor: E at a floor point p is the integral
    // of the disk (radiance I / π r², facing p) over its area.
    let (i, r, h) = (3.0f64, 0.4f64, 1.0f64);
    let light = format!("type = \"point\"\nposition = [0.1, {h}, 0]\nintensity = [{i}, {i}, {i}]\nradius = {r}\n");
    let dir = TempDir::new("soft-point");
    let s = soft_scene(&dir, &light, false);
    let exact = |x: f64, z: f64| {
        let c = [0.1, h, 0.0];
        let p = [x, 0.0, z];
        let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let n = [d[0] / dist, d[1] / dist, d[2] / dist];
        // Two unit vectors on the disk's plane.
        let t = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        let dot = t[0] * n[0] + t[1] * n[1] + t[2] * n[2];
        let mut u = [t[0] - dot * n[0], t[1] - dot * n[1], t[2] - dot * n[2]];
        let ul = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
        u = [u[0] / ul, u[1] / ul, u[2] / ul];
        let v = [n[1] * u[2] - n[2] * u[1], n[2] * u[0] - n[0] * u[2], n[0] * u[1] - n[1] * u[0]];
        let (nr, np) = (30, 60);
        let mut e = 0.0;
        for a in 0..nr {
            let rho = r * ((a as f64 + 0.5) / nr as f64).sqrt();
            for b in 0..np {
                let phi = 2.0 * PI * (b as f64 + 0.5) / np as f64;
                let q: Vec<f64> = (0..3).map(|k| c[k] + rho * (phi.cos() * u[k] + phi.sin() * v[k])).collect();
                let w = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
                let d2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
                let wl = d2.sqrt();
                let cos_p = (w[1] / wl).max(0.0);
                let cos_l = -(w[0] * n[0] + w[1] * n[1] + w[2] * n[2]) / wl;
                e += cos_p * cos_l.max(0.0) / d2;
            }
        }
        let l = i / (PI * r * r);
        0.6 / PI * l * e * PI * r * r / (nr * np) as f64
    };
    for integrator in [Integrator::Path, Integrator::PathLightOnly, Integrator::PathBsdfOnly] {
        let spp = if integrator == Integrator::PathBsdfOnly { 1024 } else { 64 };
        let img = render(&s, integrator, spp);
        let (mean, se) = ratios_above(&s, &img, &exact, 0.05);
        let power = if integrator == Integrator::PathBsdfOnly { 0.03 } else { 0.01 };
        assert!(4.0 * se < power, "{integrator:?}: too weak, se {se}");
        assert!((mean - 1.0).abs() < 4.0 * se + 5e-4, "{integrator:?}: ratio {mean} ± {se}");
    }
}

/// [`ratios`] over the pixels whose analytic value at their centre exceeds `floor`
/// times the value at floor point (1, 0) (leaving out an umbra).
fn ratios_above(s: &Scene, img: &Image, exact: &dyn Fn(f64, f64) -> f64, floor: f64) -> (f64, f64) {
    let mut r = Vec::new();
    for y in 0..s.camera.height {
        for x in 0..s.camera.width {
            let ray = s.camera.generate_ray(Vec2::new(x as f32 + 0.5, y as f32 + 0.5), Vec2::ZERO);
            let p = ray.at(-ray.origin.y / ray.dir.y);
            if floor == 0.0 || exact(p.x as f64, p.z as f64) > floor * exact(1.0, 0.0).max(1e-9) {
                let n = 6;
                let reference: f64 = (0..n * n)
                    .map(|k| {
                        let o = Vec2::new((k % n) as f32 + 0.5, (k / n) as f32 + 0.5) / n as f32;
                        let ray = s.camera.generate_ray(Vec2::new(x as f32, y as f32) + o, Vec2::ZERO);
                        let p = ray.at(-ray.origin.y / ray.dir.y);
                        exact(p.x as f64, p.z as f64)
                    })
                    .sum::<f64>()
                    / (n * n) as f64;
                r.push(img.at(x, y).x as f64 / reference);
            }
        }
    }
    assert!(r.len() > 50, "only {} pixels lit", r.len());
    mean_stderr(&r)
}
