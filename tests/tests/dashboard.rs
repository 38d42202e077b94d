//! The live dashboard in a real browser: headless Chromium (Debian's `chromium`, driven
//! by playwright-core from `tests/dashboard`, both installed by `.ci/run`) opens a farm's
//! page during a render of a real scene, sees the job and both workers, sees the image
//! change between two updates, writes a screenshot (`target/test-artifacts/`), shows
//! the noise and sample-count views with their legends, and
//! cancels the job with the page's button; the farm then reports it cancelled.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::*;
use tracer::output::views::{View, view_png};

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
        skipped(why);
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
        &[
            "--width",
            "128",
            "--spp",
            "100000",
            "--tile",
            "32",
            "--batch-spp",
            "2",
            "--aovs",
            "--name",
            "watched-cornell",
        ],
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
    for view in ["noise", "samples"] {
        let legend = said.split(&format!("\"{view}\":\"")).nth(1).and_then(|s| s.split('"').next()).unwrap_or("");
        assert!(
            legend.contains(if view == "noise" { "relative error" } else { "samples per pixel" }),
            "{view}: {said}"
        );
    }
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

/// The dashboard's noise and sample-count views of an adaptive render, over plain HTTP:
/// each is exactly the view of the EXR the farm wrote (the same PNG bytes), the samples
/// went unevenly (adaptive sampling stopped some tiles early), and every tile that
/// stopped early has its noise (its pixels' RMS relative error) at or under the target
/// in the written image. The job has finished, so these views come from its stored EXR,
/// as a finished job's do.
#[test]
fn the_dashboards_views_show_the_noise_and_where_the_samples_went() {
    let dir = TempDir::new("dashboard-views");
    let http = format!("127.0.0.1:{}", free_port());
    let coord = Coordinator::start(&dir.path("store"), &["--http", &http]);
    let _w = coord.worker(2, &dir.path("cache"));
    let out = dir.path("out.exr");
    let noise = f64::from(0.05f32); // the job keeps its target as an f32
    let args = ["--width", "64", "--spp", "256", "--tile", "16", "--batch-spp", "16", "--adaptive", "--noise", "0.05"];
    let args = [&args[..], &["--name", "views", "--wait", "-o", out.to_str().unwrap()]].concat();
    let sub = coord.submit(&scenes().join("cornell-box/scene.toml"), &args, LIMIT);
    assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
    let job = list_jobs(&coord.url).into_iter().next().expect("the job is listed").job_id;
    let written = read_exr(&out);
    // Once stored, the finished job's sums leave memory (its tiles list empties).
    let tiles = format!("/api/jobs/{job}/tiles");
    eventually("the finished job stored", LIMIT, || http_get(&http, &tiles, None, LIMIT) == (200, "[]".into()));
    assert!(!written.layers.is_empty(), "an adaptive render writes its layers");

    for (name, view) in [("samples", View::Samples), ("noise", View::Noise), ("beauty", View::Beauty)] {
        let (code, head, png) = http_get_bytes(&http, &format!("/api/jobs/{job}/image.png?view={name}"), None, LIMIT);
        assert_eq!(code, 200, "the {name} view: {head}");
        let mine = view_png(&written, view, 1.0, noise).expect("a view of the written image");
        assert!(png == mine.png, "the {name} view is the view of the written EXR");
        let scale = format!("x-tilefarm-scale: {} {}", mine.low, mine.high);
        assert!(head.to_ascii_lowercase().contains(&scale), "the {name} view's scale ({scale}) in:\n{head}");
    }
    let (fewest, most) = (written.counts.iter().min().unwrap(), written.counts.iter().max().unwrap());
    println!("samples per pixel from {fewest} to {most}");
    assert!(fewest < most && *most == 256, "adaptive sampling stopped some tiles early: {fewest} to {most} spp");
    let (code, _, _) = http_get_bytes(&http, &format!("/api/jobs/{job}/image.png?view=depth"), None, LIMIT);
    assert_eq!(code, 400, "an unknown view is refused");

    // Every tile that stopped early stopped because its noise reached the target.
    let (mut early, tile) = (0, 16);
    for (x0, y0) in
        (0..written.height).step_by(tile).flat_map(|y| (0..written.width).step_by(tile).map(move |x| (x, y)))
    {
        let (x1, y1) = ((x0 + 16).min(written.width), (y0 + 16).min(written.height));
        let pixels = (y0..y1).flat_map(|y| (x0..x1).map(move |x| (y * written.width + x) as usize));
        let squares: Vec<f64> = pixels.map(|i| written.layers[i].relative_error(written.pixels[i]).powi(2)).collect();
        let noise_of_tile = (squares.iter().sum::<f64>() / squares.len() as f64).sqrt();
        let spp = written.counts[(y0 * written.width + x0) as usize];
        if spp < 256 {
            early += 1;
            assert!(noise_of_tile <= noise, "tile at ({x0}, {y0}) stopped at {spp} spp with noise {noise_of_tile}");
        }
    }
    assert!(early > 0, "some tile stopped early");
}

/// A job without the variance has no noise view, and says how to get one.
#[test]
fn the_noise_view_of_a_job_without_layers_says_how_to_get_one() {
    let dir = TempDir::new("dashboard-noise-refused");
    let http = format!("127.0.0.1:{}", free_port());
    let coord = Coordinator::start(&dir.path("store"), &["--http", &http]);
    let _w = coord.worker(1, &dir.path("cache"));
    let out = dir.path("out.exr");
    let args = ["--width", "32", "--spp", "4", "--name", "plain", "--wait", "-o", out.to_str().unwrap()];
    let sub = coord.submit(&scenes().join("cornell-box/scene.toml"), &args, LIMIT);
    assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
    let job = list_jobs(&coord.url).into_iter().next().expect("the job is listed").job_id;
    let (code, text) = http_get(&http, &format!("/api/jobs/{job}/image.png?view=noise"), None, LIMIT);
    assert_eq!(code, 409, "{text}");
    assert!(text.contains("--aovs or --adaptive"), "{text}");
    let (code, _, png) = http_get_bytes(&http, &format!("/api/jobs/{job}/image.png?view=samples"), None, LIMIT);
    assert!(code == 200 && png.starts_with(b"\x89PNG"), "the samples view needs no layers");
}
