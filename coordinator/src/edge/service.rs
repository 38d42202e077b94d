//! The tonic services: the thin edge between the wire and the farm's state — decode
//! and check each message (`proto::wire`, [`super::wire`]), call the farm, encode the
//! answer. A bad message gets a clear status and leaves the state untouched.

use std::pin::Pin;
use std::sync::Arc;
use std::time::Instant;

use tokio::sync::mpsc;
use tokio_stream::Stream;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

use proto::auth::{Caller, Role};

use super::wire::{
    error_to_status, identities_to_proto, invalid, status_to_proto, stored_frame_to_proto, stored_job_to_proto,
};
use crate::farm::Shared;
use crate::farm::job::UnitResult;
use crate::farm::lifecycle::ImageError;

/// Longest hostname or version a worker may register with.
const MAX_NAME_BYTES: usize = 255;
/// Most units one heartbeat may renew (a worker leases twice its threads).
const MAX_HELD_PER_HEARTBEAT: usize = 65_536;
/// Loading jobs named in one lease reply with no units: an idle worker loads their
/// scenes while the coordinator checks them.
const PREPARE_EARLY: usize = 4;

/// The worker service, and whether its callers have identities (a farm with tokens or
/// certificates); on an open farm each registration is trusted as its own identity.
pub struct FarmService(pub Arc<Shared>, pub Registrations);

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Registrations {
    /// Every worker registers as the identity it proved (certificate or token).
    ByIdentity,
    /// No access control: nothing tells callers apart.
    EachItsOwn,
}

type BoxStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send>>;

#[tonic::async_trait]
impl proto::farm_server::Farm for FarmService {
    async fn register(&self, req: Request<proto::RegisterRequest>) -> Result<Response<proto::RegisterReply>, Status> {
        let caller = proto::auth::caller(&req);
        let r = req.into_inner();
        if r.protocol_version != proto::PROTOCOL_VERSION {
            return Err(Status::failed_precondition(format!(
                "protocol version {} is not this coordinator's {}",
                r.protocol_version,
                proto::PROTOCOL_VERSION
            )));
        }
        if r.hostname.len() > MAX_NAME_BYTES || r.version.len() > MAX_NAME_BYTES {
            return Err(Status::invalid_argument(format!(
                "hostname and version: at most {MAX_NAME_BYTES} bytes each (got {} and {})",
                r.hostname.len(),
                r.version.len()
            )));
        }
        let mut farm = self.0.farm();
        let identity = (self.1 == Registrations::ByIdentity).then_some(caller.name.as_str());
        let capped = caller.role != Role::Admin;
        let id = farm
            .register_as(identity, capped, r.hostname.clone(), r.threads, Instant::now())
            .map_err(error_to_status)?;
        tracing::info!(worker = id, host = %r.hostname.escape_debug(), threads = r.threads, version = %r.version.escape_debug(), identity = %caller.name, "worker registered");
        Ok(Response::new(proto::RegisterReply {
            worker_id: id,
            lease_ms: farm.config.lease.as_millis() as u32,
            heartbeat_ms: farm.config.heartbeat.as_millis() as u32,
        }))
    }

    async fn lease(&self, req: Request<proto::LeaseRequest>) -> Result<Response<proto::LeaseReply>, Status> {
        let caller = proto::auth::caller(&req);
        let r = req.into_inner();
        let mut farm = self.0.farm();
        farm.check_identity(r.worker_id, &caller.name).map_err(error_to_status)?;
        if farm.shutting_down {
            return Ok(Response::new(proto::LeaseReply { shutdown: true, ..Default::default() }));
        }
        let max = r.max_units.clamp(1, 256) as usize;
        let leased = farm.lease(r.worker_id, max, Instant::now()).map_err(error_to_status)?;
        let units: Vec<proto::Unit> =
            leased.iter().map(|l| proto::wire::unit_to_proto(&l.spec, l.unit, l.tile, l.samples)).collect();
        let retry_after_ms = if units.is_empty() { 250 } else { 0 };
        let early = if units.is_empty() { farm.loading(PREPARE_EARLY) } else { vec![] };
        let prepare = early.iter().map(|s| proto::wire::job_to_proto(s)).collect();
        Ok(Response::new(proto::LeaseReply { units, retry_after_ms, shutdown: false, prepare }))
    }

