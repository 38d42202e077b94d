//! Trust per identity, on the farm's own bookkeeping: workers of one identity cannot
//! vouch for each other, a caught identity stays banned and leaves nothing in the
//! image, malformed results count against it, and registrations are capped.

use std::time::{Duration, Instant};

use super::*;
use crate::farm::job::{JobPhase, UnitResult};
use crate::farm::state::FarmConfig;
use crate::farm::state::tests::spec;
use crate::farm::verify::Policy;

/// What a worker returns for a unit whose true value is `truth`, given how many results
/// it returned before.
type Behaviour = fn(u64, i128) -> i128;

fn honest(_: u64, truth: i128) -> i128 {
    truth
}

/// A farm checking as `serve` does, with one running job of 64 units (8×8 tiles of
/// 4×4 pixels is 4 tiles; 16 batches of 1 spp each).
fn farm(fraction: f64, probation: u64) -> (Farm, String) {
    let verify = Policy::new(fraction, probation).unwrap();
    let mut f = Farm::new(FarmConfig { verify, ..FarmConfig::default() });
    let job = f.add_job("j".into(), None, spec());
    f.entry_mut(&job).unwrap().job.start(8, 8, 16, 4, 1, true);
    (f, job)
}

fn result(f: &Farm, job: &str, unit: u64, value: i128) -> UnitResult {
    let u = &f.entry(job).unwrap().job.units[unit as usize];
    let n = u.tile.pixel_count();
    UnitResult {
        unit,
        tile: u.tile,
        samples: u.samples,
        sums: vec![[value.max(0); 3]; n],
        counts: vec![u.samples.len(); n],
        layers: Vec::new(),
        nonfinite: 0,
        rays: 1,
        render_seconds: 0.0,
    }
}

/// Runs the job to its end: workers take turns in an order drawn from `seed`, each
/// leasing one unit and answering it as it behaves; the coordinator renders (truly)
/// what no live identity can check. Returns the image's sums.
fn run(f: &mut Farm, job: &str, workers: &[(WorkerId, Behaviour)], seed: u64) -> tracer::film::Image {
    let t = Instant::now();
    let mut counts = vec![0u64; workers.len()];
    let mut x = seed | 1;
    for step in 0..100_000 {
        if f.entry(job).unwrap().job.phase != JobPhase::Running {
            break;
        }
        assert!(step < 99_999, "the job never ended");
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let k = (x % workers.len() as u64) as usize;
        let (w, behave) = workers[k];
        for l in f.lease(w, 1, t).unwrap_or_default() {
            let value = behave(counts[k], 1000 + l.unit as i128);
            counts[k] += 1;
            let r = result(f, job, l.unit, value);
            let _ = f.submit(w, job, &r, t);
        }
        for d in f.take_disputes(t) {
            let r = result(f, &d.job, d.unit, 1000 + d.unit as i128);
            f.arbitrated(&d.job, d.unit, Some(&r), t);
        }
    }
    f.entry(job).unwrap().job.image()
}

/// The image of the same job rendered by honest workers alone.
fn honest_image() -> tracer::film::Image {
    let (mut f, job) = farm(0.0, 0);
    let w = f.register("h".into(), 1, Instant::now());
    run(&mut f, &job, &[(w, honest)], 1)
}

fn register(f: &mut Farm, identity: &str) -> WorkerId {
    f.register_as(Some(identity), true, "host".into(), 1, Instant::now()).unwrap()
}

fn banned(f: &Farm, identity: &str) -> bool {
    f.identities.iter().any(|i| i.name == identity && i.banned.is_some())
}

