//! An operator's first hour, tried as a person would: a cancel that survives a restart,
//! uploads that lie about their size, scenes with missing files, and a full disk.

use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(240);

fn cornell() -> std::path::PathBuf {
    scenes().join("cornell-box/scene.toml")
}

/// Long enough (hundreds of units) that a cancel lands mid-render.
const JOB: [&str; 8] = ["--width", "96", "--spp", "64", "--tile", "16", "--batch-spp", "4"];

fn job_of(url: &str, id: &str) -> proto::JobStatus {
    list_jobs(url).into_iter().find(|j| j.job_id == id).expect("the job is listed")
}

fn workers_of(url: &str) -> Vec<proto::WorkerInfo> {
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    rt.block_on(async {
        let mut c = proto::jobs_client::JobsClient::connect(url.to_string()).await.unwrap();
        c.list_workers(proto::ListRequest {}).await.unwrap().into_inner().workers
    })
}

fn eventually(what: &str, f: impl FnMut() -> bool) {
    tilefarm_e2e::eventually(what, LIMIT, f)
}

#[test]
fn a_cancelled_job_stays_cancelled_across_a_restart_and_its_image_so_far_can_be_fetched() {
    let dir = TempDir::new("cancel-restart");
    let ckpt = dir.path("ckpt");
    let listen = format!("127.0.0.1:{}", free_port());
    let serve_args = [
        "--listen",
        listen.as_str(),
        "--checkpoint",
        ckpt.to_str().unwrap(),
        "--checkpoint-interval-ms",
        "200",
        "--lease-ms",
        "1500",
        "--heartbeat-ms",
        "300",
    ];
    let mut first = Coordinator::serve(&serve_args);
    let _worker = first.retrying_worker(&dir.path("cache"));
    let job = first.submit_id(&cornell(), &JOB, LIMIT);
    wait_for_progress(&first.url, 0.1, LIMIT);
    let cancel = run(Command::new(bin("coordinator")).args(["cancel", &job, "--coordinator", &first.url]), LIMIT);
    assert!(cancel.status.success(), "{}", String::from_utf8_lossy(&cancel.stderr));
    // The worker is told at once: it holds nothing of the cancelled job.
    eventually("the worker abandons its units", || workers_of(&first.url).iter().all(|w| w.units_held == 0));
    let done_at_cancel = job_of(&first.url, &job).units_done;
    assert!(done_at_cancel < job_of(&first.url, &job).units_total, "finished before the cancel");
    // Let a checkpoint pass record the cancel, then stop and start the farm again.
    std::thread::sleep(Duration::from_millis(800));
    let first_ids: Vec<u64> = workers_of(&first.url).iter().map(|w| w.worker_id).collect();
    assert_eq!(first_ids.len(), 1);
    signal_int(first.proc.pid());
    assert!(first.proc.wait(Duration::from_secs(30)).success(), "a clean stop");
    let second = Coordinator::serve(&serve_args);
    eventually("the job is restored", || {
        list_jobs(&second.url).iter().any(|j| j.job_id == job && j.state() != proto::JobState::Loading)
    });
    let restored = job_of(&second.url, &job);
    assert_eq!(restored.state(), proto::JobState::Cancelled, "{restored:?}");
    assert_eq!(restored.units_done, done_at_cancel);
    // Its image so far is written, and the command says it was cancelled.
    let out = dir.path("partial.exr");
    let fetch = run(
        Command::new(bin("coordinator")).args(["fetch", &job, "--coordinator", &second.url, "-q", "-o"]).arg(&out),
        LIMIT,
    );
    let err = String::from_utf8_lossy(&fetch.stderr);
    assert!(!fetch.status.success() && err.contains("was cancelled") && err.contains("image so far"), "{err}");
    let img = read_exr(&out);
    assert!(img.counts.iter().any(|&c| c > 0), "some samples were rendered before the cancel");
    assert!(img.counts.iter().any(|&c| c < 64), "and not all");
    assert_eq!(job_of(&second.url, &job).units_done, done_at_cancel, "nothing more was rendered");
    // The first worker registers again; a new one joins: two workers, two ids, none of
    // them an id the first coordinator gave out.
    let _second_worker = second.retrying_worker(&dir.path("cache2"));
    eventually("both workers are registered", || workers_of(&second.url).len() == 2);
    let ids: Vec<u64> = workers_of(&second.url).iter().map(|w| w.worker_id).collect();
    assert_ne!(ids[0], ids[1], "{ids:?}");
    assert!(ids.iter().all(|id| !first_ids.contains(id)));
}

