//! `coordinator render`: the one-command local render. It serves a farm on a free
//! loopback port, spawns local worker processes, and writes the merged image — or, with
//! `--local-workers 0`, renders the very same units in this process. Either way the
//! image is the same bits.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;

use proto::domain::JobSpec;

use crate::commands::follow::{Followed, JobFeed, follow};
use crate::commands::in_process::execute_in_process;
use crate::commands::job_args::{JobArgs, duration};
use crate::commands::local::LocalWorkers;
use crate::commands::progress::{JobBar, summary};
use crate::edge::http::HttpServer;
use crate::edge::server::Server;
use crate::farm::Shared;
use crate::farm::assets::{AssetRef, AssetStore, LocalScene};
use crate::farm::checkpoint;
use crate::farm::lifecycle::submit_job;
use crate::farm::state::Farm;
use crate::farm::status::{JobState, JobStatus};

#[derive(Args)]
pub struct RenderArgs {
    /// Scene file (.toml), or a bare .obj that is framed automatically. Without one, the
    /// built-in Cornell box is rendered.
    pub scene: Option<PathBuf>,
    /// Keep a checkpoint in this folder (the scene's files, what is done, the image so
    /// far), written every few seconds and when stopped. If the folder already holds a
    /// checkpoint of the same scene and settings, the render resumes from it and renders
    /// only what is missing; a higher --spp adds samples to a finished render.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
    #[command(flatten)]
    pub job: JobArgs,
}

#[derive(Args)]
pub struct ResumeArgs {
    /// A checkpoint folder written by `render --checkpoint`.
    pub dir: PathBuf,
    /// Raise the samples per pixel: only the new samples are rendered.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub spp: Option<u32>,
    /// Render for this long more, in whole batches (see `render --time-budget`);
    /// without it, to the job's spp.
    #[arg(long, value_name = "DURATION", value_parser = duration, allow_hyphen_values = true)]
    pub time_budget: Option<std::time::Duration>,
    #[command(flatten)]
    pub run: RunArgs,
}

/// How a local render runs (shared by `render` and `resume`).
#[derive(Args)]
pub struct RunArgs {
    /// Output image: .exr for linear HDR (RGBA float32 + a per-pixel sample count
    /// channel), .png for an sRGB tone-mapped preview.
    #[arg(short, long, default_value = "out.exr")]
    pub output: PathBuf,
    /// Worker processes to spawn. Default: one per two cores (at least one), each with
    /// two render threads — separate processes keep a crash contained, and pairs of
    /// threads share one copy of the scene in memory. 0 renders in this process,
    /// through the same units and merge (same bits).
    #[arg(long, value_name = "N")]
    pub local_workers: Option<usize>,
    /// Render threads per worker (or in this process with --local-workers 0) [default:
    /// the cores divided among the workers].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub threads: Option<u32>,
    /// Rewrite a tone-mapped PNG preview of the image so far every few seconds.
    #[arg(long, value_name = "FILE.png")]
    pub preview: Option<PathBuf>,
    /// Denoise the finished image with Intel Open Image Denoise, guided by the albedo and
    /// normal layers (implies --aovs). An EXR keeps the raw beauty in R/G/B and adds
    /// denoised.R/G/B; a PNG (output or --preview's last) shows the denoised image. Needs
    /// a build with `--features denoise` (README.md, Denoising).
    #[arg(long)]
    pub denoise: bool,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
    /// Serve the live dashboard (and /metrics) on this loopback address, e.g.
    /// 127.0.0.1:8080; its URL, with a token for this run, is printed.
    #[arg(long, value_name = "ADDRESS")]
    pub http: Option<String>,
    /// On Ctrl-C, write nothing. By default an interrupted render writes the image so far
    /// to --output (its `samples` channel shows how far each pixel got).
    #[arg(long)]
    pub no_partial: bool,
    /// Shortest time between two checkpoints, in milliseconds (writing is also kept
    /// under 1% of the time).
    #[arg(long, default_value_t = 5_000)]
    pub checkpoint_interval_ms: u64,
    /// Where local workers keep loaded scenes prepared (mesh and BVH), so that the
    /// next render of the same scene starts without parsing and building
    /// [default: ~/.cache/tilefarm/prepared, or $XDG_CACHE_HOME/tilefarm/prepared].
    #[arg(long, value_name = "DIR", env = "TILEFARM_SCENE_CACHE")]
    pub scene_cache: Option<PathBuf>,
    /// Keep no prepared scenes: every render loads its scene from its files.
    #[arg(long, conflicts_with = "scene_cache")]
    pub no_scene_cache: bool,
    #[command(flatten)]
    pub farm: crate::commands::serve::FarmArgs,
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
        let (sha256, size) = store.put_file(p)?;
        Ok(AssetRef { path: local.relative(p), sha256, size })
    };
    let scene = put(&local.scene)?;
    let assets = local.files.iter().map(|f| put(f)).collect::<anyhow::Result<Vec<_>>>()?;
    Ok((scene, assets))
}

