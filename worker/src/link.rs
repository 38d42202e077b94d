//! The worker's end of the lease → render → submit protocol, as a seam: [`Link`] is
//! what the state machine's calls go through. [`GrpcLink`] is a remote coordinator;
//! the coordinator's `render --local-workers 0` links to its own farm state in
//! process, and its load test links simulated workers over gRPC — all three drive the
//! same machine ([`crate::drive`]).

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use proto::domain::{JobSpec, UnitKey};
use proto::wire;

use crate::asset_cache::{self, AssetCache, LoadedJob};
use crate::machine::{Failure, Grant, Registration, Rendered, Renewal};
use crate::rpc::{self, Client};

const REGISTER_TIMEOUT: Duration = Duration::from_secs(5);
const LEASE_TIMEOUT: Duration = Duration::from_secs(10);
/// Jobs loaded early from one lease reply, at most (the coordinator names a few).
const MAX_PREPARE_EARLY: usize = 4;
const HEARTBEAT_TIMEOUT: Duration = Duration::from_secs(5);
const SUBMIT_TIMEOUT: Duration = Duration::from_secs(30);

/// A coordinator, as the worker's machine sees it.
pub trait Link: Clone + Send + Sync + 'static {
    fn register(&self, threads: usize) -> impl Future<Output = Result<Registration, Failure>> + Send;
    fn lease(&self, worker_id: u64, max_units: u32) -> impl Future<Output = Result<Grant, Failure>> + Send;
    fn heartbeat(&self, worker_id: u64, held: Vec<UnitKey>) -> impl Future<Output = Result<Renewal, Failure>> + Send;
    /// Sends results in one call; for each, in order, whether the coordinator merged it
    /// (false: a duplicate, acknowledged) or why it refused it.
    fn submit(
        &self,
        worker_id: u64,
        units: Vec<Arc<Rendered>>,
    ) -> impl Future<Output = Result<Vec<Result<bool, String>>, Failure>> + Send;
    /// The job's scene, loaded (its files fetched first if need be); the error names
    /// the job and the file.
    fn prepare(&self, job: Arc<JobSpec>) -> impl Future<Output = Result<Arc<LoadedJob>, String>> + Send;
}

/// A coordinator over gRPC, with the worker's asset cache for scene files.
#[derive(Clone)]
pub struct GrpcLink {
    client: Client,
    cache: Arc<AssetCache>,
    max_backoff: Duration,
}

impl GrpcLink {
    pub(crate) fn new(client: Client, cache: Arc<AssetCache>, max_backoff: Duration) -> Self {
        Self { client, cache, max_backoff }
    }

    /// A link to the coordinator at `url` (`host:port` or a URL; it connects on first
    /// use), keeping scene files in `cache_dir`.
    pub fn connect(
        url: &str,
        credentials: &rpc::Credentials,
        cache_dir: &std::path::Path,
        max_backoff: Duration,
    ) -> anyhow::Result<Self> {
        Ok(Self::new(rpc::connect(url, credentials)?, Arc::new(AssetCache::open(cache_dir)?), max_backoff))
    }

    /// A second connection to the coordinator at `url`, sharing this link's cache.
    pub fn another_connection(&self, url: &str, credentials: &rpc::Credentials) -> anyhow::Result<Self> {
        Ok(Self::new(rpc::connect(url, credentials)?, self.cache.clone(), self.max_backoff))
    }
}

impl Link for GrpcLink {
    async fn register(&self, threads: usize) -> Result<Registration, Failure> {
        let request = proto::RegisterRequest {
            protocol_version: proto::PROTOCOL_VERSION,
            threads: u32::try_from(threads).unwrap_or(u32::MAX),
            hostname: hostname(),
            version: env!("CARGO_PKG_VERSION").to_string(),
        };
        let r = rpc::call(REGISTER_TIMEOUT, self.client.clone().register(request)).await?;
        Ok(Registration { worker_id: r.worker_id, lease_ms: r.lease_ms, heartbeat_ms: r.heartbeat_ms })
    }

    async fn lease(&self, worker_id: u64, max_units: u32) -> Result<Grant, Failure> {
        let request = proto::LeaseRequest { worker_id, max_units };
        let r = rpc::call(LEASE_TIMEOUT, self.client.clone().lease(request)).await?;
        let units = r.units.into_iter().map(wire::unit_from_proto).collect();
        // A malformed spec is not loaded early; its units, if they come, say what is wrong.
        let prepare =
            r.prepare.into_iter().take(MAX_PREPARE_EARLY).filter_map(|j| wire::job_from_proto(j).ok()).map(Arc::new);
        Ok(Grant { units, retry_after_ms: r.retry_after_ms, shutdown: r.shutdown, prepare: prepare.collect() })
    }

    async fn heartbeat(&self, worker_id: u64, held: Vec<UnitKey>) -> Result<Renewal, Failure> {
        let held = held.iter().map(wire::unit_key_to_proto).collect();
        let request = proto::HeartbeatRequest { worker_id, held };
        let r = rpc::call(HEARTBEAT_TIMEOUT, self.client.clone().heartbeat(request)).await?;
        Ok(Renewal { abandon: r.abandon.into_iter().map(wire::unit_key_from_proto).collect(), shutdown: r.shutdown })
    }

    async fn submit(&self, worker_id: u64, units: Vec<Arc<Rendered>>) -> Result<Vec<Result<bool, String>>, Failure> {
        let results = units
            .iter()
            .map(|u| wire::result_to_proto(worker_id, &u.key, u.samples, &u.acc, u.rays, u.seconds))
            .collect();
        let request = proto::SubmitResultsRequest { worker_id, results };
        let reply = rpc::call(SUBMIT_TIMEOUT, self.client.clone().submit_results(request)).await?;
        Ok(wire::outcomes_from_proto(reply))
    }

    async fn prepare(&self, job: Arc<JobSpec>) -> Result<Arc<LoadedJob>, String> {
        let (client, cache) = (self.client.clone(), self.cache.clone());
        // An inner task, so that even a panic is reported and the job not stuck.
        match tokio::spawn(asset_cache::prepare_job(client, cache, job, self.max_backoff)).await {
            Ok(Ok(loaded)) => Ok(Arc::new(loaded)),
            Ok(Err(e)) => Err(format!("{e:#}")),
            Err(e) => Err(format!("scene preparation failed: {e}")),
        }
    }
}

/// This machine's name, for the coordinator's worker list.
fn hostname() -> String {
    ["/proc/sys/kernel/hostname", "/etc/hostname"]
        .iter()
        .find_map(|p| std::fs::read_to_string(p).ok().map(|s| s.trim().to_string()).filter(|s| !s.is_empty()))
        .or_else(|| std::env::var("HOSTNAME").ok().filter(|s| !s.is_empty()))
        .or_else(|| std::env::var("COMPUTERNAME").ok().filter(|s| !s.is_empty()))
        .unwrap_or_else(|| "unknown".to_string())
}