    async fn heartbeat(
        &self,
        req: Request<proto::HeartbeatRequest>,
    ) -> Result<Response<proto::HeartbeatReply>, Status> {
        let caller = proto::auth::caller(&req);
        let r = req.into_inner();
        if r.held.len() > MAX_HELD_PER_HEARTBEAT {
            return Err(Status::invalid_argument(format!(
                "held: {} units; a worker holds at most {MAX_HELD_PER_HEARTBEAT}",
                r.held.len()
            )));
        }
        let held: Vec<(String, u64)> = r.held.into_iter().map(|k| (k.job_id, k.unit_id)).collect();
        let mut farm = self.0.farm();
        farm.check_identity(r.worker_id, &caller.name).map_err(error_to_status)?;
        let abandon = farm.heartbeat(r.worker_id, &held, Instant::now()).map_err(error_to_status)?;
        Ok(Response::new(proto::HeartbeatReply {
            abandon: abandon.into_iter().map(|(job_id, unit_id)| proto::UnitKey { job_id, unit_id }).collect(),
            shutdown: farm.shutting_down,
        }))
    }

    async fn submit_result(&self, req: Request<proto::UnitResult>) -> Result<Response<proto::SubmitReply>, Status> {
        let caller = proto::auth::caller(&req);
        let proto::wire::ReceivedResult { worker_id, job_id, result } =
            proto::wire::result_from_proto(req.into_inner()).map_err(invalid)?;
        self.0.farm().check_identity(worker_id, &caller.name).map_err(error_to_status)?;
        let key = format!("{job_id}/{}", result.unit);
        match self.0.submit_result(worker_id, &job_id, &result) {
            Ok(a) => Ok(Response::new(proto::SubmitReply { accepted: a.accepted() })),
            Err(e) => {
                tracing::warn!(worker = worker_id, unit = %key, "result rejected: {e}");
                Err(error_to_status(e))
            }
        }
    }

    async fn submit_results(
        &self,
        req: Request<proto::SubmitResultsRequest>,
    ) -> Result<Response<proto::SubmitResultsReply>, Status> {
        let caller = proto::auth::caller(&req);
        let r = req.into_inner();
        self.0.farm().check_identity(r.worker_id, &caller.name).map_err(error_to_status)?;
        if r.results.len() > proto::MAX_RESULTS_PER_CALL {
            return Err(Status::invalid_argument(format!(
                "{} results in one call; at most {} are taken",
                r.results.len(),
                proto::MAX_RESULTS_PER_CALL
            )));
        }
        // Each result is checked on its own: a malformed one is refused, the others go on.
        let decoded: Vec<Result<(String, UnitResult), String>> = r
            .results
            .into_iter()
            .map(|m| {
                let received = proto::wire::result_from_proto(m)?;
                Ok((received.job_id, received.result))
            })
            .collect();
        let good = decoded.iter().filter_map(|d| d.as_ref().ok()).map(|(job, r)| (job.as_str(), r));
        let mut merged = self.0.submit_results(r.worker_id, good).map_err(error_to_status)?.into_iter();
        let outcomes = decoded
            .iter()
            .map(|d| {
                let outcome = match d {
                    Err(why) => Err(why.clone()),
                    Ok((job, r)) => match merged.next().expect("one outcome per merged result") {
                        Ok(applied) => Ok(applied.accepted()),
                        Err(e) => {
                            tracing::warn!(unit = %format!("{job}/{}", r.unit), "result rejected: {e}");
                            Err(e.to_string())
                        }
                    },
                };
                proto::wire::outcome_to_proto(outcome)
            })
            .collect();
        Ok(Response::new(proto::SubmitResultsReply { outcomes }))
    }

