//! `coordinator render`: the one-command local render. It serves a farm on a free
//! loopback port, spawns local worker processes, and writes the merged image — or, with
//! `--local-workers 0`, renders the very same units in this process. Either way the
//! image is the same bits.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use rayon::prelude::*;
use tracer::film::SampleRange;
use tracer::integrator::Integrator;

use crate::assets::{AssetRef, AssetStore, LocalScene};
use crate::farm::{Farm, FarmConfig};
use crate::job::UnitResult;
use crate::local::LocalWorkers;
use crate::progress::{JobBar, summary};
use crate::server::Server;
use crate::service::{JobDefaults, Shared, submit_job};

/// Options shared by `render` and `submit`: what to render.
#[derive(Args, Clone, Debug)]
pub struct JobArgs {
    /// Samples per pixel (default: the scene's [render] spp).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Image width in pixels (default: the scene's; the height follows the aspect ratio
    /// unless --height is given too).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels (default: the scene's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Override the scene's max_depth (path segments; -1 = unlimited).
    #[arg(long, allow_hyphen_values = true)]
    pub max_depth: Option<i32>,
    /// Override the scene's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// path (default: NEE + MIS); path-light or path-bsdf (one strategy only, to compare
    /// estimators); or an AOV: normals, albedo, depth.
    #[arg(long, default_value = "path")]
    pub integrator: Integrator,
    /// Tile size of a unit of work, in pixels.
    #[arg(long, default_value_t = 64)]
    pub tile: u32,
    /// Samples per pixel in one unit of work. Every tile gets its first batch before any
    /// tile gets its second, so a preview refines evenly.
    #[arg(long, default_value_t = 16)]
    pub batch_spp: u32,
}

impl JobArgs {
    pub fn settings(&self) -> proto::RenderSettings {
        proto::RenderSettings {
            spp: self.spp.unwrap_or(0),
            width: self.width.unwrap_or(0),
            height: self.height.unwrap_or(0),
            max_depth: self.max_depth,
            seed: self.seed,
            integrator: self.integrator.name().to_string(),
            tile_size: self.tile,
            batch_spp: self.batch_spp,
        }
    }
}

#[derive(Args)]
pub struct RenderArgs {
    /// Scene file (.toml), or a bare .obj that is framed automatically. Without one, the
    /// built-in Cornell box is rendered.
    pub scene: Option<PathBuf>,
    /// Output image: .exr for linear HDR (RGBA float32 + a per-pixel sample count
    /// channel), .png for an sRGB tone-mapped preview.
    #[arg(short, long, default_value = "out.exr")]
    pub output: PathBuf,
    /// Worker processes to spawn. Default: one per two cores (at least one), each with
    /// two render threads — separate processes keep a crash contained, and pairs of
    /// threads share one copy of the scene in memory. 0 renders in this process,
    /// through the same units and merge (same bits).
    #[arg(long)]
    pub local_workers: Option<usize>,
    /// Render threads per worker (or in this process with --local-workers 0). Default:
    /// the cores divided among the workers.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Rewrite a tone-mapped PNG preview of the image so far every few seconds.
    #[arg(long)]
    pub preview: Option<PathBuf>,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
    #[command(flatten)]
    pub job: JobArgs,
}

/// A temporary folder removed when dropped (on every exit path).
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Puts a local scene's files in the store; returns the scene's and the assets' refs.
/// Files that are referred to but missing are left out: loading the job then fails
/// with an error naming them.
pub fn store_local_scene(store: &mut AssetStore, local: &LocalScene) -> anyhow::Result<(AssetRef, Vec<AssetRef>)> {
    let mut put = |p: &Path| -> anyhow::Result<AssetRef> {
        let bytes = std::fs::read(p).with_context(|| format!("reading {}", p.display()))?;
        let (sha256, size) = store.put(&bytes)?;
        Ok(AssetRef { path: local.relative(p), sha256, size })
    };
    let scene = put(&local.scene)?;
    let assets = local.files.iter().map(|f| put(f)).collect::<anyhow::Result<Vec<_>>>()?;
    Ok((scene, assets))
}

pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(render(args))
}

