//! `render --local-workers 0`: the job's units rendered in this process, by the
//! worker's own state machine linked straight to the farm state
//! ([`crate::edge::in_process`]), on a render pool whose panics end the job.

use std::sync::Arc;

use tracer::film::SampleRange;

use crate::edge::in_process::InProcessLink;
use crate::farm::Shared;

/// Renders a job's units in this process: the worker's own machine, linked to this
/// process's farm state instead of a coordinator over the network, leases, renders and
/// submits them through the same checks and merge as remote workers. Returns when
/// `stop` is set (or the farm shuts down).
pub(crate) async fn execute_in_process(
    shared: Arc<Shared>,
    job: String,
    threads: usize,
    stop: tokio::sync::watch::Receiver<Option<worker::Stop>>,
) {
    let pool = match worker::RenderPool::new(threads) {
        Ok(p) => p,
        Err(e) => return shared.fail(&job, format!("{e:#}")),
    };
    let (lease, heartbeat) = {
        let farm = shared.farm();
        (farm.config.lease, farm.config.heartbeat)
    };
    let settings = worker::Settings {
        coordinator: "this process".into(),
        threads,
        max_backoff: heartbeat.min(lease),
        give_up_after: None,
    };
    let executor = Arc::new(FailOnPanic { pool, shared: Arc::clone(&shared), job: job.clone() });
    if let Err(e) = worker::drive(InProcessLink(Arc::clone(&shared)), executor, settings, stop).await {
        shared.fail(&job, format!("rendering in this process: {e:#}"));
    }
}

/// The render pool, with a panic in the tracer (a bug) ending the job with its
/// message, rather than the unit being leased and failing again for ever.
struct FailOnPanic<E> {
    pool: E,
    shared: Arc<Shared>,
    job: String,
}

impl<E: worker::Executor> worker::Executor for FailOnPanic<E> {
    fn threads(&self) -> usize {
        self.pool.threads()
    }

    fn render(
        &self,
        job: Arc<worker::LoadedJob>,
        tile: tracer::film::Tile,
        samples: SampleRange,
        cancel: Arc<std::sync::atomic::AtomicBool>,
        done: impl FnOnce(worker::RenderOutcome) + Send + 'static,
    ) {
        let (shared, id) = (Arc::clone(&self.shared), self.job.clone());
        self.pool.render(job, tile, samples, cancel, move |outcome| {
            if let worker::RenderOutcome::Panicked(msg) = &outcome {
                shared.fail(&id, format!("a render thread panicked (a tilefarm bug; please report it): {msg}"));
            }
            done(outcome);
        });
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;
    use std::time::Instant;

    use proto::domain::{AssetRef, JobSpec};
    use tracer::integrator::Integrator;

    use super::*;
    use crate::farm::assets::AssetStore;
    use crate::farm::state::Farm;
    use crate::farm::status::JobState;

    /// Renders nothing: every unit panics, as a tracer bug would.
    struct Panicking;

    impl worker::Executor for Panicking {
        fn threads(&self) -> usize {
            1
        }

        fn render(
            &self,
            _: Arc<worker::LoadedJob>,
            _: tracer::film::Tile,
            _: SampleRange,
            _: Arc<std::sync::atomic::AtomicBool>,
            done: impl FnOnce(worker::RenderOutcome) + Send + 'static,
        ) {
            done(worker::RenderOutcome::Panicked("unit 11 out of bounds".into()));
        }
    }

    /// A panic in a unit ends the job with its message (before, the render waited
    /// for a unit that no thread would ever finish).
    #[test]
    fn a_panicking_unit_fails_the_job_with_its_message() {
        let dir = std::env::temp_dir().join(format!("tilefarm-panic-test-{}", std::process::id()));
        let shared = Arc::new(Shared::new(Farm::new(Default::default()), AssetStore::open(&dir).unwrap()));
        let spec = JobSpec {
            job_id: String::new(),
            scene: AssetRef { path: "scene.toml".into(), sha256: "ab".repeat(32), size: 1 },
            assets: vec![],
            overrides: Default::default(),
            integrator: Integrator::Path,
            tile_size: None,
            batch_spp: None,
            spp_map: None,
            group: None,
        };
        let job = shared.farm().add_job("j".into(), None, spec);
        let executor = FailOnPanic { pool: Panicking, shared: Arc::clone(&shared), job: job.clone() };
        let scene = tracer::scene::scene_from_toml(
            "[camera]\nposition = [0, 0, -5]\nlook_at = [0, 0, 0]\nwidth = 8\nheight = 8\n",
            "scene.toml",
            Path::new("."),
        )
        .unwrap();
        let loaded = Arc::new(worker::LoadedJob {
            spec: (*shared.farm().entry(&job).unwrap().spec).clone(),
            scene: Arc::new(scene),
            integrator: Integrator::Path,
            prepared: false,
        });
        let seen = Arc::new(std::sync::Mutex::new(None));
        let s = Arc::clone(&seen);
        use worker::Executor;
        executor.render(
            loaded,
            tracer::film::Tile::new(0, 0, 8, 8),
            SampleRange::new(0, 1),
            Default::default(),
            move |o| {
                *s.lock().unwrap() = Some(matches!(o, worker::RenderOutcome::Panicked(_)));
            },
        );
        assert_eq!(*seen.lock().unwrap(), Some(true), "the machine hears of it too");
        let status = shared.farm().status(&job, Instant::now()).unwrap();
        assert_eq!(status.state, JobState::Failed);
        assert!(status.error.contains("unit 11 out of bounds"), "{}", status.error);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
