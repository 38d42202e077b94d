//! Tests of `job.rs`.

use super::*;

pub(super) const NEVER: Duration = Duration::from_secs(1 << 30);

pub(super) fn job() -> Job {
    let mut j = Job::loading("j1".into(), "test".into());
    j.start(5, 3, 4, 2, 2, true);
    j
}

pub(super) fn result_for(j: &Job, unit: UnitId, value: i128) -> UnitResult {
    let u = &j.units[unit as usize];
    let n = u.tile.pixel_count();
    UnitResult {
        unit,
        tile: u.tile,
        samples: u.samples,
        sums: vec![[value; 3]; n],
        counts: vec![u.samples.len(); n],
        layers: Vec::new(),
        nonfinite: 0,
        rays: 10,
        render_seconds: 0.0,
    }
}

#[test]
fn units_cover_every_pixel_and_sample_once_in_progressive_order() {
    let j = job();
    // 3×2 tiles of at most 2×2, spp 4 in batches of 2: 12 units, batch 0 first.
    assert_eq!(j.units.len(), 12);
    assert!(j.units[..6].iter().all(|u| u.samples == SampleRange::new(0, 2)));
    assert!(j.units[6..].iter().all(|u| u.samples == SampleRange::new(2, 4)));
    let total: u64 = j.units.iter().map(|u| u.tile.pixel_count() as u64 * u.samples.len() as u64).sum();
    assert_eq!(total, j.samples_total());
}

#[test]
fn results_merge_once_in_any_order_and_duplicates_are_ignored() {
    let t = Instant::now();
    let now = t + Duration::from_secs(60);
    let mut a = job();
    let mut b = job();
    let ids_a: Vec<_> = (0..12).map(|_| a.lease_next(1, t, now, NEVER).unwrap()).collect();
    let ids_b: Vec<_> = (0..12).map(|_| b.lease_next(1, t, now, NEVER).unwrap()).collect();
    for &id in &ids_a {
        let r = result_for(&a, id, 1000 + id as i128);
        assert_eq!(a.apply(1, &r), Ok(Applied::Merged));
    }
    for &id in ids_b.iter().rev() {
        let r = result_for(&b, id, 1000 + id as i128);
        assert_eq!(b.apply(1, &r), Ok(Applied::Merged));
        assert_eq!(b.apply(1, &r), Ok(Applied::Duplicate));
    }
    assert_eq!(a.phase, JobPhase::Done);
    assert_eq!(a.image(), b.image());
    assert_eq!(a.samples_done, a.samples_total());
    assert_eq!(b.units_done, 12);
}

#[test]
fn malformed_and_foreign_results_are_rejected_without_touching_state() {
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut j = job();
    let id = j.lease_next(7, Instant::now(), deadline, NEVER).unwrap();
    let good = result_for(&j, id, 5);
    let before = j.image();
    assert_eq!(j.apply(8, &good), Err(Rejection::NotHolder(id, 8)));
    let mut r = good.clone();
    r.unit = 99;
    assert_eq!(j.apply(7, &r), Err(Rejection::UnknownUnit(99)));
    let mut r = good.clone();
    r.tile.width += 1;
    assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
    let mut r = good.clone();
    r.sums.pop();
    assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
    let mut r = good.clone();
    r.counts[0] += 1;
    assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
    let mut r = good.clone();
    r.sums[0][1] = -1;
    assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
    let mut r = good.clone();
    r.samples.end += 1;
    assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
    // Layers the job does not keep are refused, not merged or dropped.
    let mut r = good.clone();
    r.layers = vec![[0; tracer::film::layers::CHANNELS]; r.counts.len()];
    assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
    assert_eq!(j.image(), before);
    assert_eq!(j.units_done, 0);
    assert_eq!(j.apply(7, &good), Ok(Applied::Merged));
}

#[test]
fn lapsed_leases_return_to_the_queue_and_late_results_still_count() {
    let t0 = Instant::now();
    let mut j = job();
    let id = j.lease_next(1, t0, t0 + Duration::from_millis(10), NEVER).unwrap();
    assert_eq!(j.reap_expired(t0 + Duration::from_millis(20)), 1);
    // Re-leased to another worker; the first comes back late with the result.
    assert_eq!(j.lease_next(2, t0, t0 + Duration::from_secs(60), NEVER), Some(id));
    let r = result_for(&j, id, 3);
    assert_eq!(j.apply(1, &r), Ok(Applied::Merged));
    assert_eq!(j.apply(2, &r), Ok(Applied::Duplicate));
    assert!(!j.renew(2, id, t0 + Duration::from_secs(90)), "done units are abandoned");
}

