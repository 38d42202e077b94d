//! `coordinator loadtest`: how many unit results a coordinator merges per second.
//!
//! Starts `coordinator serve` as a child process on a free loopback port, submits the
//! built-in Cornell box cut into tiny units (8×8 tiles × 1 spp by default), and lets many
//! simulated workers — each its own gRPC connection — lease units one at a time and return
//! them at once, as fast as the coordinator answers. A simulated result has the right
//! tile, sample range and per-pixel counts and zero radiance, so the coordinator does all
//! of its real work (lease bookkeeping, validation, the exact merge) and none of ours is
//! rendering. It prints results merged per second, the coordinator's CPU time and peak
//! memory (from /proc), and the bytes on the wire per unit and for the final image.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use prost::Message;
use proto::farm_client::FarmClient as WorkerRpc;
use tonic::transport::{Channel, Endpoint};

use crate::commands::builtin::BuiltinScene;
use crate::edge::client::{FarmClient, Watch};
use crate::farm::status::JobState;

#[derive(Args)]
pub struct LoadtestArgs {
    /// Simulated workers, each with its own connection.
    #[arg(long, default_value_t = 256)]
    pub connections: usize,
    /// Image width and height in pixels.
    #[arg(long, default_value_t = 256)]
    pub size: u32,
    /// Tile size of a unit, in pixels.
    #[arg(long, default_value_t = 8)]
    pub tile: u32,
    /// Samples per pixel of the job; with one sample per unit this is the number of
    /// passes over the tiles (units = tiles × spp).
    #[arg(long, default_value_t = 16)]
    pub spp: u32,
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

/// What the simulated workers did.
#[derive(Default)]
struct Tally {
    accepted: AtomicU64,
    lease_bytes: AtomicU64,
    result_bytes: AtomicU64,
}

pub fn run(args: LoadtestArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.connections > 0 && args.tile > 0 && args.spp > 0 && args.size > 0, "all sizes must be > 0");
    let server = Server::start()?;
    let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build().context("async runtime")?;
    // Bounded: a coordinator that stops answering ends the test with an error.
    rt.block_on(async {
        tokio::time::timeout(Duration::from_secs(600), drive(&server, &args))
            .await
            .unwrap_or_else(|_| Err(anyhow::anyhow!("the load test did not finish within 10 minutes")))
    })
}

