//! Light transport checked against analytic answers with statistical bounds: the white
//! furnace, a glass slab, a sphere light's irradiance, MIS consistency on the Veach
//! scene, and finite output on every bundled scene. Each test has a fixed seed, and its
//! bound comes from the measured spread of independent estimates, so it is stable and
//! still catches a 1% bias.

// Tests may use the C library's functions: they check values, not platform-free bits.
#![allow(clippy::disallowed_methods)]

mod common;

use std::path::Path;

use common::{TempDir, bundled, mean_stderr, render};

use glam::{Vec2, Vec3};
use tracer::film::Image;
use tracer::integrator::Integrator;
use tracer::scene::{Scene, scene_from_toml};

/// An axis-aligned box as OBJ faces, wound so that the front faces point outward
/// (`inward = false`) or into the box (`inward = true`).
fn box_obj(lo: Vec3, hi: Vec3, material: &str, inward: bool) -> String {
    let mut s = String::from("mtllib m.mtl\n");
    for i in 0..8 {
        let p = Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    s += &format!("usemtl {material}\n");
    // Counter-clockwise seen from outside.
    let faces = [[1, 3, 4, 2], [5, 6, 8, 7], [1, 2, 6, 5], [3, 7, 8, 4], [1, 5, 7, 3], [2, 4, 8, 6]];
    for f in faces {
        let f: Vec<i32> = if inward { f.iter().rev().copied().collect() } else { f.to_vec() };
        s += &format!("f {} {} {} {}\n", f[0], f[1], f[2], f[3]);
    }
    s
}

#[test]
fn box_obj_faces_point_the_requested_way() {
    let dir = TempDir::new("boxcheck");
    dir.write("m.mtl", "newmtl m\nKd 0.5 0.5 0.5\n");
    dir.write("b.obj", &box_obj(Vec3::splat(-1.0), Vec3::splat(1.0), "m", false));
    let model = tracer::scene::obj::load_obj(&dir.0.join("b.obj")).unwrap();
    for i in 0..model.mesh.tris.len() {
        let [a, b, c] = model.mesh.corners(i);
        let n = (b - a).cross(c - a);
        assert!(n.dot((a + b + c) / 3.0) > 0.0, "outward");
    }
}

/// A closed UV sphere of radius `r` as OBJ faces wound to face its inside.
fn inward_sphere_obj(r: f32, material: &str) -> String {
    let (rings, segments) = (24, 48);
    let mut s = format!("mtllib m.mtl\nv 0 {r} 0\nv 0 {} 0\n", -r);
    for i in 1..rings {
        let theta = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..segments {
            let phi = std::f32::consts::TAU * j as f32 / segments as f32;
            let p = r * Vec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin());
            s += &format!("v {} {} {}\n", p.x, p.y, p.z);
        }
    }
    s += &format!("usemtl {material}\n");
    let v = |i: usize, j: usize| 3 + (i - 1) * segments + j % segments; // ring i in 1..rings
    for j in 0..segments {
        // Seen from inside, counter-clockwise.
        s += &format!("f 1 {} {}\n", v(1, j), v(1, j + 1));
        s += &format!("f 2 {} {}\n", v(rings - 1, j + 1), v(rings - 1, j));
        for i in 1..rings - 1 {
            s += &format!("f {} {} {} {}\n", v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1));
        }
    }
    s
}

