//! A job's life, in one place: submitted (its files checked against the store), loaded
//! in the background, started or restored from a checkpoint (and extended to more
//! samples), then cancelled, failed or finished; a finished job's image is stored and
//! its sums evicted, and after a retention period it is forgotten. The edge and the
//! commands call these; nothing else changes a job's phase.

use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use anyhow::Context;
use proto::domain::JobSpec;
use tracer::integrator::Integrator;
use tracer::scene::prepared::PreparedScenes;

use super::assets::AssetStore;
use super::job::{Applied, IdentityId, JobPhase, Restored, UnitId, UnitResult, WorkerId};
use super::state::{Farm, FarmError};
use super::status::JobStatus;
use super::stored::{write_frame, write_owner};

/// A finished job stays listed at least this long, so that those following it see it
/// end (the status stream polls every 200 ms).
const LISTED_AT_LEAST: Duration = Duration::from_secs(2);

/// Defaults for jobs that do not set their own tile size and batch.
#[derive(Clone, Copy, Debug)]
pub struct JobDefaults {
    pub tile: u32,
    pub batch_spp: u32,
    /// A scene may refer only to its job's uploaded files (a farm's rule); `render`, which
    /// reads the user's own scene where it lies, turns it off.
    pub confine_scenes: bool,
    /// Keep each job's loaded scene (its geometry and tree) after the checks: only when
    /// the coordinator renders in process (`render --local-workers 0`). A farm's workers
    /// load their own, and the coordinator's copy would be memory for nothing.
    pub keep_scenes: bool,
}

impl Default for JobDefaults {
    fn default() -> Self {
        Self { tile: 64, batch_spp: 16, confine_scenes: true, keep_scenes: false }
    }
}

/// The farm's state as the services and the commands share it.
pub struct Shared {
    pub farm: Mutex<Farm>,
    pub store: Mutex<AssetStore>,
    pub defaults: JobDefaults,
    /// Where loaded scenes are kept prepared: a job's scene loads from there when it was
    /// loaded before, and `render`'s local workers (the same executable, the same folder)
    /// read what this process built instead of building it again.
    pub prepared: Option<PreparedScenes>,
    /// Signalled when a unit's result has been applied or a job has failed, so that
    /// `render`, which follows its job, sees the end at once instead of at its next
    /// poll (it still polls every 100 ms for everything else, such as lapsed leases).
    pub changed: tokio::sync::Notify,
    /// Merge latency and bytes moved, for the metrics.
    pub meters: super::meters::Meters,
    /// The coordinator is rendering checked units itself ([`Shared::arbitrate`]).
    pub(super) arbitrating: std::sync::atomic::AtomicBool,
}

impl Shared {
    pub fn new(farm: Farm, store: AssetStore) -> Self {
        Self {
            farm: Mutex::new(farm),
            store: Mutex::new(store),
            defaults: JobDefaults::default(),
            prepared: None,
            changed: tokio::sync::Notify::new(),
            meters: super::meters::Meters::default(),
            arbitrating: Default::default(),
        }
    }

    pub fn farm(&self) -> MutexGuard<'_, Farm> {
        self.farm.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn store(&self) -> MutexGuard<'_, AssetStore> {
        self.store.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Merges a unit's result; a result that finishes its job ends the job's render
    /// (its scene leaves memory, the farm's log records it).
    pub fn submit_result(self: &Arc<Self>, worker: WorkerId, job: &str, r: &UnitResult) -> Result<Applied, FarmError> {
        let mut out = self.submit_results(worker, std::iter::once((job, r)))?;
        out.pop().expect("one outcome per result")
    }

