//! Many jobs on one farm: running jobs share the workers by priority (weighted fair
//! share, measured on unit counts), a paused job gets no new units, and scheduling never
//! changes a pixel. Real `coordinator` and `worker` processes on 127.0.0.1.

use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(180);

/// 64 tiles × 16 batches: 1024 small units per job.
const JOB: [&str; 8] = ["--width", "64", "--spp", "64", "--tile", "8", "--batch-spp", "4"];

fn job(url: &str, id: &str) -> proto::JobStatus {
    list_jobs(url).into_iter().find(|j| j.job_id == id).unwrap_or_else(|| panic!("{id} is not listed"))
}

fn running(j: &proto::JobStatus) -> bool {
    j.state == proto::JobState::Running as i32
}

/// `coordinator update JOB ARGS…`, which must succeed.
fn update(coord: &Coordinator, id: &str, args: &[&str]) {
    let mut cmd = Command::new(bin("coordinator"));
    cmd.arg("update").arg(id).args(["--coordinator", &coord.url]).args(args);
    let o = run(&mut cmd, LIMIT);
    assert!(o.status.success(), "update {args:?}: {}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn jobs_share_workers_by_priority_and_a_paused_job_waits() {
    let dir = TempDir::new("sharing");
    let cornell = scenes().join("cornell-box/scene.toml");
    let reference = dir.path("reference.exr");
    render(&cornell, &reference, &[&JOB[..], &["--local-workers", "0"]].concat(), LIMIT);

    let coord = Coordinator::start(&dir.path("store"), &[]);
    let _worker = coord.worker(1, &dir.path("cache"));
    let a = coord.submit_id(&cornell, &[&JOB[..], &["--priority", "150", "--name", "urgent"]].concat(), LIMIT);
    let b = coord.submit_id(&cornell, &[&JOB[..], &["--name", "long"]].concat(), LIMIT);

    // Shares: from a moment when both run, the units each gets are 3 : 1.
    let mut first = (job(&coord.url, &a), job(&coord.url, &b));
    eventually("both jobs running and rendering", LIMIT, || {
        first = (job(&coord.url, &a), job(&coord.url, &b));
        running(&first.0) && running(&first.1) && first.0.units_done > 0 && first.1.units_done > 0
    });
    assert_eq!((first.0.priority, first.1.priority), (150, 50));
    assert_eq!((first.0.scene.as_str(), first.1.scene.as_str()), ("urgent", "long"));
    let mut later = first.clone();
    eventually("the urgent job rendering 300 more units", LIMIT, || {
        later = (job(&coord.url, &a), job(&coord.url, &b));
        later.0.units_done >= first.0.units_done + 300
    });
    let (da, db) = (later.0.units_done - first.0.units_done, later.1.units_done - first.1.units_done);
    let ratio = da as f64 / db.max(1) as f64;
    println!("units while both ran: {da} of priority 150, {db} of priority 50 (ratio {ratio:.2})");
    assert!((2.2..=4.0).contains(&ratio), "priority 150 against 50 should get about 3 units for 1: {da} : {db}");

    // Paused: the long job's units out finish, then it gets no more while the other runs.
    // Its count settles first (a second without a new unit): at the pause the worker may
    // hold 8 leased and 8 rendered units, and results on their way are merged after it.
    update(&coord, &b, &["--pause"]);
    let mut paused = job(&coord.url, &b);
    assert!(paused.paused);
    let at_pause = paused.units_done;
    let mut quiet_since = std::time::Instant::now();
    eventually("the paused job's units out finishing", LIMIT, || {
        let now = job(&coord.url, &b);
        if now.units_done != paused.units_done {
            (paused, quiet_since) = (now, std::time::Instant::now());
        }
        quiet_since.elapsed() >= Duration::from_secs(1)
    });
    // What settled is what was out, not a job that went on (or ran to its end) unpaused.
    assert!(
        paused.units_done <= at_pause + 48 && paused.units_done < paused.units_total,
        "the paused job went on: {at_pause} at the pause, {} of {} after",
        paused.units_done,
        paused.units_total
    );
    // Then 200 of the urgent job's units, or its end and half a second more (an idle
    // worker would render far more than 16 units of a job whose pause did not hold).
    let urgent = job(&coord.url, &a);
    let watched = std::time::Instant::now();
    eventually("the urgent job going on", LIMIT, || {
        let j = job(&coord.url, &a);
        j.units_done >= urgent.units_done + 200
            || (j.units_done == j.units_total && watched.elapsed() >= Duration::from_millis(500))
    });
    let still = job(&coord.url, &b);
    assert!(
        still.units_done <= paused.units_done + 16,
        "a paused job got new units: {} then {}",
        paused.units_done,
        still.units_done
    );
    update(&coord, &b, &["--resume", "--priority", "80"]);
    let resumed = job(&coord.url, &b);
    assert!(!resumed.paused && resumed.priority == 80);

    // Both finish with the in-process render's bits.
    for id in [&a, &b] {
        let out = dir.path(&format!("{id}.exr"));
        let mut cmd = Command::new(bin("coordinator"));
        cmd.arg("fetch").arg(id).args(["--coordinator", &coord.url, "-q", "-o"]).arg(&out);
        let o = run(&mut cmd, LIMIT);
        assert!(o.status.success(), "fetch {id}: {}", String::from_utf8_lossy(&o.stderr));
        assert_same_bits(&read_exr(&out), &read_exr(&reference), &format!("{id}, shared and paused"));
    }
}

#[test]
fn bad_priorities_and_changes_are_refused_with_the_reason() {
    let dir = TempDir::new("sharing-bad");
    let cornell = scenes().join("cornell-box/scene.toml");
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let sub = coord.submit(&cornell, &["--priority", "0"], LIMIT);
    assert!(!sub.status.success());
    assert!(String::from_utf8_lossy(&sub.stderr).contains("--priority"), "{}", String::from_utf8_lossy(&sub.stderr));
    let id = coord.submit_id(&cornell, &JOB, LIMIT);
    let mut cmd = Command::new(bin("coordinator"));
    cmd.arg("update").arg(&id).args(["--coordinator", &coord.url]);
    let none = run(&mut cmd, LIMIT);
    assert!(String::from_utf8_lossy(&none.stderr).contains("nothing to change"));
    eventually("the job running", LIMIT, || running(&job(&coord.url, &id)));
    let mut cmd = Command::new(bin("coordinator"));
    cmd.arg("update").arg(&id).args(["--coordinator", &coord.url, "--spp", "8"]);
    let fewer = run(&mut cmd, LIMIT);
    let err = String::from_utf8_lossy(&fewer.stderr);
    assert!(!fewer.status.success() && err.contains("already renders 64 spp"), "{err}");
}