#[test]
fn stragglers_get_a_spare_and_the_first_result_wins() {
    let t0 = Instant::now();
    let later = t0 + Duration::from_secs(100);
    let mut j = job();
    // Worker 1 takes everything; worker 2 finds the queue empty.
    let ids: Vec<_> = (0..12).map(|_| j.lease_next(1, t0, later, NEVER).unwrap()).collect();
    let wait = Duration::from_secs(5);
    assert_eq!(j.lease_next(2, t0 + Duration::from_secs(1), later, wait), None, "too early to speculate");
    let spare = j.lease_next(2, t0 + Duration::from_secs(6), later, wait).unwrap();
    assert_eq!(spare, ids[0], "the oldest outstanding unit");
    assert_eq!(j.held_by(2), 1);
    // One spare per unit, and never to a worker that already holds it.
    assert_eq!(j.lease_next(1, t0 + Duration::from_secs(6), later, wait), None);
    assert_eq!(j.apply(2, &result_for(&j, spare, 4)), Ok(Applied::Merged));
    assert_eq!(j.apply(1, &result_for(&j, spare, 4)), Ok(Applied::Duplicate));
    assert!(!j.renew(1, spare, later), "the straggler abandons it");
}

#[test]
fn a_lapsed_primary_hands_over_to_its_spare() {
    let t0 = Instant::now();
    let mut j = job();
    for _ in 0..12 {
        j.lease_next(1, t0, t0 + Duration::from_secs(10), NEVER).unwrap();
    }
    let id = j.lease_next(2, t0, t0 + Duration::from_secs(60), Duration::ZERO).unwrap();
    assert_eq!(j.reap_expired(t0 + Duration::from_secs(11)), 11, "the others go back to the queue");
    assert!(matches!(j.units[id as usize].state, UnitState::Leased { worker: 2, .. }));
}

fn finish_all(j: &mut Job) {
    let far = Instant::now() + Duration::from_secs(60);
    while let Some(id) = j.lease_next(1, Instant::now(), far, NEVER) {
        let r = result_for(j, id, 1 + id as i128);
        j.apply(1, &r).unwrap();
    }
}

fn restored_of(j: &Job) -> Restored {
    Restored {
        width: j.width,
        height: j.height,
        spp: j.spp,
        tile_size: j.tile_size,
        batch_spp: j.batch_spp,
        non_negative: j.non_negative,
        units: j.records(),
        tiles: j.tile_accumulations().to_vec(),
        rays: j.rays,
        nonfinite: j.nonfinite,
        cancelled: false,
        unconfirmed: Vec::new(),
    }
}

#[test]
fn restore_continues_where_it_stopped_and_refuses_inconsistency() {
    let mut j = job();
    let far = Instant::now() + Duration::from_secs(60);
    for _ in 0..5 {
        let id = j.lease_next(1, Instant::now(), far, NEVER).unwrap();
        let r = result_for(&j, id, 7);
        j.apply(1, &r).unwrap();
    }
    let mut k = Job::loading("j1".into(), "test".into());
    k.restore(restored_of(&j)).unwrap();
    assert_eq!((k.units_done, k.pending.len()), (5, 7));
    assert_eq!(k.image(), j.image());
    let mut bad = restored_of(&j);
    bad.units[0].done = !bad.units[0].done;
    assert!(Job::loading("x".into(), "x".into()).restore(bad).is_err());
    let mut bad = restored_of(&j);
    bad.tile_size += 1;
    assert!(Job::loading("x".into(), "x".into()).restore(bad).is_err());
}

#[test]
fn extending_spp_adds_only_the_new_samples_on_the_batch_grid() {
    let mut j = Job::loading("j".into(), "t".into());
    j.start(4, 4, 5, 4, 2, true);
    finish_all(&mut j);
    assert_eq!(j.phase, JobPhase::Done);
    j.extend_spp(9);
    assert_eq!(j.phase, JobPhase::Running);
    let new: Vec<_> =
        j.units.iter().filter(|u| u.state == UnitState::Pending).map(|u| (u.samples.start, u.samples.end)).collect();
    assert_eq!(new, [(5, 6), (6, 8), (8, 9)]);
    finish_all(&mut j);
    assert_eq!(j.samples_done, j.samples_total());
    assert!(j.tile_accumulations()[0].counts.iter().all(|&c| c == 9));
}

