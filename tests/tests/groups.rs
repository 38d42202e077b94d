//! Job groups (animations) on a real farm: `submit PATTERN --frames A-B` makes one group
//! of frames. Frames start in order, a few at a time, the rest queued; `status`,
//! `fetch`, `cancel` and `update` take the group's name; a killed and restarted coordinator
//! brings every frame back from its checkpoints, the queued ones too, and finishes them;
//! a group finished before the restart is still fetched by its name from the stored images.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::{
    Coordinator, TempDir, assert_same_bits, bin, eventually, free_port, list_jobs, read_exr, run, scenes,
};

const LIMIT: Duration = Duration::from_secs(180);
/// `farm::groups::FRAMES_IN_FLIGHT`.
const IN_FLIGHT: usize = 3;

/// Frames `1..=n` of the Cornell box as `DIR/NAME.####.toml`, each with its own seed.
fn frames(dir: &Path, name: &str, n: u32) -> PathBuf {
    let src = scenes().join("cornell-box");
    for f in ["cbox.obj", "cbox.mtl"] {
        std::fs::copy(src.join(f), dir.join(f)).unwrap();
    }
    let toml = std::fs::read_to_string(src.join("scene.toml")).unwrap();
    assert!(toml.contains("seed      = 0"), "the Cornell box's seed line moved");
    for i in 1..=n {
        let frame = toml.replace("seed      = 0", &format!("seed      = {i}"));
        std::fs::write(dir.join(format!("{name}.{i:04}.toml")), frame).unwrap();
    }
    dir.join(format!("{name}.####.toml"))
}

fn coordinator(url: &str, args: &[&str]) -> std::process::Output {
    run(Command::new(bin("coordinator")).args(args).args(["--coordinator", url]), LIMIT)
}

/// The group's frames as listed, in frame order.
fn group(url: &str, name: &str) -> Vec<proto::JobStatus> {
    let mut jobs: Vec<_> = list_jobs(url).into_iter().filter(|j| j.group == name).collect();
    jobs.sort_by(|a, b| a.scene.cmp(&b.scene));
    jobs
}

fn state(j: &proto::JobStatus) -> proto::JobState {
    proto::JobState::try_from(j.state).unwrap()
}

/// At most [`IN_FLIGHT`] frames loading or running, and the queued frames after all
/// the others (frames start in order).
fn check_order(frames: &[proto::JobStatus]) {
    use proto::JobState::{Loading, Queued, Running};
    let in_flight = frames.iter().filter(|f| matches!(state(f), Loading | Running)).count();
    assert!(in_flight <= IN_FLIGHT, "{in_flight} frames in flight: {frames:?}");
    let first_queued = frames.iter().position(|f| state(f) == Queued).unwrap_or(frames.len());
    assert!(frames[first_queued..].iter().all(|f| state(f) == Queued), "a frame started before an earlier one");
}

fn all_done(url: &str, name: &str, n: usize) -> bool {
    let frames = group(url, name);
    check_order(&frames);
    frames.len() == n && frames.iter().all(|f| state(f) == proto::JobState::Done)
}

