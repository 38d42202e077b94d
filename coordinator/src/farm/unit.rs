//! A unit of work — one tile × one sample batch of a job — and what can happen to it:
//! its lease states, a result as received, why a result is refused, how a valid one
//! is applied, and the record a checkpoint keeps.

use std::time::Instant;

use tracer::film::{SampleRange, Tile};

use super::verify::Check;

pub use super::ids::{By, IdentityId, UnitId, WorkerId};

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum UnitState {
    Pending,
    /// Out with `worker` since `since`; lapses at `deadline` unless renewed.
    Leased {
        worker: WorkerId,
        deadline: Instant,
        since: Instant,
    },
    Done,
}

/// A speculative second lease of a straggling unit: the first result wins.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Spare {
    pub worker: WorkerId,
    pub deadline: Instant,
}

#[derive(Clone, Debug)]
pub struct Unit {
    pub tile_index: usize,
    pub tile: Tile,
    pub samples: SampleRange,
    pub state: UnitState,
    pub spare: Option<Spare>,
    /// Every worker that ever held a lease on this unit: a late result from any of them is
    /// the same deterministic work, so it is accepted while the unit is not done.
    pub holders: Vec<WorkerId>,
    /// The answers of a unit under check (see [`crate::farm::verify`]).
    pub check: Option<Box<Check>>,
    /// Which identity's result was merged, unconfirmed by another identity (None:
    /// confirmed, or restored from a checkpoint): what to discard if it is caught lying.
    pub unchecked_from: Option<IdentityId>,
}

impl Unit {
    pub fn new(tile_index: usize, tile: Tile, samples: SampleRange, state: UnitState) -> Self {
        Self { tile_index, tile, samples, state, spare: None, holders: Vec::new(), check: None, unchecked_from: None }
    }
}

/// Why a result was refused. The job's state is untouched in every case.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum Rejection {
    #[error("unit {0} does not exist in this job")]
    UnknownUnit(UnitId),
    #[error("unit {0} was never leased to worker {1}")]
    NotHolder(UnitId, WorkerId),
    #[error("unit {unit}: {what}")]
    Malformed { unit: UnitId, what: String },
    #[error("the job is {0}")]
    NotRunning(&'static str),
}

/// What happened to a valid result.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Applied {
    Merged,
    /// The unit was already done: acknowledged and ignored.
    Duplicate,
    /// The job was cancelled or failed while the unit was out: acknowledged and dropped
    /// (the worker did nothing wrong, so this is no error).
    Discarded,
    /// The unit is under check: kept until another worker's answer agrees.
    Held,
}

impl Applied {
    /// What the worker is told: its result was taken (a held one too, so that a worker
    /// cannot tell which units are checked).
    pub fn accepted(self) -> bool {
        matches!(self, Applied::Merged | Applied::Held)
    }
}

/// The contents of one unit's result, as received (the type the wire mapping checks).
pub use proto::domain::UnitResult;

/// A unit as a checkpoint records it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnitRecord {
    pub tile_index: u32,
    pub samples: SampleRange,
    pub done: bool,
}