fn signal_int(pid: u32) {
    assert!(Command::new("kill").args(["-INT", &pid.to_string()]).status().unwrap().success());
}

/// A job whose declared asset size is not its upload's would never end (every worker's
/// download fails its check): it is refused at submit, naming the file.
#[test]
fn a_job_whose_asset_size_is_wrong_is_refused_at_submit() {
    let dir = TempDir::new("asset-size");
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    let status = rt.block_on(async {
        let mut jobs = proto::jobs_client::JobsClient::connect(coord.url.clone()).await.unwrap();
        let bytes = std::fs::read(cornell()).unwrap();
        let chunk = proto::AssetChunk { data: bytes.clone() };
        let stored = jobs.upload_asset(tokio_stream_of(chunk)).await.unwrap().into_inner();
        assert_eq!(stored.size, bytes.len() as u64);
        let scene = proto::AssetRef { path: "scene.toml".into(), sha256: stored.sha256, size: stored.size + 1 };
        jobs.submit_job(proto::SubmitJobRequest { scene: Some(scene), ..Default::default() }).await.unwrap_err()
    });
    assert_eq!(status.code(), tonic::Code::InvalidArgument, "{status:?}");
    assert!(status.message().contains("scene.toml") && status.message().contains("bytes"), "{status:?}");
    assert!(list_jobs(&coord.url).is_empty(), "no job was made");
}

fn tokio_stream_of(chunk: proto::AssetChunk) -> impl tonic::IntoStreamingRequest<Message = proto::AssetChunk> {
    tokio_stream::iter([chunk])
}

/// Missing files are listed before a job exists.
#[test]
fn submit_refuses_a_scene_with_missing_files_listing_them() {
    let dir = TempDir::new("submit-missing");
    let scene = dir.path("broken.toml");
    std::fs::write(
        &scene,
        "[camera]\nposition = [0,0,-5]\nlook_at = [0,0,0]\n[[mesh]]\nobj = \"a.obj\"\n[[mesh]]\nobj = \"b.obj\"\n",
    )
    .unwrap();
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let out = coord.submit(&scene, &[], LIMIT);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("a.obj") && err.contains("b.obj"), "{err}");
    assert!(err.contains("nothing was submitted"), "{err}");
    assert!(list_jobs(&coord.url).is_empty());
}

/// A checkpoint folder on a full disk: the render warns, naming the file, and finishes.
/// Needs a tiny tmpfs, which only root (with CAP_SYS_ADMIN) can mount.
#[test]
fn a_full_disk_warns_but_does_not_stop_a_render() {
    let dir = TempDir::new("full-disk");
    let mnt = dir.path("tiny");
    std::fs::create_dir_all(&mnt).unwrap();
    let mounted = Command::new("mount").args(["-t", "tmpfs", "-o", "size=64k", "tmpfs"]).arg(&mnt).output();
    match mounted {
        Ok(o) if o.status.success() => {}
        Ok(o) => {
            skipped(format_args!("cannot mount a tmpfs here ({})", String::from_utf8_lossy(&o.stderr).trim()));
            return;
        }
        Err(e) => {
            skipped(format_args!("no mount command ({e})"));
            return;
        }
    }
    struct Unmount(std::path::PathBuf);
    impl Drop for Unmount {
        fn drop(&mut self) {
            let _ = Command::new("umount").arg(&self.0).status();
        }
    }
    let _unmount = Unmount(mnt.clone());
    // A scene of spheres only (tiny files), whose checkpoint (about 20 B a pixel) cannot fit.
    let scene = dir.path("spheres.toml");
    std::fs::write(
        &scene,
        "[camera]\nposition = [0,0,-5]\nlook_at = [0,0,0]\nwidth = 128\nheight = 128\n[render]\nspp = 8\n\
         [[sphere]]\ncenter = [0,0,0]\nradius = 1\nkd = [0.5,0.5,0.5]\n[background]\nradiance = [1,1,1]\n",
    )
    .unwrap();
    let out = dir.path("out.exr");
    let ckpt = mnt.join("ckpt");
    let args = ["--checkpoint", ckpt.to_str().unwrap(), "--checkpoint-interval-ms", "1", "--batch-spp", "1"];
    let o = render(&scene, &out, &[&args[..], &["--local-workers", "1"]].concat(), LIMIT);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("checkpoint not written") && err.contains("checkpoint.tfck"), "{err}");
    let img = read_exr(&out);
    assert!(img.counts.iter().all(|&c| c == 8), "the render finished");
}