#[test]
fn a_job_group_renders_in_order_is_cancelled_by_name_and_survives_a_restart() {
    let dir = TempDir::new("groups");
    let port = free_port();
    let listen = format!("127.0.0.1:{port}");
    // The checkpoint folder keeps the scene files too.
    let ckpt = dir.path("ckpt");
    let args: Vec<String> =
        ["--listen", &listen, "--checkpoint-interval-ms", "100", "--checkpoint", ckpt.to_str().unwrap()]
            .iter()
            .map(|s| s.to_string())
            .collect();
    let coord = Coordinator::serve(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let url = coord.url.clone();
    let _worker = coord.retrying_worker(&dir.path("cache"));
    let small = ["--width", "48", "--height", "48", "--spp", "256", "-q"];

    // 1. Six frames: in order, three at a time, the rest queued; `status NAME` says so.
    let pattern = frames(&dir.0, "walk", 6);
    let out = coordinator(&url, &[&["submit", pattern.to_str().unwrap(), "--frames", "1-6"], &small[..]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let listed = group(&url, "walk");
    assert_eq!(listed.len(), 6);
    check_order(&listed);
    assert!(listed.iter().any(|f| state(f) == proto::JobState::Queued), "frames 4-6 wait: {listed:?}");
    let status = coordinator(&url, &["status", "walk"]);
    let text = String::from_utf8_lossy(&status.stdout);
    assert!(text.contains("group walk: 6 frames") && text.contains("queued"), "{text}");
    eventually("the group renders", LIMIT, || all_done(&url, "walk", 6));
    // `fetch NAME` writes every frame, numbered; the same bits as fetching the frame alone.
    let out = coordinator(&url, &["fetch", "walk", "-q", "-o", dir.path("walk.####.exr").to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let third = &group(&url, "walk")[2].job_id;
    let out = coordinator(&url, &["fetch", third, "-q", "-o", dir.path("third.exr").to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!((1..=6).all(|n| dir.path(&format!("walk.{n:04}.exr")).is_file()));
    assert_same_bits(&read_exr(&dir.path("walk.0003.exr")), &read_exr(&dir.path("third.exr")), "frame 3");
    assert_ne!(read_exr(&dir.path("walk.0001.exr")).pixels, read_exr(&dir.path("walk.0002.exr")).pixels);

    // 2. A group cancelled by its name: every frame not yet done ends, none starts after.
    let pattern = frames(&dir.0, "pan", 6);
    let slow = ["--width", "96", "--height", "96", "--spp", "1024", "-q"];
    let out = coordinator(&url, &[&["submit", pattern.to_str().unwrap(), "--frames", "1-6"], &slow[..]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = coordinator(&url, &["cancel", "pan"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).lines().count() >= 4, "one line per frame cancelled");
    let after = group(&url, "pan");
    assert!(after.iter().all(|f| state(f) == proto::JobState::Cancelled), "{after:?}");
    std::thread::sleep(Duration::from_millis(300));
    assert!(group(&url, "pan").iter().all(|f| state(f) == proto::JobState::Cancelled), "a cancelled frame started");
    // Cancelled again, the group has nothing left to cancel, and says so.
    let out = coordinator(&url, &["cancel", "pan"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("group pan: 6 frames (6 cancelled)") && text.contains("nothing to cancel"), "{text:?}");

    // 3. Killed while frames are queued; restarted, the farm brings them all back.
    let pattern = frames(&dir.0, "orbit", 5);
    let medium = ["--width", "64", "--height", "64", "--spp", "1024", "-q"];
    let out = coordinator(&url, &[&["submit", pattern.to_str().unwrap(), "--frames", "1-5"], &medium[..]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    eventually("the first frame progresses", LIMIT, || group(&url, "orbit").first().is_some_and(|f| f.units_done > 0));
    // Checkpoints are paced by what writing them costs: wait until every frame has one.
    let ids: Vec<String> = group(&url, "orbit").into_iter().map(|f| f.job_id).collect();
    let saved = |id: &String| ckpt.join("job-checkpoints").join(id).join("checkpoint.tfck").is_file();
    eventually("every frame is checkpointed", LIMIT, || ids.iter().all(saved));
    let queued_before = group(&url, "orbit").iter().filter(|f| state(f) == proto::JobState::Queued).count();
    assert!(queued_before > 0, "frames were queued when the coordinator was killed");
    drop(coord);
    let coord = Coordinator::serve(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let back = group(&coord.url, "orbit");
    assert_eq!(back.len(), 5, "every frame is back, the queued ones too: {back:?}");
    check_order(&back);
    eventually("the restored group renders", LIMIT, || all_done(&coord.url, "orbit", 5));
    let totals: Vec<u64> = group(&coord.url, "orbit").iter().map(|f| f.samples_total).collect();
    assert_eq!(totals, [64 * 64 * 1024; 5], "every frame at the spp it was submitted with");

    // 4. The group finished before the restart is no longer listed, but its images are
    // stored: `fetch NAME` still writes every frame, the same bits as before.
    assert!(group(&coord.url, "walk").is_empty(), "finished jobs are not restored");
    let status = coordinator(&coord.url, &["status", "walk"]);
    let text = String::from_utf8_lossy(&status.stdout);
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    assert!(text.contains("group walk: 6 frames (6 done)") && text.contains("image stored"), "{text}");
    // So is one frame, asked for by its job id.
    let status = coordinator(&coord.url, &["status", third]);
    let text = String::from_utf8_lossy(&status.stdout);
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    assert!(text.contains(third.as_str()) && text.contains("walk.0003") && text.contains("image stored"), "{text}");
    let status = coordinator(&coord.url, &["status", "job-999"]);
    assert!(
        !status.status.success() && String::from_utf8_lossy(&status.stderr).contains("no job or job group job-999")
    );
    let out = coordinator(&coord.url, &["fetch", "walk", "-q", "-o", dir.path("again.####.exr").to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for n in 1..=6 {
        let (before, after) = (dir.path(&format!("walk.{n:04}.exr")), dir.path(&format!("again.{n:04}.exr")));
        assert_same_bits(&read_exr(&before), &read_exr(&after), &format!("frame {n} after the restart"));
    }
    assert!(!dir.path("again.0007.exr").exists());
}

/// A submitted frame is checkpointed at once, not when the pacer is next due (it can wait
/// many seconds after a slow write): until its first checkpoint, a crash would lose it.
#[test]
fn frames_are_checkpointed_as_soon_as_they_are_submitted() {
    let dir = TempDir::new("groups-first-checkpoint");
    let listen = format!("127.0.0.1:{}", free_port());
    let ckpt = dir.path("ckpt");
    // A pacing interval far longer than the test: only the first writes can happen.
    let coord = Coordinator::serve(&[
        "--listen",
        &listen,
        "--checkpoint-interval-ms",
        "600000",
        "--checkpoint",
        ckpt.to_str().unwrap(),
    ]);
    let pattern = frames(&dir.0, "still", 5);
    let small = ["--width", "32", "--height", "32", "--spp", "4", "-q"];
    let out =
        coordinator(&coord.url, &[&["submit", pattern.to_str().unwrap(), "--frames", "1-5"], &small[..]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let ids: Vec<String> = group(&coord.url, "still").into_iter().map(|f| f.job_id).collect();
    assert_eq!(ids.len(), 5);
    let saved = |id: &String| ckpt.join("job-checkpoints").join(id).join("checkpoint.tfck").is_file();
    eventually("every frame is checkpointed, the queued ones too", Duration::from_secs(30), || ids.iter().all(saved));
}
