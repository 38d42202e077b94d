//! Nothing lost: workers killed or frozen mid-render, the coordinator killed and
//! resumed, damaged checkpoints, and more samples added later — each must end in the
//! same bits as an undisturbed render.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(240);

fn cornell() -> std::path::PathBuf {
    scenes().join("cornell-box/scene.toml")
}

/// Long enough (hundreds of units) that faults land mid-render.
const JOB: [&str; 8] = ["--width", "96", "--spp", "64", "--tile", "16", "--batch-spp", "4"];

fn reference(dir: &TempDir, args: &[&str]) -> tracer::film::Image {
    let out = dir.path("reference.exr");
    render(&cornell(), &out, &[args, &["--local-workers", "0"]].concat(), LIMIT);
    read_exr(&out)
}

/// Every file below `dir` with its size, for failure messages.
fn files_under(dir: &Path) -> Vec<(std::path::PathBuf, u64)> {
    let mut found = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            match e.metadata() {
                Ok(m) if m.is_dir() => todo.push(e.path()),
                Ok(m) => found.push((e.path(), m.len())),
                Err(_) => {}
            }
        }
    }
    found
}

fn signal(pid: u32, sig: &str) {
    let ok = Command::new("kill").args([sig, &pid.to_string()]).status().unwrap().success();
    assert!(ok, "kill {sig} {pid}");
}

fn wait_for_progress(url: &str, fraction: f64) -> proto::JobStatus {
    tilefarm_e2e::wait_for_progress(url, fraction, LIMIT)
}

fn submit_wait(coord: &Coordinator, out: &Path) -> Proc {
    submit_wait_with(coord, out, &JOB)
}

fn submit_wait_with(coord: &Coordinator, out: &Path, job: &[&str]) -> Proc {
    let mut cmd = Command::new(bin("coordinator"));
    cmd.arg("submit").arg(cornell()).args(["--coordinator", &coord.url, "--wait", "-q", "-o"]).arg(out).args(job);
    Proc::spawn("submit --wait", &mut cmd)
}

#[test]
fn a_worker_killed_mid_render_loses_nothing() {
    killed_worker_loses_nothing("kill-worker", &JOB);
}

/// Adaptive sampling decides from merged sums alone: a killed worker's units render
/// again elsewhere, and the image (and where its samples went) is the in-process one.
#[test]
fn a_worker_killed_mid_adaptive_render_loses_nothing() {
    // Up to 256 spp: a tile is judged from 64 on, and some go on past it.
    let job = ["--width", "96", "--spp", "256", "--tile", "16", "--batch-spp", "16", "--adaptive", "--noise", "0.05"];
    killed_worker_loses_nothing("kill-worker-adaptive", &job);
}

fn killed_worker_loses_nothing(tag: &str, job: &[&str]) {
    let dir = TempDir::new(tag);
    let expected = reference(&dir, job);
    let coord = Coordinator::start(&dir.path("store"), &["--lease-ms", "1000", "--heartbeat-ms", "250"]);
    let victim = coord.worker(1, &dir.path("cache-a"));
    let _other = coord.worker(1, &dir.path("cache-b"));
    let out = dir.path("farm.exr");
    let mut submit = submit_wait_with(&coord, &out, job);
    let at = wait_for_progress(&coord.url, 0.25);
    assert!(at.units_done < at.units_total, "finished before the kill");
    signal(victim.pid(), "-KILL");
    assert!(submit.wait(LIMIT).success());
    let j = list_jobs(&coord.url).remove(0);
    assert_eq!((j.units_done, j.samples_done), (j.units_total, j.samples_total));
    assert_same_bits(&read_exr(&out), &expected, "after a worker was killed");
    if job.contains(&"--adaptive") {
        let (least, most) = (expected.counts.iter().min(), expected.counts.iter().max());
        assert!(least < most, "some tiles converged before others ({least:?}, {most:?})");
    }
}