#[test]
fn an_evicted_job_keeps_its_status_and_acknowledges_late_duplicates() {
    let mut j = job();
    let far = Instant::now() + Duration::from_secs(60);
    let first = j.lease_next(1, Instant::now(), far, NEVER).unwrap();
    let late = result_for(&j, first, 1);
    j.evict();
    assert!(!j.is_evicted(), "a running job keeps its sums");
    j.apply(1, &late).unwrap();
    finish_all(&mut j);
    let (units, samples) = (j.units_total(), j.samples_done);
    j.evict();
    assert!(j.is_evicted());
    assert!(j.tile_accumulations().is_empty() && j.units.is_empty());
    assert_eq!((j.units_total(), j.samples_done, j.phase.clone()), (units, samples, JobPhase::Done));
    assert_eq!(j.apply(1, &late), Ok(Applied::Duplicate));
    assert_eq!(j.apply(1, &UnitResult { unit: units, ..late }), Err(Rejection::UnknownUnit(units)));
}

/// Stragglers are told by the job's own unit times: a unit out for three times the
/// median is leased again long before any fixed wait would.
#[test]
fn stragglers_are_units_out_for_a_few_times_the_median() {
    let mut j = job();
    let t0 = Instant::now();
    let far = t0 + Duration::from_secs(600);
    let fallback = Duration::from_secs(10);
    assert_eq!(j.straggler_after(fallback), fallback, "nothing timed yet");
    // Worker 1 returns units after 200 ms each; worker 2 takes one and stalls.
    let stalled = j.lease_next(2, t0, far, fallback).unwrap();
    let mut t = t0;
    while let Some(id) = j.lease_next(1, t, far, fallback) {
        if id == stalled {
            break; // worker 1 got the straggler as a spare
        }
        t += Duration::from_millis(200);
        j.apply_at(1, &result_for(&j, id, 1), t, false).unwrap();
    }
    assert_eq!(j.straggler_after(fallback), Duration::from_millis(600));
    assert!(j.units[stalled as usize].spare.is_some_and(|s| s.worker == 1));
    // It was leased again once out for 600 ms: not at the 10 s of the fallback.
    assert!(t.duration_since(t0) < Duration::from_secs(10), "{:?}", t.duration_since(t0));
}

#[test]
fn cancelled_jobs_lease_nothing_and_refuse_results() {
    let mut j = job();
    let id = j.lease_next(1, Instant::now(), Instant::now() + Duration::from_secs(5), NEVER).unwrap();
    assert_eq!(j.held_by(1), 1);
    j.cancel();
    assert_eq!(j.held_by(1), 0, "a cancelled job's leases are released");
    assert_eq!(j.reap_expired(Instant::now() + Duration::from_secs(60)), 0, "and never lapse");
    assert!(!j.renew(1, id, Instant::now()), "the worker is told to abandon the unit");
    assert_eq!(j.lease_next(1, Instant::now(), Instant::now(), NEVER), None);
    assert_eq!(j.apply(1, &result_for(&j, id, 1)), Ok(Applied::Discarded), "acknowledged, no error");
    assert_eq!(j.units_done, 0);
}

/// Leases the next unit to `by` and answers it with its true value (`1000 + id`), or a
/// wrong one when `lie`.
fn render(j: &mut Job, by: impl Into<By>, check: bool, lie: bool, t: Instant) -> (UnitId, Applied) {
    let by = by.into();
    let id = j.lease_next(by, t, t + NEVER, NEVER).expect("a unit to lease");
    let value = 1000 + id as i128 + if lie { 1 } else { 0 };
    let r = result_for(j, id, value);
    (id, j.apply_at(by, &r, t, check).unwrap())
}

fn honest_image() -> Image {
    let mut j = job();
    let t = Instant::now();
    while j.phase == JobPhase::Running {
        render(&mut j, 1, false, false, t);
    }
    j.image()
}

