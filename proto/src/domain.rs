//! The domain types that the coordinator and the worker share, apart from their wire
//! form: what a job is, which unit is which, and a unit's result as received. Plain
//! data over the tracer's types; [`crate::wire`] maps them to and from the messages.

use std::sync::Arc;

use tracer::film::{SampleRange, Tile};
use tracer::integrator::Integrator;
use tracer::scene::Overrides;

/// A unit's identity: the coordinator's (job id, unit id).
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct UnitKey {
    pub job_id: String,
    pub unit_id: u64,
}

impl std::fmt::Display for UnitKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.job_id, self.unit_id)
    }
}

/// A file of a job: its path relative to the job folder (not yet sanitised: the asset
/// cache does that, with the error naming the path) and its content digest.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AssetRef {
    pub path: String,
    pub sha256: String,
    pub size: u64,
}

/// A job: what a worker needs to load its scene, and how the coordinator cuts it.
#[derive(Clone, Debug, PartialEq)]
pub struct JobSpec {
    pub job_id: String,
    pub scene: AssetRef,
    pub assets: Vec<AssetRef>,
    pub overrides: Overrides,
    pub integrator: Integrator,
    /// The unit shape the job asks for: tile side and samples per unit (`None`: the
    /// farm's default). The coordinator's business; workers ignore them.
    pub tile_size: Option<u32>,
    pub batch_spp: Option<u32>,
}

/// One leased unit of work.
#[derive(Clone, Debug)]
pub struct WorkUnit {
    pub key: UnitKey,
    pub job: Arc<JobSpec>,
    pub tile: Tile,
    pub samples: SampleRange,
}

/// The contents of one unit's result: per-pixel fixed-point sums and sample counts.
#[derive(Clone, Debug)]
pub struct UnitResult {
    pub unit: u64,
    pub tile: Tile,
    pub samples: SampleRange,
    pub sums: Vec<[i128; 3]>,
    pub counts: Vec<u32>,
    pub nonfinite: u64,
    pub rays: u64,
}

/// A unit result as received: checked for shape (a valid tile and sample range, whole
/// pixels of sums); whether it fits its unit is the job's to check.
#[derive(Clone, Debug)]
pub struct ReceivedResult {
    pub worker_id: u64,
    pub job_id: String,
    pub result: UnitResult,
}