#[test]
fn white_furnace_converges_to_le_over_one_minus_albedo() {
    // A closed surface whose inside is emissive (Le) and diffuse (albedo a): the radiance
    // everywhere inside is Le / (1 - a), reached only with unlimited depth. A sphere (as
    // the textbook furnace) and a box (corners, flat faces, many emitters).
    let (le, a) = (0.5f32, 0.8f32);
    let expected = (le / (1.0 - a)) as f64;
    let dir = TempDir::new("furnace");
    dir.write("m.mtl", &format!("newmtl furnace\nKd {a} {a} {a}\nKe {le} {le} {le}\n"));
    dir.write("box.obj", &box_obj(Vec3::new(-1.0, -1.5, -2.0), Vec3::new(2.0, 1.0, 1.5), "furnace", true));
    dir.write("sphere.obj", &inward_sphere_obj(2.0, "furnace"));
    for mesh in ["sphere.obj", "box.obj"] {
        let s = scene_from_toml(
            &format!(
                r#"
[camera]
position = [0.1, -0.2, 0.3]
look_at = [1.0, 0.5, 1.0]
fov = 100
width = 16
height = 16
[render]
max_depth = -1
seed = 7
[[mesh]]
obj = "{mesh}"
"#
            ),
            "furnace.toml",
            &dir.0,
        )
        .unwrap();
        let img = render(&s, Integrator::Path, 512);
        // Every pixel has the same expectation, so pixel means are independent estimates.
        let px: Vec<f64> = img.pixels.iter().map(|p| p.x as f64).collect();
        let (mean, se) = mean_stderr(&px);
        let sd = se * (px.len() as f64).sqrt();
        assert!(4.0 * se < 0.01 * expected, "{mesh}: test too weak to see a 1% bias: se {se}");
        assert!((mean - expected).abs() < 4.0 * se, "{mesh}: furnace mean {mean}, expected {expected} ± {se}");
        for (i, &p) in px.iter().enumerate() {
            assert!((p - expected).abs() < 5.0 * sd.max(1e-3 * expected), "{mesh}: pixel {i}: {p} vs {expected}");
        }
        // Channels are identical for a grey furnace.
        assert!(img.pixels.iter().all(|p| p.x == p.y && p.y == p.z));
    }
}

fn slab_scene(dir: &TempDir, max_depth: i32) -> Scene {
    // A glass slab (IOR 1.5, 1 unit thick) in front of a large emitter facing the camera,
    // seen head-on through a narrow field of view.
    dir.write("m.mtl", "newmtl glass\nNi 1.5\nillum 7\nnewmtl light\nKd 0 0 0\nKe 1 1 1\n");
    let mut obj = box_obj(Vec3::new(-5.0, -5.0, 0.0), Vec3::new(5.0, 5.0, 1.0), "glass", false);
    obj += "v -50 -50 3\nv 50 -50 3\nv 50 50 3\nv -50 50 3\nusemtl light\nf 9 12 11 10\n";
    dir.write("slab.obj", &obj);
    scene_from_toml(
        &format!(
            r#"
[camera]
position = [0.0, 0.0, -100.0]
look_at = [0.0, 0.0, 0.0]
fov = 1.5
width = 32
height = 32
[render]
max_depth = {max_depth}
seed = 3
[[mesh]]
obj = "slab.obj"
"#
        ),
        "slab.toml",
        &dir.0,
    )
    .unwrap()
}

#[test]
fn glass_slab_at_normal_incidence_transmits_one_minus_f_squared() {
    let eta = 1.5f64;
    let f = ((eta - 1.0) / (eta + 1.0)).powi(2);
    let dir = TempDir::new("slab");
    // Three segments: camera → front face → back face → emitter. Only the straight
    // refracted path fits: (1 - F)².
    // Unlimited depth adds the inter-reflections inside the slab: (1 - F)² Σ F^2k = (1 - F)/(1 + F).
    for (depth, expected) in [(3, (1.0 - f) * (1.0 - f)), (-1, (1.0 - f) / (1.0 + f))] {
        let s = slab_scene(&dir, depth);
        let img = render(&s, Integrator::Path, 256);
        let px: Vec<f64> = img.pixels.iter().map(|p| p.y as f64).collect();
        let (mean, se) = mean_stderr(&px);
        assert!(4.0 * se < 0.005 * expected, "test too weak: se {se}");
        assert!(
            (mean - expected).abs() < 4.0 * se + 1e-4,
            "max_depth {depth}: transmitted {mean} ± {se}, expected {expected}"
        );
    }
}

