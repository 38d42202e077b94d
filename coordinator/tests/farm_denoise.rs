//! `--denoise` on a farm's image: `submit --denoise --wait` and `fetch --denoise` denoise
//! on the user's machine what the farm rendered, keeping the farm's EXR as it was and
//! adding the denoised layer beside it. A real `serve` and a real worker on loopback.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn coordinator() -> Command {
    Command::new(env!("CARGO_BIN_EXE_coordinator"))
}

/// Children killed when the test ends, also when it fails.
struct Procs(Vec<Child>);

impl Drop for Procs {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Runs `cmd` to its end within two minutes.
fn run(cmd: &mut Command) -> Output {
    let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("spawn");
    let deadline = Instant::now() + Duration::from_secs(120);
    while child.try_wait().expect("wait").is_none() {
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("{cmd:?} did not end within 120 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.wait_with_output().expect("output")
}

/// A farm on loopback: `serve` and one worker, both gone when the test ends.
fn farm(dir: &Path) -> (Procs, String) {
    let mut serve = coordinator()
        .args(["serve", "--listen", "127.0.0.1:0", "--exit-on-stdin-eof", "--store"])
        .arg(dir.join("store"))
        .env("RUST_LOG", "warn")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("serve");
    let mut lines = BufReader::new(serve.stdout.take().unwrap()).lines();
    let mut procs = Procs(vec![serve]);
    let line = lines.next().expect("serve printed its address").unwrap();
    let url = line.strip_prefix("listening on ").expect("a listening line").trim().to_string();
    std::thread::spawn(move || for _ in lines {});
    let worker = coordinator()
        .args(["worker", "--coordinator", &url, "--threads", "1", "--exit-on-stdin-eof", "--cache"])
        .arg(dir.join("cache"))
        .env("RUST_LOG", "warn")
        .stdin(Stdio::piped())
        .spawn()
        .expect("worker");
    procs.0.push(worker);
    (procs, url)
}

fn scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box/scene.toml")
}

fn header(path: &Path) -> exr::meta::header::LayerAttributes {
    exr::meta::MetaData::read_from_file(path, false).unwrap().headers[0].own_attributes.clone()
}

#[test]
fn denoise_a_farms_image_on_submit_and_on_fetch() {
    let dir = TempDir(std::env::temp_dir().join(format!("tilefarm-farm-denoise-{}", std::process::id())));
    std::fs::create_dir_all(&dir.0).unwrap();
    let small = ["--width", "32", "--height", "32", "--spp", "4", "-q"];
    if !tracer::denoise::AVAILABLE {
        // Refused before anything is uploaded: no farm needs to exist.
        let out = run(coordinator()
            .arg("submit")
            .arg(scene())
            .args(["--coordinator", "127.0.0.1:9", "--denoise", "--wait"])
            .args(small));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains("--features denoise"), "{err}");
        // On stderr itself: the harness hides a passing test's println!.
        let _ = writeln!(
            std::io::stderr(),
            "SKIPPED: denoising a farm's image: built without the `denoise` feature; `.ci/run` builds it"
        );
        return;
    }
    let (_procs, url) = farm(&dir.0);
    let submit = |extra: &[&str]| {
        run(coordinator().arg("submit").arg(scene()).args(["--coordinator", &url]).args(small).args(extra))
    };

    // Without --wait there is no image to denoise here: said, and nothing submitted.
    let out = submit(&["--denoise"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("fetch JOB --denoise"), "{err}");

    let denoised = dir.0.join("d.exr");
    let out = submit(&["--denoise", "--wait", "-o", denoised.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    // The same job with layers only, fetched raw and fetched denoised.
    let out = submit(&["--aovs"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let job = String::from_utf8_lossy(&out.stdout).trim().to_string();
    let raw = dir.0.join("r.exr");
    let fetched = dir.0.join("f.exr");
    let png = dir.0.join("f.png");
    for (path, extra) in [(&raw, None), (&fetched, Some("--denoise")), (&png, Some("--denoise"))] {
        let out = run(coordinator()
            .args(["fetch", &job, "--coordinator", &url, "-q", "-o", path.to_str().unwrap()])
            .args(extra));
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
    let read = |p: &Path| tracer::output::read_exr(p).unwrap();
    let (r, f, d) = (read(&raw), read(&fetched), read(&denoised));
    assert!(r.denoised.is_empty() && !r.layers.is_empty());
    for (image, what) in [(&f, "fetch --denoise"), (&d, "submit --denoise --wait")] {
        assert_eq!((&image.pixels, &image.counts, &image.layers), (&r.pixels, &r.counts, &r.layers), "{what}");
        assert_eq!(image.denoised.len(), image.pixels.len(), "{what}");
        assert!(image.denoised.iter().all(|p| p.is_finite()) && image.denoised != image.pixels, "{what}");
    }
    assert_eq!(f.denoised, d.denoised, "one image, one denoised layer");
    // The farm's header is kept; the denoiser is added.
    let key = exr::meta::attribute::Text::from("tilefarm/denoiser");
    let (mut h, hr) = (header(&fetched), header(&raw));
    assert!(h.other.remove(&key).is_some());
    assert_eq!(h, hr, "the farm's header attributes are kept");
    assert!(png.is_file());

    // A job without layers cannot be denoised: said, naming what to do.
    let out = submit(&["--wait", "-o", dir.0.join("plain.exr").to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let plain = String::from_utf8_lossy(&out.stdout).lines().next().unwrap_or_default().trim().to_string();
    let out =
        run(coordinator().args(["fetch", &plain, "--coordinator", &url, "--denoise", "-o"]).arg(dir.0.join("x.exr")));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--aovs"), "{err}");
}
