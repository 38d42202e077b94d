//! The live dashboard in a real browser: headless Chromium (Debian's `chromium`, driven
//! by playwright-core from `tests/dashboard`, both installed by `.ci/run`) opens a farm's
//! page during a render of a real scene, sees the job and both workers, sees the image
//! change between two updates, writes a screenshot (`target/test-artifacts/`), and
//! cancels the job with the page's button; the farm then reports it cancelled.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(180);

fn browser_missing() -> Option<String> {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    if !Path::new("/usr/bin/chromium").exists() {
        return Some("no /usr/bin/chromium (Debian's chromium; .ci/run installs it)".into());
    }
    if !here.join("dashboard/node_modules/playwright-core").is_dir() {
        return Some("no tests/dashboard/node_modules (npm ci in tests/dashboard; .ci/run does it)".into());
    }
    None
}

#[test]
fn the_dashboard_shows_the_render_live_and_cancels_it() {
    if let Some(why) = browser_missing() {
        println!("SKIPPED: {why}");
        return;
    }
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = TempDir::new("dashboard");
    let http = format!("127.0.0.1:{}", free_port());
    let coord = Coordinator::start(&dir.path("store"), &["--http", &http]);
    let _w1 = coord.worker(1, &dir.path("cache-1"));
    let _w2 = coord.worker(1, &dir.path("cache-2"));
    // Long enough to watch (and to cancel): many small batches.
    let job = coord.submit_id(
        &scenes().join("cornell-box/scene.toml"),
        &["--width", "128", "--spp", "100000", "--tile", "32", "--batch-spp", "2", "--name", "watched-cornell"],
        LIMIT,
    );
    let artifacts = here.join("../target/test-artifacts");
    std::fs::create_dir_all(&artifacts).unwrap();
    let shot = artifacts.join("dashboard.png");
    let mut cmd = Command::new("node");
    cmd.arg(here.join("dashboard/drive.mjs")).arg(format!("http://{http}/")).arg("watched-cornell").arg(&shot);
    let out = run(&mut cmd, LIMIT);
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "the browser run failed:\n{said}\n{}", String::from_utf8_lossy(&out.stderr));
    println!("browser: {said}");
    assert!(std::fs::metadata(&shot).map(|m| m.len() > 10_000).unwrap_or(false), "a screenshot at {}", shot.display());

    // The page's latencies: from a batch merged on the coordinator to its image shown.
    let latencies: Vec<f64> = said
        .split("\"latencies_ms\":[")
        .nth(1)
        .and_then(|s| s.split(']').next())
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_default();
    assert!(!latencies.is_empty(), "the page measured no update");
    // The median, not every update: on a loaded two-core machine (workers, the browser
    // and a build sharing it) one update can wait behind the others; what must not
    // happen is images that trail their batches as a rule.
    let mut sorted = latencies.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    assert!(median < 1000.0, "images came later than 1 s after their batches (median {median} ms): {latencies:?}");

    let status = list_jobs(&coord.url).into_iter().find(|j| j.job_id == job).expect("the job is listed");
    assert_eq!(status.state, proto::JobState::Cancelled as i32, "the page's cancel reached the farm");
}
