//! `coordinator serve`: a long-running farm.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::Context;
use clap::Args;

use crate::assets::{AssetRef, AssetStore};
use crate::checkpoint;
use crate::farm::{Farm, FarmConfig};
use crate::server::Server;
use crate::service::{JobDefaults, Shared};

#[derive(Args)]
pub struct ServeArgs {
    /// Address to listen on. Loopback unless told otherwise; port 0 picks a free port
    /// (the address is printed).
    #[arg(long, default_value = "127.0.0.1:7878")]
    pub listen: String,
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
    /// Stop (as on Ctrl-C) when standard input reaches end of file: a parent process
    /// that spawns `serve` and holds its stdin takes it down even when killed itself.
    #[arg(long, hide = true)]
    pub exit_on_stdin_eof: bool,
    #[command(flatten)]
    pub farm: FarmArgs,
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
}

impl FarmArgs {
    pub fn config(&self) -> anyhow::Result<FarmConfig> {
        anyhow::ensure!(
            self.heartbeat_ms > 0 && self.lease_ms > self.heartbeat_ms,
            "--lease-ms must exceed --heartbeat-ms"
        );
        anyhow::ensure!(self.forget_worker_ms > self.lease_ms, "--forget-worker-ms must exceed --lease-ms");
        Ok(FarmConfig {
            lease: Duration::from_millis(self.lease_ms),
            heartbeat: Duration::from_millis(self.heartbeat_ms),
            speculate_after: Duration::from_millis(self.speculate_after_ms),
            forget_worker_after: Duration::from_millis(self.forget_worker_ms),
        })
    }
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let config = args.farm.config()?;
    let store_dir = args
        .checkpoint
        .clone()
        .or_else(|| args.store.clone())
        .unwrap_or_else(|| std::env::temp_dir().join("tilefarm-coordinator-store"));
    let store = AssetStore::open(&store_dir)?;
    let shared = Arc::new(Shared {
        farm: Mutex::new(Farm::new(config)),
        store: Mutex::new(store),
        defaults: JobDefaults::default(),
        changed: tokio::sync::Notify::new(),
    });
    let ckpt_root = args.checkpoint.as_ref().map(|d| d.join("job-checkpoints"));
    let images = store_dir.join(crate::assets::IMAGES);
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
        let server = Server::start(Arc::clone(&shared), &args.listen).await?;
        // The first line of output is the URL, for scripts and tests.
        println!("listening on {}", server.url());
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
        let mut store_retry: HashMap<String, std::time::Instant> = HashMap::new();
        loop {
            tokio::select! {
                _ = &mut stop => break,
                _ = tokio::time::sleep(Duration::from_millis(250)) => {}
            }
            if let Some(root) = &ckpt_root
                && pacer.due()
            {
                let t = std::time::Instant::now();
                save_jobs(&shared, root, &mut saved).await;
                pacer.wrote(t.elapsed());
            }
            store_finished(&shared, &images, ckpt_root.as_deref(), &mut saved, &mut store_retry).await;
            forget_finished(&shared, retain);
        }
        tracing::info!("stopping");
        server.stop().await;
        if let Some(root) = &ckpt_root {
            save_jobs(&shared, root, &mut saved).await;
            tracing::info!(folder = %root.display(), "jobs checkpointed");
        }
        Ok(())
    })
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
            .filter(|e| e.job.width > 0 && !e.job.is_evicted())
            .map(|e| (e, (e.job.units_done, e.job.phase == crate::job::JobPhase::Cancelled)))
            .filter(|(e, now)| saved.get(&e.job.id) != Some(now))
            .map(|(e, now)| (e.job.id.clone(), now, checkpoint::Snapshot::of(&e.spec, &e.job)))
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

fn stored_job_numbers(images: &Path) -> impl Iterator<Item = u64> {
    let names = std::fs::read_dir(images).into_iter().flatten().flatten().map(|e| e.file_name());
    names.filter_map(|n| n.to_str()?.strip_prefix("job-")?.strip_suffix(".exr")?.parse().ok())
}

