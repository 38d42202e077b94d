//! `coordinator serve`: a long-running farm.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use clap::Args;

use proto::auth::{Access, Caller, Token};
use proto::tls::TlsDir;
use tonic::transport::ServerTlsConfig;
use tracer::scene::prepared::PreparedScenes;

use crate::edge::conn::Limits;
use crate::edge::http::HttpServer;
use crate::edge::server::Server;
use crate::farm::Shared;
use crate::farm::assets::AssetStore;
use crate::farm::checkpoint;
use crate::farm::identities::Bans;
use crate::farm::lifecycle::submit_job;
use crate::farm::state::{Farm, FarmConfig};
use crate::farm::verify::Policy;

/// Every result of an identity's first this-many is checked, and the rate falls from
/// there as this over its record until it reaches `--verify` (see `farm::verify`).
const PROBATION: u64 = 16;

/// The farm's bans, beside its store (or checkpoints): they outlive a restart.
const BANS_FILE: &str = "bans.json";

#[derive(Args)]
pub struct ServeArgs {
    /// Address to listen on. Loopback unless told otherwise; port 0 picks a free port
    /// (the address is printed).
    #[arg(long, default_value = "127.0.0.1:7878")]
    pub listen: String,
    /// The farm's TLS folder (`coordinator certs init DIR`): serve over TLS, admit
    /// workers by their certificates, and clients by the tokens in DIR (`admin.token`
    /// may do everything; `NAME.token` is user NAME, who sees only its own jobs).
    #[arg(long, value_name = "DIR")]
    pub tls: Option<PathBuf>,
    /// Serve on an address other machines can reach without TLS and tokens: anyone who
    /// reaches the port can submit, cancel and fetch jobs and join as a worker. Only on a
    /// network you trust.
    #[arg(long)]
    pub insecure: bool,
    /// A file whose first line is an admin access token: calls bearing it (workers and
    /// clients with --token or TILEFARM_TOKEN) may do everything.
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// Also serve HTTP here: Prometheus metrics at /metrics (with the farm's admin
    /// token, `Authorization: Bearer …`, when it has tokens), and /healthz and /readyz
    /// for probes. Plain HTTP: other machines may reach it only with --insecure.
    #[arg(long, value_name = "ADDRESS")]
    pub http: Option<String>,
    /// Where uploaded scene files are kept (content-addressed).
    #[arg(long)]
    pub store: Option<PathBuf>,
    /// Persist every job (what is done, the image so far) in this folder, every few
    /// seconds and on Ctrl-C/SIGTERM, and restore the jobs found there at start: a
    /// restarted coordinator continues where it stopped. Scene files are kept there too.
    #[arg(long, conflicts_with = "store")]
    pub checkpoint: Option<PathBuf>,
    /// Shortest time between two checkpoints of a job, in milliseconds.
    #[arg(long, default_value_t = 5_000)]
    pub checkpoint_interval_ms: u64,
    /// How long a finished job stays listed by `status`, in milliseconds. Its image
    /// leaves memory as soon as it is stored (in the store's images/ folder), and
    /// `fetch` reads it from there also after the job is no longer listed.
    #[arg(long, value_name = "MS", default_value_t = 86_400_000)]
    pub retain_finished_ms: u64,
    /// The fraction of units rendered again under another identity (another worker
    /// certificate or token, or the coordinator itself) and compared bit for bit: at the
    /// least; every result of an identity's first 16 is checked, and the rate falls from
    /// there to this. An identity whose result differs from the truth is banned, and what
    /// it returned unconfirmed renders again. 0 turns checking off.
    #[arg(long, value_name = "FRACTION", default_value_t = 0.02)]
    pub verify: f64,
    /// Most workers one identity (a worker certificate or a user's token) may have
    /// registered at once. Admin tokens are not limited.
    #[arg(long, value_name = "N", default_value_t = crate::farm::state::DEFAULT_WORKERS_PER_IDENTITY,
          value_parser = clap::value_parser!(u32).range(1..))]
    pub max_workers_per_identity: u32,
    /// Most jobs one user may have loading, queued or running at once; another is
    /// refused, saying so.
    #[arg(long, value_name = "N", default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_user_jobs: u32,
    /// Most memory one user's jobs may take together while they run, in MiB (each job's
    /// image, 52 bytes a pixel, and its units); a job past it fails as it starts,
    /// naming the limit.
    #[arg(long, value_name = "MIB", default_value_t = 16_384, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_user_memory_mb: u64,
    /// Most memory all running jobs may take together, in MiB; a job past it fails as it
    /// starts, naming the limit.
    #[arg(long, value_name = "MIB", default_value_t = 32_768, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_farm_memory_mb: u64,
    /// Stop (as on Ctrl-C) when standard input reaches end of file: a parent process
    /// that spawns `serve` and holds its stdin takes it down even when killed itself.
    #[arg(long, hide = true)]
    pub exit_on_stdin_eof: bool,
    #[command(flatten)]
    pub connections: ConnectionArgs,
    #[command(flatten)]
    pub farm: FarmArgs,
}

