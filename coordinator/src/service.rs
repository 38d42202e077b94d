//! The tonic services: the thin edge between the wire and the farm's state. Every
//! message is checked here or in [`crate::job`]; a bad one gets a clear status and
//! leaves the state untouched.

use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use tokio::sync::mpsc;
use tokio_stream::Stream;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};
use tracer::integrator::Integrator;

use crate::assets::{AssetRef, AssetStore};
use crate::farm::{Farm, FarmError, status_of};
use crate::job::{Applied, Rejection, Restored, UnitResult};

/// Defaults for jobs that do not set their own tile size and batch.
#[derive(Clone, Copy, Debug)]
pub struct JobDefaults {
    pub tile: u32,
    pub batch_spp: u32,
}

impl Default for JobDefaults {
    fn default() -> Self {
        Self { tile: 64, batch_spp: 16 }
    }
}

/// State shared by both services and the commands that run them in-process.
pub struct Shared {
    pub farm: Mutex<Farm>,
    pub store: Mutex<AssetStore>,
    pub defaults: JobDefaults,
    /// Signalled when a unit's result has been applied or a job has failed, so that
    /// `render`, which follows its job, sees the end at once instead of at its next
    /// poll (it still polls every 100 ms for everything else, such as lapsed leases).
    pub changed: tokio::sync::Notify,
}