    /// Merges a worker's results under one lock; one outcome per result, in order. An
    /// unknown worker fails the whole call (it must register again).
    pub fn submit_results<'a>(
        self: &Arc<Self>,
        worker: WorkerId,
        results: impl IntoIterator<Item = (&'a str, &'a UnitResult)>,
    ) -> Result<Vec<Result<Applied, FarmError>>, FarmError> {
        let mut outcomes = Vec::new();
        let arrived = Instant::now();
        let mut ended = false;
        {
            let mut farm = self.farm();
            let now = Instant::now();
            for (job, r) in results {
                self.meters.bytes_in.inc_by(result_bytes(r));
                let outcome = farm.submit(worker, job, r, now);
                if matches!(outcome, Ok((Applied::Merged, _))) {
                    self.meters.merge_seconds.observe(arrived.elapsed().as_secs_f64());
                }
                let outcome = match outcome {
                    Err(e @ FarmError::UnknownWorker(_)) => return Err(e),
                    Err(e) => Err(e),
                    Ok((applied, finished)) => {
                        if finished && let Ok(e) = farm.entry_mut(job) {
                            finish(e);
                            ended = true;
                        }
                        Ok(applied)
                    }
                };
                outcomes.push(outcome);
            }
        }
        self.changed.notify_one();
        if ended {
            start_due_frames(self);
        }
        Ok(outcomes)
    }

    pub fn cancel(self: &Arc<Self>, job: &str) -> Result<JobStatus, FarmError> {
        let status = {
            let mut farm = self.farm();
            let e = farm.entry_mut(job)?;
            e.job.cancel();
            e.scene = None;
            e.pending_restore = None;
            tracing::info!(job = %job, "job cancelled");
            farm.status(job, Instant::now())
        };
        start_due_frames(self);
        status
    }

    /// Ends a job with `error` (a job event: the farm's log keeps it at info, and the
    /// job's owner gets the error itself, once, from the job's status). The owner sees
    /// the job's files by their own names, never where the farm keeps them.
    pub fn fail(self: &Arc<Self>, job: &str, error: String) {
        let store = self.store().dir().to_path_buf();
        let error = error
            .replace(&format!("{}/", store.join("jobs").join(job).display()), "")
            .replace(&store.display().to_string(), "<the farm's store>");
        if let Ok(e) = self.farm().entry_mut(job) {
            tracing::info!(job = %job, "job failed: {error}");
            e.job.fail(error);
            e.scene = None;
        }
        self.changed.notify_one();
        start_due_frames(self);
    }

    /// Stores the image of every finished job not stored yet as `<images>/<job>.exr`
    /// and evicts its sums and its copy of the scene files; returns the ids stored. A
    /// job whose image cannot be written keeps its sums and is tried again 5 s later
    /// (`retry` holds when; the error is logged). Blocking: run it off the async threads.
    pub fn store_finished(&self, images: &Path, retry: &mut std::collections::HashMap<String, Instant>) -> Vec<String> {
        let now = Instant::now();
        let done: Vec<_> = {
            let farm = self.farm();
            farm.jobs
                .iter()
                .filter(|e| e.job.phase == JobPhase::Done && !e.job.is_evicted())
                .filter(|e| retry.get(&e.job.id).is_none_or(|&at| now >= at))
                .map(|e| {
                    (
                        e.job.id.clone(),
                        e.job.image_tiles(),
                        e.render_info(),
                        e.job.owner.clone(),
                        e.job.group.clone(),
                        e.job.name.clone(),
                    )
                })
                .collect()
        };
        let mut stored = Vec::new();
        for (id, image, info, owner, group, name) in done {
            let path = images.join(format!("{id}.exr"));
            // The sidecars first: an image is never stored without them.
            let written = write_owner(images, &id, owner.as_deref())
                .and_then(|()| write_frame(images, &id, group.as_deref(), &name))
                .and_then(|()| write_durably(&image, info.as_ref(), &path));
            if let Err(e) = written {
                tracing::warn!(job = %id, "the finished image was not stored; trying again in 5 s: {e:#}");
                retry.insert(id, now + Duration::from_secs(5));
                continue;
            }
            retry.remove(&id);
            if let Ok(e) = self.farm().entry_mut(&id) {
                e.job.evict();
                e.stored = Some(path);
            }
            // The job's copy of its scene files (the blobs themselves stay in the store).
            let copy = self.store().dir().join("jobs").join(&id);
            let _ = std::fs::remove_dir_all(copy);
            tracing::info!(job = %id, "finished image stored; its sums left memory");
            stored.push(id);
        }
        if !stored.is_empty() {
            tracer::memory::return_free_memory();
        }
        stored
    }

    /// Stops listing stored jobs that finished more than `retain` ago (their images stay
    /// in the store, where `fetch` still finds them).
    pub fn forget_finished(&self, retain: Duration) {
        let now = Instant::now();
        // Whoever follows a job polls its status a few times a second: it stays listed
        // long enough for them to see its end, whatever `retain` says.
        let retain = retain.max(LISTED_AT_LEAST);
        let gone = self.farm().remove_jobs(|e| {
            e.stored.is_some() && e.job.finished.is_some_and(|t| now.saturating_duration_since(t) >= retain)
        });
        for id in gone {
            tracing::info!(job = %id, "finished job no longer listed; its image stays in the store");
        }
    }
}