#[test]
fn three_workers_of_one_certificate_cannot_forge_an_image() {
    let reference = honest_image();
    for seed in 1..=5 {
        let (mut f, job) = farm(0.02, 16);
        let a = register(&mut f, "cert:honest-a");
        let b = register(&mut f, "cert:honest-b");
        let black: Behaviour = |_, _| 0;
        let liars: Vec<WorkerId> = (0..3).map(|_| register(&mut f, "cert:forger")).collect();
        let mut workers = vec![(a, honest as Behaviour), (b, honest)];
        workers.extend(liars.iter().map(|&w| (w, black)));
        let image = run(&mut f, &job, &workers, seed);
        assert!(image == reference, "seed {seed}: the image is the honest one");
        assert!(banned(&f, "cert:forger"), "seed {seed}");
        assert!(!banned(&f, "cert:honest-a") && !banned(&f, "cert:honest-b"), "seed {seed}: no honest identity");
        assert!(liars.iter().all(|w| f.quarantined(&f.workers[w])));
        // It may not come back under another registration.
        let again = f.register_as(Some("cert:forger"), true, "host".into(), 1, Instant::now());
        assert!(matches!(again, Err(FarmError::Forbidden(m)) if m.contains("banned")));
    }
}

/// A liar that answers honestly 4 times, then lies 5 times, then is honest again: a new
/// identity's first 16 results are all checked, so it is caught at its first lie, and
/// what it merged unconfirmed renders again.
#[test]
fn a_rare_liar_is_caught_within_its_probation_in_every_run() {
    let reference = honest_image();
    let rare: Behaviour = |n, truth| if (4..9).contains(&n) { truth + 7 } else { truth };
    for seed in 1..=20 {
        let (mut f, job) = farm(0.02, 16);
        let a = register(&mut f, "cert:a");
        let b = register(&mut f, "cert:b");
        let liar = register(&mut f, "cert:rare");
        let image = run(&mut f, &job, &[(a, honest), (b, honest), (liar, rare)], seed);
        assert!(image == reference, "seed {seed}");
        assert!(banned(&f, "cert:rare") && !banned(&f, "cert:a") && !banned(&f, "cert:b"), "seed {seed}");
    }
}

/// Two identities that disagree, and no third: the coordinator's render decides.
#[test]
fn with_two_identities_the_coordinator_decides_a_disagreement() {
    let reference = honest_image();
    let (mut f, job) = farm(0.02, 16);
    let a = register(&mut f, "cert:a");
    let liar = register(&mut f, "cert:liar");
    let image = run(&mut f, &job, &[(a, honest), (liar, |_, t| t + 1)], 3);
    assert!(image == reference);
    assert!(banned(&f, "cert:liar") && !banned(&f, "cert:a"));
}

#[test]
fn malformed_results_ban_their_identity_and_free_the_unit_at_once() {
    let (mut f, job) = farm(0.02, 16);
    let t = Instant::now();
    let w = register(&mut f, "cert:broken");
    for n in 0..MAX_REFUSED {
        let l = f.lease(w, 1, t).unwrap().pop().unwrap();
        let mut r = result(&f, &job, l.unit, 1000);
        r.counts[0] += 1;
        assert!(matches!(f.submit(w, &job, &r, t), Err(FarmError::Rejected(_))));
        let u = &f.entry(&job).unwrap().job.units[l.unit as usize];
        assert!(n + 1 == MAX_REFUSED || u.state == crate::farm::job::UnitState::Pending, "released at once");
    }
    assert!(banned(&f, "cert:broken"));
    assert!(matches!(f.lease(w, 1, t), Err(FarmError::Forbidden(_))));
}

#[test]
fn an_identity_registers_at_most_its_share_of_workers_and_admins_any() {
    let (mut f, _) = farm(0.02, 16);
    f.config.max_workers_per_identity = 3;
    for _ in 0..3 {
        register(&mut f, "cert:a");
    }
    let refused = f.register_as(Some("cert:a"), true, "h".into(), 1, Instant::now()).unwrap_err();
    assert!(refused.to_string().contains("--max-workers-per-identity 3"), "{refused}");
    for _ in 0..5 {
        f.register_as(Some("admin"), false, "h".into(), 1, Instant::now()).unwrap();
    }
    // Silent ones are forgotten, and make room.
    f.reap(Instant::now() + Duration::from_secs(3600));
    register(&mut f, "cert:a");
}

