//! The worker's protocol, driven event by event with a made-up clock: no network, no
//! threads, no sleeping.

use std::sync::Arc;
use std::time::{Duration, Instant};

use proto::domain::{AssetRef, JobSpec, UnitKey, WorkUnit};
use tracer::film::{Accumulation, SampleRange, Tile};
use tracer::integrator::Integrator;

use super::*;

const WORKER: u64 = 7;

fn spec(id: &str) -> Arc<JobSpec> {
    Arc::new(JobSpec {
        job_id: id.into(),
        scene: AssetRef { path: "scene.toml".into(), sha256: "ab".repeat(32), size: 10 },
        assets: vec![],
        overrides: Default::default(),
        integrator: Integrator::Path,
        tile_size: None,
        batch_spp: None,
        spp_map: None,
        group: None,
    })
}

/// A 64×32 scene.
fn scene() -> tracer::scene::Scene {
    let toml = "[camera]\nposition = [0, 0, -5]\nlook_at = [0, 0, 0]\nwidth = 64\nheight = 32\n\n\
                [[sphere]]\ncenter = [0, 0, 0]\nradius = 1\nkd = [0.5, 0.5, 0.5]\n";
    tracer::scene::scene_from_toml(toml, "scene.toml", std::path::Path::new(".")).unwrap()
}

fn loaded(job: &Arc<JobSpec>) -> Arc<LoadedJob> {
    Arc::new(LoadedJob { spec: (**job).clone(), scene: Arc::new(scene()), integrator: job.integrator, prepared: false })
}

fn unit(job: &Arc<JobSpec>, id: u64, tile: Tile) -> Result<WorkUnit, String> {
    let key = UnitKey { job_id: job.job_id.clone(), unit_id: id };
    Ok(WorkUnit { key, job: job.clone(), tile, samples: SampleRange::new(0, 4) })
}

fn tile(i: u32) -> Tile {
    Tile::new(16 * (i % 4), 16 * (i / 4 % 2), 16, 16)
}

fn machine(threads: usize) -> Machine {
    machine_with(threads, None)
}

fn machine_with(threads: usize, give_up_after: Option<Duration>) -> Machine {
    let settings = Settings { coordinator: "test".into(), threads, max_backoff: Duration::from_secs(8), give_up_after };
    Machine::new(settings, Instant::now())
}

fn registration(worker_id: u64) -> Event {
    Event::Registered(Ok(Registration { worker_id, lease_ms: 3000, heartbeat_ms: 1000 }))
}

/// A short name for each action, to compare lists.
fn names(actions: &[Action]) -> Vec<String> {
    actions
        .iter()
        .map(|a| match a {
            Action::Register => "register".to_string(),
            Action::Heartbeat { held, .. } => format!("heartbeat {}", held.len()),
            Action::Lease { max_units, .. } => format!("lease {max_units}"),
            Action::Submit { units, worker_id, .. } => {
                let keys: Vec<String> = units.iter().map(|u| u.key.to_string()).collect();
                format!("submit {} as {worker_id}", keys.join(","))
            }
            Action::Prepare { job } => format!("prepare {}", job.job_id),
            Action::Render { serial, .. } => format!("render #{serial}"),
        })
        .collect()
}

/// Registers `m` at `t` and answers its first heartbeat and lease with nothing.
fn registered(m: &mut Machine, t: Instant) {
    assert_eq!(names(&m.actions(t)), ["register"]);
    m.handle(registration(WORKER), t).unwrap();
    assert_eq!(names(&m.actions(t)), ["heartbeat 0", format!("lease {}", 2 * m.settings.threads).as_str()]);
    m.handle(Event::Heartbeat { worker_id: WORKER, result: Ok(Renewal::default()) }, t).unwrap();
}

fn grant(units: Vec<Result<WorkUnit, String>>) -> Event {
    Event::Leased {
        worker_id: WORKER,
        result: Ok(Grant { units, retry_after_ms: 0, shutdown: false, prepare: vec![] }),
    }
}