/// A job's last unit is merged: its render is over.
pub(super) fn finish(e: &mut super::state::JobEntry) {
    let j = &e.job;
    tracing::info!(
        job = %j.id,
        scene = %j.name,
        width = j.width,
        height = j.height,
        spp = j.spp,
        units = j.units_total(),
        samples = j.samples_done,
        rays = j.rays,
        nonfinite = j.nonfinite,
        seconds = j.elapsed().as_secs_f64(),
        "job finished"
    );
    e.scene = None;
}

/// Writes an EXR so that a crash leaves the old file or the whole new one.
fn write_durably(
    image: &super::job::ImageTiles,
    info: Option<&tracer::output::RenderInfo>,
    target: &Path,
) -> anyhow::Result<()> {
    let tmp = target.with_extension("exr.tmp");
    tracer::output::write_exr_with(&image.mosaic(), info, &tmp)?;
    std::fs::File::open(&tmp).and_then(|f| f.sync_all()).with_context(|| format!("{}", tmp.display()))?;
    std::fs::rename(&tmp, target).with_context(|| format!("replacing {}", target.display()))?;
    Ok(())
}

/// Why a job's image cannot be given.
pub enum ImageError {
    /// No such job, listed or stored.
    Unknown(FarmError),
    /// The job has no image (its scene did not load).
    None(String),
    /// Reading the stored file or encoding failed.
    Failed(String),
}

impl Shared {
    /// A job's image as an EXR file's bytes: the stored file once finished (also after
    /// the job is forgotten), else encoded from its tiles now; counted as bytes out.
    /// Blocking: run it off the async threads.
    pub fn image_exr(&self, job: &str) -> Result<Vec<u8>, ImageError> {
        let known = self.farm().entry(job).ok().map(|e| e.stored.clone());
        let stored = match known {
            Some(stored) => stored,
            None => self.store().stored_image(job).filter(|p| p.is_file()),
        };
        let bytes = match stored {
            Some(path) => {
                std::fs::read(&path).map_err(|e| ImageError::Failed(format!("reading the stored image: {e}")))?
            }
            None => {
                let (tiles, info) = {
                    let farm = self.farm();
                    let e = farm.entry(job).map_err(ImageError::Unknown)?;
                    if e.job.width == 0 {
                        return Err(ImageError::None(format!("job {job} has no image (its scene did not load)")));
                    }
                    (e.job.image_tiles(), e.render_info())
                };
                tracer::output::exr_bytes(&tiles.mosaic(), info.as_ref()).map_err(ImageError::Failed)?
            }
        };
        self.meters.bytes_out.inc_by(bytes.len() as u64);
        Ok(bytes)
    }
}

/// What a unit result carries on the wire, about: its sums (3 × 16 bytes a pixel),
/// counts (4 bytes a pixel) and any AOV layers.
fn result_bytes(r: &UnitResult) -> u64 {
    (r.sums.len() * size_of::<[i128; 3]>()
        + r.counts.len() * size_of::<u32>()
        + r.layers.len() * tracer::film::LAYER_BYTES) as u64
}

/// Creates a job from files already in the store and loads its scene in the
/// background. With `restore`, the job continues a checkpoint, keeping its id
/// (`spec.job_id`) when that is free.
pub fn submit_job(
    shared: &Arc<Shared>,
    name: String,
    owner: Option<String>,
    spec: JobSpec,
    mut restore: Option<Restored>,
) -> Result<String, FarmError> {
    {
        let store = shared.store();
        for a in std::iter::once(&spec.scene).chain(&spec.assets) {
            super::assets::safe_relative_path(&a.path).map_err(|e| FarmError::Invalid(e.to_string()))?;
            // A declared size that is not the stored blob's would make every worker's
            // download fail its check, and the job would never end: refuse it now.
            match store.size_of(&a.sha256) {
                None => {
                    return Err(FarmError::NotUploaded(format!("asset {} ({}) was not uploaded", a.path, a.sha256)));
                }
                Some(size) if size != a.size => {
                    return Err(FarmError::Invalid(format!(
                        "asset {} is declared as {} bytes, but its upload ({}) has {size}",
                        a.path, a.size, a.sha256
                    )));
                }
                Some(_) => {}
            }
        }
    }
    let name = if name.trim().is_empty() { spec.scene.path.clone() } else { name.chars().take(200).collect() };
    let (scene, files) = (spec.scene.path.clone(), spec.assets.len() + 1);
    let who = owner.clone().unwrap_or_else(|| "admin".into());
    let queued = {
        let mut farm = shared.farm();
        farm.may_submit(owner.as_deref())?;
        let id = farm.add_job(name.clone(), owner, spec);
        let e = farm.entry_mut(&id)?;
        let queued = e.job.phase == JobPhase::Queued;
        if queued {
            e.pending_restore = restore.take();
        }
        (id, queued)
    };
    let (id, queued) = queued;
    tracing::info!(job = %id, name = %name, scene = %scene, files, owner = %who, "job submitted");
    if queued {
        start_due_frames(shared);
    } else {
        spawn_load(shared, id.clone(), restore);
    }
    Ok(id)
}

