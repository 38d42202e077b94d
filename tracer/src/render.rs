//! Rendering units of work. [`render_unit`] is the one function that both the
//! in-process renderer and the farm's workers call: a tile over a range of sample
//! indices, into an [`Accumulation`] that merges exactly with any other range.

use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec2;
use rayon::prelude::*;

use crate::film::{Accumulation, FirstHit, Image, SampleRange, Tile};
use crate::integrator::{Integrator, RayCount, li, path_options};
use crate::sampler::Sampler;
use crate::scene::Scene;

/// Renders `samples` of every pixel of `tile`. Each sample's random numbers depend only
/// on (scene seed, pixel, sample index), so the result does not depend on where or in
/// which grouping the samples are rendered.
pub fn render_unit(scene: &Scene, integrator: Integrator, tile: Tile, samples: SampleRange) -> Accumulation {
    render_unit_counted(scene, integrator, tile, samples).0
}

/// [`render_unit`] that also returns the number of rays traced.
pub fn render_unit_counted(
    scene: &Scene,
    integrator: Integrator,
    tile: Tile,
    samples: SampleRange,
) -> (Accumulation, RayCount) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        if std::is_x86_feature_detected!("gfni") {
            // SAFETY: the CPU reports AVX2 and GFNI.
            return unsafe { render_unit_avx2_gfni(scene, integrator, tile, samples) };
        }
        // SAFETY: the CPU reports AVX2.
        return unsafe { render_unit_avx2(scene, integrator, tile, samples) };
    }
    render_unit_loop(scene, integrator, tile, samples)
}

/// The render loop compiled for CPUs with AVX2 and GFNI. With GFNI the sampler's bit
/// reversals (three per 2D sample) become one affine byte transform and a byte swap
/// instead of about a dozen shifts and masks each. AVX2 brings three-operand VEX forms
/// (fewer register copies), SSE4.1 rounding for the film's fixed point, and nothing
/// that changes a result: not FMA (Rust never contracts `a * b + c` anyway), and the
/// same IEEE operations, so every result is the same bit for bit; it is a few per cent
/// faster than the GFNI-only loop (`bench/RESULTS.md`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,gfni")]
fn render_unit_avx2_gfni(
    scene: &Scene,
    integrator: Integrator,
    tile: Tile,
    samples: SampleRange,
) -> (Accumulation, RayCount) {
    render_unit_simd(scene, integrator, tile, samples)
}

/// The render loop for CPUs with AVX2 but no GFNI (see [`render_unit_avx2_gfni`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn render_unit_avx2(
    scene: &Scene,
    integrator: Integrator,
    tile: Tile,
    samples: SampleRange,
) -> (Accumulation, RayCount) {
    render_unit_simd(scene, integrator, tile, samples)
}

/// The AVX2 variants' body: eight paths at a time (`integrator/eight_paths.rs`) for the path
/// integrators where that pays (see [`crate::integrator::eight_paths::pays`]), else the loop
/// below. Both give the same bits.
///
/// Only called from functions compiled with AVX2, on CPUs that have it.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn render_unit_simd(
    scene: &Scene,
    integrator: Integrator,
    tile: Tile,
    samples: SampleRange,
) -> (Accumulation, RayCount) {
    if let Some(opt) = path_options(integrator, scene)
        && crate::integrator::eight_paths::pays(scene)
        && let Some(simd) = crate::simd::Simd::detect()
    {
        return crate::integrator::eight_paths::render_unit(simd, scene, &opt, tile, samples);
    }
    render_unit_loop(scene, integrator, tile, samples)
}

/// Every sample of every pixel of `tile` (inlined, with the integrator, into each of the
/// instruction-set variants above).
#[inline(always)]
fn render_unit_loop(
    scene: &Scene,
    integrator: Integrator,
    tile: Tile,
    samples: SampleRange,
) -> (Accumulation, RayCount) {
    let layers = scene.settings.aovs;
    let mut acc = Accumulation::with_layers(tile, layers);
    let mut count = RayCount::default();
    let cam = &scene.camera;
    let seed = scene.settings.seed;
    let mut first = FirstHit::default();
    for ty in 0..tile.height {
        for tx in 0..tile.width {
            let (x, y) = (tile.x0 + tx, tile.y0 + ty);
            let i = (ty * tile.width + tx) as usize;
            for s in samples.start..samples.end {
                let mut sampler = Sampler::new(seed, x, y, s);
                // Box filter: uniform positions within the pixel.
                let film = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                let lens = if cam.has_lens() { sampler.next_2d() } else { Vec2::ZERO };
                let ray = cam.generate_ray(film, lens);
                // The first hit only when the film keeps layers (a branch per sample, not
                // a second copy of the inlined integrator).
                let f = if layers { Some(&mut first) } else { None };
                let l = li(integrator, scene, ray, &mut sampler, &mut count, f);
                acc.add_sample_at(i, l, &first);
            }
        }
    }
    (acc, count)
}