/// How long connections may take, and how many may wait, so that a flood of idle
/// connections cannot use up the process's open files.
#[derive(Args, Clone, Debug)]
pub struct ConnectionArgs {
    /// A TLS handshake on the gRPC port must finish within this many milliseconds.
    #[arg(long, value_name = "MS", default_value_t = 10_000)]
    pub handshake_timeout_ms: u64,
    /// An HTTP request's header must arrive within this many milliseconds of the
    /// connection opening or of the previous response (so an idle kept-alive connection
    /// closes after this too).
    #[arg(long, value_name = "MS", default_value_t = 10_000)]
    pub header_timeout_ms: u64,
    /// A gRPC connection that has made no authenticated call this many milliseconds
    /// after it opened is closed; an authenticated one quiet for this long is pinged,
    /// and closed if the ping goes unanswered.
    #[arg(long, value_name = "MS", default_value_t = 300_000)]
    pub idle_timeout_ms: u64,
    /// Most connections per port that have not yet authenticated (gRPC) or are waiting
    /// for a request (HTTP); past it, the oldest of them is closed to admit the new one.
    #[arg(long, value_name = "N", default_value_t = 256)]
    pub max_pending_connections: usize,
}

impl ConnectionArgs {
    pub fn limits(&self) -> anyhow::Result<Limits> {
        anyhow::ensure!(
            self.handshake_timeout_ms > 0 && self.header_timeout_ms > 0 && self.idle_timeout_ms > 0,
            "--handshake-timeout-ms, --header-timeout-ms and --idle-timeout-ms must be at least 1"
        );
        anyhow::ensure!(self.max_pending_connections > 0, "--max-pending-connections must be at least 1");
        Ok(Limits {
            handshake: Duration::from_millis(self.handshake_timeout_ms),
            header: Duration::from_millis(self.header_timeout_ms),
            idle: Duration::from_millis(self.idle_timeout_ms),
            max_pending: self.max_pending_connections,
        })
    }
}

/// How the farm treats leases; shared by `serve` and `render`.
#[derive(Args, Clone, Debug)]
pub struct FarmArgs {
    /// A lease lapses this many milliseconds after its last renewal; its unit then goes
    /// back to the queue (this bounds how long a dead worker's units wait).
    #[arg(long, default_value_t = 10_000)]
    pub lease_ms: u64,
    /// How often workers renew their leases, in milliseconds.
    #[arg(long, default_value_t = 2_000)]
    pub heartbeat_ms: u64,
    /// When no unit is left in the queue, a unit out with one worker for three times the
    /// job's median unit time is also given to an idle worker; the first result wins.
    /// Until a job has timed a few units, this many milliseconds stands in for that.
    #[arg(long, default_value_t = 10_000)]
    pub speculate_after_ms: u64,
    /// Forget a worker not heard from for this many milliseconds (it registers again if
    /// it comes back). Must exceed --lease-ms.
    #[arg(long, default_value_t = 60_000)]
    pub forget_worker_ms: u64,
    /// Most memory one job's image may take while it renders (52 bytes per pixel), in
    /// MiB; a larger job is refused, naming the limit, before anything is allocated.
    #[arg(long, value_name = "MIB", default_value_t = 8192)]
    pub max_job_memory_mb: u64,
    /// Largest file a user may upload, in MiB (streamed to disk, never held in memory).
    #[arg(long, value_name = "MIB", default_value_t = 4096)]
    pub max_upload_mb: u64,
    /// Most MiB of uploaded scene files the store keeps; an upload past it is refused.
    #[arg(long, value_name = "MIB", default_value_t = 65_536)]
    pub max_store_mb: u64,
    /// Most MiB of prepared scenes (mesh and BVH, kept after a scene's first load so
    /// that loading it again reads them back) to keep; the least recently used go first.
    /// 0 keeps none.
    #[arg(long, value_name = "MIB", default_value_t = tracer::scene::prepared::DEFAULT_MAX_BYTES >> 20)]
    pub scene_cache_max_mb: u64,
}