#[test]
fn a_frozen_worker_past_its_lease_counts_nothing_twice() {
    let dir = TempDir::new("freeze-worker");
    let expected = reference(&dir, &JOB);
    let coord = Coordinator::start(&dir.path("store"), &["--lease-ms", "1000", "--heartbeat-ms", "250"]);
    let frozen = coord.worker(1, &dir.path("cache-a"));
    let _other = coord.worker(1, &dir.path("cache-b"));
    let out = dir.path("farm.exr");
    let mut submit = submit_wait(&coord, &out);
    wait_for_progress(&coord.url, 0.2);
    signal(frozen.pid(), "-STOP");
    std::thread::sleep(Duration::from_millis(2500)); // well past its 1 s lease
    signal(frozen.pid(), "-CONT");
    assert!(submit.wait(LIMIT).success());
    let j = list_jobs(&coord.url).remove(0);
    assert_eq!((j.units_done, j.samples_done), (j.units_total, j.samples_total), "no unit counted twice");
    assert_same_bits(&read_exr(&out), &expected, "after a worker was frozen");
}

/// Parses `units: D from checkpoint + R rendered = T` from a render's output.
fn units_line(stdout: &str) -> (u64, u64, u64) {
    let line = stdout.lines().find(|l| l.contains("units: ")).unwrap_or_else(|| panic!("no units line in {stdout}"));
    let rest = &line[line.find("units: ").unwrap() + 7..];
    let nums: Vec<u64> = rest
        .split(|c: char| !c.is_ascii_digit())
        .filter(|s| !s.is_empty())
        .take(3)
        .map(|s| s.parse().unwrap())
        .collect();
    (nums[0], nums[1], nums[2])
}

/// The `resuming from …: D of T units done` line, if the run resumed.
fn resumed_line(stderr: &str) -> Option<u64> {
    let line = stderr.lines().find(|l| l.starts_with("resuming from"))?;
    let after = &line[line.rfind(": ").unwrap() + 2..];
    after.split_whitespace().next()?.parse().ok()
}

#[test]
fn a_coordinator_killed_at_random_points_resumes_to_the_same_bits() {
    let dir = TempDir::new("kill-coordinator");
    let args = ["--width", "128", "--spp", "64", "--tile", "16", "--batch-spp", "4"];
    let expected = reference(&dir, &args);
    let ckpt = dir.path("ckpt");
    let render_cmd = || {
        let mut cmd = Command::new(bin("coordinator"));
        cmd.arg("render")
            .arg(cornell())
            .args(["-q", "--local-workers", "1", "--threads", "2", "--checkpoint-interval-ms", "100", "--checkpoint"])
            .arg(&ckpt)
            .arg("-o")
            .arg(dir.path("out.exr"))
            .args(args);
        cmd
    };
    // Deterministic "random" kill times.
    let mut x: u64 = 0x2545_F491_4F6C_DD1D;
    let mut done_before = 0;
    for round in 0..3 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let delay = Duration::from_millis(400 + x % 900);
        let log = dir.path(&format!("round{round}.log"));
        let mut cmd = render_cmd();
        cmd.stdout(std::process::Stdio::null()).stderr(std::fs::File::create(&log).unwrap());
        let mut p = Proc::spawn("render --checkpoint", &mut cmd);
        std::thread::sleep(delay);
        if p.child.try_wait().unwrap().is_some() {
            break; // finished before the kill
        }
        signal(p.pid(), "-KILL");
        p.wait(Duration::from_secs(10));
        // Each run starts from what the last one checkpointed: never less.
        let resumed = resumed_line(&std::fs::read_to_string(&log).unwrap()).unwrap_or(0);
        assert!(resumed >= done_before, "round {round}: checkpoint went back from {done_before} to {resumed}");
        eprintln!("round {round}: killed after {delay:?}; that run had resumed from {resumed} units");
        done_before = resumed;
        std::thread::sleep(Duration::from_millis(200)); // its workers see their stdin close and exit
    }
    // Resume until done; the run reports what the checkpoint held and what it rendered.
    let out = run(&mut render_cmd(), LIMIT);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (from_checkpoint, rendered, total) = units_line(&String::from_utf8_lossy(&out.stdout));
    assert_eq!(resumed_line(&String::from_utf8_lossy(&out.stderr)).unwrap_or(0), from_checkpoint);
    assert!(from_checkpoint >= done_before);
    eprintln!("final run: {from_checkpoint} units from the checkpoint + {rendered} rendered = {total}");
    assert_eq!(from_checkpoint + rendered, total, "units done in the checkpoint were not rendered again");
    assert_same_bits(&read_exr(&dir.path("out.exr")), &expected, "after coordinator kills");
    // A finished checkpoint resumes to the same image without rendering anything.
    let again =
        run(Command::new(bin("coordinator")).args(["resume", "-q", "-o"]).arg(dir.path("again.exr")).arg(&ckpt), LIMIT);
    assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
    let (_, rendered, _) = units_line(&String::from_utf8_lossy(&again.stdout));
    assert_eq!(rendered, 0);
    assert_same_bits(&read_exr(&dir.path("again.exr")), &expected, "resume of a finished checkpoint");
}