/// Renders a Lambertian floor (albedo kd) under a sphere light of radiance `l`, radius
/// `r` at height `h`, and compares pixels with the analytic radiance
/// kd · L · (r/d)² · cos θ (the irradiance of a sphere fully above the horizon is
/// π L sin²α cos θ, with sin α = r/d).
#[test]
fn sphere_light_irradiance_matches_pi_l_sin_squared() {
    let (kd, l, r, c) = (0.5f32, 4.0f32, 0.5f32, Vec3::new(0.3, 3.5, 1.0));
    let dir = TempDir::new("spherelight");
    dir.write("m.mtl", &format!("newmtl floor\nKd {kd} {kd} {kd}\n"));
    dir.write("floor.obj", "mtllib m.mtl\nv -20 0 -20\nv 20 0 -20\nv 20 0 20\nv -20 0 20\nusemtl floor\nf 1 4 3 2\n");
    for integrator in [Integrator::Path, Integrator::PathLightOnly, Integrator::PathBsdfOnly] {
        let s = scene_from_toml(
            &format!(
                r#"
[camera]
position = [0.0, 3.0, -3.0]
look_at = [0.0, 0.0, 1.0]
fov = 40
width = 24
height = 18
[render]
max_depth = 2
seed = 11
[[mesh]]
obj = "floor.obj"
[[sphere]]
center = [{}, {}, {}]
radius = {r}
ke = [{l}, {l}, {l}]
"#,
                c.x, c.y, c.z
            ),
            "sphere-light.toml",
            &dir.0,
        )
        .unwrap();
        let spp = if integrator == Integrator::PathBsdfOnly { 1024 } else { 128 };
        let img = render(&s, integrator, spp);
        let analytic = |film: Vec2| -> f32 {
            let ray = s.camera.generate_ray(film, Vec2::ZERO);
            let p = ray.at(-ray.origin.y / ray.dir.y);
            let d = c - p;
            let dist = d.length();
            kd * l * (r / dist).powi(2) * (d.y / dist)
        };
        // Ratios of estimate to the pixel-averaged analytic value: independent, mean 1.
        let mut ratios = Vec::new();
        for y in 0..s.camera.height {
            for x in 0..s.camera.width {
                let n = 8;
                let reference: f32 = (0..n * n)
                    .map(|k| {
                        let o = Vec2::new((k % n) as f32 + 0.5, (k / n) as f32 + 0.5) / n as f32;
                        analytic(Vec2::new(x as f32, y as f32) + o)
                    })
                    .sum::<f32>()
                    / (n * n) as f32;
                ratios.push(img.at(x, y).x as f64 / reference as f64);
            }
        }
        let (mean, se) = mean_stderr(&ratios);
        // BSDF sampling alone is the weak strategy for a small light: a looser check.
        let power = if integrator == Integrator::PathBsdfOnly { 0.05 } else { 0.01 };
        assert!(4.0 * se < power, "{integrator:?}: test too weak, se {se}");
        assert!((mean - 1.0).abs() < 4.0 * se + 5e-4, "{integrator:?}: ratio {mean} ± {se}");
    }
}

#[test]
fn sphere_light_sampling_estimates_irradiance_exactly() {
    use tracer::light::Light;
    // Irradiance at a point facing the sphere's centre: E = π L sin²θ, sin θ = r/d.
    let (l, r, d) = (3.0f32, 0.7f32, 2.5f32);
    let light = Light::Sphere { prim: 0, center: Vec3::new(0.0, 0.0, d), radius: r, radiance: Vec3::splat(l) };
    let n = 1 << 16;
    let mut sum = 0.0f64;
    for i in 0..n {
        let mut sampler = tracer::sampler::Sampler::new(5, 0, 0, i);
        let s = light.sample_li(Vec3::ZERO, sampler.next_2d()).unwrap();
        sum += (s.li.x * s.wi.z.max(0.0) / s.pdf) as f64;
    }
    let estimate = sum / n as f64;
    let exact = std::f64::consts::PI * l as f64 * (r as f64 / d as f64).powi(2);
    assert!((estimate / exact - 1.0).abs() < 1e-3, "{estimate} vs {exact}");
}

/// Per-pixel means over `seeds` independent renders, and their per-pixel variance.
fn seeded_stats(s: &mut Scene, integrator: Integrator, spp: u32, seeds: u64) -> (Vec<f64>, Vec<f64>) {
    let imgs: Vec<Image> = (0..seeds)
        .map(|seed| {
            s.settings.seed = 1000 + seed;
            render(s, integrator, spp)
        })
        .collect();
    let n = imgs[0].pixels.len();
    let lum = |p: Vec3| (p.x + p.y + p.z) as f64 / 3.0;
    let mut mean = vec![0.0; n];
    let mut var = vec![0.0; n];
    for i in 0..n {
        let v: Vec<f64> = imgs.iter().map(|im| lum(im.pixels[i])).collect();
        let m = v.iter().sum::<f64>() / v.len() as f64;
        mean[i] = m;
        var[i] = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() as f64 - 1.0);
    }
    (mean, var)
}

