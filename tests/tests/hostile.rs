//! Hostile input against a running farm: requests that once aborted the coordinator or
//! read files outside a job are refused with an error naming what is wrong, and the
//! farm carries on with an honest job.

use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(120);

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

/// Uploads `text` as the job's only file, `scene.toml`, submits it with `settings` and
/// follows it to its end; returns the final status.
fn submit_scene_text(url: &str, text: &str, settings: proto::RenderSettings) -> proto::JobStatus {
    runtime().block_on(async {
        let mut jobs = proto::jobs_client::JobsClient::connect(url.to_string()).await.unwrap();
        let chunk = proto::AssetChunk { data: text.as_bytes().to_vec() };
        let stored = jobs.upload_asset(tokio_stream::iter([chunk])).await.unwrap().into_inner();
        let scene = proto::AssetRef { path: "scene.toml".into(), sha256: stored.sha256, size: stored.size };
        let request = proto::SubmitJobRequest { scene: Some(scene), settings: Some(settings), ..Default::default() };
        let job = jobs.submit_job(request).await.unwrap().into_inner().job_id;
        let mut watch = jobs.watch_job(proto::JobRequest { job_id: job }).await.unwrap().into_inner();
        let mut last = None;
        while let Some(s) = tokio::time::timeout(LIMIT, watch.message()).await.expect("progress").unwrap() {
            last = Some(s);
        }
        last.expect("a status")
    })
}

const SPHERE: &str = "[camera]\nposition = [0, 0, -5]\nlook_at = [0, 0, 0]\nwidth = 32\nheight = 32\n\
                      [render]\nspp = 4\n[[sphere]]\ncenter = [0, 0, 0]\nradius = 1\nkd = [0.5, 0.5, 0.5]\n\
                      [[light]]\ntype = \"point\"\nposition = [0, 3, -3]\nintensity = [5, 5, 5]\n";

#[test]
fn absurd_job_sizes_are_refused_before_anything_is_allocated() {
    let dir = TempDir::new("hostile-sizes");
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let cases = [
        // Once: 2^32 units of one sample each, then an abort.
        (proto::RenderSettings { spp: u32::MAX, batch_spp: 1, ..Default::default() }, "units of work"),
        // Once: 4 GiB of tiles, 223 GB of sums.
        (
            proto::RenderSettings { width: 65_536, height: 65_536, tile_size: 1, ..Default::default() },
            "--max-job-memory-mb",
        ),
        (proto::RenderSettings { tile_size: 100_000, ..Default::default() }, "tile size"),
    ];
    for (settings, says) in cases {
        let s = submit_scene_text(&coord.url, SPHERE, settings.clone());
        assert_eq!(s.state(), proto::JobState::Failed, "{settings:?}: {s:?}");
        assert!(s.error.contains(says), "{settings:?}: {}", s.error);
    }
    // The farm is still up and renders an honest job.
    let _w = coord.worker(1, &dir.path("cache"));
    let s = submit_scene_text(&coord.url, SPHERE, proto::RenderSettings::default());
    assert_eq!(s.state(), proto::JobState::Done, "{s:?}");
}