/// What to render, resolved from the command line and any checkpoint.
struct Plan {
    store: AssetStore,
    spec: JobSpec,
    restore: Option<checkpoint::Snapshot>,
    checkpoint_dir: Option<PathBuf>,
    _tmp: Option<TempDir>,
}

fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")
}

impl RunArgs {
    /// The output and preview paths must be writable before anything is rendered.
    fn check_outputs(&self) -> anyhow::Result<()> {
        if self.denoise {
            tracer::denoise::check_available().map_err(|e| anyhow::anyhow!("--denoise: {e}"))?;
        }
        Ok(tracer::output::check_output_paths(&self.output, self.preview.as_deref())?)
    }
}

/// The folder of a `render` without --checkpoint. Folders of earlier renders that were
/// killed (their process is gone, so their own cleanup never ran) are removed first.
fn render_temp_dir() -> TempDir {
    let tmp = std::env::temp_dir();
    if let Ok(entries) = std::fs::read_dir(&tmp) {
        for e in entries.flatten() {
            let name = e.file_name();
            let Some(pid) = name.to_str().and_then(|n| n.strip_prefix("tilefarm-render-")) else { continue };
            if pid.parse::<u32>().is_ok_and(|pid| !process_alive(pid)) {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
    TempDir(tmp.join(format!("tilefarm-render-{}", std::process::id())))
}

/// Whether a process of that id runs (on Linux, by /proc; elsewhere assumed alive, so
/// nothing is removed that might be in use).
fn process_alive(pid: u32) -> bool {
    if cfg!(target_os = "linux") { Path::new(&format!("/proc/{pid}")).exists() } else { true }
}

pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    args.run.check_outputs()?;
    let builtin = match &args.scene {
        Some(_) => None,
        None => Some(crate::commands::builtin::BuiltinScene::write()?),
    };
    let scene_path = args.scene.clone().or_else(|| builtin.as_ref().map(|b| b.path())).expect("a scene path");
    let local = LocalScene::collect(&scene_path)?;
    let (store_dir, tmp) = match &args.checkpoint {
        Some(d) => (d.clone(), None),
        None => {
            let t = render_temp_dir();
            (t.0.clone(), Some(t))
        }
    };
    let mut store = AssetStore::open(&store_dir)?;
    let (scene, assets) = store_local_scene(&mut store, &local)?;
    let mut spec = args.job.spec_with_map(scene, assets)?;
    // The denoiser is guided by the albedo and normal layers.
    spec.overrides.aovs |= args.run.denoise;
    let restore = match &args.checkpoint {
        None => None,
        Some(dir) => {
            let found = checkpoint::read(dir)?;
            if let Some(snap) = &found {
                anyhow::ensure!(
                    checkpoint::scene_key(&snap.spec) == checkpoint::scene_key(&spec),
                    "{} holds a checkpoint of a different scene or different settings (size, max_depth, seed, \
                     integrator); refusing to mix them: use another folder, or `coordinator resume {}`",
                    dir.display(),
                    dir.display()
                );
            }
            found
        }
    };
    let plan = Plan { store, spec, restore, checkpoint_dir: args.checkpoint.clone(), _tmp: tmp };
    runtime()?.block_on(execute(plan, &args.run))
}

pub fn resume(args: ResumeArgs) -> anyhow::Result<()> {
    args.run.check_outputs()?;
    let snap = checkpoint::read(&args.dir)?
        .with_context(|| format!("{} holds no checkpoint", checkpoint::path(&args.dir).display()))?;
    anyhow::ensure!(
        !args.run.denoise || snap.job.tiles.first().is_some_and(|t| t.has_layers()),
        "--denoise: the checkpoint in {} was rendered without the AOV layers the denoiser needs (--aovs)",
        args.dir.display()
    );
    let store = AssetStore::open(&args.dir)?;
    let mut spec = snap.spec.clone();
    spec.job_id = String::new();
    // A budget is for one run: the checkpoint's was spent.
    spec.overrides.time_budget = args.time_budget;
    spec.overrides.spp = match args.spp {
        Some(spp) => {
            anyhow::ensure!(
                spp >= snap.job.spp,
                "the checkpoint already has {} spp; --spp cannot lower it",
                snap.job.spp
            );
            Some(spp)
        }
        None => None,
    };
    let plan = Plan { store, spec, restore: Some(snap), checkpoint_dir: Some(args.dir.clone()), _tmp: None };
    runtime()?.block_on(execute(plan, &args.run))
}

/// Writes a checkpoint of `job` if there is one to write (off the async threads).
async fn save_checkpoint(shared: &Arc<Shared>, job: &str, dir: &Path) -> anyhow::Result<()> {
    let snap = {
        let farm = shared.farm();
        let e = farm.entry(job)?;
        if e.job.width == 0 {
            return Ok(()); // the scene never loaded: nothing to keep
        }
        checkpoint::Snapshot::of(&e.spec, &e.job)
    };
    let dir = dir.to_path_buf();
    let t = Instant::now();
    let bytes = tokio::task::spawn_blocking(move || checkpoint::write(&dir, &snap)).await??;
    tracing::debug!(bytes, seconds = t.elapsed().as_secs_f64(), "checkpoint written");
    Ok(())
}

/// A render's own job, followed in this process: its status straight from the farm
/// state (woken by each merged result), its checkpoints written as the pacer allows,
/// and its local workers watched.
struct LocalJob<'a> {
    shared: &'a Arc<Shared>,
    job: &'a str,
    children: Option<&'a mut LocalWorkers>,
    checkpoint: Option<&'a Path>,
    pacer: checkpoint::Pacer,
    /// Finished units in the last checkpoint written.
    saved_units: u64,
    /// The first status is read at once, later ones on a change or every 100 ms.
    polled: bool,
}

impl JobFeed for LocalJob<'_> {
    async fn next_status(&mut self) -> anyhow::Result<Option<JobStatus>> {
        if self.polled {
            tokio::select! {
                _ = tokio::time::sleep(Duration::from_millis(100)) => {}
                _ = self.shared.changed.notified() => {}
            }
        }
        self.polled = true;
        Ok(Some(self.shared.farm().status(self.job, Instant::now())?))
    }

    async fn image(&mut self) -> anyhow::Result<tracer::film::Image> {
        Ok(self.shared.farm().entry(self.job)?.job.image())
    }

    async fn tick(&mut self, status: &JobStatus, bar: &JobBar) -> anyhow::Result<()> {
        if let Some(c) = self.children.as_mut()
            && c.running() == 0
        {
            anyhow::bail!("all local workers exited before the render finished (see their log above)");
        }
        if let Some(dir) = self.checkpoint
            && status.units_done > self.saved_units
            && self.pacer.due()
        {
            let t = Instant::now();
            // A failed write (disk full, folder gone) must not throw the render away: say
            // so, and write again at the next interval.
            match save_checkpoint(self.shared, self.job, dir).await {
                Ok(()) => self.saved_units = status.units_done,
                Err(e) => bar.warn(&format!("checkpoint not written, retrying at the next interval: {e:#}")),
            }
            self.pacer.wrote(t.elapsed());
        }
        Ok(())
    }
}