impl FarmArgs {
    /// The folder of prepared scenes at `dir`, unless none are to be kept or it cannot
    /// be used (said once: loading from the files is slower, never wrong).
    pub fn prepared_scenes(&self, dir: &Path) -> Option<PreparedScenes> {
        if self.scene_cache_max_mb == 0 {
            return None;
        }
        PreparedScenes::open(dir, self.scene_cache_max_mb.saturating_mul(1 << 20))
            .inspect_err(|e| tracing::warn!("{e}"))
            .ok()
    }

    pub fn config(&self) -> anyhow::Result<FarmConfig> {
        anyhow::ensure!(
            self.heartbeat_ms > 0 && self.lease_ms > self.heartbeat_ms,
            "--lease-ms must exceed --heartbeat-ms"
        );
        anyhow::ensure!(self.forget_worker_ms > self.lease_ms, "--forget-worker-ms must exceed --lease-ms");
        anyhow::ensure!(self.max_job_memory_mb > 0, "--max-job-memory-mb must be at least 1");
        Ok(FarmConfig {
            max_job_bytes: self.max_job_memory_mb << 20,
            max_upload_bytes: self.max_upload_mb << 20,
            max_store_bytes: self.max_store_mb << 20,
            verify: Default::default(),
            lease: Duration::from_millis(self.lease_ms),
            heartbeat: Duration::from_millis(self.heartbeat_ms),
            speculate_after: Duration::from_millis(self.speculate_after_ms),
            forget_worker_after: Duration::from_millis(self.forget_worker_ms),
            // A local render's one job is bounded by --max-job-memory-mb alone; `serve`
            // sets the users' and the farm's budgets.
            max_user_bytes: u64::MAX,
            max_farm_bytes: u64::MAX,
            ..FarmConfig::default()
        })
    }
}

/// Who may call this farm, and its TLS configuration. Off loopback, a farm needs TLS and
/// at least one token, unless `--insecure` says otherwise (loudly).
fn access_of(args: &ServeArgs) -> anyhow::Result<(Access, Option<ServerTlsConfig>)> {
    let (mut access, tls) = match &args.tls {
        Some(dir) => {
            let dir = TlsDir::new(dir);
            (dir.access().map_err(anyhow::Error::msg)?, Some(dir.server().map_err(anyhow::Error::msg)?))
        }
        None => (Access::open(), None),
    };
    if let Some(f) = &args.token_file {
        access = access.with_token(Token::from_file(f).map_err(anyhow::Error::msg)?, Caller::admin());
    }
    if !loopback_only(&args.listen).with_context(|| format!("--listen {}", args.listen))?
        && (tls.is_none() || !access.has_tokens())
    {
        anyhow::ensure!(
            args.insecure,
            "--listen {}: other machines could reach this farm, so it needs TLS and access tokens: make them with \
             `coordinator certs init DIR` and add --tls DIR (or listen on 127.0.0.1; --insecure serves it \
             unprotected on a network you trust)",
            args.listen
        );
        eprintln!(
            "\n!!! WARNING: serving on {} without TLS and access tokens (--insecure): anyone who can reach this \
             port can submit, cancel and fetch jobs, join as a worker and poison images !!!\n",
            args.listen
        );
    }
    Ok((access, tls))
}