/// A farm's scene may not read the coordinator's (or a worker's) files: references
/// outside the job's own files are errors naming them, and their content never shows.
#[test]
fn scenes_cannot_reach_outside_their_job() {
    let dir = TempDir::new("hostile-paths");
    let secret = dir.path("secret.obj");
    std::fs::write(&secret, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let coord = Coordinator::start(&dir.path("store"), &[]);
    for reference in [secret.display().to_string(), "../../../../../../../../../../etc/hostname".to_string()] {
        let text = format!("{SPHERE}[[mesh]]\nobj = \"{reference}\"\n");
        let s = submit_scene_text(&coord.url, &text, proto::RenderSettings::default());
        assert_eq!(s.state(), proto::JobState::Failed, "{reference}: {s:?}");
        assert!(s.error.contains("not one of the job's files"), "{reference}: {}", s.error);
    }
}

#[test]
fn oversized_registrations_are_refused() {
    let dir = TempDir::new("hostile-register");
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let status = runtime().block_on(async {
        let mut farm = proto::farm_client::FarmClient::connect(coord.url.clone()).await.unwrap();
        let request = proto::RegisterRequest {
            protocol_version: proto::PROTOCOL_VERSION,
            threads: 1,
            hostname: "h".repeat(1 << 20),
            version: "1".into(),
        };
        farm.register(request).await.unwrap_err()
    });
    assert_eq!(status.code(), tonic::Code::InvalidArgument, "{status:?}");
    assert!(status.message().contains("hostname"), "{status:?}");
}

#[test]
fn serve_refuses_a_reachable_address_without_insecure() {
    let dir = TempDir::new("hostile-listen");
    let out = run(
        Command::new(bin("coordinator")).args(["serve", "--listen", "0.0.0.0:0", "--store"]).arg(dir.path("store")),
        LIMIT,
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--insecure") && err.contains("0.0.0.0:0"), "{err}");
}

/// A local render whose OBJ names a device as its material library gets a warning and
/// its image (once it read `/dev/zero` until memory ran out).
#[cfg(unix)]
#[test]
fn a_device_named_by_a_scene_is_not_read() {
    let dir = TempDir::new("hostile-device");
    std::fs::write(dir.path("m.obj"), "mtllib /dev/zero\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let scene = dir.path("scene.toml");
    std::fs::write(&scene, format!("{SPHERE}[[mesh]]\nobj = \"m.obj\"\n")).unwrap();
    let out = render(&scene, &dir.path("out.exr"), &["--local-workers", "0"], LIMIT);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("not a regular file"), "{err}");
    assert!(dir.path("out.exr").is_file());
}

/// A farm with an access token serves only calls that bear it: a client or worker
/// without it is refused (the worker stops, saying why), one with it is served.
#[test]
fn a_farm_with_a_token_serves_only_those_who_have_it() {
    let dir = TempDir::new("hostile-token");
    let token_file = dir.path("farm.token");
    std::fs::write(&token_file, "s3cret-token-for-this-test\n").unwrap();
    let coord = Coordinator::start(&dir.path("store"), &["--token-file", token_file.to_str().unwrap()]);
    let status = |token: Option<&str>| {
        let mut cmd = Command::new(bin("coordinator"));
        cmd.args(["status", "--coordinator", &coord.url]).env_remove("TILEFARM_TOKEN");
        if let Some(t) = token {
            cmd.env("TILEFARM_TOKEN", t);
        }
        run(&mut cmd, LIMIT)
    };
    let refused = status(None);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("access token"), "{refused:?}");
    assert!(!status(Some("a-guess")).status.success());
    assert!(status(Some("s3cret-token-for-this-test")).status.success());
    let mut outsider = Command::new(bin("worker"));
    outsider.args(["--coordinator", &coord.url, "--threads", "1", "--cache"]).arg(dir.path("cache"));
    let out = run(outsider.env_remove("TILEFARM_TOKEN"), LIMIT);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("access token"), "{out:?}");
}

/// Uploads are streamed to disk within a per-file limit: a larger one is refused, naming
/// the limit, and leaves nothing behind.
#[test]
fn uploads_past_the_farms_limit_are_refused() {
    let dir = TempDir::new("hostile-upload");
    let store = dir.path("store");
    let coord = Coordinator::start(&store, &["--max-upload-mb", "1"]);
    let status = runtime().block_on(async {
        let mut jobs = proto::jobs_client::JobsClient::connect(coord.url.clone()).await.unwrap();
        let chunks = (0..3).map(|_| proto::AssetChunk { data: vec![7u8; 512 * 1024] });
        jobs.upload_asset(tokio_stream::iter(chunks.collect::<Vec<_>>())).await.unwrap_err()
    });
    assert_eq!(status.code(), tonic::Code::ResourceExhausted, "{status:?}");
    assert!(status.message().contains("--max-upload-mb"), "{status:?}");
    let left: Vec<_> = std::fs::read_dir(store.join("blobs")).unwrap().flatten().map(|e| e.file_name()).collect();
    assert!(left.is_empty(), "{left:?}");
    // Still serving: a file within the limit is stored, where its digest says.
    let stored = runtime().block_on(async {
        let mut jobs = proto::jobs_client::JobsClient::connect(coord.url.clone()).await.unwrap();
        let chunk = proto::AssetChunk { data: SPHERE.as_bytes().to_vec() };
        jobs.upload_asset(tokio_stream::iter([chunk])).await.unwrap().into_inner()
    });
    assert_eq!(std::fs::read(store.join("blobs").join(&stored.sha256)).unwrap(), SPHERE.as_bytes());
}