impl Shared {
    pub fn farm(&self) -> MutexGuard<'_, Farm> {
        self.farm.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn store(&self) -> MutexGuard<'_, AssetStore> {
        self.store.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// Upper bound on one uploaded file.
const MAX_ASSET_BYTES: usize = 4 << 30;

fn status_of_error(e: FarmError) -> Status {
    match e {
        FarmError::UnknownWorker(_) | FarmError::UnknownJob(_) => Status::not_found(e.to_string()),
        FarmError::Rejected(r @ (Rejection::UnknownUnit(_) | Rejection::Malformed { .. })) => {
            Status::invalid_argument(r.to_string())
        }
        FarmError::Rejected(r @ (Rejection::NotHolder(..) | Rejection::NotRunning(_))) => {
            Status::failed_precondition(r.to_string())
        }
    }
}

/// Creates a job from files already in the store and loads its scene in the background.
pub fn submit_job(
    shared: &Arc<Shared>,
    name: String,
    scene: AssetRef,
    assets: Vec<AssetRef>,
    settings: proto::RenderSettings,
    restore: Option<(String, Restored)>,
) -> Result<String, Status> {
    {
        let store = shared.store();
        for a in std::iter::once(&scene).chain(&assets) {
            crate::assets::safe_relative_path(&a.path).map_err(|e| Status::invalid_argument(e.to_string()))?;
            // A declared size that is not the stored blob's would make every worker's
            // download fail its check, and the job would never end: refuse it now.
            match store.size_of(&a.sha256) {
                None => {
                    return Err(Status::failed_precondition(format!(
                        "asset {} ({}) was not uploaded",
                        a.path, a.sha256
                    )));
                }
                Some(size) if size != a.size => {
                    return Err(Status::invalid_argument(format!(
                        "asset {} is declared as {} bytes, but its upload ({}) has {size}",
                        a.path, a.size, a.sha256
                    )));
                }
                Some(_) => {}
            }
        }
    }
    proto::wire::settings_from_proto(Some(&settings))
        .map_err(|e| Status::invalid_argument(format!("settings: {e}")))?;
    let (wanted_id, restore) = match restore {
        Some((id, r)) => (id, Some(r)),
        None => (String::new(), None),
    };
    let spec = proto::JobSpec {
        job_id: wanted_id,
        scene: Some((&scene).into()),
        assets: assets.iter().map(Into::into).collect(),
        settings: Some(settings.clone()),
    };
    let name = if name.trim().is_empty() { scene.path.clone() } else { name.chars().take(200).collect() };
    let id = shared.farm().add_job(name.clone(), spec);
    tracing::info!(job = %id, name = %name, scene = %scene.path, files = assets.len() + 1, "job submitted");
    let shared = Arc::clone(shared);
    let job = id.clone();
    std::thread::spawn(move || {
        let result = load_job(&shared, &job, &scene, &assets, &settings, restore);
        let mut farm = shared.farm();
        if let Ok(e) = farm.entry_mut(&job) {
            match result {
                Ok(()) => {}
                Err(err) => {
                    // A job event like "job started": the farm's log keeps it at info, and
                    // the job's owner gets the error itself, once, from the job's status.
                    tracing::info!(job = %job, "job failed: {err:#}");
                    e.job.fail(format!("{err:#}"));
                }
            }
        }
    });
    Ok(id)
}

fn load_job(
    shared: &Arc<Shared>,
    job: &str,
    scene: &AssetRef,
    assets: &[AssetRef],
    settings: &proto::RenderSettings,
    restore: Option<Restored>,
) -> anyhow::Result<()> {
    let scene_path = {
        let store = shared.store();
        let dir = store.dir().join("jobs").join(job);
        store.materialize(&dir, scene, assets)?
    };
    let (overrides, integrator) = proto::wire::settings_from_proto(Some(settings)).map_err(anyhow::Error::msg)?;
    // Named as the user named them (`quad.mtl`), not as the job folder's copies.
    let mut loaded = tracer::scene::load_scene_as(&scene_path, &scene.path, overrides.up)?;
    // The one report of the scene's problems: in the job's status, which whoever follows
    // the job prints (workers keep theirs quiet), and the farm's log.
    for w in &loaded.warnings {
        tracing::info!(job = %job, "scene warning: {w}");
    }
    let warnings = crate::job::bounded_warnings(&loaded.warnings);
    overrides.apply(&mut loaded).map_err(anyhow::Error::msg)?;
    let non_negative = matches!(integrator, Integrator::Path | Integrator::PathLightOnly | Integrator::PathBsdfOnly);
    let tile = if settings.tile_size > 0 { settings.tile_size } else { shared.defaults.tile };
    let batch = if settings.batch_spp > 0 { settings.batch_spp } else { shared.defaults.batch_spp };
    let (w, h, spp) = (loaded.camera.width, loaded.camera.height, loaded.settings.spp);
    let mut farm = shared.farm();
    let e = farm.entry_mut(job)?;
    if e.job.phase.is_final() {
        return Ok(()); // cancelled while loading
    }
    match restore {
        None => e.job.start(w, h, spp, tile, batch, non_negative),
        Some(r) => {
            anyhow::ensure!(
                (r.width, r.height) == (w, h),
                "the checkpoint is of a {}×{} image, the scene renders {w}×{h}",
                r.width,
                r.height
            );
            e.job.restore(r).map_err(|m| anyhow::anyhow!("the checkpoint is inconsistent: {m}"))?;
            if settings.spp > e.job.spp {
                e.job.extend_spp(settings.spp);
            }
        }
    }
    e.info = Some(tracer::output::RenderInfo::of(&loaded, &scene.path, integrator.name()));
    e.job.warnings = warnings;
    e.scene = Some(Arc::new(loaded));
    tracing::info!(job = %job, width = w, height = h, spp, tile, batch, units = e.job.units.len(), "job started");
    Ok(())
}

pub struct FarmService(pub Arc<Shared>);

type BoxStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send>>;

#[tonic::async_trait]
impl proto::farm_server::Farm for FarmService {
    async fn register(&self, req: Request<proto::RegisterRequest>) -> Result<Response<proto::RegisterReply>, Status> {
        let r = req.into_inner();
        if r.protocol_version != proto::PROTOCOL_VERSION {
            return Err(Status::failed_precondition(format!(
                "protocol version {} is not this coordinator's {}",
                r.protocol_version,
                proto::PROTOCOL_VERSION
            )));
        }
        let mut farm = self.0.farm();
        let id = farm.register(r.hostname.clone(), r.threads, Instant::now());
        tracing::info!(worker = id, host = %r.hostname, threads = r.threads, version = %r.version, "worker registered");
        Ok(Response::new(proto::RegisterReply {
            worker_id: id,
            lease_ms: farm.config.lease.as_millis() as u32,
            heartbeat_ms: farm.config.heartbeat.as_millis() as u32,
        }))
    }

    async fn lease(&self, req: Request<proto::LeaseRequest>) -> Result<Response<proto::LeaseReply>, Status> {
        let r = req.into_inner();
        let mut farm = self.0.farm();
        if farm.shutting_down {
            return Ok(Response::new(proto::LeaseReply { shutdown: true, ..Default::default() }));
        }
        let max = r.max_units.clamp(1, 256) as usize;
        let leased = farm.lease(r.worker_id, max, Instant::now()).map_err(status_of_error)?;
        let units: Vec<proto::Unit> =
            leased.into_iter().map(|l| proto::wire::unit_to_proto(l.spec, l.unit, l.tile, l.samples)).collect();
        let retry_after_ms = if units.is_empty() { 250 } else { 0 };
        Ok(Response::new(proto::LeaseReply { units, retry_after_ms, shutdown: false }))
    }

