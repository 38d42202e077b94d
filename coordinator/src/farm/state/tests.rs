//! The farm's bookkeeping against its rules: unknown callers, silent workers, shares, job changes.

use super::*;

/// A job of a scene in the store, as submitted.
pub(in crate::farm) fn spec() -> JobSpec {
    let scene = proto::domain::AssetRef { path: "scene.toml".into(), sha256: "ab".repeat(32), size: 10 };
    JobSpec {
        job_id: String::new(),
        scene,
        assets: vec![],
        overrides: Default::default(),
        integrator: Default::default(),
        tile_size: None,
        batch_spp: None,
        spp_map: None,
        group: None,
    }
}

#[test]
fn unknown_workers_and_jobs_are_errors() {
    let mut f = Farm::new(FarmConfig::default());
    let now = Instant::now();
    assert_eq!(f.lease(42, 1, now).err(), Some(FarmError::UnknownWorker(42)));
    let w = f.register("h".into(), 2, now);
    assert!(f.lease(w, 4, now).unwrap().is_empty());
    assert!(matches!(f.status("nope", now), Err(FarmError::UnknownJob(_))));
}

#[test]
fn silent_workers_are_forgotten_after_the_grace_period() {
    let config = FarmConfig { forget_worker_after: Duration::from_secs(30), ..FarmConfig::default() };
    let mut f = Farm::new(config);
    let t0 = Instant::now();
    let quiet = f.register("quiet".into(), 1, t0);
    let busy = f.register("busy".into(), 1, t0);
    f.reap(t0 + Duration::from_secs(20));
    assert_eq!(f.workers.len(), 2, "within the grace period");
    f.lease(busy, 1, t0 + Duration::from_secs(25)).unwrap();
    f.reap(t0 + Duration::from_secs(40));
    assert_eq!(f.workers.keys().copied().collect::<Vec<_>>(), [busy]);
    // The forgotten worker is told to register again.
    assert_eq!(f.lease(quiet, 1, t0 + Duration::from_secs(41)).err(), Some(FarmError::UnknownWorker(quiet)));
}

/// A restarted coordinator must not give a new worker the id of one registered with
/// its previous run.
#[test]
fn worker_ids_are_unique_across_restarts() {
    let now = Instant::now();
    let mut before = Farm::new(FarmConfig::default());
    let old: Vec<WorkerId> = (0..3).map(|_| before.register("a".into(), 1, now)).collect();
    std::thread::sleep(Duration::from_millis(2));
    let mut after = Farm::new(FarmConfig::default());
    let new = after.register("b".into(), 1, now);
    assert!(old.iter().all(|&o| o < new), "{old:?} then {new}");
}

/// Units leased to one worker, `n` at a time, by job.
fn leased_by_job(f: &mut Farm, w: WorkerId, n: usize, now: Instant) -> HashMap<String, usize> {
    let mut by = HashMap::new();
    for l in f.lease(w, n, now).unwrap() {
        *by.entry(l.spec.job_id.clone()).or_default() += 1;
    }
    by
}

#[test]
fn running_jobs_share_the_workers_by_priority() {
    let mut f = Farm::new(FarmConfig::default());
    let now = Instant::now();
    let w = f.register("h".into(), 16, now); // holds up to 128 units
    let a = f.add_job("a".into(), None, spec());
    let b = f.add_job("b".into(), None, spec());
    // 64 tiles × 4 batches each.
    f.entry_mut(&a).unwrap().job.start(64, 64, 8, 8, 2, true);
    f.entry_mut(&b).unwrap().job.start(64, 64, 8, 8, 2, true);
    // Equal priorities: ties go to the earlier job, then they alternate.
    let first: Vec<String> = f.lease(w, 4, now).unwrap().into_iter().map(|l| l.spec.job_id.clone()).collect();
    assert_eq!(first, [a.clone(), b.clone(), a.clone(), b.clone()]);
    f.update_job(&a, &JobChange { priority: Some(150), ..JobChange::default() }).unwrap();
    let by = leased_by_job(&mut f, w, 40, now);
    assert_eq!((by[&a], by[&b]), (30, 10), "priority 150 against 50: three units for one");
    // Paused: no new units; the others take them all.
    f.update_job(&a, &JobChange { paused: Some(true), ..JobChange::default() }).unwrap();
    let by = leased_by_job(&mut f, w, 20, now);
    assert_eq!((by.get(&a), by[&b]), (None, 20));
    f.update_job(&a, &JobChange { paused: Some(false), ..JobChange::default() }).unwrap();
    let by = leased_by_job(&mut f, w, 8, now);
    assert_eq!((by[&a], by[&b]), (6, 2), "resumed where the clock stands, not owed the pause");
}

#[test]
fn job_changes_are_checked() {
    let mut f = Farm::new(FarmConfig::default());
    let a = f.add_job("a".into(), None, spec());
    let bad = |f: &mut Farm, c: JobChange| f.update_job(&a, &c).unwrap_err().to_string();
    assert!(bad(&mut f, JobChange { spp: Some(64), ..JobChange::default() }).contains("still loading"));
    f.entry_mut(&a).unwrap().job.start(8, 8, 4, 8, 2, true);
    assert!(bad(&mut f, JobChange { priority: Some(0), ..JobChange::default() }).contains("from 1"));
    assert!(bad(&mut f, JobChange { priority: Some(5000), ..JobChange::default() }).contains("1 to 1000"));
    assert!(bad(&mut f, JobChange { spp: Some(4), ..JobChange::default() }).contains("already renders 4 spp"));
    f.update_job(&a, &JobChange { spp: Some(10), ..JobChange::default() }).unwrap();
    let j = &f.entry(&a).unwrap().job;
    assert_eq!((j.spp, j.units_total()), (10, 5), "one tile, batches 0-2, 2-4, 4-6, 6-8, 8-10");
    f.entry_mut(&a).unwrap().job.cancel();
    assert!(bad(&mut f, JobChange { paused: Some(true), ..JobChange::default() }).contains("has ended"));
}

/// A user's jobs are limited in number and in memory together, and so are all jobs.
#[test]
fn users_and_the_farm_keep_to_their_budgets() {
    let config = FarmConfig { max_user_jobs: 2, max_user_bytes: 100, max_farm_bytes: 150, ..FarmConfig::default() };
    let mut f = Farm::new(config);
    let alice = Some("alice".to_string());
    let a = f.add_job("a".into(), alice.clone(), spec());
    let b = f.add_job("b".into(), alice.clone(), spec());
    let e = f.may_submit(Some("alice")).unwrap_err().to_string();
    assert!(e.contains("--max-user-jobs 2"), "{e}");
    assert!(f.may_submit(Some("bob")).is_ok() && f.may_submit(None).is_ok());
    f.reserve(&a, 60).unwrap();
    let e = f.reserve(&b, 50).unwrap_err();
    assert!(e.contains("--max-user-memory-mb"), "{e}");
    let c = f.add_job("c".into(), Some("bob".into()), spec());
    let e = f.reserve(&c, 100).unwrap_err();
    assert!(e.contains("--max-farm-memory-mb"), "{e}");
    // A job that has ended holds nothing.
    f.entry_mut(&a).unwrap().job.cancel();
    f.reserve(&c, 100).unwrap();
    assert!(f.may_submit(Some("alice")).is_ok(), "one of alice's two has ended");
}