async fn execute(plan: Plan, args: &RunArgs) -> anyhow::Result<()> {
    let Plan { store, spec, restore, checkpoint_dir, _tmp } = plan;
    let cache = store.dir().join("cache");
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let workers = args.local_workers.unwrap_or((cores / 2).max(1));
    let threads = args.threads.map_or_else(|| (cores / workers.max(1)).max(1), |t| t as usize);
    let mut shared = Shared::new(Farm::new(args.farm.config()?), store);
    let scene_cache =
        if args.no_scene_cache { None } else { args.scene_cache.clone().or_else(tracer::scene::prepared::user_dir) };
    // The coordinator and its local workers share the folder: what one builds, the others read.
    shared.prepared = scene_cache.as_deref().and_then(|dir| args.farm.prepared_scenes(dir));
    let scene_cache = shared.prepared.as_ref().map(|p| p.dir().to_path_buf());
    // The user's own scene, read where it lies (also through absolute paths).
    shared.defaults.confine_scenes = false;
    // Rendering in process needs the scene the coordinator loads; workers load their own.
    shared.defaults.keep_scenes = workers == 0;
    if workers > 0 {
        // The scene it loads for its checks is freed at once: give it back to the system.
        tracer::memory::return_large_buffers_when_freed();
    }
    let shared = Arc::new(shared);
    let resumed = restore.as_ref().map_or(0, |s| s.units_done() as u64);
    let (earlier_samples, earlier_rays) = restore.as_ref().map_or((0, 0), |s| (s.samples_done(), s.job.rays));
    if let (Some(s), Some(dir)) = (&restore, &checkpoint_dir) {
        eprintln!("resuming from {}: {} of {} units done", dir.display(), s.units_done(), s.job.units.len());
    }
    let name = spec.scene.path.clone();
    let job = submit_job(&shared, name, None, spec, restore.map(|s| s.job))?;

    let dashboard = match &args.http {
        Some(listen) => Some(start_dashboard(&shared, listen).await?),
        None => None,
    };
    let mut renderers = Renderers::start(&shared, &job, workers, threads, &cache, scene_cache.as_deref()).await?;
    let mut bar = JobBar::new(args.quiet);
    let mut feed = LocalJob {
        shared: &shared,
        job: &job,
        children: renderers.children.as_mut(),
        checkpoint: checkpoint_dir.as_deref(),
        pacer: checkpoint::Pacer::new(Duration::from_millis(args.checkpoint_interval_ms)),
        saved_units: resumed,
        polled: false,
    };
    let followed = follow(&mut feed, &mut bar, args.preview.as_deref()).await;
    let interrupted = matches!(followed, Ok(Followed::Interrupted));
    let outcome = match followed {
        Ok(Followed::Ended(status)) => match status.state {
            JobState::Done => Ok(status),
            JobState::Cancelled => Err(anyhow::anyhow!("the job was cancelled")),
            _ => Err(anyhow::anyhow!("{}", status.error)),
        },
        Ok(Followed::Interrupted) => Err(anyhow::anyhow!("interrupted")),
        Err(e) => Err(e),
    };
    bar.finish();

    renderers.stop(&shared, outcome.is_ok()).await;
    if let Some(d) = dashboard {
        d.stop().await;
    }
    // Whatever happened, keep what was rendered.
    // (A checkpoint that cannot be written must not cost the image: say so, write it.)
    if let Some(dir) = &checkpoint_dir {
        match save_checkpoint(&shared, &job, dir).await {
            Ok(()) if outcome.is_err() => {
                eprintln!("checkpoint saved in {}; continue with `coordinator resume {}`", dir.display(), dir.display())
            }
            Ok(()) => {}
            Err(e) => bar.warn(&format!("the last checkpoint was not written: {e:#}")),
        }
    }
    if interrupted && !args.no_partial {
        write_partial(&shared, &job, args)?;
    }
    let status = outcome?;
    write_result(&shared, &job, args, &status, resumed, (earlier_samples, earlier_rays))
}

