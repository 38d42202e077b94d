//! `coordinator loadtest`: how many unit results a coordinator merges per second.
//!
//! Starts `coordinator serve` as a child process on a free loopback port, submits the
//! built-in Cornell box cut into tiny units (8×8 tiles × 1 spp by default), and lets many
//! simulated workers — each its own gRPC connection — lease units and return them at
//! once, as fast as the coordinator answers. A simulated worker is the real worker's
//! machine and gRPC link ([`worker::drive`]) with an executor that renders nothing: its
//! result has the right tile, sample range and per-pixel counts and zero radiance, so
//! the coordinator does all of its real work (lease bookkeeping, validation, the exact
//! merge) and none of ours is rendering. It prints results merged per second, the coordinator's CPU time and peak
//! memory (from /proc), and the bytes on the wire per unit and for the final image.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use prost::Message;
use proto::domain::{JobSpec, UnitKey};
use tracer::film::{Accumulation, SampleRange, Tile};
use worker::{Failure, GrpcLink, LoadedJob, RenderOutcome, Rendered};

use crate::commands::builtin::BuiltinScene;
use crate::edge::client::{FarmClient, Watch};
use crate::farm::status::JobState;

#[derive(Args)]
pub struct LoadtestArgs {
    /// Simulated workers, each with its own connection.
    #[arg(long, default_value_t = 64)]
    pub connections: usize,
    /// Image width and height in pixels.
    #[arg(long, default_value_t = 256)]
    pub size: u32,
    /// Tile size of a unit, in pixels.
    #[arg(long, default_value_t = 8)]
    pub tile: u32,
    /// Samples per pixel of the job; with one sample per unit this is the number of
    /// passes over the tiles (units = tiles × spp).
    #[arg(long, default_value_t = 16, conflicts_with = "units")]
    pub spp: u32,
    /// Units of the job instead of --spp: the samples per pixel become units ÷ tiles,
    /// rounded up (so the job has at least this many units).
    #[arg(long, value_name = "N")]
    pub units: Option<u64>,
    /// Render threads each simulated worker claims: it keeps twice as many units leased
    /// and returns those that are ready together, as a real worker does.
    #[arg(long, value_name = "N", default_value_t = 4)]
    pub threads: usize,
}

/// The `coordinator serve` child with its own asset store; killed when dropped, whatever
/// happened, and stopping by itself if this process dies (its stdin closes).
struct Server {
    child: Child,
    url: String,
    store: PathBuf,
}

impl Server {
    fn start() -> anyhow::Result<Self> {
        let exe = std::env::current_exe().context("locating the coordinator binary")?;
        let store = std::env::temp_dir().join(format!("tilefarm-loadtest-{}", std::process::id()));
        let mut child = Command::new(exe)
            .args(["serve", "--listen", "127.0.0.1:0", "--exit-on-stdin-eof", "--store"])
            .arg(&store)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .context("starting coordinator serve")?;
        let stdout = child.stdout.take().context("serve's stdout")?;
        let mut server = Self { child, url: String::new(), store };
        let mut line = String::new();
        BufReader::new(stdout).read_line(&mut line).context("reading serve's address")?;
        server.url = line
            .strip_prefix("listening on ")
            .with_context(|| format!("unexpected first line from serve: {line:?}"))?
            .trim()
            .to_string();
        Ok(server)
    }

    /// User and system CPU seconds so far, and peak resident memory in bytes.
    fn usage(&self) -> anyhow::Result<(f64, u64)> {
        let pid = self.child.id();
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).context("reading /proc/PID/stat")?;
        // Fields after the parenthesised command name; utime and stime are fields 14, 15.
        let rest = stat.rsplit_once(')').context("parsing /proc/PID/stat")?.1;
        let f: Vec<&str> = rest.split_whitespace().collect();
        // Clock ticks: USER_HZ is 100 on Linux, a fixed part of its user-space ABI.
        let ticks: u64 = f[11].parse::<u64>()? + f[12].parse::<u64>()?;
        let status = std::fs::read_to_string(format!("/proc/{pid}/status")).context("reading /proc/PID/status")?;
        let hwm_kb = status
            .lines()
            .find_map(|l| l.strip_prefix("VmHWM:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
            .context("parsing VmHWM")?;
        Ok((ticks as f64 / 100.0, hwm_kb * 1024))
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.store);
    }
}

pub fn run(args: LoadtestArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.connections > 0 && args.tile > 0 && args.spp > 0 && args.size > 0 && args.threads > 0,
        "all sizes must be > 0"
    );
    let mut args = args;
    if let Some(n) = args.units {
        let tiles = u64::from(args.size.div_ceil(args.tile)).pow(2);
        args.spp = u32::try_from(n.div_ceil(tiles).max(1)).context("--units: too many for one job")?;
    }
    let server = Server::start()?;
    let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build().context("async runtime")?;
    // Bounded: a coordinator that stops answering ends the test with an error.
    rt.block_on(async {
        tokio::time::timeout(Duration::from_secs(600), drive(&server, &args))
            .await
            .unwrap_or_else(|_| Err(anyhow::anyhow!("the load test did not finish within 10 minutes")))
    })
}