    type FetchAssetStream = BoxStream<proto::AssetChunk>;

    async fn fetch_asset(&self, req: Request<proto::AssetRequest>) -> Result<Response<Self::FetchAssetStream>, Status> {
        let sha = req.into_inner().sha256;
        let path = {
            let store = self.0.store();
            if sha.len() != 64 || !sha.bytes().all(|b| b.is_ascii_hexdigit()) || !store.contains(&sha) {
                return Err(Status::not_found(format!("no asset {}", proto::wire::quote(&sha))));
            }
            store.blob_path(&sha)
        };
        let (tx, rx) = mpsc::channel(4);
        let shared = Arc::clone(&self.0);
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
                        shared.meters.bytes_out.inc_by(n as u64);
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

impl JobsService {
    /// May `caller` watch, fetch or cancel `job`? Users only their own; a job not
    /// listed any more is judged by its stored image's owner, read off the async
    /// threads (a file on the store's disk).
    async fn may_touch(&self, caller: &Caller, job: &str) -> Result<(), Status> {
        if caller.role == Role::Admin {
            return Ok(());
        }
        let owner = match self.listed_owner(job) {
            Some(owner) => owner,
            None => {
                let image = self.0.store().stored_image(job);
                blocking(move || image.and_then(|p| crate::farm::stored::stored_owner(&p))).await?
            }
        };
        Self::judge(caller, job, owner.as_deref())
    }

    /// The owner of `job` if the farm still lists it (`Some(None)`: listed, no owner).
    fn listed_owner(&self, job: &str) -> Option<Option<String>> {
        self.0.farm().entry(job).ok().map(|e| e.job.owner.clone())
    }

    /// `caller`'s access to `job`, owned by `owner`.
    fn judge(caller: &Caller, job: &str, owner: Option<&str>) -> Result<(), Status> {
        if caller.role == Role::Admin || caller.may_touch(owner) {
            Ok(())
        } else {
            Err(Status::permission_denied(format!("{job} is not one of your jobs")))
        }
    }
}

/// `f` on tokio's blocking threads: file reads and stats stay off the async ones.
async fn blocking<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> Result<T, Status> {
    tokio::task::spawn_blocking(f).await.map_err(|e| Status::internal(e.to_string()))
}

#[tonic::async_trait]
impl proto::jobs_server::Jobs for JobsService {
    async fn upload_asset(
        &self,
        req: Request<Streaming<proto::AssetChunk>>,
    ) -> Result<Response<proto::AssetRef>, Status> {
        let mut stream = req.into_inner();
        let (max_file, max_store) = {
            let farm = self.0.farm();
            (farm.config.max_upload_bytes, farm.config.max_store_bytes)
        };
        let room = max_store.saturating_sub(self.0.store().stored_bytes());
        // The client learns that the farm failed, not where the farm keeps its files:
        // the farm's log has the whole error.
        let internal = |e: anyhow::Error| {
            tracing::error!("storing an upload: {e:#}");
            Status::internal("the farm could not store the upload (its log says why)")
        };
        let mut up = self.0.store().begin_upload().map_err(internal)?;
        while let Some(chunk) = stream.message().await? {
            let total = up.written() + chunk.data.len() as u64;
            if total > max_file {
                return Err(Status::resource_exhausted(format!(
                    "the file is larger than this farm's limit of {} MiB per file (--max-upload-mb)",
                    max_file >> 20
                )));
            }
            if total > room {
                return Err(Status::resource_exhausted(format!(
                    "this farm's store is full: {} MiB of {} MiB used (--max-store-mb)",
                    (max_store - room) >> 20,
                    max_store >> 20
                )));
            }
            // Chunks are at most 1 MiB (and a message at most 64): a short blocking write.
            tokio::task::block_in_place(|| up.write(&chunk.data)).map_err(internal)?;
            self.0.meters.bytes_in.inc_by(chunk.data.len() as u64);
        }
        let shared = Arc::clone(&self.0);
        let (sha256, size) = blocking(move || shared.store().finish_upload(up)).await?.map_err(internal)?;
        Ok(Response::new(proto::AssetRef { path: String::new(), sha256, size }))
    }

    async fn submit_job(
        &self,
        req: Request<proto::SubmitJobRequest>,
    ) -> Result<Response<proto::SubmitJobReply>, Status> {
        let caller = proto::auth::caller(&req);
        let owner = (caller.role == Role::User).then(|| caller.name.clone());
        let r = req.into_inner();
        let spec =
            proto::wire::submission_from_proto(r.scene, r.assets, r.settings.as_ref(), r.group).map_err(invalid)?;
        let priority = crate::farm::schedule::priority(r.priority).map_err(invalid)?;
        let job_id = crate::farm::lifecycle::submit_job(&self.0, r.name, owner, spec, None).map_err(error_to_status)?;
        if let Ok(e) = self.0.farm().entry_mut(&job_id) {
            e.job.share.priority = priority;
        }
        Ok(Response::new(proto::SubmitJobReply { job_id }))
    }

    type WatchJobStream = BoxStream<proto::JobStatus>;

    async fn watch_job(&self, req: Request<proto::JobRequest>) -> Result<Response<Self::WatchJobStream>, Status> {
        let caller = proto::auth::caller(&req);
        let job = req.into_inner().job_id;
        self.may_touch(&caller, &job).await?;
        self.0.farm().status(&job, Instant::now()).map_err(error_to_status)?;
        let (tx, rx) = mpsc::channel(4);
        let shared = Arc::clone(&self.0);
        tokio::spawn(async move {
            let mut last = None;
            loop {
                let status = shared.farm().status(&job, Instant::now());
                let Ok(status) = status else { break };
                let done = status.state.is_final();
                let key = (status.state, status.units_done, status.workers);
                if last != Some(key) || done {
                    if tx.send(Ok(status_to_proto(status))).await.is_err() {
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
        let caller = proto::auth::caller(&req);
        let job = req.into_inner().job_id;
        self.may_touch(&caller, &job).await?;
        let shared = Arc::clone(&self.0);
        let bytes = blocking(move || shared.image_exr(&job)).await?.map_err(|e| match e {
            ImageError::Unknown(e) => error_to_status(e),
            ImageError::None(m) => Status::failed_precondition(m),
            ImageError::Failed(m) => Status::internal(m),
        })?;
        let chunks: Vec<Result<proto::ImageChunk, Status>> =
            bytes.chunks(proto::ASSET_CHUNK_BYTES).map(|c| Ok(proto::ImageChunk { exr: c.to_vec() })).collect();
        Ok(Response::new(Box::pin(tokio_stream::iter(chunks))))
    }

    async fn cancel_job(&self, req: Request<proto::JobRequest>) -> Result<Response<proto::JobStatus>, Status> {
        let caller = proto::auth::caller(&req);
        let job = req.into_inner().job_id;
        self.may_touch(&caller, &job).await?;
        Ok(Response::new(status_to_proto(self.0.cancel(&job).map_err(error_to_status)?)))
    }

    async fn update_job(&self, req: Request<proto::UpdateJobRequest>) -> Result<Response<proto::JobStatus>, Status> {
        let caller = proto::auth::caller(&req);
        let r = req.into_inner();
        self.may_touch(&caller, &r.job_id).await?;
        let change = crate::farm::state::JobChange { priority: r.priority, paused: r.paused, spp: r.spp };
        let mut farm = self.0.farm();
        farm.update_job(&r.job_id, &change).map_err(error_to_status)?;
        tracing::info!(job = %r.job_id, ?change, by = %caller.name, "job changed");
        let status = farm.status(&r.job_id, Instant::now()).map_err(error_to_status)?;
        drop(farm);
        // A raised spp reopens work, a resume frees units: wake whoever waits for either.
        self.0.changed.notify_one();
        Ok(Response::new(status_to_proto(status)))
    }

    async fn list_jobs(&self, req: Request<proto::ListRequest>) -> Result<Response<proto::ListJobsReply>, Status> {
        let caller = proto::auth::caller(&req);
        let statuses = self.0.farm().statuses_of(Instant::now(), |owner| caller.may_touch(owner));
        let jobs = statuses.into_iter().map(status_to_proto).collect();
        Ok(Response::new(proto::ListJobsReply { jobs }))
    }

    async fn stored_frames(&self, req: Request<proto::GroupRequest>) -> Result<Response<proto::ListJobsReply>, Status> {
        let caller = proto::auth::caller(&req);
        let Some(group) = proto::wire::group_from_proto(req.into_inner().name).map_err(invalid)? else {
            return Err(Status::invalid_argument("group: a name is needed"));
        };
        let images = self.0.store().images();
        let group_name = group.clone();
        let frames = blocking(move || crate::farm::stored::stored_frames(&images, &group)).await?;
        let jobs = frames
            .into_iter()
            .filter(|f| caller.may_touch(f.owner.as_deref()))
            .map(|f| stored_frame_to_proto(f, &group_name))
            .collect();
        Ok(Response::new(proto::ListJobsReply { jobs }))
    }

    async fn stored_job(&self, req: Request<proto::JobRequest>) -> Result<Response<proto::JobStatus>, Status> {
        let caller = proto::auth::caller(&req);
        let job = req.into_inner().job_id;
        // Whether an image is stored first: a name that is no job's is not found, rather
        // than refused for having no owner.
        let listed = self.listed_owner(&job);
        let image = self.0.store().stored_image(&job);
        let stored = blocking(move || {
            let image = image.filter(|p| p.is_file())?;
            Some((crate::farm::stored::stored_owner(&image), crate::farm::stored::stored_frame_name(&image)))
        })
        .await?;
        let Some((owner, name)) = stored else {
            return Err(Status::not_found(format!("no job {job} on the farm, and no image of it stored")));
        };
        // A job still listed is judged by its listed owner, as `may_touch` does.
        Self::judge(&caller, &job, listed.unwrap_or_else(|| owner.clone()).as_deref())?;
        Ok(Response::new(stored_job_to_proto(job, owner, name)))
    }

    /// Every user sees the workers' counts; only admins see who they are (hostnames,
    /// identities) and the identities' records and bans.
    async fn list_workers(
        &self,
        req: Request<proto::ListRequest>,
    ) -> Result<Response<proto::ListWorkersReply>, Status> {
        let admin = proto::auth::caller(&req).role == Role::Admin;
        let farm = self.0.farm();
        let now = Instant::now();
        let shown = |s: &str| if admin { s.to_string() } else { String::new() };
        let workers = farm
            .workers
            .values()
            .map(|w| proto::WorkerInfo {
                worker_id: w.id,
                hostname: shown(&w.hostname),
                threads: w.threads,
                units_held: farm.jobs.iter().map(|e| e.job.held_by(w.id) as u32).sum(),
                units_done: w.units_done,
                last_seen_s: now.duration_since(w.last_seen).as_secs_f64(),
                quarantined: farm.quarantined(w),
                identity: shown(farm.identities.get(w.trust).map_or("", |i| i.name.as_str())),
            })
            .collect();
        let identities = if admin { identities_to_proto(&farm) } else { Vec::new() };
        Ok(Response::new(proto::ListWorkersReply { workers, identities }))
    }

    async fn unban(&self, req: Request<proto::UnbanRequest>) -> Result<Response<proto::UnbanReply>, Status> {
        if proto::auth::caller(&req).role != Role::Admin {
            return Err(Status::permission_denied("only an admin may lift a ban"));
        }
        let name = req.into_inner().identity;
        let lifted = self.0.farm().identities.unban(&name);
        match lifted {
            Some(ban) => {
                tracing::warn!(identity = %name.escape_debug(), "ban lifted (it was banned: {})", ban.reason);
                Ok(Response::new(proto::UnbanReply { reason: ban.reason }))
            }
            None => Err(Status::not_found(format!("{}: no such banned identity", proto::wire::quote(&name)))),
        }
    }
}
