//! The worker executable from the outside: its help, and that it exits when its
//! standard input closes even though no coordinator ever answers.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const WORKER: &str = env!("CARGO_BIN_EXE_worker");

#[test]
fn help_lists_the_flags() {
    let out = Command::new(WORKER).arg("--help").output().expect("run worker --help");
    assert!(out.status.success(), "{out:?}");
    let help = String::from_utf8_lossy(&out.stdout);
    for flag in ["--coordinator", "--threads", "--cache", "--exit-on-stdin-eof", "--max-backoff-ms"] {
        assert!(help.contains(flag), "--help does not mention {flag}:\n{help}");
    }
}

#[test]
fn the_coordinator_flag_is_required() {
    let out = Command::new(WORKER).output().expect("run worker");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--coordinator"));
}

/// Waits up to `limit` for the child; kills it (and fails) on timeout.
fn wait_bounded(child: &mut std::process::Child, limit: Duration) -> std::process::ExitStatus {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait for worker") {
            return status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("worker did not exit within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn exits_when_stdin_closes_without_a_coordinator() {
    let cache = std::env::temp_dir().join(format!("tilefarm-worker-cli-test-{}", std::process::id()));
    let mut child = Command::new(WORKER)
        .args(["--coordinator", "http://127.0.0.1:1", "--threads", "1", "--exit-on-stdin-eof", "--cache"])
        .arg(&cache)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start worker");
    // Let it try to register a few times, then close its standard input.
    std::thread::sleep(Duration::from_millis(500));
    drop(child.stdin.take());
    let start = Instant::now();
    let status = wait_bounded(&mut child, Duration::from_secs(5));
    assert!(status.success(), "{status:?}");
    assert!(start.elapsed() < Duration::from_secs(3), "took {:?}", start.elapsed());
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    assert!(stderr.contains("cannot register"), "{stderr}");
    assert!(stderr.contains("standard input closed"), "{stderr}");
    let _ = std::fs::remove_dir_all(&cache);
}

#[test]
fn gives_up_on_an_unreachable_coordinator_when_asked() {
    let cache = std::env::temp_dir().join(format!("tilefarm-worker-cli-giveup-{}", std::process::id()));
    let mut child = Command::new(WORKER)
        .args(["--coordinator", "http://127.0.0.1:1", "--threads", "1", "--give-up-after-ms", "600", "--cache"])
        .arg(&cache)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start worker");
    let start = Instant::now();
    let status = wait_bounded(&mut child, Duration::from_secs(10));
    assert!(status.success(), "{status:?}");
    assert!(start.elapsed() >= Duration::from_millis(600), "gave up too early: {:?}", start.elapsed());
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    assert!(stderr.contains("giving up"), "{stderr}");
    let _ = std::fs::remove_dir_all(&cache);
}

#[test]
fn exits_at_once_with_stdin_already_closed() {
    let cache = std::env::temp_dir().join(format!("tilefarm-worker-cli-test2-{}", std::process::id()));
    let mut child = Command::new(WORKER)
        .args(["--coordinator", "127.0.0.1:1", "--exit-on-stdin-eof", "--cache"])
        .arg(&cache)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start worker");
    let status = wait_bounded(&mut child, Duration::from_secs(5));
    assert!(status.success(), "{status:?}");
    let _ = std::fs::remove_dir_all(&cache);
}

#[test]
fn sigterm_stops_it_promptly() {
    let cache = std::env::temp_dir().join(format!("tilefarm-worker-cli-test3-{}", std::process::id()));
    let mut child = Command::new(WORKER)
        .args(["--coordinator", "http://127.0.0.1:1", "--threads", "1", "--cache"])
        .arg(&cache)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start worker");
    std::thread::sleep(Duration::from_millis(300));
    let killed = Command::new("kill").args(["-TERM", &child.id().to_string()]).status();
    if !killed.is_ok_and(|s| s.success()) {
        let _ = child.kill();
        let _ = child.wait();
        return; // no `kill` command here: nothing to test
    }
    let status = wait_bounded(&mut child, Duration::from_secs(5));
    assert!(status.success(), "{status:?}");
    let _ = std::fs::remove_dir_all(&cache);
}

// ---------------------------------------------------------------- a fake coordinator

mod fake {
    use std::collections::BTreeMap;
    use std::sync::{Arc, Mutex};

    use proto::farm_server::{Farm, FarmServer};
    use sha2::{Digest, Sha256};
    use tonic::{Request, Response, Status};

    pub const SCENE: &str = "[camera]\nposition = [0, 0, -5]\nlook_at = [0, 0, 0]\nwidth = 64\nheight = 32\n\n\
        [[sphere]]\ncenter = [0, 0, 0]\nradius = 1.5\nkd = [0.5, 0.5, 0.5]\n";
    pub const NOTES: &[u8] = b"an extra file of the job, laid out beside the scene\n";
    pub const JOB: &str = "job-7";

    pub fn asset(path: &str, content: &[u8]) -> proto::AssetRef {
        proto::AssetRef { path: path.into(), sha256: hex::encode(Sha256::digest(content)), size: content.len() as u64 }
    }

    pub fn job() -> proto::JobSpec {
        proto::JobSpec {
            job_id: JOB.into(),
            scene: Some(asset("scene/scene.toml", SCENE.as_bytes())),
            assets: vec![asset("scene/extra/notes.txt", NOTES)],
            settings: Some(proto::RenderSettings {
                width: 16,
                integrator: "normals".into(),
                tile_size: 8,
                ..Default::default()
            }),
            group: String::new(),
        }
    }

    /// The four good units (two 8×8 tiles × two sample ranges), and two bad ones.
    pub fn units() -> Vec<proto::Unit> {
        let unit = |unit_id, x0, width, s0, s1| proto::Unit {
            job: Some(job()),
            unit_id,
            tile: Some(proto::Tile { x0, y0: 0, width, height: 8 }),
            sample_start: s0,
            sample_end: s1,
        };
        vec![
            unit(0, 0, 8, 0, 2),
            unit(1, 8, 8, 0, 2),
            unit(2, 0, 8, 2, 4),
            unit(3, 8, 8, 2, 4),
            unit(98, 0, 0, 0, 2),        // empty tile
            unit(99, 100, 8, 0, 2),      // outside the 16×8 image
            unit(97, 0, 8, 0, u32::MAX), // absurd sample range
        ]
    }

    #[derive(Default)]
    pub struct State {
        pub registrations: u32,
        pub current_id: u64,
        pub leases: u32,
        pub max_units_asked: Vec<u32>,
        pub fetches: Vec<String>,
        pub heartbeats: u32,
        pub submits: u32,
        pub results: BTreeMap<u64, proto::UnitResult>,
        pub refused_once: bool,
        /// The `held` list of each heartbeat, and when the big unit was abandoned.
        pub held: Vec<Vec<u64>>,
        pub abandoned_at: Option<usize>,
    }

    #[derive(Clone, Default)]
    pub struct Fake {
        pub state: Arc<Mutex<State>>,
        /// Serve assets with one byte flipped.
        pub corrupt: bool,
        /// Answer `Unavailable` to this many submissions first.
        pub unavailable_submits: Arc<Mutex<u32>>,
        /// Also lease unit 5, far too long to render, and abandon it at a heartbeat.
        pub big_unit: bool,
    }

    impl Fake {
        /// A submission: refused while "restarting", then once as if the coordinator had
        /// restarted (the worker must register again and send the same results under its
        /// new id); then each result is taken, once.
        fn take(&self, worker_id: u64, results: Vec<proto::UnitResult>) -> Result<Vec<proto::ResultOutcome>, Status> {
            {
                let mut unavailable = self.unavailable_submits.lock().unwrap();
                if *unavailable > 0 {
                    *unavailable -= 1;
                    return Err(Status::unavailable("coordinator busy restarting"));
                }
            }
            self.check_worker(worker_id)?;
            let mut s = self.state.lock().unwrap();
            s.submits += 1;
            if !s.refused_once {
                s.refused_once = true;
                s.current_id = 0;
                return Err(Status::unauthenticated(format!("unknown worker {worker_id}")));
            }
            Ok(results
                .into_iter()
                .map(|r| proto::ResultOutcome {
                    accepted: s.results.insert(r.unit_id, r).is_none(),
                    refused: String::new(),
                })
                .collect())
        }

        fn check_worker(&self, id: u64) -> Result<(), Status> {
            if self.state.lock().unwrap().current_id == id {
                Ok(())
            } else {
                Err(Status::unauthenticated(format!("unknown worker {id}")))
            }
        }
    }

    #[tonic::async_trait]
    impl Farm for Fake {
        async fn register(
            &self,
            request: Request<proto::RegisterRequest>,
        ) -> Result<Response<proto::RegisterReply>, Status> {
            let r = request.into_inner();
            assert_eq!(r.protocol_version, proto::PROTOCOL_VERSION);
            assert_eq!(r.threads, 2);
            let mut s = self.state.lock().unwrap();
            s.registrations += 1;
            s.current_id = 100 + s.registrations as u64;
            Ok(Response::new(proto::RegisterReply { worker_id: s.current_id, lease_ms: 2000, heartbeat_ms: 100 }))
        }

        async fn lease(&self, request: Request<proto::LeaseRequest>) -> Result<Response<proto::LeaseReply>, Status> {
            let r = request.into_inner();
            self.check_worker(r.worker_id)?;
            let mut s = self.state.lock().unwrap();
            s.leases += 1;
            s.max_units_asked.push(r.max_units);
            let reply = if s.leases == 1 {
                let mut units = units();
                if self.big_unit {
                    units.push(proto::Unit {
                        job: Some(job()),
                        unit_id: 5,
                        tile: Some(proto::Tile { x0: 0, y0: 0, width: 16, height: 8 }),
                        sample_start: 0,
                        sample_end: 1 << 20,
                    });
                }
                proto::LeaseReply { units, retry_after_ms: 0, shutdown: false, prepare: vec![] }
            } else if (s.results.len() == 4 && (!self.big_unit || s.abandoned_at.is_some()))
                || (self.corrupt && !s.fetches.is_empty() && s.leases > 3)
            {
                proto::LeaseReply { units: vec![], retry_after_ms: 0, shutdown: true, prepare: vec![] }
            } else {
                proto::LeaseReply { units: vec![], retry_after_ms: 50, shutdown: false, prepare: vec![] }
            };
            Ok(Response::new(reply))
        }

        async fn heartbeat(
            &self,
            request: Request<proto::HeartbeatRequest>,
        ) -> Result<Response<proto::HeartbeatReply>, Status> {
            let r = request.into_inner();
            self.check_worker(r.worker_id)?;
            let mut s = self.state.lock().unwrap();
            s.heartbeats += 1;
            let held: Vec<u64> = r.held.iter().map(|k| k.unit_id).collect();
            let mut reply = proto::HeartbeatReply::default();
            if self.big_unit && s.abandoned_at.is_none() && held.contains(&5) {
                s.abandoned_at = Some(s.held.len());
                reply.abandon.push(proto::UnitKey { job_id: JOB.into(), unit_id: 5 });
            }
            s.held.push(held);
            Ok(Response::new(reply))
        }

        async fn submit_result(
            &self,
            request: Request<proto::UnitResult>,
        ) -> Result<Response<proto::SubmitReply>, Status> {
            let r = request.into_inner();
            let accepted = self.take(r.worker_id, vec![r])?[0].accepted;
            Ok(Response::new(proto::SubmitReply { accepted }))
        }

        async fn submit_results(
            &self,
            request: Request<proto::SubmitResultsRequest>,
        ) -> Result<Response<proto::SubmitResultsReply>, Status> {
            let r = request.into_inner();
            Ok(Response::new(proto::SubmitResultsReply { outcomes: self.take(r.worker_id, r.results)? }))
        }

        type FetchAssetStream = tokio_stream::Iter<std::vec::IntoIter<Result<proto::AssetChunk, Status>>>;

        async fn fetch_asset(
            &self,
            request: Request<proto::AssetRequest>,
        ) -> Result<Response<Self::FetchAssetStream>, Status> {
            let sha = request.into_inner().sha256;
            self.state.lock().unwrap().fetches.push(sha.clone());
            let mut content = [SCENE.as_bytes(), NOTES]
                .into_iter()
                .find(|c| hex::encode(Sha256::digest(c)) == sha)
                .ok_or_else(|| Status::not_found(format!("no asset {sha}")))?
                .to_vec();
            if self.corrupt {
                content[3] ^= 0x20;
            }
            let (a, b) = content.split_at(content.len() / 2);
            let chunks = vec![Ok(proto::AssetChunk { data: a.to_vec() }), Ok(proto::AssetChunk { data: b.to_vec() })];
            Ok(Response::new(tokio_stream::iter(chunks)))
        }
    }

    /// Serves `fake` on a free loopback port; returns the URL.
    pub async fn serve(fake: Fake) -> String {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        tokio::spawn(
            tonic::transport::Server::builder()
                .add_service(FarmServer::new(fake))
                .serve_with_incoming(tokio_stream::wrappers::TcpListenerStream::new(listener)),
        );
        format!("http://{addr}")
    }
}

fn start_worker(url: &str, cache: &std::path::Path) -> std::process::Child {
    Command::new(WORKER)
        .args(["--coordinator", url, "--threads", "2", "--max-backoff-ms", "200", "--cache"])
        .arg(cache)
        .env("RUST_LOG", "debug,h2=info,hyper=info,tower=info,tonic=info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start worker")
}

async fn wait_async(child: &mut std::process::Child, limit: Duration) -> (std::process::ExitStatus, String) {
    let start = Instant::now();
    let mut stderr_pipe = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut stderr_pipe, &mut s);
        s
    });
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            let stderr = reader.join().unwrap();
            panic!("worker did not exit within {limit:?}; its log:\n{stderr}");
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    (status, reader.join().unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn renders_a_job_for_a_fake_coordinator() {
    let fake = fake::Fake::default();
    let url = fake::serve(fake.clone()).await;
    let cache = std::env::temp_dir().join(format!("tilefarm-worker-fake-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cache);
    let mut child = start_worker(&url, &cache);
    let (status, log) = wait_async(&mut child, Duration::from_secs(30)).await;
    assert!(status.success(), "{status:?}\n{log}");

    let s = fake.state.lock().unwrap();
    assert_eq!(s.registrations, 2, "registers again after 'unknown worker'\n{log}");
    assert_eq!(s.max_units_asked[0], 4, "asks for 2 × threads units first");
    assert_eq!(s.fetches.len(), 2, "each asset fetched once: {:?}", s.fetches);
    assert!(s.heartbeats >= 1);
    assert_eq!(s.results.keys().copied().collect::<Vec<_>>(), [0, 1, 2, 3], "{log}");
    for bad in ["unit job-7/98", "unit job-7/97", "unit job-7/99"] {
        assert!(log.contains(bad), "no message about {bad}:\n{log}");
    }

    // The files are laid out under the job folder, by their own paths.
    assert_eq!(std::fs::read(cache.join("jobs/job-7/scene/extra/notes.txt")).unwrap(), fake::NOTES);

    // The results are exactly what the tracer renders locally.
    let scene_path = cache.join("jobs/job-7/scene/scene.toml");
    let mut scene = tracer::scene::load_scene(&scene_path).unwrap();
    tracer::scene::Overrides { width: Some(16), ..Default::default() }.apply(&mut scene).unwrap();
    for u in fake::units().into_iter().take(4) {
        let t = u.tile.unwrap();
        let tile = tracer::film::Tile::new(t.x0, t.y0, t.width, t.height);
        let samples = tracer::film::SampleRange::new(u.sample_start, u.sample_end);
        let (acc, rays) =
            tracer::render::render_unit_counted(&scene, tracer::integrator::Integrator::Normals, tile, samples);
        let r = &s.results[&u.unit_id];
        assert_eq!(r.worker_id, 102);
        assert_eq!(r.job_id, fake::JOB);
        assert_eq!(r.tile, Some(t));
        assert_eq!((r.sample_start, r.sample_end), (u.sample_start, u.sample_end));
        assert_eq!(r.sums, acc.sums_to_bytes(), "unit {}", u.unit_id);
        assert_eq!(r.counts, acc.counts);
        assert!(r.counts.iter().all(|&c| c == 2));
        assert_eq!(r.nonfinite, acc.nonfinite);
        assert_eq!(r.rays, rays.rays);
    }
    let _ = std::fs::remove_dir_all(&cache);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_corrupted_asset_is_refused_and_the_worker_carries_on() {
    let fake = fake::Fake { corrupt: true, ..Default::default() };
    let url = fake::serve(fake.clone()).await;
    let cache = std::env::temp_dir().join(format!("tilefarm-worker-corrupt-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cache);
    let mut child = start_worker(&url, &cache);
    let (status, log) = wait_async(&mut child, Duration::from_secs(30)).await;
    assert!(status.success(), "{status:?}\n{log}");
    let s = fake.state.lock().unwrap();
    assert!(s.results.is_empty());
    assert!(log.contains("digest") && log.contains("scene/scene.toml"), "{log}");
    let sha = fake::asset("x", fake::SCENE.as_bytes()).sha256;
    assert!(!cache.join("blobs").join(&sha).exists(), "a corrupted blob must not be kept");
    let _ = std::fs::remove_dir_all(&cache);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn abandoned_units_are_dropped_and_results_survive_transport_errors() {
    let fake = fake::Fake { big_unit: true, unavailable_submits: std::sync::Arc::new(3.into()), ..Default::default() };
    let url = fake::serve(fake.clone()).await;
    let cache = std::env::temp_dir().join(format!("tilefarm-worker-abandon-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cache);
    let mut child = start_worker(&url, &cache);
    let start = Instant::now();
    let (status, log) = wait_async(&mut child, Duration::from_secs(30)).await;
    assert!(status.success(), "{status:?}\n{log}");
    // Unit 5 would take far longer than this: the worker neither waited for it nor sent it.
    assert!(start.elapsed() < Duration::from_secs(8), "took {:?}\n{log}", start.elapsed());
    let s = fake.state.lock().unwrap();
    assert_eq!(s.results.keys().copied().collect::<Vec<_>>(), [0, 1, 2, 3], "{log}");
    assert_eq!(*fake.unavailable_submits.lock().unwrap(), 0);
    assert!(log.contains("retrying"), "{log}");
    let at = s.abandoned_at.expect("unit 5 was reported as held");
    assert!(s.held[at + 1..].iter().all(|h| !h.contains(&5)), "still reported after abandon: {:?}", s.held);
    let _ = std::fs::remove_dir_all(&cache);
}