/// Uploads the built-in Cornell box and submits it cut into the test's units; returns
/// the job's spec and id.
async fn submit_job(jobs: &mut FarmClient, args: &LoadtestArgs) -> anyhow::Result<(JobSpec, String)> {
    let scene = BuiltinScene::write()?;
    let scene_ref = jobs.upload(&scene.path(), "scene.toml".into()).await?;
    let mut assets = Vec::new();
    for name in ["cbox.obj", "cbox.mtl"] {
        assets.push(jobs.upload(&scene.path().with_file_name(name), name.into()).await?);
    }
    let spec = JobSpec {
        job_id: String::new(),
        scene: scene_ref,
        assets,
        overrides: tracer::scene::Overrides {
            spp: Some(args.spp),
            width: Some(args.size),
            height: Some(args.size),
            ..Default::default()
        },
        integrator: tracer::integrator::Integrator::Path,
        tile_size: Some(args.tile),
        batch_spp: Some(1),
        spp_map: None,
        group: None,
    };
    let job = jobs.submit("loadtest".into(), 0, &spec).await.context("submitting the job")?;
    Ok((spec, job))
}

/// Simulated workers, each the worker's machine over its own gRPC connection; stopped
/// with `stop`.
fn start_workers(
    server: &Server,
    args: &LoadtestArgs,
    flow: &Arc<Flow>,
    stop: &tokio::sync::watch::Receiver<Option<worker::Stop>>,
) -> anyhow::Result<Vec<tokio::task::JoinHandle<anyhow::Result<u64>>>> {
    let cache = server.store.with_extension("worker-cache");
    let base = GrpcLink::connect(&server.url, &Default::default(), &cache, Duration::from_millis(500))?;
    let scene = Arc::new(tokio::sync::OnceCell::new());
    let mut workers = Vec::new();
    for _ in 0..args.connections {
        let link = SimulatedLink {
            link: base.another_connection(&server.url, &Default::default())?,
            scene: Arc::clone(&scene),
            flow: Arc::clone(flow),
        };
        let settings = worker::Settings {
            coordinator: server.url.clone(),
            threads: args.threads,
            max_backoff: Duration::from_millis(500),
            give_up_after: Some(Duration::from_secs(30)),
        };
        let executor = Arc::new(EmptyResults(args.threads));
        workers.push(tokio::spawn(worker::drive(link, executor, settings, stop.clone())));
    }
    Ok(workers)
}

async fn drive(server: &Server, args: &LoadtestArgs) -> anyhow::Result<()> {
    let mut jobs = FarmClient::connect(&server.url, None, None).await?;
    let (spec, job) = submit_job(&mut jobs, args).await?;
    let tiles = args.size.div_ceil(args.tile) as u64;
    let units = tiles * tiles * args.spp as u64;
    println!(
        "coordinator {} (pid {}); job {job}: {units} units of {t}×{t} px × 1 spp; {} simulated workers × {} threads",
        server.url,
        server.child.id(),
        args.connections,
        args.threads,
        t = args.tile
    );

    // The coordinator loads the scene before it leases units: start the clock once it has.
    let Watch::Stream(mut watch) = jobs.watch(&job).await? else { anyhow::bail!("the farm lost job {job}") };
    loop {
        let s = watch.next().await?.context("the job's status stream ended before it ran")?;
        match s.state {
            JobState::Running | JobState::Done => break,
            JobState::Failed | JobState::Cancelled => anyhow::bail!("the job failed: {}", s.error),
            JobState::Queued | JobState::Loading => {}
        }
    }
    drop(watch);

    let (cpu0, _) = server.usage()?;
    let flow = Arc::new(Flow::default());
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(None);
    let start = Instant::now();
    let workers = start_workers(server, args, &flow, &stop_rx)?;
    // Done when the job is: every unit merged once.
    let Watch::Stream(mut watch) = jobs.watch(&job).await? else { anyhow::bail!("the farm lost job {job}") };
    let mut done = 0;
    while let Some(s) = watch.next().await? {
        done = s.units_done;
        match s.state {
            JobState::Done => break,
            JobState::Failed | JobState::Cancelled => anyhow::bail!("the job ended early: {}", s.error),
            JobState::Queued | JobState::Loading | JobState::Running => {}
        }
    }
    let secs = start.elapsed().as_secs_f64();
    let (cpu1, peak) = server.usage()?;
    let _ = stop_tx.send(Some(worker::Stop::Signal));
    let mut submitted = 0;
    for w in workers {
        submitted += w.await.context("a simulated worker panicked")??;
    }
    let image_bytes = jobs.fetch_exr(&job).await?.len();

    anyhow::ensure!(done == units, "the job reports {done} of {units} units done");
    let flowing = flow.seconds().unwrap_or(secs);
    println!(
        "merged {done} unit results in {flowing:.3} s from the first result sent to the last answered: {:.0} \
         results/s ({:.0}/s over {secs:.2} s with the workers' start); {submitted} sent, {} duplicates",
        done as f64 / flowing,
        done as f64 / secs,
        submitted.saturating_sub(done)
    );
    println!(
        "coordinator CPU {:.2} s ({:.0} % of one core), peak memory {:.1} MiB",
        cpu1 - cpu0,
        100.0 * (cpu1 - cpu0) / secs,
        peak as f64 / (1 << 20) as f64
    );
    let (lease, result) = wire_sizes(&JobSpec { job_id: job.clone(), ..spec.clone() }, args.tile);
    println!(
        "wire per unit: leased unit {lease} B + result {result} B (protobuf); final image {:.1} KiB of EXR for {}×{} px",
        image_bytes as f64 / 1024.0,
        args.size,
        args.size
    );
    let _ = std::fs::remove_dir_all(server.store.with_extension("worker-cache"));
    Ok(())
}