    async fn heartbeat(
        &self,
        req: Request<proto::HeartbeatRequest>,
    ) -> Result<Response<proto::HeartbeatReply>, Status> {
        let r = req.into_inner();
        let held: Vec<(String, u64)> = r.held.into_iter().map(|k| (k.job_id, k.unit_id)).collect();
        let mut farm = self.0.farm();
        let abandon = farm.heartbeat(r.worker_id, &held, Instant::now()).map_err(status_of_error)?;
        Ok(Response::new(proto::HeartbeatReply {
            abandon: abandon.into_iter().map(|(job_id, unit_id)| proto::UnitKey { job_id, unit_id }).collect(),
            shutdown: farm.shutting_down,
        }))
    }

    async fn submit_result(&self, req: Request<proto::UnitResult>) -> Result<Response<proto::SubmitReply>, Status> {
        let proto::wire::ReceivedResult { worker_id, key, tile, samples, sums, counts, nonfinite, rays } =
            proto::wire::result_from_proto(req.into_inner()).map_err(Status::invalid_argument)?;
        let result = UnitResult { unit: key.unit_id, tile, samples, sums, counts, nonfinite, rays };
        let applied = self.0.farm().submit(worker_id, &key.job_id, &result, Instant::now());
        self.0.changed.notify_one();
        match applied {
            Ok(a) => Ok(Response::new(proto::SubmitReply { accepted: a == Applied::Merged })),
            Err(e) => {
                tracing::warn!(worker = worker_id, unit = %key, "result rejected: {e}");
                Err(status_of_error(e))
            }
        }
    }

    type FetchAssetStream = BoxStream<proto::AssetChunk>;