/// `units` of job-1 (units 0, 1, ... on tiles 0, 1, ...) leased and their scene loaded.
fn leased_and_loaded(m: &mut Machine, t: Instant, units: u64) -> Arc<JobSpec> {
    let job = spec("job-1");
    m.handle(grant((0..units).map(|i| unit(&job, i, tile(i as u32))).collect()), t).unwrap();
    m.handle(Event::JobReady { job: job.clone(), result: Ok(loaded(&job)) }, t).unwrap();
    job
}

fn done(serial: u64, t: Tile) -> Event {
    let outcome = RenderOutcome::Done { acc: Accumulation::new(t), rays: 10, elapsed: Duration::from_millis(5) };
    Event::Rendered { serial, outcome }
}

/// The answer to a submission of `serials`.
fn answered(serials: &[u64], result: Result<Vec<Result<bool, String>>, Failure>) -> Event {
    Event::Submitted { serials: serials.to_vec(), worker_id: WORKER, result }
}

fn transport() -> Failure {
    Failure::Transport("tcp connect error".into())
}

#[test]
fn leased_units_wait_for_their_scene_once_then_render() {
    let (mut m, t) = (machine(2), Instant::now());
    registered(&mut m, t);
    let job = spec("job-1");
    m.handle(grant((0..4).map(|i| unit(&job, i, tile(i as u32))).collect()), t).unwrap();
    // One download for the four units; the prefetch window (2 × 2 threads) is full.
    assert_eq!(names(&m.actions(t)), ["prepare job-1"]);
    m.handle(Event::JobReady { job: job.clone(), result: Ok(loaded(&job)) }, t).unwrap();
    assert_eq!(names(&m.actions(t)), ["render #0", "render #1", "render #2", "render #3"]);
    assert!(m.actions(t + Duration::from_millis(1)).is_empty(), "nothing more until a unit is rendered");
}

/// A job the coordinator is still checking is loaded at once, once; its units, when
/// they come, find the scene loading (or loaded) and wait for nothing more.
#[test]
fn a_job_still_being_checked_is_loaded_before_its_units_come() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    let job = spec("job-1");
    let early = |job: &Arc<JobSpec>| Event::Leased {
        worker_id: WORKER,
        result: Ok(Grant { retry_after_ms: 250, prepare: vec![job.clone()], ..Default::default() }),
    };
    m.handle(early(&job), t).unwrap();
    assert_eq!(names(&m.actions(t)), ["prepare job-1"]);
    let t1 = t + Duration::from_millis(250);
    m.handle(early(&job), t1).unwrap();
    m.handle(grant(vec![unit(&job, 0, tile(0))]), t1).unwrap();
    assert!(!names(&m.actions(t1)).iter().any(|a| a.starts_with("prepare")), "loading already");
    m.handle(Event::JobReady { job: job.clone(), result: Ok(loaded(&job)) }, t1).unwrap();
    assert_eq!(names(&m.actions(t1)), ["render #0"]);
    // Loaded: named again, it is not loaded again.
    m.handle(early(&job), t1).unwrap();
    assert!(!names(&m.actions(t1)).iter().any(|a| a.starts_with("prepare")));
    // A job whose load failed is not tried again on a hint.
    let bad = spec("job-2");
    m.handle(early(&bad), t1).unwrap();
    assert_eq!(names(&m.actions(t1)), ["prepare job-2"]);
    m.handle(Event::JobReady { job: bad.clone(), result: Err("no such file".into()) }, t1).unwrap();
    m.handle(early(&bad), t1).unwrap();
    assert!(!names(&m.actions(t1)).iter().any(|a| a.starts_with("prepare")));
}

#[test]
fn a_rendered_unit_is_submitted_and_the_window_refilled() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    let job = leased_and_loaded(&mut m, t, 2);
    assert_eq!(names(&m.actions(t)), ["prepare job-1", "render #0", "render #1"]);
    m.handle(done(0, tile(0)), t).unwrap();
    assert_eq!(names(&m.actions(t)), ["lease 1", "submit job-1/0 as 7"]);
    m.handle(answered(&[0], Ok(vec![Ok(true)])), t).unwrap();
    assert_eq!(m.submitted(), 1);
    assert_eq!(m.unsent(), 0);
    // A second scene of the same job is not loaded again.
    m.handle(grant(vec![unit(&job, 2, tile(2))]), t).unwrap();
    assert_eq!(names(&m.actions(t)), ["render #2"]);
}

