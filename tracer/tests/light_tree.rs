//! Many lights (issue 50): a floor under 1,000 small sphere lights of unequal power. The
//! light hierarchy must beat choosing by power alone at equal samples, measured against
//! a reference rendered by power selection (an estimator independent of the hierarchy)
//! at 64× the samples and another seed.

// Tests may use the C library's functions: they check values, not platform-free bits.
#![allow(clippy::disallowed_methods)]

mod common;

use std::time::Instant;

use common::TempDir;
use tracer::film::{Image, SampleRange};
use tracer::integrator::Integrator;
use tracer::render::render_image;
use tracer::scene::{Scene, scene_from_toml};

fn render(s: &Scene, spp: u32) -> (Image, f64) {
    let t = Instant::now();
    let (img, stats) = render_image(s, Integrator::Path, SampleRange::new(0, spp), 8, &|_| {});
    assert_eq!(stats.nonfinite, 0, "non-finite samples");
    (img, t.elapsed().as_secs_f64())
}

/// Mean over pixels of (x − ref)² / (ref² + ε), on the luminance.
fn rel_mse(img: &Image, reference: &Image) -> f64 {
    let lum = |p: glam::Vec3| f64::from(p.x + p.y + p.z) / 3.0;
    let n = img.pixels.len() as f64;
    img.pixels
        .iter()
        .zip(&reference.pixels)
        .map(|(&a, &r)| (lum(a) - lum(r)).powi(2) / (lum(r).powi(2) + 1e-4))
        .sum::<f64>()
        / n
}

fn scene(dir: &TempDir, seed: u64) -> Scene {
    dir.write("m.mtl", "newmtl floor\nKd 0.7 0.7 0.7\n");
    dir.write("floor.obj", "mtllib m.mtl\nv -12 0 -12\nv 12 0 -12\nv 12 0 12\nv -12 0 12\nusemtl floor\nf 1 4 3 2\n");
    let mut toml = format!(
        "[camera]\nposition = [0, 9, 7]\nlook_at = [0, 0, 0]\nfov = 60\nwidth = 48\nheight = 32\n\
         [render]\nmax_depth = 2\nseed = {seed}\n[[mesh]]\nobj = \"floor.obj\"\n"
    );
    // A 40 × 25 grid of small lights, their power spread over two decades.
    for i in 0..1000u32 {
        let (gx, gz) = ((i % 40) as f32, (i / 40) as f32);
        let h = ((i * 7919) % 97) as f32 / 97.0;
        let power = 0.2 * 100f32.powf(((i * 104_729) % 89) as f32 / 89.0);
        toml += &format!(
            "[[sphere]]\ncenter = [{}, {}, {}]\nradius = 0.03\nke = [{power}, {}, {}]\n",
            -10.0 + gx * 0.5 + 0.1 * h,
            0.2 + 0.6 * h,
            -6.0 + gz * 0.5,
            power * (0.5 + 0.5 * h),
            power * (1.0 - 0.5 * h),
        );
    }
    scene_from_toml(&toml, "many.toml", &dir.0).unwrap()
}

#[test]
fn the_light_hierarchy_beats_power_selection_on_a_thousand_lights() {
    let dir = TempDir::new("many-lights");
    let tree = scene(&dir, 1);
    assert!(tree.lights.tree_bytes() > 0, "a thousand lights build the hierarchy");
    let mut power = scene(&dir, 1);
    power.lights.use_power_selection();
    let mut reference_scene = scene(&dir, 77);
    reference_scene.lights.use_power_selection();
    let spp = 16;
    let (reference, _) = render(&reference_scene, 64 * spp);
    // Alternated rounds for the times (printed, not asserted).
    let (mut t_tree, mut t_power) = (Vec::new(), Vec::new());
    let (mut e_tree, mut e_power) = (0.0, 0.0);
    for _ in 0..3 {
        let (img, t) = render(&tree, spp);
        (e_tree, _) = (rel_mse(&img, &reference), t_tree.push(t));
        let (img, t) = render(&power, spp);
        (e_power, _) = (rel_mse(&img, &reference), t_power.push(t));
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (tt, tp) = (median(&mut t_tree), median(&mut t_power));
    // The reference's own error, for scale: the same render at another seed and spp.
    println!(
        "1,000 lights, {spp} spp: relMSE hierarchy {e_tree:.4e}, power {e_power:.4e} ({:.1}× lower); \
         render {tt:.3} s against {tp:.3} s; at equal time the hierarchy's relMSE is {:.1}× lower",
        e_power / e_tree,
        e_power / (e_tree * tt / tp),
    );
    assert!(e_tree * 2.0 < e_power, "the hierarchy ({e_tree:.3e}) is not 2× better than power ({e_power:.3e})");
}
