//! The render threads: a dedicated rayon pool, one unit per thread at a time, each
//! rendered by the tracer's `render_unit_counted`.

use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use tracer::film::{SampleRange, Tile};

use crate::asset_cache::LoadedJob;
use crate::executor::{Executor, RenderOutcome};

pub struct RenderPool {
    pool: rayon::ThreadPool,
    threads: usize,
}

impl RenderPool {
    pub fn new(threads: usize) -> anyhow::Result<Self> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("render-{i}"))
            .build()
            .map_err(|e| anyhow::anyhow!("cannot start {threads} render threads: {e}"))?;
        Ok(Self { pool, threads })
    }
}

impl Executor for RenderPool {
    fn threads(&self) -> usize {
        self.threads
    }

    /// Queues a unit. `cancel` set before a thread starts it skips it; `done` is called
    /// exactly once, on the render thread.
    fn render(
        &self,
        job: Arc<LoadedJob>,
        tile: Tile,
        samples: SampleRange,
        cancel: Arc<AtomicBool>,
        done: impl FnOnce(RenderOutcome) + Send + 'static,
    ) {
        self.pool.spawn(move || {
            if cancel.load(Ordering::Relaxed) {
                return done(RenderOutcome::Skipped);
            }
            let start = Instant::now();
            let r = std::panic::catch_unwind(AssertUnwindSafe(|| {
                tracer::render::render_unit_counted(&job.scene, job.integrator, tile, samples)
            }));
            done(match r {
                Ok((acc, count)) => RenderOutcome::Done { acc, rays: count.rays, elapsed: start.elapsed() },
                Err(p) => RenderOutcome::Panicked(tracer::render::panic_message(p.as_ref())),
            })
        });
    }
}