    async fn fetch_asset(&self, req: Request<proto::AssetRequest>) -> Result<Response<Self::FetchAssetStream>, Status> {
        let sha = req.into_inner().sha256;
        let path = {
            let store = self.0.store();
            if sha.len() != 64 || !sha.bytes().all(|b| b.is_ascii_hexdigit()) || !store.contains(&sha) {
                return Err(Status::not_found(format!("no asset {sha}")));
            }
            store.blob_path(&sha)
        };
        let (tx, rx) = mpsc::channel(4);
        tokio::spawn(async move {
            use tokio::io::AsyncReadExt;
            let mut f = match tokio::fs::File::open(&path).await {
                Ok(f) => f,
                Err(e) => {
                    let _ = tx.send(Err(Status::internal(format!("reading asset: {e}")))).await;
                    return;
                }
            };
            let mut buf = vec![0u8; proto::ASSET_CHUNK_BYTES];
            loop {
                match f.read(&mut buf).await {
                    Ok(0) => break,
                    Ok(n) => {
                        if tx.send(Ok(proto::AssetChunk { data: buf[..n].to_vec() })).await.is_err() {
                            break;
                        }
                    }
                    Err(e) => {
                        let _ = tx.send(Err(Status::internal(format!("reading asset: {e}")))).await;
                        break;
                    }
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }
}

pub struct JobsService(pub Arc<Shared>);

#[tonic::async_trait]
impl proto::jobs_server::Jobs for JobsService {
    async fn upload_asset(
        &self,
        req: Request<Streaming<proto::AssetChunk>>,
    ) -> Result<Response<proto::AssetRef>, Status> {
        let mut stream = req.into_inner();
        let mut data = Vec::new();
        while let Some(chunk) = stream.message().await? {
            if data.len() + chunk.data.len() > MAX_ASSET_BYTES {
                return Err(Status::resource_exhausted("asset larger than 4 GiB"));
            }
            data.extend_from_slice(&chunk.data);
        }
        let shared = Arc::clone(&self.0);
        let (sha256, size) = tokio::task::spawn_blocking(move || shared.store().put(&data))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(|e| Status::internal(format!("storing asset: {e:#}")))?;
        Ok(Response::new(proto::AssetRef { path: String::new(), sha256, size }))
    }

    async fn submit_job(
        &self,
        req: Request<proto::SubmitJobRequest>,
    ) -> Result<Response<proto::SubmitJobReply>, Status> {
        let r = req.into_inner();
        let scene = r.scene.as_ref().map(AssetRef::from).ok_or_else(|| Status::invalid_argument("missing scene"))?;
        let assets = r.assets.iter().map(AssetRef::from).collect();
        let job_id = submit_job(&self.0, r.name, scene, assets, r.settings.unwrap_or_default(), None)?;
        Ok(Response::new(proto::SubmitJobReply { job_id }))
    }

    type WatchJobStream = BoxStream<proto::JobStatus>;

    async fn watch_job(&self, req: Request<proto::JobRequest>) -> Result<Response<Self::WatchJobStream>, Status> {
        let job = req.into_inner().job_id;
        self.0.farm().status(&job, Instant::now()).map_err(status_of_error)?;
        let (tx, rx) = mpsc::channel(4);
        let shared = Arc::clone(&self.0);
        tokio::spawn(async move {
            let mut last = None;
            loop {
                let status = shared.farm().status(&job, Instant::now());
                let Ok(status) = status else { break };
                let done = matches!(
                    status.state(),
                    proto::JobState::Done | proto::JobState::Failed | proto::JobState::Cancelled
                );
                let key = (status.state, status.units_done, status.workers);
                if last != Some(key) || done {
                    if tx.send(Ok(status)).await.is_err() {
                        break;
                    }
                    last = Some(key);
                }
                if done {
                    break;
                }
                tokio::time::sleep(std::time::Duration::from_millis(200)).await;
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    type FetchImageStream = BoxStream<proto::ImageChunk>;

    async fn fetch_image(&self, req: Request<proto::JobRequest>) -> Result<Response<Self::FetchImageStream>, Status> {
        let job = req.into_inner().job_id;
        // A finished job's image lives in the store (also once the job is forgotten).
        let known = self.0.farm().entry(&job).ok().map(|e| e.stored.clone());
        let stored = match known {
            Some(stored) => stored,
            None => self.0.store().stored_image(&job).filter(|p| p.is_file()),
        };
        if let Some(path) = stored {
            let bytes =
                tokio::fs::read(&path).await.map_err(|e| Status::internal(format!("reading the stored image: {e}")))?;
            let chunks: Vec<Result<proto::ImageChunk, Status>> =
                bytes.chunks(proto::ASSET_CHUNK_BYTES).map(|c| Ok(proto::ImageChunk { exr: c.to_vec() })).collect();
            return Ok(Response::new(Box::pin(tokio_stream::iter(chunks))));
        }
        let image = {
            let farm = self.0.farm();
            let e = farm.entry(&job).map_err(status_of_error)?;
            if e.job.width == 0 {
                return Err(Status::failed_precondition(format!("job {job} has no image (its scene did not load)")));
            }
            (e.job.image(), e.render_info())
        };
        let bytes = tokio::task::spawn_blocking(move || tracer::output::exr_bytes(&image.0, image.1.as_ref()))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(Status::internal)?;
        let chunks: Vec<Result<proto::ImageChunk, Status>> =
            bytes.chunks(proto::ASSET_CHUNK_BYTES).map(|c| Ok(proto::ImageChunk { exr: c.to_vec() })).collect();
        Ok(Response::new(Box::pin(tokio_stream::iter(chunks))))
    }

    async fn cancel_job(&self, req: Request<proto::JobRequest>) -> Result<Response<proto::JobStatus>, Status> {
        let job = req.into_inner().job_id;
        let mut farm = self.0.farm();
        farm.cancel(&job).map_err(status_of_error)?;
        Ok(Response::new(farm.status(&job, Instant::now()).map_err(status_of_error)?))
    }

    async fn list_jobs(&self, _: Request<proto::ListRequest>) -> Result<Response<proto::ListJobsReply>, Status> {
        let farm = self.0.farm();
        let workers = farm.live_workers(Instant::now());
        let jobs = farm.jobs.iter().map(|e| status_of(&e.job, workers)).collect();
        Ok(Response::new(proto::ListJobsReply { jobs }))
    }

    async fn list_workers(&self, _: Request<proto::ListRequest>) -> Result<Response<proto::ListWorkersReply>, Status> {
        let farm = self.0.farm();
        let now = Instant::now();
        let workers = farm
            .workers
            .values()
            .map(|w| proto::WorkerInfo {
                worker_id: w.id,
                hostname: w.hostname.clone(),
                threads: w.threads,
                units_held: farm.jobs.iter().map(|e| e.job.held_by(w.id) as u32).sum(),
                units_done: w.units_done,
                last_seen_s: now.duration_since(w.last_seen).as_secs_f64(),
            })
            .collect();
        Ok(Response::new(proto::ListWorkersReply { workers }))
    }
}