/// A rogue client that holds real leases and returns well-formed but forged sums (black,
/// and near `i128::MAX`) is told they were accepted, like any worker, but a farm checks
/// a new worker's first results on other workers: the forgeries never reach the image,
/// the rogue is quarantined and refused from then on (also on a farm of one honest
/// worker, where the coordinator decides), and the image is the undisturbed
/// render's, bit for bit. Results for another worker's lease and digests that climb out
/// of the store are refused too.
#[test]
fn forged_results_for_held_leases_are_caught_and_never_reach_the_image() {
    use proto::farm_client::FarmClient;
    use tonic::Code;

    const JOB: [&str; 8] = ["--width", "48", "--spp", "16", "--tile", "16", "--batch-spp", "4"];
    let dir = TempDir::new("hostile-forger");
    let cornell = scenes().join("cornell-box/scene.toml");
    let reference = dir.path("reference.exr");
    render(&cornell, &reference, &[&JOB[..], &["--local-workers", "0"]].concat(), LIMIT);
    let coord = Coordinator::start(&dir.path("store"), &["--lease-ms", "2000", "--heartbeat-ms", "500"]);
    let job = coord.submit_id(&cornell, &JOB, LIMIT);
    let register = proto::RegisterRequest {
        protocol_version: proto::PROTOCOL_VERSION,
        threads: 1,
        hostname: "rogue".into(),
        version: "0".into(),
    };
    let rt = runtime();
    let (rogue, mut farm) = rt.block_on(async {
        let mut farm = FarmClient::connect(coord.url.clone()).await.unwrap();
        let me = farm.register(register.clone()).await.unwrap().into_inner().worker_id;
        let other = farm.register(register.clone()).await.unwrap().into_inner().worker_id;
        let mut units = Vec::new();
        let start = std::time::Instant::now();
        while units.len() < 2 {
            assert!(start.elapsed() < LIMIT, "no units leased");
            let req = proto::LeaseRequest { worker_id: me, max_units: 2 };
            units.extend(farm.lease(req).await.unwrap().into_inner().units);
        }
        let forged = |u: &proto::Unit, value: i128| forged_result(me, &job, u, value);
        // Another worker's lease: refused, and nothing about the unit is revealed.
        let theirs = proto::UnitResult { worker_id: other, ..forged(&units[0], 0) };
        let e = farm.submit_result(theirs).await.unwrap_err();
        assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
        // Its own leases: forged sums look accepted…
        for (u, value) in units.iter().zip([0, i128::MAX / 4]) {
            assert!(farm.submit_result(forged(u, value)).await.unwrap().into_inner().accepted);
        }
        // Digests that climb out of the store find nothing.
        for sha in ["../../../../etc/passwd", "..", &"a".repeat(64)] {
            let e = farm.fetch_asset(proto::AssetRequest { sha256: sha.to_string() }).await.unwrap_err();
            assert_eq!(e.code(), Code::NotFound, "{sha}: {e:?}");
        }
        (me, farm)
    });
    // One honest worker renders the job, checking the rogue's answers on the way; with
    // no third worker to decide between the two, the coordinator renders the disputed
    // units itself.
    let _worker = coord.worker(2, &dir.path("c1"));
    let out = dir.path("farm.exr");
    let fetched = run(
        Command::new(bin("coordinator")).args(["fetch", &job, "--coordinator", &coord.url, "-q", "-o"]).arg(&out),
        LIMIT,
    );
    assert!(fetched.status.success(), "{}", String::from_utf8_lossy(&fetched.stderr));
    assert_same_bits(&read_exr(&out), &read_exr(&reference), "after forged results");
    rt.block_on(async {
        let e = farm.lease(proto::LeaseRequest { worker_id: rogue, max_units: 1 }).await.unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
        assert!(e.message().contains("quarantined"), "{e:?}");
    });
    let status = run(Command::new(bin("coordinator")).args(["status", "--coordinator", &coord.url]), LIMIT);
    let shown = String::from_utf8_lossy(&status.stdout);
    assert!(shown.contains("QUARANTINED") && shown.contains("was banned"), "{shown}");
    assert_eq!(shown.matches("QUARANTINED").count(), 1, "only the rogue: {shown}");
}

/// `submit` never follows a link out of the scene's folder: a scene whose OBJ is a link
/// to a private file fails before anything is uploaded, naming the link, and the
/// farm's store holds none of it.
#[cfg(unix)]
#[test]
fn submit_refuses_a_link_out_of_the_scene_folder() {
    let dir = TempDir::new("hostile-link");
    let secret = dir.path("id_ed25519");
    std::fs::write(&secret, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n# PRIVATE KEY\n").unwrap();
    let folder = dir.path("shot");
    std::fs::create_dir_all(&folder).unwrap();
    std::os::unix::fs::symlink(&secret, folder.join("model.obj")).unwrap();
    let scene = folder.join("scene.toml");
    std::fs::write(&scene, format!("{SPHERE}[[mesh]]\nobj = \"model.obj\"\n")).unwrap();
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let out = coord.submit(&scene, &[], LIMIT);
    assert!(!out.status.success(), "a link out of the folder was submitted");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("model.obj: a symbolic link that leads outside the scene's folder"), "{err}");
    let blobs: Vec<_> = std::fs::read_dir(dir.path("store").join("blobs")).unwrap().flatten().collect();
    let secret_text = std::fs::read(&secret).unwrap();
    assert!(blobs.iter().all(|b| std::fs::read(b.path()).unwrap() != secret_text), "the secret reached the store");
    assert!(list_jobs(&coord.url).is_empty(), "no job was made");
}