#[test]
fn a_checked_unit_waits_for_a_second_worker_and_merges_once_they_agree() {
    let t = Instant::now();
    let mut j = job();
    let (id, a) = render(&mut j, 1, true, false, t);
    assert_eq!(a, Applied::Held);
    assert_eq!((j.units_done, j.units_in_check()), (0, 1));
    // The worker that answered is not given its own unit to check.
    let next = j.lease_next(1, t, t + NEVER, NEVER).unwrap();
    assert_ne!(next, id);
    // Another worker is, before any other unit.
    assert_eq!(j.lease_next(2, t, t + NEVER, NEVER), Some(id));
    assert_eq!(j.apply_at(2, &result_for(&j, id, 1000 + id as i128), t, false), Ok(Applied::Merged));
    assert_eq!((j.units_done, j.units_checked, j.units_in_check()), (1, 1, 0));
    assert!(j.take_caught().is_empty());
}

#[test]
fn a_liar_is_caught_by_the_third_answer_and_its_tiles_render_again() {
    let t = Instant::now();
    let mut j = job();
    // The liar (9) returns wrong sums, unchecked, for the first three units…
    let lied: Vec<UnitId> = (0..3).map(|_| render(&mut j, 9, false, true, t).0).collect();
    assert_eq!(j.units_done, 3);
    // …and for a checked one, which an honest worker then disagrees with.
    let (checked, _) = render(&mut j, 9, true, true, t);
    assert_eq!(j.lease_next(1, t, t + NEVER, NEVER), Some(checked));
    let honest = result_for(&j, checked, 1000 + checked as i128);
    assert_eq!(j.apply_at(1, &honest, t, false), Ok(Applied::Held), "two answers that differ need a third");
    assert_eq!(j.lease_next(2, t, t + NEVER, NEVER), Some(checked));
    assert_eq!(j.apply_at(2, &honest, t, false), Ok(Applied::Merged));
    assert_eq!(j.take_caught(), [9]);
    // Everything the liar merged goes, with the rest of its tiles.
    assert_eq!(j.discard_from(9, &[9]), 3);
    assert_eq!(j.units_discarded, 3);
    assert!(lied.iter().all(|&u| j.units[u as usize].state == UnitState::Pending));
    // Honest workers finish the job: the image is the honest one, bit for bit.
    while j.phase == JobPhase::Running {
        render(&mut j, 1, false, false, t);
    }
    assert_eq!(j.image(), honest_image());
    assert_eq!(j.samples_done, j.samples_total());
}

#[test]
fn a_dispute_no_live_worker_can_settle_goes_to_the_coordinator_whose_render_decides() {
    let t = Instant::now();
    let mut j = job();
    let (id, _) = render(&mut j, 9, true, true, t);
    assert_eq!(j.lease_next(1, t, t + NEVER, NEVER), Some(id));
    let truth = result_for(&j, id, 1000 + id as i128);
    assert_eq!(j.apply_at(1, &truth, t, false), Ok(Applied::Held));
    // A third live worker could settle it: not yet the coordinator's.
    assert!(j.disputes_nobody_can_settle(&[1, 9, 2]).is_empty());
    assert_eq!(j.disputes_nobody_can_settle(&[1, 9]), [id]);
    // Taken off the check queue while the coordinator renders it.
    assert_ne!(j.lease_next(2, t, t + NEVER, NEVER), Some(id));
    assert_eq!(j.arbitrate(&truth, t), Ok(Applied::Merged));
    assert_eq!(j.take_caught(), [9]);
    assert_eq!(j.units[id as usize].state, UnitState::Done);
}

#[test]
fn a_finished_job_reopens_when_a_liar_is_caught_after_it() {
    let t = Instant::now();
    let mut j = job();
    render(&mut j, 9, false, true, t);
    while j.phase == JobPhase::Running {
        render(&mut j, 1, false, false, t);
    }
    assert_eq!(j.discard_from(9, &[9]), 1);
    assert_eq!(j.phase, JobPhase::Running);
    while j.phase == JobPhase::Running {
        render(&mut j, 1, false, false, t);
    }
    assert_eq!(j.image(), honest_image());
}

