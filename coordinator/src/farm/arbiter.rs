//! The coordinator as the identity of last resort: it renders the checked units that no
//! live identity can settle (two that disagree with no third, or a farm of one
//! identity), and its render decides.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

use tracer::scene::Scene;

use super::job::UnitResult;
use super::lifecycle::{Shared, finish, load_scene_of, start_due_frames};

impl Shared {
    /// Renders, on the coordinator, each checked unit that no live identity can settle
    /// (every live identity has answered: two answers differ on a farm of two, or a
    /// farm of one identity has no one else to check it): its render is the truth, and
    /// identities that answered otherwise are banned. In the background, one unit at a
    /// time on one thread, each job's scene loaded once for all its units.
    pub fn arbitrate(self: &Arc<Self>) {
        if self.arbitrating.swap(true, std::sync::atomic::Ordering::AcqRel) {
            return;
        }
        let shared = Arc::clone(self);
        std::thread::spawn(move || {
            let mut scenes: HashMap<String, Option<Arc<Scene>>> = HashMap::new();
            loop {
                let disputes = shared.farm().take_disputes(Instant::now());
                if disputes.is_empty() {
                    break;
                }
                // Only the scenes of jobs that still have units to check stay loaded.
                scenes.retain(|job, _| disputes.iter().any(|d| &d.job == job));
                let mut failed = false;
                for d in disputes {
                    // Routine on a farm of one identity (every check): not worth a log line each.
                    tracing::debug!(job = %d.job, unit = d.unit, "no other identity can check a unit: the coordinator \
                        renders it");
                    let scene = scenes.entry(d.job.clone()).or_insert_with(|| scene_for_dispute(&shared, &d));
                    let result = scene.as_ref().and_then(|scene| render_dispute(scene, &d));
                    failed |= result.is_none();
                    let finished = {
                        let mut farm = shared.farm();
                        let finished = farm.arbitrated(&d.job, d.unit, result.as_ref(), Instant::now());
                        if finished && let Ok(e) = farm.entry_mut(&d.job) {
                            finish(e);
                        }
                        finished
                    };
                    shared.changed.notify_waiters();
                    if finished {
                        start_due_frames(&shared);
                    }
                }
                // A unit that could not be decided waits for the reaper's next turn, not
                // a loop that would try it again at once.
                if failed {
                    break;
                }
            }
            shared.arbitrating.store(false, std::sync::atomic::Ordering::Release);
        });
    }
}

/// The scene to render a dispute with: the job's own when the coordinator keeps it, else
/// loaded again (a farm keeps no geometry), and refused if that load found more problems
/// than the job's first (then it did not read the same scene).
fn scene_for_dispute(shared: &Arc<Shared>, d: &super::state::Dispute) -> Option<Arc<Scene>> {
    if let Some(s) = &d.scene {
        return Some(Arc::clone(s));
    }
    match load_scene_of(shared, &d.job, false) {
        Ok(s) if s.warnings.len() <= d.scene_warnings => Some(Arc::new(s)),
        Ok(s) => {
            tracing::warn!(job = %d.job, "the scene loaded to check a unit is not the one the job loaded ({} \
                warnings, first {}); not deciding", s.warnings.len(), d.scene_warnings);
            None
        }
        Err(e) => {
            tracing::warn!(job = %d.job, "loading the scene to check a unit: {e:#}");
            None
        }
    }
}

/// The coordinator's own render of a disputed unit (None: it panicked).
fn render_dispute(scene: &Scene, d: &super::state::Dispute) -> Option<UnitResult> {
    let rendered =
        std::panic::catch_unwind(|| tracer::render::render_unit_counted(scene, d.integrator, d.tile, d.samples));
    rendered.ok().map(|(acc, count)| UnitResult {
        unit: d.unit,
        tile: d.tile,
        samples: d.samples,
        sums: acc.sums,
        counts: acc.counts,
        layers: acc.layers,
        rays: count.rays,
        nonfinite: acc.nonfinite,
        render_seconds: 0.0,
    })
}