async fn render(args: RenderArgs) -> anyhow::Result<()> {
    let builtin = match &args.scene {
        Some(_) => None,
        None => Some(crate::builtin::BuiltinScene::write()?),
    };
    let scene_path = args.scene.clone().or_else(|| builtin.as_ref().map(|b| b.path())).expect("a scene path");
    let local = LocalScene::collect(&scene_path)?;
    let tmp = TempDir(std::env::temp_dir().join(format!("tilefarm-render-{}", std::process::id())));
    let mut store = AssetStore::open(&tmp.0)?;
    let (scene_ref, assets) = store_local_scene(&mut store, &local)?;

    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let workers = args.local_workers.unwrap_or((cores / 2).max(1));
    let threads = args.threads.unwrap_or_else(|| (cores / workers.max(1)).max(1));
    let shared = Arc::new(Shared {
        farm: Mutex::new(Farm::new(FarmConfig::default())),
        store: Mutex::new(store),
        defaults: JobDefaults::default(),
    });
    let job =
        submit_job(&shared, scene_ref, assets, args.job.settings()).map_err(|s| anyhow::anyhow!("{}", s.message()))?;

    let (server, mut children) = if workers > 0 {
        let server = Server::start(Arc::clone(&shared), "127.0.0.1:0").await?;
        let children = LocalWorkers::spawn(workers, threads, &server.url(), &tmp.0.join("cache"))?;
        tracing::info!("serving on {}; {workers} local worker(s) × {threads} thread(s)", server.url());
        (Some(server), Some(children))
    } else {
        let shared = Arc::clone(&shared);
        let job = job.clone();
        std::thread::spawn(move || execute_in_process(&shared, &job, threads));
        (None, None)
    };

    let bar = JobBar::new(args.quiet);
    let mut last_preview = Instant::now();
    let stop = crate::stop_signal();
    tokio::pin!(stop);
    let outcome = loop {
        tokio::select! {
            _ = &mut stop => break Err(anyhow::anyhow!("interrupted")),
            _ = tokio::time::sleep(Duration::from_millis(100)) => {}
        }
        let status = shared.farm().status(&job, Instant::now())?;
        bar.update(&status);
        match status.state() {
            proto::JobState::Done => break Ok(status),
            proto::JobState::Failed => break Err(anyhow::anyhow!("{}", status.error)),
            proto::JobState::Cancelled => break Err(anyhow::anyhow!("the job was cancelled")),
            _ => {}
        }
        if let Some(c) = children.as_mut()
            && c.running() == 0
        {
            break Err(anyhow::anyhow!("all local workers exited before the render finished (see their log above)"));
        }
        if let Some(p) = &args.preview
            && last_preview.elapsed() > Duration::from_secs(3)
            && status.state() == proto::JobState::Running
        {
            let image = shared.farm().entry(&job)?.job.image();
            tracer::output::write_png(&image, p)?;
            last_preview = Instant::now();
        }
    };
    bar.finish();

    // Tell the workers to stop, give them a moment, then make sure they are gone.
    shared.farm().shutting_down = true;
    if let Some(c) = children {
        if outcome.is_ok() {
            c.shutdown(Duration::from_secs(5)).await;
        } else {
            c.kill().await;
        }
    }
    if let Some(s) = server {
        s.stop().await;
    }
    let status = outcome?;
    let image = shared.farm().entry(&job)?.job.image();
    tracer::output::write_image(&image, &args.output)?;
    if let Some(p) = &args.preview {
        tracer::output::write_png(&image, p)?;
    }
    println!("{}; wrote {}", summary(&status), args.output.display());
    let nonfinite = shared.farm().entry(&job)?.job.nonfinite;
    if nonfinite > 0 {
        eprintln!("warning: {nonfinite} non-finite samples were replaced by zero");
    }
    Ok(())
}

/// Renders a job's units in this process: leases from the same farm state as remote
/// workers do, renders on the rayon pool, and submits through the same checks and merge.
fn execute_in_process(shared: &Shared, job: &str, threads: usize) {
    let pool = match rayon::ThreadPoolBuilder::new().num_threads(threads).build() {
        Ok(p) => p,
        Err(e) => {
            if let Ok(en) = shared.farm().entry_mut(job) {
                en.job.fail(format!("starting render threads: {e}"));
            }
            return;
        }
    };
    let me = shared.farm().register("in-process".into(), threads as u32, Instant::now());
    loop {
        let (units, scene, integrator, finished) = {
            let mut farm = shared.farm();
            let units = farm.lease(me, threads * 2, Instant::now()).unwrap_or_default();
            let Ok(e) = farm.entry(job) else { return };
            let integrator: Integrator =
                e.spec.settings.as_ref().and_then(|s| s.integrator.parse().ok()).unwrap_or_default();
            (units, e.scene.clone(), integrator, e.job.phase.is_final())
        };
        if finished {
            return;
        }
        let Some(scene) = scene.filter(|_| !units.is_empty()) else {
            std::thread::sleep(Duration::from_millis(20));
            continue;
        };
        let results: Vec<UnitResult> = pool.install(|| {
            units
                .par_iter()
                .map(|u| {
                    let (acc, count) = tracer::render::render_unit_counted(&scene, integrator, u.tile, u.samples);
                    UnitResult {
                        unit: u.unit,
                        tile: u.tile,
                        samples: SampleRange::new(u.samples.start, u.samples.end),
                        sums: acc.sums,
                        counts: acc.counts,
                        nonfinite: acc.nonfinite,
                        rays: count.rays,
                    }
                })
                .collect()
        });
        let mut farm = shared.farm();
        for r in &results {
            if let Err(e) = farm.submit(me, job, r, Instant::now()) {
                tracing::error!("in-process result rejected: {e}");
            }
        }
    }
}