/// Three workers of one identity (one certificate) are one answer to a check: they
/// cannot settle it between them, and when the identity is caught everything it merged
/// unconfirmed goes, whichever of its workers returned it.
#[test]
fn workers_of_one_identity_cannot_vouch_for_each_other() {
    let t = Instant::now();
    let mut j = job();
    let liar = |worker| By { worker, identity: 9 };
    let lied: Vec<UnitId> = [91, 92].iter().map(|&w| render(&mut j, liar(w), false, true, t).0).collect();
    let (checked, a) = render(&mut j, liar(93), true, true, t);
    assert_eq!(a, Applied::Held);
    // Its other workers are not given the check; the same answer from them is no second.
    for w in [91, 92] {
        assert_ne!(j.lease_next(liar(w), t, t + NEVER, NEVER), Some(checked));
    }
    let forged = result_for(&j, checked, 1001 + checked as i128);
    j.units[checked as usize].holders.push(92);
    assert_eq!(j.apply_at(liar(92), &forged, t, false), Ok(Applied::Duplicate));
    assert_eq!(j.units_in_check(), 1);
    // Two other identities settle it, and the liar is caught.
    let truth = result_for(&j, checked, 1000 + checked as i128);
    for honest in [1, 2] {
        assert_eq!(j.lease_next(honest, t, t + NEVER, NEVER), Some(checked));
        j.apply_at(honest, &truth, t, false).unwrap();
    }
    assert_eq!(j.units[checked as usize].state, UnitState::Done);
    assert_eq!(j.take_caught(), [9]);
    assert_eq!(j.discard_from(9, &[91, 92, 93]), 2);
    assert!(lied.iter().all(|&u| j.units[u as usize].state == UnitState::Pending));
    assert!(!j.units.iter().any(|u| u.holders.iter().any(|w| [91, 92, 93].contains(w))));
    while j.phase == JobPhase::Running {
        render(&mut j, 1, false, false, t);
    }
    assert_eq!(j.image(), honest_image());
}

/// With one identity live, nobody else can check its answers: the coordinator does.
#[test]
fn with_one_identity_live_its_checks_go_to_the_coordinator() {
    let t = Instant::now();
    let mut j = job();
    let (id, a) = render(&mut j, 1, true, false, t);
    assert_eq!(a, Applied::Held);
    assert!(j.disputes_nobody_can_settle(&[1, 2]).is_empty(), "identity 2 can check it");
    assert_eq!(j.disputes_nobody_can_settle(&[1]), [id]);
    let truth = result_for(&j, id, 1000 + id as i128);
    assert_eq!(j.arbitrate(&truth, t), Ok(Applied::Merged));
    assert!(j.take_caught().is_empty());
    assert_eq!((j.units[id as usize].state.clone(), j.units[id as usize].unchecked_from), (UnitState::Done, None));
    // A lapsed check lease goes back to the check queue, not the ordinary one.
    let (id, _) = render(&mut j, 1, true, false, t);
    let later = t + Duration::from_secs(1);
    assert_eq!(j.lease_next(2, later, later + Duration::from_millis(1), NEVER), Some(id));
    j.reap_expired(later + Duration::from_secs(1));
    assert_eq!(j.units_in_check(), 1);
}

/// A checked unit a hoarder holds: an identity that answers it on a spare lease frees
/// the spare at once for a third, instead of sitting on it until the spare lapses.
#[test]
fn an_answer_on_a_spare_frees_the_spare_for_another_identity() {
    let t = Instant::now();
    let mut j = job();
    // The hoarder holds every unit, and never answers.
    let id = j.lease_next(9, t, t + NEVER, NEVER).unwrap();
    while j.lease_next(9, t, t + NEVER, NEVER).is_some() {}
    let later = t + Duration::from_secs(1);
    assert_eq!(j.lease_next_among(By::from(1), &[1], later, later + NEVER, Duration::ZERO), Some(id), "a spare");
    let truth = result_for(&j, id, 1000 + id as i128);
    assert_eq!(j.apply_at(1, &truth, later, true), Ok(Applied::Held));
    assert_eq!(j.units[id as usize].spare, None, "freed");
    assert_eq!(j.lease_next_among(By::from(2), &[2], later, later + NEVER, Duration::ZERO), Some(id));
    assert_eq!(j.apply_at(2, &truth, later, false), Ok(Applied::Merged));
}

/// A unit whose result was refused as malformed goes back at once, not when its lease
/// lapses; a spare lease on it carries on instead.
#[test]
fn a_released_unit_is_leased_again_at_once() {
    let t = Instant::now();
    let mut j = job();
    let id = j.lease_next(1, t, t + NEVER, NEVER).unwrap();
    j.release(1, id, t);
    assert_eq!(j.units[id as usize].state, UnitState::Pending);
    assert_eq!(j.lease_next(2, t, t + NEVER, NEVER), Some(id), "first in line again");
    j.release(1, id, t);
    assert!(matches!(j.units[id as usize].state, UnitState::Leased { worker: 2, .. }), "not 1's to release");
}

