//! A user's connection to a farm's `Jobs` service: each call encodes its request,
//! decodes and checks the answer, and returns the farm's own types, so the commands
//! never see a wire message.

use std::time::Duration;

use anyhow::Context;
use proto::auth::{ClientAuth, Token};
use proto::domain::{AssetRef, JobSpec};
use proto::jobs_client::JobsClient;
use proto::tls::TlsDir;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;

use super::wire::status_from_proto;
use crate::farm::assets::sha256_hex;
use crate::farm::status::JobStatus;

pub struct FarmClient {
    jobs: JobsClient<InterceptedService<Channel, ClientAuth>>,
}

/// A job's progress stream, or why there is none.
pub enum Watch {
    Stream(StatusStream),
    /// The farm does not list the job (it may have finished long ago: its image can
    /// still be stored).
    NotFound(String),
}

pub struct StatusStream(Box<tonic::Streaming<proto::JobStatus>>);

impl StatusStream {
    /// The job's next status; `None` when the stream ends.
    pub async fn next(&mut self) -> anyhow::Result<Option<JobStatus>> {
        match self.0.message().await? {
            Some(s) => Ok(Some(status_from_proto(s).map_err(anyhow::Error::msg)?)),
            None => Ok(None),
        }
    }
}

/// A worker as `status` lists it.
pub struct WorkerRow {
    pub id: u64,
    /// Empty unless an admin asks, as `identity`.
    pub hostname: String,
    pub identity: String,
    pub threads: u32,
    pub units_held: u32,
    pub units_done: u64,
    pub last_seen_s: f64,
    pub quarantined: bool,
}

/// An identity as `coordinator workers` lists it (admins only).
pub struct IdentityRow {
    pub name: String,
    pub answers: u64,
    pub refused: u32,
    /// Why and when (seconds since 1970) it was banned.
    pub ban: Option<(String, u64)>,
    pub workers: u32,
}

fn message(s: tonic::Status) -> anyhow::Error {
    use tonic::Code;
    match s.code() {
        // What a plain-text client sees of a TLS farm (and the reverse): say what to try.
        Code::Unavailable | Code::Cancelled | Code::Unknown => anyhow::anyhow!(
            "{} (the connection failed: is the address right, and does the farm use TLS? then give --tls DIR)",
            s.message()
        ),
        _ => anyhow::anyhow!("{}", s.message()),
    }
}

impl FarmClient {
    /// Connects to a coordinator given as `host:port` or a URL; every call bears `token`.
    /// With `tls`, over TLS, trusting only the farm's CA.
    pub async fn connect(address: &str, token: Option<&Token>, tls: Option<&TlsDir>) -> anyhow::Result<Self> {
        let url = proto::tls::url(address, tls.is_some()).map_err(|e| anyhow::anyhow!("--coordinator {e}"))?;
        let mut endpoint = tonic::transport::Endpoint::from_shared(url.clone())
            .map_err(|e| anyhow::anyhow!("--coordinator {address}: not an address ({e})"))?
            .connect_timeout(Duration::from_secs(10));
        if let Some(tls) = tls {
            endpoint = endpoint.tls_config(tls.client().map_err(anyhow::Error::msg)?).context("--tls")?;
        }
        let channel = endpoint.connect().await.with_context(|| format!("connecting to {url}"))?;
        let jobs = JobsClient::with_interceptor(channel, ClientAuth::new(token))
            .max_decoding_message_size(proto::MAX_MESSAGE_BYTES)
            .max_encoding_message_size(proto::MAX_MESSAGE_BYTES);
        Ok(Self { jobs })
    }

    /// Uploads a file, checking the farm stored what was sent; `rel` is its path in
    /// the job.
    pub async fn upload(&mut self, path: &std::path::Path, rel: String) -> anyhow::Result<AssetRef> {
        let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let sha = sha256_hex(&bytes);
        let chunks: Vec<proto::AssetChunk> =
            bytes.chunks(proto::ASSET_CHUNK_BYTES).map(|c| proto::AssetChunk { data: c.to_vec() }).collect();
        let reply =
            self.jobs.upload_asset(tokio_stream::iter(chunks)).await.with_context(|| format!("uploading {rel}"))?;
        let r = reply.into_inner();
        anyhow::ensure!(r.sha256 == sha, "upload of {rel} was corrupted (digest {} ≠ {sha})", r.sha256);
        Ok(AssetRef { path: rel, sha256: sha, size: bytes.len() as u64 })
    }

    /// Submits a job of uploaded files; returns its id. `priority` 0 is the farm's default.
    pub async fn submit(&mut self, name: String, priority: u32, spec: &JobSpec) -> anyhow::Result<String> {
        let request = proto::SubmitJobRequest {
            scene: Some((&spec.scene).into()),
            assets: spec.assets.iter().map(Into::into).collect(),
            settings: Some(proto::wire::settings_to_proto(spec)),
            name,
            priority,
            group: spec.group.clone().unwrap_or_default(),
        };
        Ok(self.jobs.submit_job(request).await.map_err(message)?.into_inner().job_id)
    }