/// The encoded sizes of one leased unit and of its result.
fn wire_sizes(spec: &JobSpec, tile: u32) -> (usize, usize) {
    let tile = Tile::new(0, 0, tile, tile);
    let samples = SampleRange::new(0, 1);
    let unit = proto::wire::unit_to_proto(spec, 1, tile, samples);
    let key = UnitKey { job_id: "job-1".into(), unit_id: 1 };
    let mut acc = Accumulation::new(tile);
    acc.counts.fill(1);
    (unit.encoded_len(), proto::wire::result_to_proto(1, &key, samples, &acc, 0, 0.0).encoded_len())
}

/// When results flowed: the first sent, the last answered.
#[derive(Default)]
struct Flow {
    first_sent: std::sync::OnceLock<Instant>,
    last_answered: std::sync::Mutex<Option<Instant>>,
}

impl Flow {
    fn seconds(&self) -> Option<f64> {
        let first = self.first_sent.get()?;
        let last = (*self.last_answered.lock().unwrap_or_else(|p| p.into_inner()))?;
        Some(last.duration_since(*first).as_secs_f64()).filter(|&s| s > 0.0)
    }
}

/// The real gRPC link, with the scene loaded once for all simulated workers (they
/// all share one process; a farm's workers each load it once too), and the flow of
/// results timed.
#[derive(Clone)]
struct SimulatedLink {
    link: GrpcLink,
    scene: Arc<tokio::sync::OnceCell<Arc<LoadedJob>>>,
    flow: Arc<Flow>,
}

impl worker::Link for SimulatedLink {
    async fn register(&self, threads: usize) -> Result<worker::Registration, Failure> {
        self.link.register(threads).await
    }

    async fn lease(&self, worker_id: u64, max_units: u32) -> Result<worker::Grant, Failure> {
        self.link.lease(worker_id, max_units).await
    }

    async fn heartbeat(&self, worker_id: u64, held: Vec<UnitKey>) -> Result<worker::Renewal, Failure> {
        self.link.heartbeat(worker_id, held).await
    }

    async fn submit(&self, worker_id: u64, units: Vec<Arc<Rendered>>) -> Result<Vec<Result<bool, String>>, Failure> {
        self.flow.first_sent.get_or_init(Instant::now);
        let outcomes = self.link.submit(worker_id, units).await;
        *self.flow.last_answered.lock().unwrap_or_else(|p| p.into_inner()) = Some(Instant::now());
        outcomes
    }

    async fn prepare(&self, job: Arc<JobSpec>) -> Result<Arc<LoadedJob>, String> {
        let first = self.scene.get_or_try_init(|| self.link.prepare(job.clone())).await?;
        Ok(Arc::new(LoadedJob {
            spec: (*job).clone(),
            scene: Arc::clone(&first.scene),
            integrator: job.integrator,
            prepared: false,
        }))
    }
}

/// Renders nothing: a unit's result is zero radiance with the right sample counts.
struct EmptyResults(usize);

impl worker::Executor for EmptyResults {
    fn threads(&self) -> usize {
        self.0
    }

    fn render(
        &self,
        _: Arc<LoadedJob>,
        tile: Tile,
        samples: SampleRange,
        _: Arc<AtomicBool>,
        done: impl FnOnce(RenderOutcome) + Send + 'static,
    ) {
        let mut acc = Accumulation::new(tile);
        acc.counts.fill(samples.len());
        done(RenderOutcome::Done { acc, rays: 0, elapsed: Duration::ZERO });
    }
}