/// Whether every address `listen` names is a loopback one.
pub(crate) fn loopback_only(listen: &str) -> anyhow::Result<bool> {
    use std::net::ToSocketAddrs;
    let addrs: Vec<std::net::SocketAddr> = listen.to_socket_addrs().context("not an address")?.collect();
    Ok(!addrs.is_empty() && addrs.iter().all(|a| a.ip().is_loopback()))
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let (access, tls) = access_of(&args)?;
    if let Some(http) = &args.http
        && !args.insecure
        && !loopback_only(http).with_context(|| format!("--http {http}"))?
    {
        anyhow::bail!(
            "--http {http}: other machines could reach it, and it is plain HTTP (tokens would cross the network \
             unencrypted): serve it on 127.0.0.1 behind a TLS proxy, or give --insecure on a network you trust"
        );
    }
    let limits = args.connections.limits()?;
    let mut config = args.farm.config()?;
    config.verify = Policy::new(args.verify, PROBATION).map_err(anyhow::Error::msg)?;
    config.max_workers_per_identity = args.max_workers_per_identity as usize;
    config.max_user_jobs = args.max_user_jobs as usize;
    (config.max_user_bytes, config.max_farm_bytes) = (args.max_user_memory_mb << 20, args.max_farm_memory_mb << 20);
    tracer::memory::return_large_buffers_when_freed();
    let store_dir = args
        .checkpoint
        .clone()
        .or_else(|| args.store.clone())
        .unwrap_or_else(|| std::env::temp_dir().join("tilefarm-coordinator-store"));
    let store = AssetStore::open(&store_dir)?;
    let mut shared = Shared::new(Farm::new(config), store);
    shared.prepared = args.farm.prepared_scenes(&store_dir.join("prepared"));
    let bans = store_dir.join(BANS_FILE);
    shared.farm().identities.restore(Bans::read(&bans)?, std::time::Instant::now());
    let shared = Arc::new(shared);
    let ckpt_root = args.checkpoint.as_ref().map(|d| d.join("job-checkpoints"));
    let images = store_dir.join(crate::farm::assets::IMAGES);
    std::fs::create_dir_all(&images).with_context(|| format!("creating {}", images.display()))?;
    // Ids of finished jobs whose images are stored stay taken.
    if let Some(n) = stored_job_numbers(&images).max() {
        shared.farm().reserve_job_ids_through(n);
    }
    if let Some(root) = &ckpt_root {
        restore_jobs(&shared, root)?;
    }
    let retain = Duration::from_millis(args.retain_finished_ms);
    let runtime =
        tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().context("async runtime")?;
    runtime.block_on(async move {
        let server = Server::start(Arc::clone(&shared), &args.listen, access.clone(), tls, limits).await?;
        // The first line of output is the URL, for scripts and tests.
        println!("listening on {}", server.url());
        let http = match &args.http {
            Some(listen) => {
                let h = HttpServer::start(Arc::clone(&shared), listen, access, limits).await?;
                tracing::info!(metrics = %format!("{}/metrics", h.url()), "serving HTTP");
                Some(h)
            }
            None => None,
        };
        tracing::info!(store = %store_dir.display(), "coordinator serving");
        let stdin_eof = stdin_closed(args.exit_on_stdin_eof);
        let stop = async {
            tokio::select! {
                _ = crate::stop_signal() => {}
                _ = stdin_eof => {}
            }
        };
        tokio::pin!(stop);
        let mut pacer = checkpoint::Pacer::new(Duration::from_millis(args.checkpoint_interval_ms));
        let mut saved: HashMap<String, Saved> = HashMap::new();
        // The jobs a write has been attempted for.
        let mut tried: HashSet<String> = HashSet::new();
        let mut store_retry: HashMap<String, std::time::Instant> = HashMap::new();
        loop {
            tokio::select! {
                _ = &mut stop => break,
                _ = tokio::time::sleep(Duration::from_millis(250)) => {}
            }
            // A job never written is written at once: it is lost to a crash until then, and
            // the pacer can wait many seconds after a slow write. (A first write that fails
            // is retried at the pacer's pace, as any other.)
            if let Some(root) = &ckpt_root
                && (pacer.due() || never_tried(&shared, &tried))
            {
                tried = shared.farm().jobs.iter().filter(|e| checkpointed(e)).map(|e| e.job.id.clone()).collect();
                let t = std::time::Instant::now();
                save_jobs(&shared, root, &mut saved).await;
                let before = pacer.interval();
                pacer.wrote(t.elapsed());
                if pacer.interval() > before.max(Duration::from_millis(args.checkpoint_interval_ms)) {
                    tracing::info!(
                        "checkpoints took {:.1} s to write: writing every {:.0} s, not every --checkpoint-interval-ms",
                        t.elapsed().as_secs_f64(),
                        pacer.interval().as_secs_f64()
                    );
                }
            }
            store_finished(&shared, &images, ckpt_root.as_deref(), &mut saved, &mut store_retry).await;
            shared.forget_finished(retain);
            save_bans(&shared, &bans).await;
        }
        tracing::info!("stopping");
        if let Some(h) = http {
            h.stop().await;
        }
        server.stop().await;
        save_bans(&shared, &bans).await;
        if let Some(root) = &ckpt_root {
            save_jobs(&shared, root, &mut saved).await;
            tracing::info!(folder = %root.display(), "jobs checkpointed");
        }
        Ok(())
    })
}

