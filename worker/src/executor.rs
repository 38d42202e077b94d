//! Where the machine's units are rendered: [`Executor`] is the seam, the render pool
//! ([`crate::RenderPool`], which implements it) the real one; the load test's executor returns empty results
//! at once, to measure the coordinator alone.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use tracer::film::{SampleRange, Tile};

use crate::asset_cache::LoadedJob;
use crate::render_pool::RenderOutcome;

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