/// The dashboard of a local render, on a loopback address, with a token of this run's
/// own (printed in the URL, after `#`, so the page keeps it out of requests' lines).
async fn start_dashboard(shared: &Arc<Shared>, listen: &str) -> anyhow::Result<HttpServer> {
    if !crate::commands::serve::loopback_only(listen).with_context(|| format!("--http {listen}"))? {
        anyhow::bail!("--http {listen}: a local render serves its dashboard on loopback only (e.g. 127.0.0.1:8080)");
    }
    let token = proto::auth::Token::random().map_err(anyhow::Error::msg)?;
    let access = proto::auth::Access::default().with_token(token.clone(), proto::auth::Caller::admin());
    let http = HttpServer::start(Arc::clone(shared), listen, access, Default::default()).await?;
    eprintln!("dashboard: {}/#token={}", http.url(), token.secret());
    Ok(http)
}

/// What renders a local job: worker processes with the server they connect to, or the
/// worker's machine in this process.
struct Renderers {
    server: Option<Server>,
    children: Option<LocalWorkers>,
    in_process: Option<tokio::task::JoinHandle<()>>,
    stop: tokio::sync::watch::Sender<Option<worker::Stop>>,
}

impl Renderers {
    async fn start(
        shared: &Arc<Shared>,
        job: &str,
        workers: usize,
        threads: usize,
        cache: &Path,
        scene_cache: Option<&Path>,
    ) -> anyhow::Result<Self> {
        let (stop, stop_rx) = tokio::sync::watch::channel(None);
        if workers == 0 {
            let task = tokio::spawn(execute_in_process(Arc::clone(shared), job.to_string(), threads, stop_rx));
            return Ok(Self { server: None, children: None, in_process: Some(task), stop });
        }
        // A secret for this run alone: another user of this machine cannot reach the farm.
        let token = proto::auth::Token::random().map_err(anyhow::Error::msg)?;
        let server = Server::start(
            Arc::clone(shared),
            "127.0.0.1:0",
            proto::auth::Access::default().with_token(token.clone(), proto::auth::Caller::admin()),
            None,
            Default::default(),
        )
        .await?;
        let children = LocalWorkers::spawn(workers, threads, &server.url(), cache, scene_cache, &token)?;
        tracing::info!("serving on {}; {workers} local worker(s) × {threads} thread(s)", server.url());
        Ok(Self { server: Some(server), children: Some(children), in_process: None, stop })
    }