/// A hoarder with all the ids it may register takes at most an even share of a small
/// job while other identities are live; they get the rest, and spares of its units go
/// only to them.
#[test]
fn a_hoarder_takes_at_most_its_share_and_never_its_own_spares() {
    let (mut f, job) = farm(0.0, 0);
    // Leases that outlast the test: the hoarder renews its leases forever.
    f.config.lease = Duration::from_secs(600);
    let t = Instant::now();
    let a = f.register_as(Some("cert:a"), true, "a".into(), 16, t).unwrap();
    let b = f.register_as(Some("cert:b"), true, "b".into(), 16, t).unwrap();
    let hoarder: Vec<WorkerId> = (0..8).map(|_| register(&mut f, "cert:hoarder")).collect();
    let hoarded: usize = hoarder.iter().map(|&w| f.lease(w, 256, t).unwrap().len()).sum();
    assert_eq!(hoarded, 64usize.div_ceil(3), "an even share of 64 units among 3 identities");
    let mut rest = 0;
    for w in [a, b].into_iter().cycle().take(8) {
        for l in f.lease(w, 256, t).unwrap() {
            let r = result(&f, &job, l.unit, 1000 + l.unit as i128);
            f.submit(w, &job, &r, t).unwrap();
            rest += 1;
        }
    }
    assert_eq!(hoarded + rest, 64, "the honest identities render the rest");
    // Long after, with the queue empty, spares of the hoarded units go to the honest
    // identities only, and the job ends without the hoarder.
    let later = t + Duration::from_secs(30);
    assert!(hoarder.iter().all(|&w| f.lease(w, 256, later).unwrap().is_empty()));
    while f.entry(&job).unwrap().job.phase == JobPhase::Running {
        let spares = f.lease(a, 8, later).unwrap();
        assert!(!spares.is_empty(), "spares of the hoarder's units");
        for l in spares {
            let r = result(&f, &job, l.unit, 1000 + l.unit as i128);
            f.submit(a, &job, &r, later).unwrap();
        }
    }
}

/// What an identity returned unconfirmed is kept by name with the job's checkpoint; an
/// identity banned by then (its ban outlives the restart) has those units rendered again.
#[test]
fn units_a_banned_identity_returned_unconfirmed_are_thrown_away_after_a_restart() {
    let (mut f, job) = farm(0.0, 0);
    let t = Instant::now();
    let liar = register(&mut f, "cert:liar");
    let honest = register(&mut f, "cert:honest");
    for (w, n) in [(liar, 3), (honest, 2)] {
        for l in f.lease(w, n, t).unwrap() {
            let r = result(&f, &job, l.unit, 1000 + l.unit as i128);
            f.submit(w, &job, &r, t).unwrap();
        }
    }
    let kept = f.unconfirmed_names(&f.entry(&job).unwrap().job);
    assert_eq!(
        kept.iter().map(|(n, u)| (n.as_str(), u.len())).collect::<Vec<_>>(),
        [("cert:liar", 3), ("cert:honest", 2)]
    );
    // After a restart: the liar banned (its ban read back), the units restored done.
    let (mut after, job2) = farm(0.0, 0);
    let id = after.identities.named("cert:liar", t).id;
    after.identities.ban(id, "lied".into());
    let units: Vec<u64> = kept[0].1.clone();
    let j = &mut after.entry_mut(&job2).unwrap().job;
    for &u in &units {
        let r = {
            let unit = &j.units[u as usize];
            let n = unit.tile.pixel_count();
            UnitResult {
                unit: u,
                tile: unit.tile,
                samples: unit.samples,
                sums: vec![[1; 3]; n],
                counts: vec![unit.samples.len(); n],
                layers: Vec::new(),
                nonfinite: 0,
                rays: 1,
                render_seconds: 0.0,
            }
        };
        j.lease_next(1, t, t + Duration::from_secs(60), Duration::MAX);
        j.units[u as usize].holders.push(1);
        j.apply(1, &r).unwrap();
    }
    j.mark_unconfirmed(id, &units);
    let done = j.units_done;
    assert_eq!(j.discard_from(id, &[]), units.len() as u64);
    assert!(j.units_done < done);
}
