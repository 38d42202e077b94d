//! The farm end to end: real `coordinator` and `worker` processes on 127.0.0.1, ports
//! from the OS, every wait bounded, every process killed when a test ends.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(180);

fn cornell() -> std::path::PathBuf {
    scenes().join("cornell-box/scene.toml")
}

/// Settings shared by every render compared in these tests.
const JOB: [&str; 8] = ["--width", "64", "--spp", "32", "--tile", "16", "--batch-spp", "8"];

fn reference(dir: &TempDir) -> tracer::film::Image {
    let out = dir.path("reference.exr");
    render(&cornell(), &out, &[&JOB[..], &["--local-workers", "0"]].concat(), LIMIT);
    read_exr(&out)
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

async fn jobs_client(url: &str) -> proto::jobs_client::JobsClient<tonic::transport::Channel> {
    proto::jobs_client::JobsClient::connect(url.to_string()).await.unwrap()
}

#[test]
fn any_number_of_workers_gives_the_same_bits_as_in_process() {
    let dir = TempDir::new("workers");
    let expected = reference(&dir);
    assert!(expected.counts.iter().all(|&c| c == 32));
    for (workers, threads) in [("1", "2"), ("2", "1"), ("4", "1")] {
        let out = dir.path(&format!("w{workers}.exr"));
        render(&cornell(), &out, &[&JOB[..], &["--local-workers", workers, "--threads", threads]].concat(), LIMIT);
        assert_same_bits(&read_exr(&out), &expected, &format!("{workers} local workers"));
    }
}

#[test]
fn a_worker_joining_half_way_contributes_and_the_image_is_unchanged() {
    let dir = TempDir::new("join");
    let args = ["--width", "96", "--spp", "64", "--tile", "16", "--batch-spp", "4"];
    let out_ref = dir.path("ref.exr");
    render(&cornell(), &out_ref, &[&args[..], &["--local-workers", "0"]].concat(), LIMIT);
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let _first = coord.worker(1, &dir.path("cache-a"));
    let out = dir.path("farm.exr");
    let mut submit = {
        let mut cmd = std::process::Command::new(bin("coordinator"));
        cmd.arg("submit").arg(cornell()).args(["--coordinator", &coord.url, "--wait", "-q", "-o"]).arg(&out).args(args);
        Proc::spawn("submit --wait", &mut cmd)
    };
    let rt = runtime();
    let mut second = None;
    let start = Instant::now();
    rt.block_on(async {
        let mut jobs = jobs_client(&coord.url).await;
        loop {
            assert!(start.elapsed() < LIMIT, "job did not progress");
            let list = jobs.list_jobs(proto::ListRequest {}).await.unwrap().into_inner().jobs;
            if let Some(j) = list.first()
                && j.units_total > 0
                && j.units_done * 4 >= j.units_total
            {
                assert!(j.units_done < j.units_total, "the job finished before the second worker could join");
                second = Some(coord.worker(1, &dir.path("cache-b")));
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    });
    assert!(submit.wait(LIMIT).success());
    let workers = rt.block_on(async {
        let mut jobs = jobs_client(&coord.url).await;
        jobs.list_workers(proto::ListRequest {}).await.unwrap().into_inner().workers
    });
    assert_eq!(workers.len(), 2);
    assert!(workers.iter().all(|w| w.units_done > 0), "both workers contributed: {workers:?}");
    assert_same_bits(&read_exr(&out), &read_exr(&out_ref), "farm with a late joiner");
    drop(second);
}

/// Registers a forger and leases until it holds a unit.
async fn registered_with_a_unit(
    farm: &mut proto::farm_client::FarmClient<tonic::transport::Channel>,
) -> (u64, proto::Unit) {
    let request = proto::RegisterRequest {
        protocol_version: proto::PROTOCOL_VERSION,
        threads: 1,
        hostname: "forger".into(),
        version: "0".into(),
    };
    let me = farm.register(request).await.unwrap().into_inner().worker_id;
    let start = Instant::now();
    loop {
        assert!(start.elapsed() < LIMIT);
        let lease = proto::LeaseRequest { worker_id: me, max_units: 1 };
        if let Some(u) = farm.lease(lease).await.unwrap().into_inner().units.pop() {
            return (me, u);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[test]
fn forged_and_malformed_results_are_rejected_and_the_image_is_unaffected() {
    use proto::farm_client::FarmClient;
    use tonic::Code;

    let dir = TempDir::new("forged");
    let expected = reference(&dir);
    // Short leases, so that the units the forger leased and never returns are re-leased.
    let coord = Coordinator::start(&dir.path("store"), &["--lease-ms", "1500", "--heartbeat-ms", "500"]);
    let sub = coord.submit(&cornell(), &JOB, LIMIT);
    assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
    let job = String::from_utf8_lossy(&sub.stdout).trim().to_string();
    let rt = runtime();
    /// A forged result for a unit and what the farm must answer.
    type Case = (&'static str, fn(proto::UnitResult, &proto::Unit) -> proto::UnitResult, Code);
    let pixels = |u: &proto::Unit| u.tile.map_or(0, |t| (t.width * t.height) as usize);
    let cases: Vec<Case> = vec![
        (
            "a unit it does not hold",
            |g, u| proto::UnitResult { unit_id: u.unit_id + 40, ..g },
            Code::FailedPrecondition,
        ),
        ("a unit that does not exist", |g, _| proto::UnitResult { unit_id: 1 << 40, ..g }, Code::InvalidArgument),
        ("too few pixels", |g, _| proto::UnitResult { sums: g.sums[48..].to_vec(), ..g }, Code::InvalidArgument),
        ("a torn pixel", |g, _| proto::UnitResult { sums: g.sums[1..].to_vec(), ..g }, Code::InvalidArgument),
        (
            "wrong sample counts",
            |g, _| proto::UnitResult { counts: g.counts.iter().map(|c| c + 1).collect(), ..g },
            Code::InvalidArgument,
        ),
        (
            "negative radiance",
            |mut g, _| {
                g.sums[..16].copy_from_slice(&(-1i128).to_le_bytes());
                g
            },
            Code::InvalidArgument,
        ),
        (
            "the wrong sample range",
            |g, u| proto::UnitResult { sample_end: u.sample_end + 1, ..g },
            Code::InvalidArgument,
        ),
        (
            "the wrong tile",
            |g, u| {
                let tile = u.tile.unwrap();
                proto::UnitResult { tile: Some(proto::Tile { x0: tile.x0 + 1, ..tile }), ..g }
            },
            Code::InvalidArgument,
        ),
        ("an unknown job", |g, _| proto::UnitResult { job_id: "job-999".into(), ..g }, Code::NotFound),
        ("an unknown worker", |g, _| proto::UnitResult { worker_id: 9999, ..g }, Code::NotFound),
    ];
    rt.block_on(async {
        let mut farm = FarmClient::connect(coord.url.clone()).await.unwrap();
        // Each case from a registration of its own (on this open farm, an identity of its
        // own): three malformed results ban an identity, and its fourth would be refused
        // for that (as the last part shows).
        for (what, forge, code) in cases {
            let (me, u) = registered_with_a_unit(&mut farm).await;
            assert!(pixels(&u) > 1);
            let err = farm.submit_result(forge(forged_result(me, &job, &u, 0), &u)).await.expect_err(what);
            assert_eq!(err.code(), code, "{what}: {}", err.message());
            assert!(!err.message().is_empty());
        }
        let (me, u) = registered_with_a_unit(&mut farm).await;
        let mut codes = Vec::new();
        for _ in 0..4 {
            let mut r = forged_result(me, &job, &u, 0);
            r.counts[0] += 1;
            codes.push(farm.submit_result(r).await.unwrap_err().code());
        }
        assert_eq!(codes, [Code::InvalidArgument; 3].into_iter().chain([Code::PermissionDenied]).collect::<Vec<_>>());
    });
    // Real workers finish the job; the forger's leases lapse and are re-leased.
    let _w = coord.worker(2, &dir.path("cache"));
    let out = dir.path("farm.exr");
    rt.block_on(async {
        let mut jobs = jobs_client(&coord.url).await;
        let mut watch = jobs.watch_job(proto::JobRequest { job_id: job.clone() }).await.unwrap().into_inner();
        let mut last = None;
        while let Some(s) = tokio::time::timeout(LIMIT, watch.message()).await.expect("progress").unwrap() {
            last = Some(s);
        }
        assert_eq!(last.unwrap().state(), proto::JobState::Done);
        let mut img = jobs.fetch_image(proto::JobRequest { job_id: job.clone() }).await.unwrap().into_inner();
        let mut bytes = Vec::new();
        while let Some(c) = img.message().await.unwrap() {
            bytes.extend_from_slice(&c.exr);
        }
        std::fs::write(&out, bytes).unwrap();
    });
    assert_same_bits(&read_exr(&out), &expected, "after forged results");
}

#[test]
fn a_missing_obj_fails_its_job_by_name_and_the_farm_keeps_serving() {
    let dir = TempDir::new("missing");
    let scene = dir.path("broken.toml");
    std::fs::write(&scene, "[camera]\nposition = [0,0,-5]\nlook_at = [0,0,0]\n[[mesh]]\nobj = \"no-such-mesh.obj\"\n")
        .unwrap();
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let _w = coord.worker(2, &dir.path("cache"));
    let bad = coord.submit(&scene, &["--wait"], LIMIT);
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("no-such-mesh.obj"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    // The coordinator is still up and renders the next job.
    let out = dir.path("ok.exr");
    let good = coord.submit(&cornell(), &[&JOB[..], &["--wait", "-o", out.to_str().unwrap()]].concat(), LIMIT);
    assert!(good.status.success(), "{}", String::from_utf8_lossy(&good.stderr));
    assert_same_bits(&read_exr(&out), &reference(&dir), "after a failed job");
    assert!(Path::new(&out).exists());
}

#[test]
fn the_load_test_merges_every_unit_its_simulated_workers_return() {
    // 64×64 px in 8×8 tiles × 2 spp = 128 units over 16 connections; the command itself
    // fails unless the job reports every unit done and every result was accepted.
    let out = run(
        Command::new(bin("coordinator")).args(["loadtest", "--connections", "16", "--size", "64", "--spp", "2"]),
        LIMIT,
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("merged 128 unit results"), "{text}");
}

/// A finished job's image leaves the coordinator's memory for its store: once the job is
/// no longer listed, `fetch` still writes the same bits, and a restarted farm on the same
/// store never gives its id to a new job. Even with no retention at all, `submit --wait`
/// sees its job end (it stays listed long enough).
#[test]
fn finished_images_are_fetched_from_the_store_after_the_job_is_forgotten() {
    let dir = TempDir::new("retention");
    let expected = reference(&dir);
    let store = dir.path("store");
    let coord = Coordinator::start(&store, &["--retain-finished-ms", "0"]);
    let _w = coord.worker(2, &dir.path("cache"));
    let first = dir.path("first.exr");
    let sub = coord.submit(&cornell(), &[&JOB[..], &["--wait", "-o", first.to_str().unwrap()]].concat(), LIMIT);
    assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
    assert_same_bits(&read_exr(&first), &expected, "while listed");
    eventually("the finished job is no longer listed", LIMIT, || list_jobs(&coord.url).is_empty());
    assert!(store.join("images/job-1.exr").is_file());
    let again = dir.path("again.exr");
    let fetch = run(
        std::process::Command::new(bin("coordinator"))
            .args(["fetch", "job-1", "--coordinator", &coord.url, "-q", "-o"])
            .arg(&again),
        LIMIT,
    );
    assert!(fetch.status.success(), "{}", String::from_utf8_lossy(&fetch.stderr));
    assert_same_bits(&read_exr(&again), &expected, "from the store");
    drop(coord);
    let restarted = Coordinator::start(&store, &[]);
    let id = restarted.submit_id(&cornell(), &JOB, LIMIT);
    assert_ne!(id, "job-1", "a stored job's id is not reused");
}

/// A scene lit by an environment map (a sky with a sun, written here as an EXR) and an
/// area light: the map ships to the workers with the job, and 1, 2 and 3 workers give
/// the in-process bits.
#[test]
fn an_environment_map_scene_gives_the_same_bits_for_any_number_of_workers() {
    let dir = TempDir::new("workers-map");
    let (w, h) = (64u32, 33u32);
    let pixels = (0..h)
        .flat_map(|r| (0..w).map(move |c| (r, c)))
        .map(|(r, c)| match (r, c) {
            (8..=9, 20..=21) => glam::Vec3::new(400.0, 380.0, 300.0),
            (0..=16, _) => glam::Vec3::new(0.3, 0.45, 0.9),
            _ => glam::Vec3::new(0.12, 0.1, 0.08),
        })
        .collect();
    let map = tracer::film::Image {
        width: w,
        height: h,
        pixels,
        counts: vec![1; (w * h) as usize],
        layers: vec![],
        denoised: vec![],
    };
    tracer::output::write_exr(&map, &dir.path("sky.exr")).unwrap();
    std::fs::write(
        dir.path("scene.toml"),
        "[camera]\nposition = [0, 1.2, 4]\nlook_at = [0, 0.5, 0]\nfov = 40\nwidth = 48\nheight = 32\n\
         [render]\nspp = 16\nmax_depth = 6\nseed = 4\n\
         [[sphere]]\ncenter = [-0.6, 0.5, 0]\nradius = 0.5\nkd = [0.8, 0.7, 0.6]\n\
         [[sphere]]\ncenter = [0.6, 0.5, 0]\nradius = 0.5\nks = [0.9, 0.9, 0.9]\nillum = 3\n\
         [[sphere]]\ncenter = [0, -1000, 0]\nradius = 1000\nkd = [0.5, 0.5, 0.5]\n\
         [[light]]\ntype = \"area\"\nsize = [1, 0.5]\nposition = [0, 2, 1]\ndirection = [0, -1, -0.5]\npower = 30\n\
         [background]\nmap = \"sky.exr\"\nstrength = 1.5\nrotate = 40\n",
    )
    .unwrap();
    let scene = dir.path("scene.toml");
    let job = ["--tile", "16", "--batch-spp", "4"];
    let reference = dir.path("reference.exr");
    render(&scene, &reference, &[&job[..], &["--local-workers", "0"]].concat(), LIMIT);
    let expected = read_exr(&reference);
    assert!(expected.pixels.iter().any(|p| p.max_element() > 0.5), "the map lights the scene");
    for workers in ["1", "2", "3"] {
        let out = dir.path(&format!("w{workers}.exr"));
        render(&scene, &out, &[&job[..], &["--local-workers", workers, "--threads", "1"]].concat(), LIMIT);
        assert_same_bits(&read_exr(&out), &expected, &format!("{workers} local workers with a map"));
    }
}