/// A job that keeps the AOV layers takes only results that carry them, merges them, and
/// its image shows them.
#[test]
fn a_job_with_layers_wants_them_in_every_result() {
    let mut j = Job::loading("j2".into(), "test".into());
    j.layers = true;
    j.start(4, 2, 2, 2, 2, true);
    let id = j.lease_next(7, Instant::now(), Instant::now() + NEVER, Duration::MAX).unwrap();
    let plain = result_for(&j, id, 5);
    assert!(matches!(j.apply(7, &plain), Err(Rejection::Malformed { .. })));
    let mut r = plain.clone();
    r.layers = vec![[1 << 32; tracer::film::layers::CHANNELS]; r.counts.len()];
    r.layers.pop();
    assert!(matches!(j.apply(7, &r), Err(Rejection::Malformed { .. })));
    r.layers.push([1 << 32; tracer::film::layers::CHANNELS]);
    assert_eq!(j.apply(7, &r), Ok(Applied::Merged));
    let tile = &j.tile_accumulations()[j.units[id as usize].tile_index];
    assert_eq!(tile.layers[0], [1 << 32; tracer::film::layers::CHANNELS]);
    assert!(tile.layers_at(0).is_some_and(|l| l.albedo == glam::Vec3::splat(0.5)), "two samples' albedo sums, 1 each");
}

/// A job's shape is checked before anything is allocated, counting the layers' memory
/// and their share of a result's message.
#[test]
fn the_size_check_counts_the_layers() {
    let gib = 1u64 << 30;
    assert!(Job::check_size((1000, 1000), 16, (1000, 16), false, gib).is_ok());
    let e = Job::check_size((1000, 1000), 16, (1000, 16), true, gib).unwrap_err();
    assert!(e.contains("tile size 1000") && e.contains("message"), "{e}");
    assert!(Job::check_size((1000, 1000), 16, (256, 16), true, gib).is_ok());
    // 52 bytes a pixel without layers, 228 with: 100 MiB holds a 1,400² image only without.
    let limit = 100 << 20;
    assert!(Job::check_size((1400, 1400), 16, (64, 16), false, limit).is_ok());
    let e = Job::check_size((1400, 1400), 16, (64, 16), true, limit).unwrap_err();
    assert!(e.contains("--max-job-memory-mb"), "{e}");
}

/// A result of `unit` whose every sample is `v` (so zero variance) or, with `noisy`,
/// alternately 0 and 2v (the same mean, a large variance), with the squared sums that
/// adaptive sampling judges by.
fn layered_result(j: &Job, unit: UnitId, v: f64, noisy: bool) -> UnitResult {
    let mut r = result_for(j, unit, 0);
    let n = r.samples.len() as f64;
    let one = (1u64 << 32) as f64;
    let sum = (n * v * one) as i128;
    let squares = if noisy { (n * 2.0 * v * v * one) as i128 } else { (n * v * v * one) as i128 };
    r.sums = vec![[sum; 3]; r.counts.len()];
    let mut l = [0i128; tracer::film::layers::CHANNELS];
    l[tracer::film::layers::SQUARES_AT..tracer::film::layers::SQUARES_AT + 3].fill(squares);
    r.layers = vec![l; r.counts.len()];
    r
}