/// Loads a job's scene in the background and starts the job (or restores it).
fn spawn_load(shared: &Arc<Shared>, job: String, restore: Option<Restored>) {
    let shared = Arc::clone(shared);
    std::thread::spawn(move || {
        if let Err(err) = load_job(&shared, &job, restore) {
            shared.fail(&job, format!("{err:#}"));
        }
    });
}

/// Starts loading the queued frames of job groups that may start now
/// ([`Farm::due_frames`]). Called whenever a job ends or a frame is submitted.
///
/// [`Farm::due_frames`]: super::state::Farm::due_frames
pub fn start_due_frames(shared: &Arc<Shared>) {
    let due: Vec<(String, Option<Restored>)> = {
        let mut farm = shared.farm();
        let ids = farm.due_frames();
        ids.into_iter()
            .map(|id| {
                let restore = farm.entry_mut(&id).ok().and_then(|e| e.pending_restore.take());
                (id, restore)
            })
            .collect()
    };
    for (job, restore) in due {
        tracing::info!(job = %job, "frame starts: earlier frames of its group are done or rendering");
        spawn_load(shared, job, restore);
    }
}

/// Where a job's scene file lies in the store's folder for the job. `fresh` lays the
/// folder out anew from the store (a job's first load); otherwise the folder its first
/// load made is read as it is, so that loads running at once never see it half made.
fn scene_path_of(shared: &Shared, job: &str, spec: &JobSpec, fresh: bool) -> anyhow::Result<std::path::PathBuf> {
    let store = shared.store();
    let dir = store.dir().join("jobs").join(job);
    let laid_out = dir.join(super::assets::safe_relative_path(&spec.scene.path)?);
    let scene_path =
        if fresh || !laid_out.is_file() { store.materialize(&dir, &spec.scene, &spec.assets)? } else { laid_out };
    if shared.defaults.confine_scenes {
        tracer::scene::assets::check_within(&scene_path, &dir)?;
    }
    Ok(scene_path)
}

/// Loads a job's scene from its files (in the store's folder for the job), with the
/// job's overrides applied; `fresh` as for [`scene_path_of`].
pub fn load_scene_of(shared: &Shared, job: &str, fresh: bool) -> anyhow::Result<tracer::scene::Scene> {
    let spec = Arc::clone(&shared.farm().entry(job)?.spec);
    let scene_path = scene_path_of(shared, job, &spec, fresh)?;
    // Named as the user named them (`quad.mtl`), not as the job folder's copies.
    let (key, what) = (spec.scene_key(shared.defaults.confine_scenes), format!("job {job}"));
    if let Some(scene) = shared.prepared.as_ref().and_then(|p| p.get(&key, &what)) {
        return Ok(scene);
    }
    let mut loaded = tracer::scene::load_scene_as(&scene_path, &spec.scene.path, spec.overrides.up)?;
    spec.overrides.apply(&mut loaded).map_err(anyhow::Error::msg)?;
    if let Some(p) = &shared.prepared {
        // Before the job starts, so that workers sharing the folder find it.
        p.put(&key, &loaded, &what);
    }
    Ok(loaded)
}

/// What starting a job needs of its scene: the whole scene when the coordinator renders
/// it in process, else only a check (its errors and warnings, camera and settings; the
/// files are read in blocks and no geometry is kept), while the workers load it.
enum Prepared {
    Loaded(Box<tracer::scene::Scene>),
    Checked(tracer::scene::SceneCheck),
}

impl Prepared {
    fn of(shared: &Shared, job: &str) -> anyhow::Result<Self> {
        if shared.defaults.keep_scenes {
            return Ok(Self::Loaded(Box::new(load_scene_of(shared, job, true)?)));
        }
        let spec = Arc::clone(&shared.farm().entry(job)?.spec);
        let scene_path = scene_path_of(shared, job, &spec, true)?;
        let mut checked = tracer::scene::check_scene_as(&scene_path, &spec.scene.path, spec.overrides.up)?;
        checked.apply(&spec.overrides).map_err(anyhow::Error::msg)?;
        Ok(Self::Checked(checked))
    }

