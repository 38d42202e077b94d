//! The worker protocol without the wire: a [`worker::Link`] straight to this process's
//! farm state, for `render --local-workers 0`. The same worker machine drives it as
//! drives a remote worker, through the same farm operations and checks as the gRPC
//! services; only the encoding is skipped.

use std::sync::Arc;
use std::time::Instant;

use proto::domain::{JobSpec, UnitKey, WorkUnit};
use worker::{Failure, Grant, LoadedJob, Registration, Rendered, Renewal};

use crate::farm::job::UnitResult;
use crate::farm::{FarmError, Shared};

/// How long an idle in-process worker waits before asking again.
const IDLE_RETRY_MS: u32 = 20;

#[derive(Clone)]
pub struct InProcessLink(pub Arc<Shared>);

fn failure(e: FarmError) -> Failure {
    match e {
        FarmError::UnknownWorker(_) => Failure::UnknownWorker(e.to_string()),
        e => Failure::Rejected { code: "Rejected".into(), message: e.to_string() },
    }
}

impl worker::Link for InProcessLink {
    async fn register(&self, threads: usize) -> Result<Registration, Failure> {
        let mut farm = self.0.farm();
        let worker_id = farm.register("in-process".into(), threads as u32, Instant::now());
        let (lease, heartbeat) = (farm.config.lease, farm.config.heartbeat);
        Ok(Registration { worker_id, lease_ms: lease.as_millis() as u32, heartbeat_ms: heartbeat.as_millis() as u32 })
    }

    async fn lease(&self, worker_id: u64, max_units: u32) -> Result<Grant, Failure> {
        let mut farm = self.0.farm();
        if farm.shutting_down {
            return Ok(Grant { shutdown: true, ..Default::default() });
        }
        let leased = farm.lease(worker_id, max_units.clamp(1, 256) as usize, Instant::now()).map_err(failure)?;
        let units: Vec<Result<WorkUnit, String>> = leased
            .into_iter()
            .map(|l| {
                let key = UnitKey { job_id: l.spec.job_id.clone(), unit_id: l.unit };
                Ok(WorkUnit { key, job: l.spec, tile: l.tile, samples: l.samples })
            })
            .collect();
        let retry_after_ms = if units.is_empty() { IDLE_RETRY_MS } else { 0 };
        Ok(Grant { units, retry_after_ms, shutdown: false, prepare: vec![] })
    }

    async fn heartbeat(&self, worker_id: u64, held: Vec<UnitKey>) -> Result<Renewal, Failure> {
        let held: Vec<(String, u64)> = held.into_iter().map(|k| (k.job_id, k.unit_id)).collect();
        let mut farm = self.0.farm();
        let abandon = farm.heartbeat(worker_id, &held, Instant::now()).map_err(failure)?;
        let abandon = abandon.into_iter().map(|(job_id, unit_id)| UnitKey { job_id, unit_id }).collect();
        Ok(Renewal { abandon, shutdown: farm.shutting_down })
    }

    async fn submit(&self, worker_id: u64, units: Vec<Arc<Rendered>>) -> Result<Vec<Result<bool, String>>, Failure> {
        let results: Vec<UnitResult> = units
            .iter()
            .map(|u| UnitResult {
                unit: u.key.unit_id,
                tile: u.acc.tile,
                samples: u.samples,
                sums: u.acc.sums.clone(),
                counts: u.acc.counts.clone(),
                layers: u.acc.layers.clone(),
                nonfinite: u.acc.nonfinite,
                rays: u.rays,
                render_seconds: u.seconds,
            })
            .collect();
        let pairs = units.iter().zip(&results).map(|(u, r)| (u.key.job_id.as_str(), r));
        let outcomes = self.0.submit_results(worker_id, pairs).map_err(failure)?;
        Ok(outcomes.into_iter().map(|o| o.map(|a| a.accepted()).map_err(|e| e.to_string())).collect())
    }

    /// The scene the farm loaded for the job: no copy, no second load.
    async fn prepare(&self, job: Arc<JobSpec>) -> Result<Arc<LoadedJob>, String> {
        let farm = self.0.farm();
        let entry = farm.entry(&job.job_id).map_err(|e| e.to_string())?;
        let scene = entry.scene.clone().ok_or_else(|| format!("job {}: its scene is not loaded", job.job_id))?;
        Ok(Arc::new(LoadedJob { spec: (*job).clone(), scene, integrator: job.integrator, prepared: false }))
    }
}
