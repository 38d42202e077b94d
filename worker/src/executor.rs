//! Where the machine's units are rendered: [`Executor`] is the seam, with how a unit
//! ended ([`RenderOutcome`]); the render pool ([`crate::RenderPool`]) is the real one,
//! and the load test's executor returns empty results at once, to measure the
//! coordinator alone.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use tracer::film::{Accumulation, SampleRange, Tile};

use crate::asset_cache::LoadedJob;

/// How a unit given to an executor ended.
pub enum RenderOutcome {
    Done {
        acc: Accumulation,
        rays: u64,
        elapsed: Duration,
    },
    /// Abandoned before a thread picked it up.
    Skipped,
    /// The tracer panicked (a bug); the unit is dropped, the worker carries on.
    Panicked(String),
}

pub trait Executor: Send + Sync + 'static {
    /// Units rendered at once (the machine leases twice as many).
    fn threads(&self) -> usize;

    /// Queues a unit. `cancel` set before it starts skips it; `done` is called exactly
    /// once, from any thread.
    fn render(
        &self,
        job: Arc<LoadedJob>,
        tile: Tile,
        samples: SampleRange,
        cancel: Arc<AtomicBool>,
        done: impl FnOnce(RenderOutcome) + Send + 'static,
    );
}