#[test]
fn heartbeats_renew_what_is_held_and_abandoned_units_are_cancelled() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    leased_and_loaded(&mut m, t, 2);
    let renders: Vec<Action> = m.actions(t).into_iter().filter(|a| matches!(a, Action::Render { .. })).collect();
    let Action::Render { cancel, .. } = &renders[1] else { panic!("{renders:?}") };
    let t1 = t + Duration::from_secs(1);
    assert_eq!(names(&m.actions(t1)), ["heartbeat 2"]);
    let abandon = vec![UnitKey { job_id: "job-1".into(), unit_id: 0 }];
    m.handle(Event::Heartbeat { worker_id: WORKER, result: Ok(Renewal { abandon, shutdown: false }) }, t1).unwrap();
    let Action::Render { cancel: first, .. } = &renders[0] else { panic!() };
    assert!(first.load(Ordering::Relaxed), "the abandoned unit's render is cancelled");
    assert!(!cancel.load(Ordering::Relaxed));
    // Its result, should the thread have finished it anyway, is dropped, not sent.
    m.handle(done(0, tile(0)), t1).unwrap();
    assert_eq!(names(&m.actions(t1)), ["lease 1"]);
    let t2 = t1 + Duration::from_secs(1);
    assert_eq!(names(&m.actions(t2)), ["heartbeat 1"]);
}

/// Results finished together leave in one call. Those that could not be sent are kept
/// and sent again after a backoff; one the coordinator refuses (its lease lapsed) is
/// dropped, and the others of the call are taken.
#[test]
fn results_are_batched_resent_after_transport_failures_and_dropped_when_refused() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    leased_and_loaded(&mut m, t, 2);
    m.actions(t);
    m.handle(done(0, tile(0)), t).unwrap();
    m.handle(done(1, tile(1)), t).unwrap();
    assert_eq!(names(&m.actions(t)), ["lease 2", "submit job-1/0,job-1/1 as 7"]);
    m.handle(answered(&[0, 1], Err(transport())), t).unwrap();
    assert_eq!(m.unsent(), 2);
    assert!(m.actions(t).iter().all(|a| !matches!(a, Action::Submit { .. })), "not at once");
    let retry = m.next_deadline(t).unwrap();
    assert!(retry > t && retry <= t + Duration::from_millis(100), "{:?}", retry - t);
    assert_eq!(names(&m.actions(retry)), ["submit job-1/0,job-1/1 as 7"]);
    m.handle(answered(&[0, 1], Ok(vec![Err("lease lapsed".into()), Ok(true)])), retry).unwrap();
    assert_eq!((m.unsent(), m.submitted()), (0, 1));
}

/// A refusal of the whole call (say, a coordinator of another protocol) drops its
/// results rather than sending them for ever.
#[test]
fn a_refused_call_drops_its_results() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    leased_and_loaded(&mut m, t, 1);
    m.actions(t);
    m.handle(done(0, tile(0)), t).unwrap();
    assert_eq!(names(&m.actions(t)), ["submit job-1/0 as 7"]);
    let refused = Failure::Rejected { code: "InvalidArgument".into(), message: "too many results".into() };
    m.handle(answered(&[0], Err(refused)), t).unwrap();
    assert_eq!((m.unsent(), m.submitted()), (0, 0));
}

/// A coordinator that is away: registration retries back off exponentially, with
/// jitter, up to the cap, and reset once it answers.
#[test]
fn registration_retries_back_off_with_jitter() {
    let (mut m, mut t) = (machine(1), Instant::now());
    let mut waits = Vec::new();
    for _ in 0..8 {
        assert_eq!(names(&m.actions(t)), ["register"]);
        m.handle(Event::Registered(Err(transport())), t).unwrap();
        assert!(m.actions(t).is_empty());
        let next = m.next_deadline(t).unwrap();
        waits.push((next - t).as_secs_f64() * 1000.0);
        t = next;
    }
    for (i, w) in waits.iter().enumerate() {
        let base = (100.0 * 2f64.powi(i as i32)).min(8000.0);
        assert!((base / 2.0..=base).contains(w), "retry {i}: {w} ms for a base of {base} ms");
    }
    // Jitter: two workers that lost the same coordinator do not retry in step.
    let mut other = machine(1);
    let mut t2 = Instant::now();
    let mut other_waits = Vec::new();
    for _ in 0..8 {
        other.actions(t2);
        other.handle(Event::Registered(Err(transport())), t2).unwrap();
        let next = other.next_deadline(t2).unwrap();
        other_waits.push((next - t2).as_secs_f64() * 1000.0);
        t2 = next;
    }
    assert_ne!(waits, other_waits);
    m.handle(registration(WORKER), t).unwrap();
    assert_eq!(names(&m.actions(t)), ["heartbeat 0", "lease 2"]);
}