#[test]
fn damaged_or_foreign_checkpoints_are_refused() {
    let dir = TempDir::new("bad-ckpt");
    let ckpt = dir.path("ckpt");
    let args = ["--width", "48", "--spp", "8", "--local-workers", "0"];
    let mut good = Command::new(bin("coordinator"));
    good.arg("render")
        .arg(cornell())
        .arg("-q")
        .arg("--checkpoint")
        .arg(&ckpt)
        .arg("-o")
        .arg(dir.path("a.exr"))
        .args(args);
    assert!(run(&mut good, LIMIT).status.success());
    let file = ckpt.join("checkpoint.tfck");
    let bytes = std::fs::read(&file).unwrap();
    let try_resume =
        || run(Command::new(bin("coordinator")).args(["resume", "-q", "-o"]).arg(dir.path("b.exr")).arg(&ckpt), LIMIT);

    std::fs::write(&file, &bytes[..bytes.len() / 2]).unwrap();
    let out = try_resume();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("refused") && err.contains("truncated or corrupt"), "{err}");

    let mut flipped = bytes.clone();
    flipped[bytes.len() / 3] ^= 0x40;
    std::fs::write(&file, &flipped).unwrap();
    let out = try_resume();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("refused"), "{err}");

    std::fs::write(&file, &bytes).unwrap();
    let mut other = Command::new(bin("coordinator"));
    other
        .arg("render")
        .arg(scenes().join("cube/scene.toml"))
        .arg("-q")
        .arg("--checkpoint")
        .arg(&ckpt)
        .arg("-o")
        .arg(dir.path("c.exr"))
        .args(args);
    let out = run(&mut other, LIMIT);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("different scene"), "{err}");
    assert!(!err.contains("panicked"));
    // The intact checkpoint still resumes.
    assert!(try_resume().status.success());
}

#[test]
fn more_samples_later_equal_a_fresh_render() {
    let dir = TempDir::new("extend");
    let ckpt = dir.path("ckpt");
    let base = ["--width", "64", "--tile", "16", "--batch-spp", "16", "--local-workers", "1"];
    let step = |spp: &str, out: &str| {
        let mut cmd = Command::new(bin("coordinator"));
        cmd.arg("render").arg(cornell()).arg("-q").arg("--checkpoint").arg(&ckpt).arg("-o").arg(dir.path(out));
        cmd.args(base).args(["--spp", spp]);
        let o = run(&mut cmd, LIMIT);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        units_line(&String::from_utf8_lossy(&o.stdout))
    };
    assert_eq!(step("16", "16.exr"), (0, 16, 16));
    assert_eq!(step("64", "64.exr"), (16, 48, 64), "only the new batches are rendered");
    let fresh = dir.path("fresh.exr");
    render(&cornell(), &fresh, &[&base[..], &["--spp", "64"]].concat(), LIMIT);
    assert_same_bits(&read_exr(&dir.path("64.exr")), &read_exr(&fresh), "16 spp extended to 64");
}