    fn view(&self) -> (&tracer::camera::Camera, &tracer::scene::RenderSettings, &[String]) {
        match self {
            Self::Loaded(s) => (&s.camera, &s.settings, &s.warnings),
            Self::Checked(c) => (&c.camera, &c.settings, &c.warnings),
        }
    }
}

/// Loads a job's scene from its files and starts the job (or restores its checkpoint).
fn load_job(shared: &Arc<Shared>, job: &str, mut restore: Option<Restored>) -> anyhow::Result<()> {
    let spec = Arc::clone(&shared.farm().entry(job)?.spec);
    let prepared = Prepared::of(shared, job)?;
    let (camera, settings, scene_warnings) = prepared.view();
    // The one report of the scene's problems: in the job's status, which whoever follows
    // the job prints (workers keep theirs quiet), and the farm's log.
    for w in scene_warnings {
        tracing::info!(job = %job, "scene warning: {w}");
    }
    let warnings = super::job::bounded_warnings(scene_warnings);
    let non_negative =
        matches!(spec.integrator, Integrator::Path | Integrator::PathLightOnly | Integrator::PathBsdfOnly);
    let tile = spec.tile_size.unwrap_or(shared.defaults.tile);
    let batch = spec.batch_spp.unwrap_or(shared.defaults.batch_spp);
    let (w, h, mut spp) = (camera.width, camera.height, settings.spp);
    if let Some(map) = &spec.spp_map {
        anyhow::ensure!(
            (map.width, map.height, map.tile_size) == (w, h, tile),
            "the spp map is of a {}×{} image in tiles of {}; the job renders {w}×{h} in tiles of {tile}",
            map.width,
            map.height,
            map.tile_size
        );
        spp = map.most().max(1);
    }
    let max_bytes = shared.farm().config.max_job_bytes;
    let bytes = super::job::Job::check_size((w, h), spp, (tile, batch), settings.aovs, max_bytes)
        .map_err(anyhow::Error::msg)?;
    let mut farm = shared.farm();
    if farm.entry(job)?.job.phase.is_final() {
        return Ok(()); // cancelled while loading
    }
    farm.reserve(job, bytes).map_err(anyhow::Error::msg)?;
    // Who returned the restored units that no other identity confirmed (and whether
    // that identity has been banned since).
    let unconfirmed: Vec<(IdentityId, bool, Vec<UnitId>)> = restore
        .as_mut()
        .map(|r| std::mem::take(&mut r.unconfirmed))
        .unwrap_or_default()
        .into_iter()
        .map(|(name, units)| {
            let i = farm.identities.named(&name, Instant::now());
            (i.id, i.banned.is_some(), units)
        })
        .collect();
    let e = farm.entry_mut(job)?;
    match restore {
        None => {
            (e.job.layers, e.job.adaptive, e.job.budget) = (settings.aovs, settings.noise, spec.overrides.time_budget);
            e.job.tile_spp = spec.spp_map.as_ref().map(|m| m.tile_spp.clone()).unwrap_or_default();
            e.job.start(w, h, spp, tile, batch, non_negative);
        }
        Some(r) => {
            anyhow::ensure!(
                (r.width, r.height) == (w, h),
                "the checkpoint is of a {}×{} image, the scene renders {w}×{h}",
                r.width,
                r.height
            );
            (e.job.adaptive, e.job.budget) = (settings.noise, spec.overrides.time_budget);
            e.job.tile_spp = spec.spp_map.as_ref().map(|m| m.tile_spp.clone()).unwrap_or_default();
            e.job.restore(r).map_err(|m| anyhow::anyhow!("the checkpoint is inconsistent: {m}"))?;
            for (identity, banned, units) in &unconfirmed {
                e.job.mark_unconfirmed(*identity, units);
                if *banned {
                    e.job.discard_from(*identity, &[]);
                }
            }
            if let Some(more) = spec.overrides.spp
                && more > e.job.spp
            {
                e.job.extend_spp(more);
            }
        }
    }
    e.info = Some(tracer::output::RenderInfo::of_view(camera, settings, &spec.scene.path, spec.integrator.name()));
    e.scene_warnings = scene_warnings.len();
    e.job.warnings = warnings;
    let units = e.job.units.len();
    let checked = match prepared {
        Prepared::Loaded(scene) => {
            e.scene = Some(Arc::from(scene));
            None
        }
        Prepared::Checked(c) => Some(c),
    };
    drop(farm);
    // What the check read (materials' textures, the positions) is given back.
    if checked.is_some() {
        drop(checked);
        tracer::memory::return_free_memory();
    }
    tracing::info!(job = %job, width = w, height = h, spp, tile, batch, units, "job started");
    Ok(())
}