/// A restarted coordinator forgets the worker: it registers again and sends what it
/// rendered under its new id.
#[test]
fn an_unknown_worker_registers_again_and_keeps_its_results() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    leased_and_loaded(&mut m, t, 1);
    assert_eq!(names(&m.actions(t)), ["prepare job-1", "render #0", "lease 1"]);
    m.handle(done(0, tile(0)), t).unwrap();
    assert_eq!(names(&m.actions(t)), ["submit job-1/0 as 7"], "the lease is still out");
    let unknown = Failure::UnknownWorker("unknown worker 7: register again".into());
    m.handle(answered(&[0], Err(unknown)), t).unwrap();
    assert_eq!(names(&m.actions(t)), ["register"]);
    m.handle(registration(8), t).unwrap();
    // It renews the unit it holds (rendered, unsent) at once, and leases afresh.
    assert_eq!(names(&m.actions(t)), ["heartbeat 1", "lease 2", "submit job-1/0 as 8"]);
}

#[test]
fn the_coordinators_stop_drains_finished_results_and_drops_the_rest() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    let (a, b) = (spec("job-1"), spec("job-2"));
    m.handle(grant(vec![unit(&a, 0, tile(0)), unit(&b, 0, tile(1))]), t).unwrap();
    m.handle(Event::JobReady { job: a.clone(), result: Ok(loaded(&a)) }, t).unwrap();
    assert_eq!(names(&m.actions(t)), ["prepare job-1", "prepare job-2", "render #0"]);
    m.handle(done(0, tile(0)), t).unwrap();
    let stop = Event::Leased { worker_id: WORKER, result: Ok(Grant { shutdown: true, ..Default::default() }) };
    m.handle(stop, t).unwrap();
    assert!(!m.done(t), "a finished result is still to be sent");
    // No more leases or heartbeats; the unit waiting for job-2's scene is dropped.
    assert_eq!(names(&m.actions(t)), ["submit job-1/0 as 7"]);
    m.handle(answered(&[0], Ok(vec![Ok(true)])), t).unwrap();
    assert!(m.done(t));
}

#[test]
fn a_signal_stops_within_the_grace_period_even_with_unsent_results() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    leased_and_loaded(&mut m, t, 1);
    m.actions(t);
    m.handle(done(0, tile(0)), t).unwrap();
    m.begin_drain("signal received", SIGNAL_GRACE, t);
    assert_eq!(names(&m.actions(t)), ["submit job-1/0 as 7"]);
    m.handle(answered(&[0], Err(transport())), t).unwrap();
    // While stopping, retries come at least every DRAIN_RETRY.
    let retry = m.next_deadline(t).unwrap();
    assert!(retry - t <= DRAIN_RETRY, "{:?}", retry - t);
    assert!(!m.done(t + Duration::from_secs(1)));
    assert!(m.done(t + SIGNAL_GRACE));
    assert_eq!(m.unsent(), 1);
}

#[test]
fn units_of_a_scene_that_fails_to_load_are_dropped_for_a_while() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    let job = spec("job-1");
    m.handle(grant(vec![unit(&job, 0, tile(0))]), t).unwrap();
    assert_eq!(names(&m.actions(t)), ["prepare job-1", "lease 1"]);
    m.handle(Event::JobReady { job: job.clone(), result: Err("scene.toml: bad".into()) }, t).unwrap();
    assert!(m.actions(t).is_empty(), "the lease is still out");
    m.handle(grant(vec![]), t).unwrap();
    m.handle(grant(vec![unit(&job, 1, tile(1))]), t).unwrap();
    assert!(m.actions(t).is_empty(), "dropped without another download");
    let later = t + FAILED_JOB_MEMORY + Duration::from_secs(1);
    let _ = m.actions(later);
    m.handle(grant(vec![unit(&job, 2, tile(2))]), later).unwrap();
    assert!(names(&m.actions(later)).contains(&"prepare job-1".to_string()), "tried again later");
}