/// Writes the farm's bans when they changed. A write that fails is a warning naming the
/// file, and is tried again at the next turn.
async fn save_bans(shared: &Arc<Shared>, path: &Path) {
    let bans = {
        let mut farm = shared.farm();
        if !farm.identities.take_changed() {
            return;
        }
        farm.identities.bans()
    };
    let p = path.to_path_buf();
    let written = tokio::task::spawn_blocking(move || bans.write(&p)).await.map_err(anyhow::Error::from);
    if let Err(e) = written.and_then(|r| r) {
        tracing::warn!("bans not written, retrying: {e:#}");
        shared.farm().identities.mark_changed();
    }
}

/// Resolves when standard input reaches end of file (never, unless `watch`). A plain
/// thread does the blocking read, so the runtime's shutdown never waits for it.
async fn stdin_closed(watch: bool) {
    if !watch {
        return std::future::pending().await;
    }
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let spawned = std::thread::Builder::new().name("stdin-watch".into()).spawn(move || {
        worker::block_until_stdin_eof();
        let _ = tx.send(());
    });
    match spawned {
        Ok(_) => {
            let _ = rx.await;
        }
        Err(e) => {
            tracing::warn!("cannot watch standard input: {e}");
            std::future::pending::<()>().await
        }
    }
}

/// What a job's last checkpoint holds: its finished units and whether it was cancelled.
type Saved = (u64, bool);

/// Writes the checkpoint of every job whose progress (or cancellation) changed since its
/// last one. A write that fails (disk full, folder gone, read-only) is a warning naming
/// the file: the farm goes on, and the job is written again at the next interval.
async fn save_jobs(shared: &Arc<Shared>, root: &Path, saved: &mut HashMap<String, Saved>) {
    let snaps: Vec<(String, Saved, checkpoint::Snapshot)> = {
        let farm = shared.farm();
        farm.jobs
            .iter()
            .filter(|e| checkpointed(e))
            .map(|e| (e, (e.job.units_done, e.job.phase == crate::farm::job::JobPhase::Cancelled)))
            .filter(|(e, now)| saved.get(&e.job.id) != Some(now))
            .map(|(e, now)| {
                let mut snap = checkpoint::Snapshot::of(&e.spec, &e.job);
                snap.job.unconfirmed = farm.unconfirmed_names(&e.job);
                (e.job.id.clone(), now, snap)
            })
            .collect()
    };
    for (id, now, snap) in snaps {
        let dir = root.join(&id);
        let written = tokio::task::spawn_blocking(move || -> anyhow::Result<()> {
            std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
            checkpoint::write(&dir, &snap)?;
            if snap.job.cancelled {
                checkpoint::mark_cancelled(&dir)?;
            }
            Ok(())
        })
        .await
        .map_err(anyhow::Error::from)
        .and_then(|r| r);
        match written {
            Ok(()) => {
                saved.insert(id, now);
            }
            Err(e) => tracing::warn!(job = %id, "checkpoint not written, retrying at the next interval: {e:#}"),
        }
    }
}