async fn drive(server: &Server, args: &LoadtestArgs) -> anyhow::Result<()> {
    let scene = BuiltinScene::write()?;
    let mut jobs = FarmClient::connect(&server.url).await?;
    let scene_ref = jobs.upload(&scene.path(), "scene.toml".into()).await?;
    let mut assets = Vec::new();
    for name in ["cbox.obj", "cbox.mtl"] {
        assets.push(jobs.upload(&scene.path().with_file_name(name), name.into()).await?);
    }
    let spec = proto::domain::JobSpec {
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
    };
    let job = jobs.submit("loadtest".into(), &spec).await.context("submitting the job")?;
    let tiles = args.size.div_ceil(args.tile) as u64;
    let units = tiles * tiles * args.spp as u64;
    println!(
        "coordinator {} (pid {}); job {job}: {units} units of {t}×{t} px × 1 spp; {} simulated workers",
        server.url,
        server.child.id(),
        args.connections,
        t = args.tile
    );

    // The coordinator loads the scene before it leases units: start the clock once it has.
    let Watch::Stream(mut watch) = jobs.watch(&job).await? else { anyhow::bail!("the farm lost job {job}") };
    loop {
        let s = watch.next().await?.context("the job's status stream ended before it ran")?;
        match s.state {
            JobState::Running | JobState::Done => break,
            JobState::Failed | JobState::Cancelled => anyhow::bail!("the job failed: {}", s.error),
            JobState::Loading => {}
        }
    }
    drop(watch);

    let (cpu0, _) = server.usage()?;
    let tally = Arc::new(Tally::default());
    let start = Instant::now();
    let mut tasks = Vec::new();
    for _ in 0..args.connections {
        let channel = Endpoint::from_shared(server.url.clone())?.connect().await.context("connecting a worker")?;
        let tally = tally.clone();
        tasks.push(tokio::spawn(simulated_worker(channel, tally, units)));
    }
    for t in tasks {
        t.await.context("a simulated worker panicked")??;
    }
    let secs = start.elapsed().as_secs_f64();
    let (cpu1, peak) = server.usage()?;

    let done = match jobs.watch(&job).await? {
        Watch::Stream(mut s) => s.next().await?.map_or(0, |s| s.units_done),
        Watch::NotFound(_) => 0,
    };
    let image_bytes = jobs.fetch_exr(&job).await?.len();

    let accepted = tally.accepted.load(Ordering::Relaxed);
    anyhow::ensure!(done == units, "the job reports {done} of {units} units done");
    anyhow::ensure!(accepted == units, "{accepted} results accepted for {units} units");
    println!("merged {accepted} unit results in {secs:.2} s: {:.0} results/s", accepted as f64 / secs);
    println!(
        "coordinator CPU {:.2} s ({:.0} % of one core), peak memory {:.1} MiB",
        cpu1 - cpu0,
        100.0 * (cpu1 - cpu0) / secs,
        peak as f64 / (1 << 20) as f64
    );
    println!(
        "wire per unit: lease reply {:.0} B + result {:.0} B (protobuf); final image {:.1} KiB of EXR for {}×{} px",
        tally.lease_bytes.load(Ordering::Relaxed) as f64 / units as f64,
        tally.result_bytes.load(Ordering::Relaxed) as f64 / units as f64,
        image_bytes as f64 / 1024.0,
        args.size,
        args.size
    );
    Ok(())
}

/// Registers, then leases one unit at a time and returns it at once until all `units`
/// have been accepted.
async fn simulated_worker(channel: Channel, tally: Arc<Tally>, units: u64) -> anyhow::Result<()> {
    let mut farm = WorkerRpc::new(channel)
        .max_decoding_message_size(proto::MAX_MESSAGE_BYTES)
        .max_encoding_message_size(proto::MAX_MESSAGE_BYTES);
    let worker_id = farm
        .register(proto::RegisterRequest {
            protocol_version: proto::PROTOCOL_VERSION,
            threads: 1,
            hostname: "loadtest".into(),
            version: env!("CARGO_PKG_VERSION").into(),
        })
        .await?
        .into_inner()
        .worker_id;
    loop {
        let reply = farm.lease(proto::LeaseRequest { worker_id, max_units: 1 }).await?.into_inner();
        if reply.units.is_empty() {
            // Nothing to lease now: the job is done, or its last units are out with
            // other simulated workers, who return them at once.
            if tally.accepted.load(Ordering::Relaxed) >= units {
                return Ok(());
            }
            tokio::time::sleep(Duration::from_millis(u64::from(reply.retry_after_ms).clamp(1, 100))).await;
            continue;
        }
        tally.lease_bytes.fetch_add(reply.encoded_len() as u64, Ordering::Relaxed);
        for unit in reply.units {
            let tile = unit.tile.context("a unit without a tile")?;
            let pixels = (tile.width * tile.height) as usize;
            let spp = unit.sample_end - unit.sample_start;
            let result = proto::UnitResult {
                worker_id,
                job_id: unit.job.map(|j| j.job_id).unwrap_or_default(),
                unit_id: unit.unit_id,
                tile: Some(tile),
                sample_start: unit.sample_start,
                sample_end: unit.sample_end,
                sums: vec![0; pixels * 48],
                counts: vec![spp; pixels],
                nonfinite: 0,
                rays: 0,
            };
            tally.result_bytes.fetch_add(result.encoded_len() as u64, Ordering::Relaxed);
            if farm.submit_result(result).await?.into_inner().accepted {
                tally.accepted.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}
