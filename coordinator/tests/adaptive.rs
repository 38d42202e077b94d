//! Adaptive sampling and time budgets as a user runs them (`render --adaptive`,
//! `--time-budget`): the same bits with any number of worker processes, and through a
//! checkpoint and `resume`; more samples where the noise is; a lower error than uniform
//! sampling at the same total; a budget that stops in whole batches.

use std::path::{Path, PathBuf};
use std::process::Command;

use tracer::film::Image;

struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let d = std::env::temp_dir().join(format!("tilefarm-adaptive-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A wall whose left half is an emitter (every sample sees exactly its radiance: no
/// noise) and whose right half is white and lit by a small sphere light (noisy).
fn halves(dir: &Path) -> PathBuf {
    std::fs::write(dir.join("halves.mtl"), "newmtl lamp\nKd 0 0 0\nKe 1 1 1\nnewmtl white\nKd 0.8 0.8 0.8\n").unwrap();
    std::fs::write(
        dir.join("halves.obj"),
        "mtllib halves.mtl\nv -10 -10 0\nv 0 -10 0\nv 0 10 0\nv -10 10 0\nv 10 -10 0\nv 10 10 0\n\
         usemtl lamp\nf 1 4 3 2\nusemtl white\nf 2 3 6 5\n",
    )
    .unwrap();
    let scene = dir.join("halves.toml");
    std::fs::write(
        &scene,
        "[camera]\nposition = [0.0, 0.0, -4.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 40\nwidth = 32\nheight = 16\n\
         [render]\nspp = 256\n[[mesh]]\nobj = \"halves.obj\"\n\
         [[sphere]]\ncenter = [1.2, 0.0, -1.5]\nradius = 0.1\nke = [40.0, 40.0, 40.0]\n",
    )
    .unwrap();
    scene
}

/// Renders `scene` with `args` to `name` in `dir`; the image.
fn render(dir: &Path, scene: &Path, name: &str, args: &[&str]) -> Image {
    let out = dir.join(name);
    let run = Command::new(env!("CARGO_BIN_EXE_coordinator"))
        .arg("render")
        .arg(scene)
        .args(["-q", "--tile", "8", "--batch-spp", "8"])
        .args(args)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert!(run.status.success(), "{args:?}: {}", String::from_utf8_lossy(&run.stderr));
    tracer::output::read_exr(&out).unwrap()
}

/// Mean over pixels and channels of (x - ref)² / (ref² + 0.01).
fn rel_mse(x: &Image, reference: &Image) -> f64 {
    let mut sum = 0.0;
    for (a, r) in x.pixels.iter().zip(&reference.pixels) {
        for k in 0..3 {
            let (a, r) = (a[k] as f64, r[k] as f64);
            sum += (a - r).powi(2) / (r * r + 0.01);
        }
    }
    sum / (3 * x.pixels.len()) as f64
}

#[test]
fn adaptive_renders_are_the_same_bits_for_any_workers_and_spend_samples_on_noise() {
    let dir = TempDir::new("halves");
    let scene = halves(&dir.0);
    let adaptive = ["--adaptive", "--noise", "0.02"];
    let in_process = render(&dir.0, &scene, "a0.exr", &[&adaptive[..], &["--local-workers", "0"]].concat());
    for workers in ["1", "2", "3"] {
        let farm = render(&dir.0, &scene, "a.exr", &[&adaptive[..], &["--local-workers", workers]].concat());
        assert_eq!(farm, in_process, "{workers} worker processes");
    }
    // Its `samples` channel, as a map, renders the same bits again without adaptive
    // sampling (layers kept, to compare them too).
    let map = dir.0.join("a0.exr");
    let again = render(&dir.0, &scene, "again.exr", &["--spp-map", map.to_str().unwrap(), "--aovs"]);
    assert_eq!(again, in_process, "rendered again from its spp map");
    let meta = exr::meta::MetaData::read_from_file(dir.0.join("a0.exr"), false).unwrap();
    let key = exr::meta::attribute::Text::from("tilefarm/noiseTarget");
    assert_eq!(meta.headers[0].own_attributes.other.get(&key), Some(&exr::meta::attribute::AttributeValue::F32(0.02)));

    // Where the samples went: the emitter's tiles stop at the least a tile is judged
    // on; tiles of the lit wall take more.
    let counts = &in_process.counts;
    let (least, most) = (*counts.iter().min().unwrap(), *counts.iter().max().unwrap());
    assert_eq!(least, 64, "converged tiles stop at 64 spp");
    assert!(most >= 2 * least, "noisy tiles take more samples ({most})");
    let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
    let pixels = counts.len() as u64;
    assert!(total < 256 * pixels, "adaptive sampling took fewer than the 256 spp asked for");

    // At the same total, a lower error than uniform sampling (against 2048 spp).
    let uniform_spp = (total / pixels).to_string();
    let uniform = render(&dir.0, &scene, "u.exr", &["--spp", &uniform_spp, "--local-workers", "0"]);
    let reference = render(&dir.0, &scene, "r.exr", &["--spp", "2048", "--local-workers", "0"]);
    let (e_adaptive, e_uniform) = (rel_mse(&in_process, &reference), rel_mse(&uniform, &reference));
    println!(
        "relMSE at {:.1} spp on average: adaptive {e_adaptive:.6}, uniform {e_uniform:.6} ({:.2}×)",
        total as f64 / pixels as f64,
        e_uniform / e_adaptive
    );
    assert!(e_adaptive < e_uniform, "adaptive {e_adaptive} is not below uniform {e_uniform}");
}

/// A checkpointed adaptive render continued by `resume` to more spp is the same bits as
/// one rendered to that spp at once: the restored job decides each tile again from the
/// same sums.
#[test]
fn a_resumed_adaptive_render_equals_an_uninterrupted_one() {
    let dir = TempDir::new("resume");
    let scene = halves(&dir.0);
    let ckpt = dir.0.join("ckpt");
    let ckpt_arg = ckpt.to_str().unwrap();
    let first = ["--adaptive", "--noise", "0.03", "--spp", "32", "--local-workers", "1", "--checkpoint", ckpt_arg];
    render(&dir.0, &scene, "part.exr", &first);
    let out = dir.0.join("resumed.exr");
    let run = Command::new(env!("CARGO_BIN_EXE_coordinator"))
        .args(["resume", ckpt_arg, "--spp", "128", "-q", "--local-workers", "2", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let resumed = tracer::output::read_exr(&out).unwrap();
    let whole = render(&dir.0, &scene, "whole.exr", &["--adaptive", "--noise", "0.03", "--spp", "128"]);
    assert_eq!(resumed, whole);
    assert!(whole.counts.iter().any(|&c| c > 32), "the resume rendered more");
}

/// `--time-budget` stops the render in whole batches: it ends soon after its budget,
/// every tile within one batch of the others, `--spp-map` of its EXR renders the same
/// bits again, and each pixel is the same bits as a render to the spp its tile reached.
#[test]
fn a_time_budget_ends_in_whole_batches_that_render_again_to_the_same_bits() {
    let dir = TempDir::new("budget");
    let cornell = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box/scene.toml");
    let started = std::time::Instant::now();
    let budget = render(
        &dir.0,
        &cornell,
        "budget.exr",
        &["--width", "48", "--spp", "100000", "--time-budget", "2s", "--local-workers", "1"],
    );
    let took = started.elapsed();
    // Generous: the point is that it stops (the loaded test machine sets the rest).
    assert!(took < std::time::Duration::from_secs(60), "a 2 s budget took {took:?}");
    let (least, most) = (*budget.counts.iter().min().unwrap(), *budget.counts.iter().max().unwrap());
    assert!(least >= 8 && most - least <= 8, "tiles within one batch: {least}..{most} spp");
    println!("2 s budget: {least}..{most} spp in {took:?}");
    // Its `samples` channel is the map to render the same bits again (in-process here,
    // with a worker above).
    let map = dir.0.join("budget.exr");
    let again = render(&dir.0, &cornell, "again.exr", &["--spp-map", map.to_str().unwrap()]);
    assert_eq!(again, budget, "rendered again from its spp map");
    // And each pixel is what a render to its tile's spp gives.
    for spp in [least, most] {
        let uniform = render(&dir.0, &cornell, "uniform.exr", &["--width", "48", "--spp", &spp.to_string()]);
        for (i, &c) in budget.counts.iter().enumerate() {
            if c == spp {
                assert_eq!(budget.pixels[i].to_array(), uniform.pixels[i].to_array(), "pixel {i} at {spp} spp");
            }
        }
    }
    // A map of another size, or cut in other tiles, is refused with what differs.
    let mut halves = Image::new(48, 48);
    halves.counts.iter_mut().enumerate().for_each(|(i, c)| *c = if i % 48 < 24 { 8 } else { 16 });
    let halves_map = dir.0.join("halves.exr");
    tracer::output::write_exr(&halves, &halves_map).unwrap();
    for (file, args, says) in [
        (&map, &["--tile", "8", "--width", "64"][..], "the spp map is of a 48×48 image"),
        (&halves_map, &["--tile", "48"][..], "give the --tile of the render that wrote it"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_coordinator"))
            .args(["render", "-q", "--local-workers", "0", "--spp-map", file.to_str().unwrap()])
            .args(args)
            .arg(&cornell)
            .arg("-o")
            .arg(dir.0.join("x.exr"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(says), "{args:?}: {err}");
    }
    for bad in ["0", "soon", "-5s"] {
        let out = Command::new(env!("CARGO_BIN_EXE_coordinator"))
            .args(["render", "-q", "--time-budget", bad, "-o"])
            .arg(dir.0.join("x.exr"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains("--time-budget"), "{bad}: {err}");
    }
}

/// A time budget with adaptive sampling: tiles that have not converged end within one
/// batch of each other, and `--spp-map` of the result renders the same bits again.
#[test]
fn an_adaptive_render_on_a_time_budget_renders_again_from_its_map() {
    let dir = TempDir::new("adaptive-budget");
    let scene = halves(&dir.0);
    // A target no tile reaches within the budget: each goes on until the budget ends.
    let args = ["--adaptive", "--noise", "0.0001", "--spp", "1000000", "--time-budget", "3s", "--local-workers", "1"];
    let budget = render(&dir.0, &scene, "budget.exr", &args);
    // The emitter's half (the image's right) converges at once; the lit half's tiles go on.
    let half = |lit: bool| budget.counts.iter().enumerate().filter(move |(i, _)| (i % 32 < 16) == lit).map(|(_, &c)| c);
    let (least, most) = (half(true).min().unwrap(), half(true).max().unwrap());
    println!("3 s adaptive budget: the lit half at {least}..{most} spp");
    assert!(half(false).all(|c| c == 64), "the emitter's tiles stop at 64 spp");
    assert!(least > 64 && most - least <= 8, "unconverged tiles within one batch: {least}..{most} spp");
    let map = dir.0.join("budget.exr");
    let again = render(&dir.0, &scene, "again.exr", &["--spp-map", map.to_str().unwrap(), "--aovs"]);
    assert_eq!(again, budget, "rendered again from its spp map");
}