    /// Tells the workers to stop, gives them a moment (when the job went well), then
    /// makes sure they are gone.
    async fn stop(self, shared: &Shared, gently: bool) {
        shared.farm().shutting_down = true;
        let _ = self.stop.send(Some(worker::Stop::Signal));
        if let Some(task) = self.in_process {
            let _ = tokio::time::timeout(Duration::from_secs(5), task).await;
        }
        if let Some(c) = self.children {
            if gently {
                c.shutdown(Duration::from_secs(5)).await;
            } else {
                c.kill().await;
            }
        }
        if let Some(s) = self.server {
            s.stop().await;
        }
    }
}

/// Writes a finished render's image (and preview) and prints its summary; `earlier` are
/// the samples and rays a checkpoint already held.
fn write_result(
    shared: &Shared,
    job: &str,
    args: &RunArgs,
    status: &JobStatus,
    resumed: u64,
    earlier: (u64, u64),
) -> anyhow::Result<()> {
    let (image, info, nonfinite, total, skipped, budget) = {
        let farm = shared.farm();
        let e = farm.entry(job)?;
        let total = e.job.units_total();
        let spp = e.job.tile_accumulations().iter().filter_map(|a| a.counts.first().copied());
        let reached = spp.clone().min().zip(spp.max());
        let budget = e.job.budget.filter(|_| e.job.units_done < total).and(reached);
        (e.job.image_tiles(), e.render_info(), e.job.nonfinite, total, e.job.units.len() as u64 - total, budget)
    };
    write_images(&image, info.as_ref(), args)?;
    let mut converged =
        if skipped > 0 { format!(" ({skipped} more skipped: their tiles had converged)") } else { String::new() };
    if let Some((least, most)) = budget {
        converged += &format!(" (the time budget ended it with tiles at {least}–{most} spp)");
    }
    println!(
        "{}; units: {resumed} from checkpoint + {} rendered = {total}{converged}; wrote {}",
        summary(status, earlier.0, earlier.1),
        status.units_done - resumed,
        args.output.display()
    );
    if nonfinite > 0 {
        eprintln!("warning: {nonfinite} non-finite samples were replaced by zero");
    }
    Ok(())
}

/// Writes the image of an interrupted render so far: each pixel the mean of the samples
/// it has, its count in the `samples` channel.
fn write_partial(shared: &Shared, job: &str, args: &RunArgs) -> anyhow::Result<()> {
    let (image, info, done, total) = {
        let farm = shared.farm();
        let e = farm.entry(job)?;
        if e.job.width == 0 {
            return Ok(()); // the scene never loaded: there is no image
        }
        (e.job.image_tiles(), e.render_info(), e.job.samples_done, e.job.samples_total())
    };
    write_images(&image, info.as_ref(), args)?;
    eprintln!(
        "wrote the image so far to {} ({:.1}% of its samples; --no-partial writes nothing)",
        args.output.display(),
        100.0 * done as f64 / total.max(1) as f64
    );
    Ok(())
}

/// Writes a render's image to --output (and its --preview), denoised beside the raw
/// image with --denoise.
fn write_images(
    image: &crate::farm::job::ImageTiles,
    info: Option<&tracer::output::RenderInfo>,
    args: &RunArgs,
) -> anyhow::Result<()> {
    if !args.denoise {
        tracer::output::write_image_with(&image.mosaic(), info, &args.output)?;
        if let Some(p) = &args.preview {
            tracer::output::write_png(&tracer::film::Image::of(&image.mosaic()), p)?;
        }
        return Ok(());
    }
    let mut assembled = tracer::film::Image::of(&image.mosaic());
    let started = Instant::now();
    assembled.denoised = tracer::denoise::denoise(&assembled).map_err(|e| anyhow::anyhow!("--denoise: {e}"))?;
    tracing::info!("denoised in {:.2} s", started.elapsed().as_secs_f64());
    tracer::output::write_image_with(&assembled, info, &args.output)?;
    if let Some(p) = &args.preview {
        tracer::output::write_png(&assembled, p)?;
    }
    Ok(())
}