    pub async fn watch(&mut self, job: &str) -> anyhow::Result<Watch> {
        match self.jobs.watch_job(proto::JobRequest { job_id: job.to_string() }).await {
            Ok(r) => Ok(Watch::Stream(StatusStream(Box::new(r.into_inner())))),
            Err(s) if s.code() == tonic::Code::NotFound => Ok(Watch::NotFound(s.message().to_string())),
            Err(s) => Err(message(s)),
        }
    }

    /// The job's image as the coordinator encodes it: an EXR file with its header.
    pub async fn fetch_exr(&mut self, job: &str) -> anyhow::Result<Vec<u8>> {
        let request = proto::JobRequest { job_id: job.to_string() };
        let mut stream = self.jobs.fetch_image(request).await.map_err(message)?.into_inner();
        let mut exr = Vec::new();
        while let Some(chunk) = stream.message().await? {
            exr.extend_from_slice(&chunk.exr);
        }
        Ok(exr)
    }

    pub async fn jobs(&mut self) -> anyhow::Result<Vec<JobStatus>> {
        let jobs = self.jobs.list_jobs(proto::ListRequest {}).await.map_err(message)?.into_inner().jobs;
        jobs.into_iter().map(|s| status_from_proto(s).map_err(anyhow::Error::msg)).collect()
    }

    /// A job group's frames whose images are stored and which are no longer listed (or
    /// still are: the caller merges); none from a coordinator without the call.
    pub async fn stored_frames(&mut self, group: &str) -> anyhow::Result<Vec<JobStatus>> {
        let request = proto::GroupRequest { name: group.to_string() };
        let jobs = match self.jobs.stored_frames(request).await {
            Ok(r) => r.into_inner().jobs,
            Err(s) if s.code() == tonic::Code::Unimplemented => return Ok(Vec::new()),
            Err(s) => return Err(message(s)),
        };
        jobs.into_iter().map(|s| status_from_proto(s).map_err(anyhow::Error::msg)).collect()
    }

    /// A job no longer listed whose image is stored (done); None when none is (or the
    /// coordinator has no such call).
    pub async fn stored_job(&mut self, job: &str) -> anyhow::Result<Option<JobStatus>> {
        let request = proto::JobRequest { job_id: job.to_string() };
        match self.jobs.stored_job(request).await {
            Ok(r) => status_from_proto(r.into_inner()).map(Some).map_err(anyhow::Error::msg),
            Err(s) if matches!(s.code(), tonic::Code::NotFound | tonic::Code::Unimplemented) => Ok(None),
            Err(s) => Err(message(s)),
        }
    }

    pub async fn workers(&mut self) -> anyhow::Result<Vec<WorkerRow>> {
        let workers = self.jobs.list_workers(proto::ListRequest {}).await.map_err(message)?.into_inner().workers;
        Ok(workers
            .into_iter()
            .map(|w| WorkerRow {
                id: w.worker_id,
                hostname: w.hostname.chars().take(255).collect(),
                identity: w.identity.chars().take(255).collect(),
                threads: w.threads,
                units_held: w.units_held,
                units_done: w.units_done,
                last_seen_s: w.last_seen_s,
                quarantined: w.quarantined,
            })
            .collect())
    }

    /// Changes a job's priority, pauses or resumes it, or raises its spp.
    pub async fn update(&mut self, job: &str, change: &crate::farm::state::JobChange) -> anyhow::Result<JobStatus> {
        let request = proto::UpdateJobRequest {
            job_id: job.to_string(),
            priority: change.priority,
            paused: change.paused,
            spp: change.spp,
        };
        let s = self.jobs.update_job(request).await.map_err(message)?;
        status_from_proto(s.into_inner()).map_err(anyhow::Error::msg)
    }

    /// The farm's identities with their records and bans (empty unless an admin asks).
    pub async fn identities(&mut self) -> anyhow::Result<Vec<IdentityRow>> {
        let reply = self.jobs.list_workers(proto::ListRequest {}).await.map_err(message)?.into_inner();
        let clip = |s: String| s.chars().take(255).collect::<String>();
        Ok(reply
            .identities
            .into_iter()
            .map(|i| IdentityRow {
                ban: i.banned.then(|| (clip(i.ban_reason), i.banned_at_unix_s)),
                name: clip(i.name),
                answers: i.answers,
                refused: i.refused,
                workers: i.workers,
            })
            .collect())
    }

    /// Lifts `identity`'s ban; returns why it had been banned.
    pub async fn unban(&mut self, identity: &str) -> anyhow::Result<String> {
        let request = proto::UnbanRequest { identity: identity.to_string() };
        Ok(self.jobs.unban(request).await.map_err(message)?.into_inner().reason)
    }

    pub async fn cancel(&mut self, job: &str) -> anyhow::Result<JobStatus> {
        let s = self.jobs.cancel_job(proto::JobRequest { job_id: job.to_string() }).await.map_err(message)?;
        status_from_proto(s.into_inner()).map_err(anyhow::Error::msg)
    }
}