/// Stores the image of every newly finished job (atomically: temp file, fsync, rename)
/// and then drops its sums from memory, and its checkpoint and scene copy from disk: a
/// farm's memory follows its running jobs, not its history. A failed write is a warning,
/// and is tried again after a few seconds (`retry`).
async fn store_finished(
    shared: &Arc<Shared>,
    images: &Path,
    ckpt_root: Option<&Path>,
    saved: &mut HashMap<String, Saved>,
    retry: &mut HashMap<String, std::time::Instant>,
) {
    let now = std::time::Instant::now();
    let done: Vec<(String, tracer::film::Image, Option<tracer::output::RenderInfo>)> = {
        let farm = shared.farm();
        farm.jobs
            .iter()
            .filter(|e| e.job.phase == crate::job::JobPhase::Done && !e.job.is_evicted())
            .filter(|e| retry.get(&e.job.id).is_none_or(|&at| now >= at))
            .map(|e| (e.job.id.clone(), e.job.image(), e.render_info()))
            .collect()
    };
    let evicting = !done.is_empty();
    for (id, image, info) in done {
        let path = images.join(format!("{id}.exr"));
        let target = path.clone();
        let written = tokio::task::spawn_blocking(move || -> anyhow::Result<()> {
            let tmp = target.with_extension("exr.tmp");
            tracer::output::write_exr_with(&image, info.as_ref(), &tmp)?;
            std::fs::File::open(&tmp).and_then(|f| f.sync_all()).with_context(|| format!("{}", tmp.display()))?;
            std::fs::rename(&tmp, &target).with_context(|| format!("replacing {}", target.display()))?;
            Ok(())
        })
        .await
        .map_err(anyhow::Error::from)
        .and_then(|r| r);
        if let Err(e) = written {
            tracing::warn!(job = %id, "the finished image was not stored; trying again in 5 s: {e:#}");
            retry.insert(id, now + Duration::from_secs(5));
            continue;
        }
        retry.remove(&id);
        if let Ok(e) = shared.farm().entry_mut(&id) {
            e.job.evict();
            e.stored = Some(path);
        }
        // The job's copy of its scene files (the blobs themselves stay in the store).
        let copy = shared.store().dir().join("jobs").join(&id);
        let _ = std::fs::remove_dir_all(copy);
        if let Some(root) = ckpt_root {
            // The image is all that is left to keep: a restart must not load it again.
            let _ = std::fs::remove_dir_all(root.join(&id));
            saved.remove(&id);
        }
        tracing::info!(job = %id, "finished image stored; its sums left memory");
    }
    if evicting {
        tracer::memory::return_free_memory();
    }
}

/// Stops listing stored jobs that finished longer than `retain` ago.
fn forget_finished(shared: &Arc<Shared>, retain: Duration) {
    let now = std::time::Instant::now();
    let gone = shared.farm().remove_jobs(|e| {
        e.stored.is_some() && e.job.finished.is_some_and(|t| now.saturating_duration_since(t) >= retain)
    });
    for id in gone {
        tracing::info!(job = %id, "finished job no longer listed; its image stays in the store");
    }
}

/// Restores the jobs checkpointed under `root`. A damaged checkpoint is reported and
/// left alone (never used); the farm serves the others.
fn restore_jobs(shared: &Arc<Shared>, root: &Path) -> anyhow::Result<()> {
    let Ok(entries) = std::fs::read_dir(root) else { return Ok(()) };
    let mut dirs: Vec<PathBuf> = entries.flatten().map(|e| e.path()).filter(|p| p.is_dir()).collect();
    dirs.sort();
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
        let scene = snap.spec.scene.as_ref().map(AssetRef::from).context("a checkpoint names no scene")?;
        let assets = snap.spec.assets.iter().map(AssetRef::from).collect();
        let mut settings = snap.spec.settings.clone().unwrap_or_default();
        settings.spp = 0;
        let (done, total) = (snap.units_done(), snap.job.units.len());
        let id = crate::service::submit_job(
            shared,
            snap.name.clone(),
            scene,
            assets,
            settings,
            Some((snap.spec.job_id.clone(), snap.job)),
        )
        .map_err(|s| anyhow::anyhow!("restoring {}: {}", dir.display(), s.message()))?;
        tracing::info!(job = %id, done, total, "job restored from its checkpoint");
    }
    Ok(())
}