/// Whether a job is kept in checkpoints: from its submission until its image is stored.
/// A job whose scene is still being checked, or a queued frame, has no image yet, but
/// the client was given its id: it must come back after a restart (and does, under that
/// id, to load afresh).
fn checkpointed(e: &crate::farm::state::JobEntry) -> bool {
    !e.job.is_evicted()
}

/// Whether a job kept in checkpoints has had no write attempted yet.
fn never_tried(shared: &Shared, tried: &HashSet<String>) -> bool {
    shared.farm().jobs.iter().any(|e| checkpointed(e) && !tried.contains(&e.job.id))
}

fn stored_job_numbers(images: &Path) -> impl Iterator<Item = u64> {
    let names = std::fs::read_dir(images).into_iter().flatten().flatten().map(|e| e.file_name());
    names.filter_map(|n| n.to_str()?.strip_prefix("job-")?.strip_suffix(".exr")?.parse().ok())
}

/// Stores finished jobs' images and evicts their sums (see the lifecycle); their
/// checkpoints go, since a restart must not load them again.
async fn store_finished(
    shared: &Arc<Shared>,
    images: &Path,
    ckpt_root: Option<&Path>,
    saved: &mut HashMap<String, Saved>,
    retry: &mut HashMap<String, std::time::Instant>,
) {
    let (shared, images, mut pending) = (Arc::clone(shared), images.to_path_buf(), std::mem::take(retry));
    let stored = tokio::task::spawn_blocking(move || {
        let stored = shared.store_finished(&images, &mut pending);
        (stored, pending)
    })
    .await;
    let Ok((stored, pending)) = stored else { return };
    *retry = pending;
    for id in stored {
        if let Some(root) = ckpt_root {
            let _ = std::fs::remove_dir_all(root.join(&id));
            saved.remove(&id);
        }
    }
}

