//! What keeping the AOV layers (`[render] aovs`) costs a render: the bundled scenes'
//! tiles rendered with and without them, single-threaded, in alternating rounds (this
//! host's speed drifts, so only a ratio from interleaved rounds is steady). Prints each
//! scene's median time per round both ways and their ratio.
//!
//! `cargo bench -p tracer --bench layers` (`LAYERS_ROUNDS=N`, default 15;
//! `LAYERS_SCENES=cornell-box,glass`, default: the Cornell box, glass and Veach MIS).

use std::time::Instant;

use tracer::film::{SampleRange, Tile};
use tracer::integrator::Integrator;
use tracer::render::render_unit;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let rounds: usize = std::env::var("LAYERS_ROUNDS").ok().and_then(|s| s.parse().ok()).unwrap_or(15);
    let scenes = std::env::var("LAYERS_SCENES").unwrap_or_else(|_| "cornell-box,glass,veach-mis".into());
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    println!("{:<14} {:>12} {:>12} {:>8}", "scene", "plain ms", "layers ms", "ratio");
    for name in scenes.split(',') {
        let mut scene = tracer::scene::load_scene(&root.join(name).join("scene.toml")).expect("a bundled scene");
        (scene.camera.width, scene.camera.height) = (64, 64);
        let tile = Tile::new(0, 0, 64, 64);
        let samples = SampleRange::new(0, 16);
        let mut time = |aovs: bool| {
            scene.settings.aovs = aovs;
            let t = Instant::now();
            std::hint::black_box(render_unit(&scene, Integrator::Path, tile, samples));
            t.elapsed().as_secs_f64() * 1e3
        };
        time(false);
        time(true);
        let (mut plain, mut layered) = (Vec::new(), Vec::new());
        for r in 0..rounds {
            // Alternate which goes first, so that neither always follows the other.
            if r % 2 == 0 {
                plain.push(time(false));
                layered.push(time(true));
            } else {
                layered.push(time(true));
                plain.push(time(false));
            }
        }
        let ratios: Vec<f64> = layered.iter().zip(&plain).map(|(l, p)| l / p).collect();
        println!("{name:<14} {:>12.1} {:>12.1} {:>8.3}", median(plain), median(layered), median(ratios));
    }
}