/// Adaptive sampling: one unit of a tile out at a time; a tile whose merged samples are
/// converged skips the rest, one that is noisy renders to spp; the decisions come back
/// the same from a checkpoint.
#[test]
fn adaptive_jobs_render_a_tile_a_batch_at_a_time_and_stop_converged_tiles() {
    let mut j = Job::loading("a".into(), "test".into());
    (j.layers, j.adaptive) = (true, Some(0.01));
    j.start(4, 2, 256, 2, 8, true); // two tiles, 32 batches each
    let far = Instant::now() + NEVER;
    let lease = |j: &mut Job| j.lease_next(7, Instant::now(), far, Duration::MAX);
    let (a, b) = (lease(&mut j).unwrap(), lease(&mut j).unwrap());
    assert_ne!(j.units[a as usize].tile_index, j.units[b as usize].tile_index);
    assert_eq!(lease(&mut j), None, "each tile's next batch waits for its first");
    let mut rendered = [0u32; 2];
    let mut out = vec![a, b];
    while let Some(id) = out.pop() {
        let t = j.units[id as usize].tile_index;
        rendered[t] += 1;
        let r = layered_result(&j, id, 0.5, t == 1);
        assert_eq!(j.apply(7, &r), Ok(Applied::Merged));
        out.extend(lease(&mut j));
    }
    // Tile 0 converged at 64 spp (eight batches, the least judged); tile 1 ran to 256.
    assert_eq!(rendered, [8, 32]);
    assert_eq!(j.phase, JobPhase::Done);
    assert_eq!((j.units_done, j.units_total()), (40, 40));
    assert_eq!(j.samples_done, j.samples_total());
    assert_eq!(j.tile_accumulations()[0].counts[0], 64);
    assert_eq!(j.tile_accumulations()[1].counts[0], 256);
    // The dashboard's overlay: the converged tile is done and marked; the other is done.
    let shown: Vec<(f32, bool)> = j.tile_progress().iter().map(|p| (p.done, p.converged)).collect();
    assert_eq!(shown, [(1.0, true), (1.0, false)]);

    // A checkpoint keeps the skipped units as not done; restored, they are skipped again.
    let mut r = Job::loading("a".into(), "test".into());
    r.adaptive = Some(0.01);
    r.restore(Restored {
        width: 4,
        height: 2,
        spp: 256,
        tile_size: 2,
        batch_spp: 8,
        non_negative: true,
        units: j.records(),
        tiles: j.tile_accumulations().to_vec(),
        rays: 0,
        nonfinite: 0,
        cancelled: false,
        unconfirmed: Vec::new(),
    })
    .unwrap();
    assert_eq!(r.phase, JobPhase::Done);
    assert_eq!(r.units_total(), 40);
}

/// An adaptive job on a time budget keeps its tiles in step: a tile's batch two ahead
/// of another open tile's waits for it.
#[test]
fn adaptive_tiles_on_a_budget_stay_within_a_batch_of_each_other() {
    let mut j = Job::loading("a".into(), "test".into());
    (j.layers, j.adaptive, j.budget) = (true, Some(1e-6), Some(Duration::from_secs(3600)));
    j.start(4, 2, 256, 2, 8, true); // two tiles, 32 batches each
    let far = Instant::now() + NEVER;
    let lease = |j: &mut Job| j.lease_next(7, Instant::now(), far, Duration::MAX);
    let (a, b) = (lease(&mut j).unwrap(), lease(&mut j).unwrap());
    let merge =
        |j: &mut Job, id: UnitId| assert_eq!(j.apply(7, &layered_result(j, id, 0.5, true)), Ok(Applied::Merged));
    merge(&mut j, a);
    let a1 = lease(&mut j).expect("one batch ahead of the other tile: leased");
    assert_eq!(j.units[a1 as usize].samples.start, 8);
    merge(&mut j, a1);
    assert_eq!(lease(&mut j), None, "two batches ahead of a tile whose first is still out: waits");
    merge(&mut j, b);
    let next: Vec<u32> =
        [lease(&mut j).unwrap(), lease(&mut j).unwrap()].map(|id| j.units[id as usize].samples.start).into();
    assert_eq!(next, [8, 16], "the tile behind first, then the one ahead");
}

/// Once its time budget has passed, a job leases nothing more, and ends when the units
/// out are in: with what is done, and nothing thrown away.
#[test]
fn a_spent_time_budget_stops_leasing_and_ends_the_job_when_the_units_out_are_in() {
    let mut j = job();
    j.budget = Some(Duration::from_secs(3600));
    let now = Instant::now();
    let out = j.lease_next(7, now, now + NEVER, Duration::MAX).unwrap();
    let later = now + Duration::from_secs(3601);
    assert_eq!(j.lease_next(7, later, later + NEVER, Duration::MAX), None, "nothing is leased after the budget");
    assert_eq!(j.phase, JobPhase::Running, "a unit is still out");
    assert_eq!(j.apply(7, &result_for(&j, out, 5)), Ok(Applied::Merged));
    assert!(!j.budget_spent(now), "not yet spent at the start");
    assert!(j.budget_spent(later));
    assert_eq!(j.phase, JobPhase::Done);
    assert_eq!(j.units_done, 1, "the unit out was merged, not lost");
}