#[test]
fn veach_mis_estimators_agree_and_mis_beats_each_where_it_fails() {
    let mut s = tracer::scene::load_scene(&bundled("veach-mis")).unwrap();
    s.camera.width = 96;
    s.camera.height = 64;
    s.settings.max_depth = 2;
    // Which plate each pixel's centre sees.
    let plate_of: Vec<Option<usize>> = (0..s.camera.height)
        .flat_map(|y| (0..s.camera.width).map(move |x| (x, y)))
        .map(|(x, y)| {
            let ray = s.camera.generate_ray(Vec2::new(x as f32 + 0.5, y as f32 + 0.5), Vec2::ZERO);
            let hit = s.intersect(&ray, f32::INFINITY)?;
            let si = s.interaction(&ray, &hit);
            let name = &s.material_names[si.material as usize];
            name.strip_prefix("plate").and_then(|k| k.parse::<usize>().ok()).map(|k| k - 1)
        })
        .collect();
    let seeds = 6;
    let (m_mis, v_mis) = seeded_stats(&mut s, Integrator::Path, 16, seeds);
    let (m_light, v_light) = seeded_stats(&mut s, Integrator::PathLightOnly, 16, seeds);
    let (m_bsdf, v_bsdf) = seeded_stats(&mut s, Integrator::PathBsdfOnly, 16, seeds);
    let mut region_var = [[0.0f64; 3]; 4];
    for (plate, rv) in region_var.iter_mut().enumerate() {
        let pixels: Vec<usize> = (0..plate_of.len()).filter(|&i| plate_of[i] == Some(plate)).collect();
        assert!(pixels.len() > 50, "plate {plate} covers {} pixels", pixels.len());
        // Region sums: the variance of a sum of independent pixels is the sum of variances.
        let sum = |m: &[f64]| pixels.iter().map(|&i| m[i]).sum::<f64>();
        let var_of_mean = |v: &[f64]| pixels.iter().map(|&i| v[i]).sum::<f64>() / seeds as f64;
        let (a, b, c) = (sum(&m_mis), sum(&m_light), sum(&m_bsdf));
        let (va, vb, vc) = (var_of_mean(&v_mis), var_of_mean(&v_light), var_of_mean(&v_bsdf));
        eprintln!("plate {plate}: mis {a} ± {} light {b} ± {} bsdf {c} ± {}", va.sqrt(), vb.sqrt(), vc.sqrt());
        for (name, x, vx) in [("light", b, vb), ("bsdf", c, vc)] {
            let bound = 5.0 * (va + vx).sqrt() + 1e-3 * a.abs();
            assert!((a - x).abs() < bound, "plate {plate}: MIS {a} vs {name}-only {x} (bound {bound})");
        }
        let mean_var = |v: &[f64]| pixels.iter().map(|&i| v[i]).sum::<f64>() / pixels.len() as f64;
        *rv = [mean_var(&v_mis), mean_var(&v_light), mean_var(&v_bsdf)];
    }
    // Light sampling fails on the sharpest plate (plate 4), BSDF sampling on the roughest
    // (plate 1): MIS must be clearly better than the failing strategy there.
    let [mis, light, _] = region_var[3];
    assert!(mis * 2.0 < light, "sharp plate: MIS variance {mis} vs light-only {light}");
    let [mis, _, bsdf] = region_var[0];
    assert!(mis * 2.0 < bsdf, "rough plate: MIS variance {mis} vs BSDF-only {bsdf}");
    eprintln!("per-plate pixel variance [mis, light, bsdf]: {region_var:?}");
}

#[test]
fn every_bundled_scene_renders_finite() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .filter(|e| e.path().join("scene.toml").exists())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert!(names.len() >= 6, "{names:?}");
    for name in names {
        let mut s = tracer::scene::load_scene(&bundled(&name)).unwrap();
        let aspect = s.camera.width as f32 / s.camera.height as f32;
        s.camera.width = 48;
        s.camera.height = (48.0 / aspect).round() as u32;
        for integrator in [Integrator::Path, Integrator::Normals, Integrator::Albedo, Integrator::Depth] {
            let img = render(&s, integrator, 4);
            assert!(img.pixels.iter().all(|p| p.is_finite()), "{name} {integrator:?}");
            if integrator == Integrator::Path {
                assert!(img.pixels.iter().any(|p| p.max_element() > 0.0), "{name} is black");
            }
        }
    }
}