#[test]
fn a_farm_stopped_with_ctrl_c_checkpoints_and_continues_after_restart() {
    let dir = TempDir::new("serve-restart");
    let expected = reference(&dir, &JOB);
    let ckpt = dir.path("ckpt");
    let listen = format!("127.0.0.1:{}", free_port());
    let serve_args =
        ["--listen", listen.as_str(), "--checkpoint", ckpt.to_str().unwrap(), "--checkpoint-interval-ms", "200"];
    let mut first = Coordinator::serve(&serve_args);
    let _worker = first.retrying_worker(&dir.path("cache"));
    let job = first.submit_id(&cornell(), &JOB, LIMIT);
    let at_stop = wait_for_progress(&first.url, 0.3);
    assert!(at_stop.units_done < at_stop.units_total, "finished before the stop");
    signal(first.proc.pid(), "-INT");
    assert!(first.proc.wait(Duration::from_secs(30)).success(), "a clean stop");
    // Back on the same address: the job is restored with at least what was done, and
    // the worker that kept retrying finishes it.
    let second = Coordinator::serve(&serve_args);
    let start = Instant::now();
    let restored = loop {
        let Some(j) = list_jobs(&second.url).into_iter().find(|j| j.job_id == job) else {
            // Say what the stop left behind, so that a failure here can be told apart
            // (no checkpoint written, or one the restart refused: its error is above).
            panic!(
                "{job} was not restored ({} of {} units done at the stop); the checkpoint folder holds {:?}",
                at_stop.units_done,
                at_stop.units_total,
                files_under(&ckpt.join("job-checkpoints"))
            );
        };
        if j.state() != proto::JobState::Loading {
            break j;
        }
        assert!(start.elapsed() < LIMIT);
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(restored.units_done >= at_stop.units_done, "{} < {}", restored.units_done, at_stop.units_done);
    let out = dir.path("out.exr");
    let fetch = run(
        Command::new(bin("coordinator")).args(["fetch", &job, "--coordinator", &second.url, "-q", "-o"]).arg(&out),
        LIMIT,
    );
    assert!(fetch.status.success(), "{}", String::from_utf8_lossy(&fetch.stderr));
    let j = list_jobs(&second.url).into_iter().find(|j| j.job_id == job).unwrap();
    assert_eq!((j.units_done, j.samples_done), (j.units_total, j.samples_total));
    assert_same_bits(&read_exr(&out), &expected, "across a coordinator restart");
}

/// A farm killed with SIGKILL (no chance to checkpoint on the way out) redoes at most
/// one checkpoint interval of work: what was done one interval and a write before the
/// kill is restored.
#[test]
fn a_farm_killed_outright_loses_at_most_one_checkpoint_interval() {
    const LONG: [&str; 8] = ["--width", "128", "--spp", "256", "--tile", "16", "--batch-spp", "4"];
    let dir = TempDir::new("serve-sigkill");
    let ckpt = dir.path("ckpt");
    let listen = format!("127.0.0.1:{}", free_port());
    let interval = Duration::from_millis(500);
    let ms = interval.as_millis().to_string();
    let serve_args =
        ["--listen", listen.as_str(), "--checkpoint", ckpt.to_str().unwrap(), "--checkpoint-interval-ms", &ms];
    let first = Coordinator::serve(&serve_args);
    let _worker = first.retrying_worker(&dir.path("cache"));
    let job = first.submit_id(&cornell(), &LONG, LIMIT);
    let seen = wait_for_progress(&first.url, 0.2);
    // One interval, and as long again for the write to land.
    std::thread::sleep(2 * interval + Duration::from_millis(200));
    let before_kill = list_jobs(&first.url).into_iter().find(|j| j.job_id == job).unwrap();
    assert!(before_kill.units_done < before_kill.units_total, "finished before the kill");
    signal(first.proc.pid(), "-KILL");
    drop(first);
    let second = Coordinator::serve(&serve_args);
    let start = Instant::now();
    let restored = loop {
        let j = list_jobs(&second.url).into_iter().find(|j| j.job_id == job).expect("the job is restored");
        if j.state() != proto::JobState::Loading {
            break j;
        }
        assert!(start.elapsed() < LIMIT);
        std::thread::sleep(Duration::from_millis(20));
    };
    eprintln!(
        "units done: {} seen, {} at the kill {:?} later, {} restored",
        seen.units_done,
        before_kill.units_done,
        2 * interval + Duration::from_millis(200),
        restored.units_done
    );
    assert!(restored.units_done >= seen.units_done, "{} < {}", restored.units_done, seen.units_done);
}