fn restore_jobs(shared: &Arc<Shared>, root: &Path) -> anyhow::Result<()> {
    let Ok(entries) = std::fs::read_dir(root) else { return Ok(()) };
    let mut dirs: Vec<PathBuf> = entries.flatten().map(|e| e.path()).filter(|p| p.is_dir()).collect();
    // In submission order (job-2 before job-10): a group's frames start in that order,
    // and it breaks the fair share's ties.
    let number = |p: &PathBuf| p.file_name()?.to_str()?.strip_prefix("job-")?.parse::<u64>().ok();
    dirs.sort_by_key(|p| (number(p).unwrap_or(u64::MAX), p.clone()));
    for dir in dirs {
        let snap = match checkpoint::read(&dir) {
            Ok(Some(s)) => s,
            Ok(None) => continue,
            Err(e) => {
                tracing::error!("{e:#}");
                eprintln!("error: {e:#}");
                continue;
            }
        };
        let mut spec = snap.spec;
        let (done, total) = (snap.job.units.iter().filter(|u| u.done).count(), snap.job.units.len());
        // A frame saved before it started has nothing to restore: it starts afresh in its
        // turn, or not at all if it was cancelled.
        let restore = match snap.job.width {
            0 if snap.job.cancelled => {
                let _ = std::fs::remove_dir_all(&dir);
                continue;
            }
            0 => None,
            _ => {
                // The checkpoint's samples per pixel, not the first submission's.
                spec.overrides.spp = None;
                Some(snap.job)
            }
        };
        let id = submit_job(shared, snap.name, snap.owner, spec, restore)
            .with_context(|| format!("restoring {}", dir.display()))?;
        tracing::info!(job = %id, done, total, "job restored from its checkpoint");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        serve: ServeArgs,
    }

    fn access(args: &[&str]) -> anyhow::Result<bool> {
        let cli = Cli::try_parse_from(std::iter::once("serve").chain(args.iter().copied()))?;
        access_of(&cli.serve).map(|(_, tls)| tls.is_some())
    }

    /// Off loopback, a farm needs TLS and a token (or --insecure); on loopback, neither.
    #[test]
    fn reachable_farms_need_tls_and_tokens() {
        let dir = std::env::temp_dir().join(format!("tilefarm-serve-access-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let tls = dir.join("tls");
        crate::commands::certs::init(crate::commands::certs::InitArgs {
            dir: tls.clone(),
            workers: 1,
            users: vec!["user".into()],
            host: vec![],
        })
        .unwrap();
        let t = tls.to_str().unwrap();
        assert!(!access(&["--listen", "127.0.0.1:0"]).unwrap());
        let e = access(&["--listen", "0.0.0.0:0"]).unwrap_err().to_string();
        assert!(e.contains("certs init") && e.contains("--insecure"), "{e}");
        assert!(access(&["--listen", "0.0.0.0:0", "--insecure"]).is_ok());
        assert!(access(&["--listen", "0.0.0.0:0", "--tls", t]).unwrap());
        // TLS without a single token would leave users no way in but --insecure's.
        for token in ["admin.token", "user.token"] {
            std::fs::remove_file(tls.join(token)).unwrap();
        }
        assert!(access(&["--listen", "0.0.0.0:0", "--tls", t]).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A job is checkpointed while its scene is still being checked (a large scene takes
    /// seconds): a coordinator killed then brings it back under the id its client holds.
    /// Before, only jobs whose scene had loaded (and frames of groups) were written.
    #[test]
    fn a_job_whose_scene_is_still_loading_survives_a_restart() {
        use proto::domain::{AssetRef, JobSpec};
        let dir = std::env::temp_dir().join(format!("tilefarm-serve-loading-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let (store, root) = (dir.join("store"), dir.join("job-checkpoints"));
        let shared = Arc::new(Shared::new(Farm::new(Default::default()), AssetStore::open(&store).unwrap()));
        let toml = "[camera]\nposition = [0, 0, -5]\nlook_at = [0, 0, 0]\nwidth = 8\nheight = 8\n";
        let (sha256, size) = shared.store().put(toml.as_bytes()).unwrap();
        let spec = JobSpec {
            job_id: String::new(),
            scene: AssetRef { path: "scene.toml".into(), sha256, size },
            assets: vec![],
            overrides: Default::default(),
            integrator: tracer::integrator::Integrator::Path,
            tile_size: None,
            batch_spp: None,
            spp_map: None,
            group: None,
        };
        // Added but not loaded: where a job stands while its scene is being checked.
        let id = shared.farm().add_job("hero".into(), Some("alice".into()), spec);
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        runtime.block_on(save_jobs(&shared, &root, &mut HashMap::new()));
        assert!(root.join(&id).join("checkpoint.tfck").is_file(), "the loading job was not checkpointed");

        let again = Arc::new(Shared::new(Farm::new(Default::default()), AssetStore::open(&store).unwrap()));
        restore_jobs(&again, &root).unwrap();
        let (name, owner) = {
            let farm = again.farm();
            let e = farm.entry(&id).expect("the job is back under its id");
            (e.job.name.clone(), e.job.owner.clone())
        };
        assert_eq!((name.as_str(), owner.as_deref()), ("hero", Some("alice")));
        // It loads afresh and starts; wait for that before the folder goes.
        let started = std::time::Instant::now();
        while again.farm().entry(&id).unwrap().job.width == 0 {
            let phase = again.farm().entry(&id).unwrap().job.phase.clone();
            assert!(!matches!(phase, crate::farm::job::JobPhase::Failed(_)), "{phase:?}");
            assert!(started.elapsed() < Duration::from_secs(30), "the restored job never started");
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(again.farm().entry(&id).unwrap().job.width, 8);
        std::fs::remove_dir_all(&dir).ok();
    }
}