#[test]
fn malformed_units_and_tiles_outside_the_image_are_dropped() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    let job = spec("job-1");
    m.handle(Event::JobReady { job: job.clone(), result: Ok(loaded(&job)) }, t).unwrap();
    let outside = Tile::new(60, 0, 16, 16); // the image is 64 wide
    m.handle(grant(vec![Err("unit 3: tile is missing".into()), unit(&job, 4, outside)]), t).unwrap();
    let names = names(&m.actions(t));
    assert!(names.iter().all(|n| !n.starts_with("render")), "{names:?}");
    assert_eq!(m.slots.len(), 0);
}

#[test]
fn an_idle_farm_is_asked_again_after_its_hint() {
    let (mut m, t) = (machine(1), Instant::now());
    registered(&mut m, t);
    let idle = Grant { units: vec![], retry_after_ms: 250, shutdown: false, prepare: vec![] };
    m.handle(Event::Leased { worker_id: WORKER, result: Ok(idle) }, t).unwrap();
    assert!(m.actions(t + Duration::from_millis(249)).iter().all(|a| !matches!(a, Action::Lease { .. })));
    assert_eq!(names(&m.actions(t + Duration::from_millis(250))), ["lease 2"]);
}

/// Merged results can unlock work (an adaptive tile's next batch waits for its last
/// one to merge): a worker told to wait asks again as soon as a result is accepted,
/// not after the wait; a refused result does not hurry it.
#[test]
fn an_accepted_result_ends_an_idle_wait() {
    for (accepted, asks) in [(true, true), (false, false)] {
        let (mut m, t) = (machine(1), Instant::now());
        registered(&mut m, t);
        leased_and_loaded(&mut m, t, 1);
        assert_eq!(names(&m.actions(t)), ["prepare job-1", "render #0", "lease 1"]);
        let idle = Grant { units: vec![], retry_after_ms: 250, shutdown: false, prepare: vec![] };
        m.handle(Event::Leased { worker_id: WORKER, result: Ok(idle) }, t).unwrap();
        m.handle(done(0, tile(0)), t).unwrap();
        assert_eq!(names(&m.actions(t)), [format!("submit job-1/0 as {WORKER}")]);
        let outcome = if accepted { Ok(true) } else { Err("refused".into()) };
        let later = t + Duration::from_millis(10);
        m.handle(answered(&[0], Ok(vec![outcome])), later).unwrap();
        let leases = m.actions(later).iter().filter(|a| matches!(a, Action::Lease { .. })).count();
        assert_eq!(leases == 1, asks, "accepted {accepted}");
    }
}

#[test]
fn a_worker_gives_up_on_a_coordinator_gone_for_too_long() {
    let mut m = machine_with(1, Some(Duration::from_secs(5)));
    let t = Instant::now();
    m.actions(t);
    m.handle(Event::Registered(Err(transport())), t).unwrap();
    assert!(!m.done(t));
    let late = t + Duration::from_secs(6);
    m.actions(late);
    assert!(m.done(late), "nothing to submit: it stops at once");
}

#[test]
fn a_submission_carries_at_most_the_calls_limit() {
    let (mut m, t) = (machine(150), Instant::now());
    registered(&mut m, t);
    leased_and_loaded(&mut m, t, 300);
    m.actions(t);
    for serial in 0..300 {
        m.handle(done(serial, tile(serial as u32)), t).unwrap();
    }
    let sizes: Vec<usize> = m
        .actions(t)
        .iter()
        .filter_map(|a| match a {
            Action::Submit { units, .. } => Some(units.len()),
            _ => None,
        })
        .collect();
    assert_eq!(sizes, [proto::MAX_RESULTS_PER_CALL, 300 - proto::MAX_RESULTS_PER_CALL]);
}
