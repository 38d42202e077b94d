//! `coordinator render`: the in-process renderer.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use tracer::film::SampleRange;
use tracer::integrator::Integrator;

#[derive(Args)]
pub struct RenderArgs {
    /// Scene file (.toml), or a bare .obj that is framed automatically. Without one, the
    /// built-in Cornell box is rendered.
    pub scene: Option<PathBuf>,
    /// Output image: .exr for linear HDR (RGBA float32 + sample counts), .png for an
    /// sRGB tone-mapped preview.
    #[arg(short, long, default_value = "out.exr")]
    pub output: PathBuf,
    /// Samples per pixel (default: the scene's [render] spp).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Image width in pixels (default: the scene's; the height follows the aspect ratio
    /// unless --height is given too).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels (default: the scene's).
    #[arg(long)]
    pub height: Option<u32>,
    /// path (default: NEE + MIS); path-light or path-bsdf (one strategy only, to compare
    /// estimators); or an AOV: normals, albedo, depth.
    #[arg(long, default_value = "path")]
    pub integrator: Integrator,
    /// Override the scene's max_depth (path segments; -1 = unlimited).
    #[arg(long, allow_hyphen_values = true)]
    pub max_depth: Option<i32>,
    /// Override the scene's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Tile size in pixels for scheduling work on the threads.
    #[arg(long, default_value_t = 16)]
    pub tile: u32,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
}

pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    if let Some(n) = args.threads {
        rayon::ThreadPoolBuilder::new().num_threads(n.max(1)).build_global().context("setting up threads")?;
    }
    let t_load = Instant::now();
    let mut scene = crate::builtin::load(args.scene.as_deref())?;
    apply_overrides(&mut scene, &args)?;
    let load_secs = t_load.elapsed().as_secs_f64();
    let (w, h, spp) = (scene.camera.width, scene.camera.height, scene.settings.spp);
    eprintln!(
        "scene: {} triangles, {} spheres, {} lights; {w}×{h}, {spp} spp, max_depth {}, loaded in {load_secs:.2}s",
        scene.geometry.mesh.tris.len(),
        scene.geometry.spheres.len(),
        scene.lights.lights.len(),
        scene.settings.max_depth,
    );

    let total = w as u64 * h as u64 * spp as u64;
    let bar = if args.quiet { ProgressBar::hidden() } else { ProgressBar::new(total) };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {wide_bar} {percent}% {per_sec} ETA {eta}")
            .expect("static template"),
    );
    let start = Instant::now();
    let (image, stats) =
        tracer::render::render_image(&scene, args.integrator, SampleRange::new(0, spp), args.tile.max(1), &|n| {
            bar.inc(n)
        });
    bar.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    tracer::output::write_image(&image, &args.output)?;
    println!(
        "rendered {w}×{h} at {spp} spp in {secs:.2}s: {:.3} M samples/s, {:.3} M rays/s; wrote {}",
        stats.samples as f64 / secs / 1e6,
        stats.rays as f64 / secs / 1e6,
        args.output.display()
    );
    if stats.nonfinite > 0 {
        eprintln!("warning: {} non-finite samples were replaced by zero", stats.nonfinite);
    }
    Ok(())
}

fn apply_overrides(scene: &mut tracer::scene::Scene, args: &RenderArgs) -> anyhow::Result<()> {
    let cam = &mut scene.camera;
    let aspect = cam.width as f64 / cam.height as f64;
    match (args.width, args.height) {
        (Some(w), Some(h)) => (cam.width, cam.height) = (w, h),
        (Some(w), None) => (cam.width, cam.height) = (w, ((w as f64 / aspect).round() as u32).max(1)),
        (None, Some(h)) => (cam.width, cam.height) = (((h as f64 * aspect).round() as u32).max(1), h),
        (None, None) => {}
    }
    anyhow::ensure!(cam.width > 0 && cam.height > 0, "--width and --height must be positive");
    if let Some(spp) = args.spp {
        anyhow::ensure!(spp > 0, "--spp must be at least 1");
        scene.settings.spp = spp;
    }
    if let Some(d) = args.max_depth {
        anyhow::ensure!(d == -1 || d >= 1, "--max-depth must be -1 (unlimited) or ≥ 1");
        scene.settings.max_depth = d;
    }
    if let Some(s) = args.seed {
        scene.settings.seed = s;
    }
    Ok(())
}