/// Ctrl-C on `render` writes the image so far: its samples channel shows how far each
/// pixel got.
#[test]
fn ctrl_c_on_render_writes_the_image_so_far() {
    let dir = TempDir::new("ctrl-c");
    let out = dir.path("partial.exr");
    let mut cmd = Command::new(bin("coordinator"));
    // Minutes of work: the interrupt lands mid-render.
    cmd.args(["render", "-q", "--width", "128", "--spp", "4096", "--batch-spp", "1", "--local-workers", "1", "-o"])
        .arg(&out)
        .stderr(std::process::Stdio::piped());
    let mut render = Proc::spawn("render", &mut cmd);
    std::thread::sleep(Duration::from_secs(3));
    assert!(Command::new("kill").args(["-INT", &render.pid().to_string()]).status().unwrap().success());
    let status = render.wait(Duration::from_secs(60));
    let mut err = String::new();
    std::io::Read::read_to_string(&mut render.child.stderr.take().unwrap(), &mut err).unwrap();
    assert_eq!(status.code(), Some(130), "{err}");
    assert!(err.contains("wrote the image so far"), "{err}");
    let img = read_exr(&out);
    assert!(img.counts.iter().all(|&c| c < 4096), "stopped early");
    assert!(img.counts.iter().any(|&c| c > 0), "with the samples done before the interrupt");
}

/// Every farm command finds the coordinator in TILEFARM_COORDINATOR, as host:port.
#[test]
fn the_coordinator_address_comes_from_the_environment_as_host_and_port() {
    let dir = TempDir::new("env-address");
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let host_port = coord.url.trim_start_matches("http://").to_string();
    let status = run(Command::new(bin("coordinator")).arg("status").env("TILEFARM_COORDINATOR", &host_port), LIMIT);
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    assert!(String::from_utf8_lossy(&status.stdout).contains("jobs:"));
    let id = run(
        Command::new(bin("coordinator"))
            .args(["submit", "-q", "--name", "box"])
            .arg(cornell())
            .env("TILEFARM_COORDINATOR", &host_port),
        LIMIT,
    );
    assert!(id.status.success(), "{}", String::from_utf8_lossy(&id.stderr));
    let job = String::from_utf8_lossy(&id.stdout).trim().to_string();
    let listed = run(Command::new(bin("coordinator")).args(["status", "--coordinator", &host_port]), LIMIT);
    let text = String::from_utf8_lossy(&listed.stdout);
    assert!(text.lines().any(|l| l.contains(&job) && l.contains("box") && l.contains("samples")), "{text}");
}

/// A scene's problem (here a texture that is no image) reaches the user who submitted
/// it, once, named as in their files.
#[test]
fn submit_wait_shows_the_scenes_warnings_once() {
    let dir = TempDir::new("submit-warn");
    let copy = dir.path("box");
    std::fs::create_dir_all(&copy).unwrap();
    for f in ["scene.toml", "cbox.obj", "cbox.mtl"] {
        std::fs::copy(scenes().join("cornell-box").join(f), copy.join(f)).unwrap();
    }
    let mtl = std::fs::read_to_string(copy.join("cbox.mtl")).unwrap();
    std::fs::write(copy.join("cbox.mtl"), format!("{mtl}\nmap_Kd gone.png\n")).unwrap();
    std::fs::write(copy.join("gone.png"), b"not a picture").unwrap();
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let _w = coord.worker(2, &dir.path("cache"));
    let out = dir.path("out.exr");
    let args = ["--width", "32", "--spp", "4", "--wait", "-o", out.to_str().unwrap()];
    let sub = coord.submit(&copy.join("scene.toml"), &args, LIMIT);
    let err = String::from_utf8_lossy(&sub.stderr);
    assert!(sub.status.success(), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.contains("gone.png")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].starts_with("warning: cbox.mtl: material"), "{err}");
    assert!(!err.contains("/jobs/job-"), "no internal paths: {err}");
}