/// Totals of a whole-image render.
#[derive(Clone, Copy, Debug, Default)]
pub struct RenderStats {
    pub samples: u64,
    pub rays: u64,
    pub nonfinite: u64,
}

/// What a panic's payload says (`panic!` with a literal or a formatted message), for
/// reporting a render unit that panicked instead of losing it.
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}

/// Renders the whole image in this process on the rayon pool: tiles in parallel, each
/// over all of `samples`. `progress(samples_done)` is called as tiles finish.
pub fn render_image(
    scene: &Scene,
    integrator: Integrator,
    samples: SampleRange,
    tile_size: u32,
    progress: &(dyn Fn(u64) + Sync),
) -> (Image, RenderStats) {
    let (w, h) = (scene.camera.width, scene.camera.height);
    let rays = AtomicU64::new(0);
    let accs: Vec<Accumulation> = Tile::grid(w, h, tile_size)
        .into_par_iter()
        .map(|tile| {
            let (acc, count) = render_unit_counted(scene, integrator, tile, samples);
            rays.fetch_add(count.rays, Ordering::Relaxed);
            progress(tile.pixel_count() as u64 * samples.len() as u64);
            acc
        })
        .collect();
    let mut image = Image::new(w, h);
    let mut stats = RenderStats { rays: rays.into_inner(), ..Default::default() };
    for acc in &accs {
        image.put(acc);
        stats.nonfinite += acc.nonfinite;
        stats.samples += acc.counts.iter().map(|&c| c as u64).sum::<u64>();
    }
    (image, stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bundled scenes, plus one with what they lack: stochastic opacity on triangles
    /// and spheres, a thin lens, an environment, spot, point and directional lights, an
    /// emissive sphere, glass and a mirror.
    // Long on purpose: A table of test scenes, one entry each; long as a list is, not as logic.
    fn test_scenes() -> Vec<(String, Scene)> {
        let dir = std::env::temp_dir().join(format!("tilefarm-render-variants-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("m.mtl"),
            "newmtl floor\nKd 0.6 0.6 0.5\nKs 0.2 0.2 0.2\nNs 40\n\
             newmtl screen\nKd 0.3 0.7 0.3\nd 0.5\n\
             newmtl lamp\nKd 0 0 0\nKe 4 4 3\n",
        )
        .unwrap();
        std::fs::write(
            dir.join("m.obj"),
            "mtllib m.mtl\nv -3 0 -3\nv 3 0 -3\nv 3 0 3\nv -3 0 3\nv -1 0 1\nv 1 0 1\nv 1 2 1\nv -1 2 1\n\
             v -0.5 3 -0.5\nv 0.5 3 -0.5\nv 0.5 3 0.5\nv -0.5 3 0.5\n\
             usemtl floor\nf 1 4 3 2\nusemtl screen\nf 5 6 7 8\nusemtl lamp\nf 9 10 11 12\n",
        )
        .unwrap();
        let toml = r#"
[camera]
position = [0.5, 1.5, -6.0]
look_at = [0.0, 0.8, 0.0]
fov = 45
width = 64
height = 48
aperture = 0.05
focus_distance = 6.0
[render]
max_depth = 7
seed = 3
[[mesh]]
obj = "m.obj"
[[sphere]]
center = [-1.5, 0.6, -0.5]
radius = 0.6
ks = [1.0, 1.0, 1.0]
ni = 1.5
illum = 7
[[sphere]]
center = [1.5, 0.5, -0.8]
radius = 0.5
ks = [0.9, 0.9, 0.9]
illum = 3
[[sphere]]
center = [0.0, 0.4, -1.5]
radius = 0.4
kd = [0.5, 0.2, 0.2]
d = 0.4
[[sphere]]
center = [2.0, 2.5, 1.0]
radius = 0.2
ke = [20.0, 15.0, 10.0]
[[light]]
type = "point"
position = [-2.0, 3.0, -2.0]
intensity = [5.0, 5.0, 5.0]
[[light]]
type = "spot"
position = [2.0, 3.0, -2.0]
direction = [-0.5, -1.0, 0.5]
intensity = [20.0, 10.0, 5.0]
cone_angle = 30
falloff_start = 20
[[light]]
type = "directional"
direction = [0.3, -1.0, 0.2]
irradiance = [0.5, 0.5, 0.6]
[background]
radiance = [0.1, 0.15, 0.2]
"#;
        let extra = crate::scene::scene_from_toml(toml, "variants.toml", &dir).unwrap();
        assert!(extra.has_cutouts && extra.camera.has_lens() && extra.packed.is_some());
        // For the eight-path renderer's wide route: an open box lit by a triangle lamp,
        // a sphere light, a point light, a spot light (half the box in its cone), a
        // directional light and the background,
        // with diffuse and glossy surfaces, spheres and smooth-shaded triangles (one
        // whose `vn` are zero, so the loader computes them, one whose normals face
        // away: its lanes), a mirror sphere
        // (lanes it leaves to the one-path code), and unlimited depth (long paths,
        // Russian roulette).
        std::fs::write(
            dir.join("w.mtl"),
            "newmtl wall\nKd 0.8 0.75 0.7\nnewmtl shiny\nKd 0.2 0.3 0.2\nKs 0.5 0.5 0.5\nNs 60\n\
             newmtl lamp\nKd 0.5 0.5 0.5\nKe 3 3 2.5\n",
        )
        .unwrap();
        std::fs::write(
            dir.join("w.obj"),
            "mtllib w.mtl\nv -2 0 -2\nv 2 0 -2\nv 2 0 2\nv -2 0 2\nv -2 3 -2\nv 2 3 -2\nv 2 3 2\nv -2 3 2\n\
             v -0.5 2.99 -0.5\nv 0.5 2.99 -0.5\nv 0.5 2.99 0.5\nv -0.5 2.99 0.5\n\
             v -1 0.01 0\nv 0 0.01 1.5\nv 1 1.5 1\nvn 0.3 1 0.1\nvn -0.2 1 0.3\nvn 0.5 0.5 -0.2\n\
             v -1.9 0.01 -1.5\nv -1.2 0.01 -1.5\nv -1.5 1.0 -1.9\nvn 0 0 0\nvn 0 -1 0\n\
             usemtl shiny\nf 1 4 3 2\nusemtl wall\nf 4 8 7 3\nf 1 5 8 4\nf 2 3 7 6\nf 5 6 7 8\n\
             usemtl lamp\nf 9 10 11 12\nusemtl shiny\nf 13//1 14//2 15//3\nusemtl wall\nf 16//4 17//4 18//4\n\
             f 16//5 18//5 17//5\n",
        )
        .unwrap();
        let toml = r#"
[camera]
position = [0.0, 1.5, -7.0]
look_at = [0.0, 1.2, 0.0]
fov = 40
width = 64
height = 48
[render]
max_depth = -1
seed = 5
[[mesh]]
obj = "w.obj"
[[sphere]]
center = [-0.9, 0.5, -0.3]
radius = 0.5
kd = [0.3, 0.3, 0.7]
ks = [0.4, 0.4, 0.4]
ns = 200
[[sphere]]
center = [0.9, 0.4, 0.4]
radius = 0.4
kd = [0.7, 0.6, 0.2]
[[sphere]]
center = [0.2, 0.3, -1.2]
radius = 0.3
ks = [0.9, 0.9, 0.9]
illum = 3
[[sphere]]
center = [1.5, 2.5, 1.5]
radius = 0.1
ke = [30.0, 25.0, 20.0]
[[light]]
type = "point"
position = [-1.5, 2.5, -1.0]
intensity = [2.0, 2.0, 2.0]
[[light]]
type = "spot"
position = [1.0, 2.8, -1.0]
direction = [-0.3, -1.0, 0.4]
intensity = [8.0, 6.0, 4.0]
cone_angle = 35
falloff_start = 15
[[light]]
type = "directional"
direction = [0.4, -1.0, 0.6]
irradiance = [0.3, 0.3, 0.35]
[background]
radiance = [0.05, 0.06, 0.08]
"#;
        let wide = crate::scene::scene_from_toml(toml, "wide.toml", &dir).unwrap();
        assert!(wide.lights.wide_ok() && wide.lights.lights.len() == 7 && wide.packed.is_some());
        // The same under an environment map (turned, Z up): its samples on the wide route.
        let sky = image::RgbImage::from_fn(16, 9, |x, y| image::Rgb([(x * 15) as u8, (y * 28) as u8, 200]));
        sky.save(dir.join("sky.png")).unwrap();
        // And two area lights (a rectangle by its frame, a disk by its matrix) and a point,
        // a spot and a sun with a size: lit by light sampling on the wide route, met by
        // the scattered rays of both routes.
        let with_map = toml.replace(
            "[background]\nradiance = [0.05, 0.06, 0.08]",
            "[[light]]\ntype = \"area\"\nsize = [0.8, 0.5]\nposition = [-1.0, 2.5, 0.5]\ndirection = [0.3, -1, 0]\n\
             power = 20\n[[light]]\ntype = \"area\"\nshape = \"disk\"\nsize = 0.6\n\
             matrix = [[1, 0, 0, 1.2], [0, 0, 1, 2.0], [0, -1, 0, -0.5], [0, 0, 0, 1]]\nradiance = [4, 3, 2]\n\
             [[light]]\ntype = \"point\"\nposition = [0.5, 2.0, -1.0]\nintensity = [1, 1, 1]\nradius = 0.2\n\
             [[light]]\ntype = \"spot\"\nposition = [-0.5, 2.5, 0.0]\ndirection = [0, -1, 0.2]\n\
             intensity = [3, 3, 3]\ncone_angle = 40\nfalloff_start = 20\nradius = 0.1\n\
             [[light]]\ntype = \"directional\"\ndirection = [-0.3, -1.0, 0.4]\nirradiance = [0.3, 0.3, 0.3]\n\
             angle = 8\n\
             [background]\nmap = \"sky.png\"\nstrength = 0.2\nrotate = 30\nup = \"z\"",
        );
        let wide_map = crate::scene::scene_from_toml(&with_map, "wide-map.toml", &dir).unwrap();
        assert!(wide_map.lights.wide_ok() && wide_map.lights.environment_map().is_some());
        // The same with a finely divided back wall: too many triangles for brute force,
        // so the eight paths' rays go through the kd-tree one by one.
        let mut grid = String::from("mtllib w.mtl\nusemtl wall\n");
        for j in 0..=12 {
            for i in 0..=12 {
                grid += &format!("v {} {} 1.99\n", -2.0 + i as f32 / 3.0, j as f32 / 4.0);
            }
        }
        for j in 0..12 {
            for i in 0..12 {
                let v = 1 + j * 13 + i;
                grid += &format!("f {} {} {} {}\n", v, v + 13, v + 14, v + 1);
            }
        }
        std::fs::write(dir.join("grid.obj"), &grid).unwrap();
        let tree =
            crate::scene::scene_from_toml(&format!("{toml}[[mesh]]\nobj = \"grid.obj\"\n"), "wide-tree.toml", &dir)
                .unwrap();
        // The grid alone as a mirror: no surface takes the wide route, so eight paths
        // at a time would not pay.
        std::fs::write(dir.join("m.mtl"), "newmtl wall\nKs 0.9 0.9 0.9\nillum 3\n").unwrap();
        std::fs::write(dir.join("mirror.obj"), grid.replace("w.mtl", "m.mtl")).unwrap();
        let light = "[[light]]\ntype = \"point\"\nposition = [0.0, 2.0, 0.0]\nintensity = [1.0, 1.0, 1.0]\n";
        let camera = &toml[..toml.find("[[mesh]]").unwrap()];
        let mirror =
            crate::scene::scene_from_toml(&format!("{camera}[[mesh]]\nobj = \"mirror.obj\"\n{light}"), "m.toml", &dir)
                .unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert!(tree.packed.is_none() && crate::integrator::eight_paths::pays(&tree));
        assert!(mirror.packed.is_none() && mirror.lights.wide_ok() && !crate::integrator::eight_paths::pays(&mirror));
        let mut scenes = vec![
            ("variants.toml".to_string(), extra),
            ("wide.toml".to_string(), wide),
            ("wide-map.toml".to_string(), wide_map),
            ("wide-tree.toml".to_string(), tree),
        ];
        // Every bundled scene, so that every material and light kind is covered.
        let bundled = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
        for dir in std::fs::read_dir(&bundled).unwrap() {
            let path = dir.unwrap().path().join("scene.toml");
            if path.exists() {
                scenes.push((path.display().to_string(), crate::scene::load_scene(&path).unwrap()));
            }
        }
        assert!(scenes.len() >= 10, "only {} bundled scenes found", scenes.len() - 4);
        scenes
    }

    /// The instruction-set variants of the render loop, and with them the eight-path
    /// renderer of `integrator/eight_paths.rs` (with packet queries for the scenes traced by
    /// brute force, all but the cup), give the baseline loop's bits, for every path
    /// integrator and an AOV.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn loop_variants_are_the_baseline_loop() {
        crate::simd::tests::require_avx2();
        let integrators = [Integrator::Path, Integrator::PathLightOnly, Integrator::PathBsdfOnly, Integrator::Normals];
        let mut in_packets = 0;
        for (name, mut scene) in test_scenes() {
            in_packets += usize::from(scene.packed.as_ref().is_some_and(|p| p.packets()));
            (scene.camera.width, scene.camera.height) = (24, 16);
            // A tile whose pixel count is not a multiple of eight, and a sample range
            // that starts at neither zero nor a multiple of eight.
            let tile = Tile::new(1, 2, 23, 13);
            let samples = SampleRange::new(3, 14);
            for integrator in integrators {
                let base = render_unit_loop(&scene, integrator, tile, samples);
                // SAFETY: AVX2 was detected above.
                let avx2 = unsafe { render_unit_avx2(&scene, integrator, tile, samples) };
                assert_eq!(base, avx2, "{name} {integrator:?}");
                if std::is_x86_feature_detected!("gfni") {
                    // SAFETY: AVX2 and GFNI were detected.
                    let gfni = unsafe { render_unit_avx2_gfni(&scene, integrator, tile, samples) };
                    assert_eq!(base, gfni, "{name} {integrator:?}");
                }
                assert!(base.0.sums.iter().any(|s| *s != [0; 3]), "nothing rendered in {name}");
            }
            // Firefly control clamps the same samples on both routes.
            scene.settings.clamp = Some(0.25);
            let base = render_unit_loop(&scene, Integrator::Path, tile, samples);
            // SAFETY: AVX2 was detected above.
            let avx2 = unsafe { render_unit_avx2(&scene, Integrator::Path, tile, samples) };
            assert_eq!(base, avx2, "{name} clamped");
            for i in 0..tile.pixel_count() {
                let m = base.0.mean(i).max_element();
                assert!(m <= 0.25 + 1e-6 || !m.is_finite(), "{name}: pixel {i} at {m} above the clamp");
            }
            // With the AOV layers kept: the same layers on both routes, and the beauty
            // pass's bits unchanged by keeping them.
            scene.settings.aovs = true;
            let layered = render_unit_loop(&scene, Integrator::Path, tile, samples);
            // SAFETY: AVX2 was detected above.
            let avx2 = unsafe { render_unit_avx2(&scene, Integrator::Path, tile, samples) };
            assert_eq!(layered, avx2, "{name} with layers");
            assert_eq!((&layered.0.sums, &layered.0.counts), (&base.0.sums, &base.0.counts), "{name}");
            assert!(layered.0.layers.iter().any(|l| l[crate::film::layers::HITS_AT] > 0), "{name}: no hits");
            // The first-hit layers, which the paths record from the surface data they
            // shade with, are what the AOV integrators find along the same camera rays;
            // also where paths end at their first hit (`max_depth = 1`).
            use crate::film::layers::{ALBEDO_AT, DEPTH_AT, NORMAL_AT};
            let aovs = [
                (Integrator::Albedo, ALBEDO_AT, 3),
                (Integrator::Normals, NORMAL_AT, 3),
                (Integrator::Depth, DEPTH_AT, 1),
            ]
            .map(|(integrator, at, n)| (integrator, at, n, render_unit_loop(&scene, integrator, tile, samples)));
            scene.settings.max_depth = 1;
            // SAFETY: AVX2 was detected above.
            let shallow = unsafe { render_unit_avx2(&scene, Integrator::Path, tile, samples) };
            for (integrator, at, n, aov) in &aovs {
                for layered in [&layered, &shallow] {
                    for (i, (l, s)) in layered.0.layers.iter().zip(&aov.0.sums).enumerate() {
                        assert_eq!(l[*at..at + n], s[..*n], "{name} {integrator:?}: pixel {i}");
                    }
                }
            }
        }
        assert!(in_packets >= 7, "only {in_packets} scenes traced in packets");
    }
}
