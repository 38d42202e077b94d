//! Verified results end to end: a worker that returns wrong sums is caught by a check,
//! quarantined, and everything it returned is rendered again, so the farm's image is
//! bit-identical to an honest render.
//!
//! The liar is the real worker (its protocol machine, gRPC link and render pool) with
//! one change: after its first results (which a farm always checks) it adds 1 to one sum
//! of every result, as a subtly broken or malicious machine would.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use tilefarm_e2e::*;
use tracer::film::{SampleRange, Tile};
use worker::{Executor, LoadedJob, RenderOutcome, RenderPool};

const LIMIT: Duration = Duration::from_secs(240);
/// 64×64 in 16² tiles × 16 batches of 4 spp: 256 units, enough for the liar to be
/// checked many times over.
const JOB: [&str; 8] = ["--width", "64", "--spp", "64", "--tile", "16", "--batch-spp", "4"];
/// Results of a worker's first this-many are all checked (`serve`'s rule).
const PROBATION: u64 = 4;

struct Liar {
    pool: RenderPool,
    results: Arc<AtomicU64>,
    lies: Arc<AtomicU64>,
}

impl Executor for Liar {
    fn threads(&self) -> usize {
        self.pool.threads()
    }

    fn render(
        &self,
        job: Arc<LoadedJob>,
        tile: Tile,
        samples: SampleRange,
        cancel: Arc<AtomicBool>,
        done: impl FnOnce(RenderOutcome) + Send + 'static,
    ) {
        let (results, lies) = (Arc::clone(&self.results), Arc::clone(&self.lies));
        self.pool.render(job, tile, samples, cancel, move |outcome| {
            done(match outcome {
                RenderOutcome::Done { mut acc, rays, elapsed } => {
                    if results.fetch_add(1, Ordering::SeqCst) >= PROBATION {
                        acc.sums[0][0] += 1;
                        lies.fetch_add(1, Ordering::SeqCst);
                    }
                    RenderOutcome::Done { acc, rays, elapsed }
                }
                other => other,
            })
        });
    }
}

#[test]
fn a_lying_worker_is_quarantined_and_the_image_equals_the_honest_render() {
    let dir = TempDir::new("verify-liar");
    let reference = dir.path("reference.exr");
    // For the figures in bench/RESULTS.md: TILEFARM_LIAR_VERIFY=0.02 TILEFARM_LIAR_SPP=1024
    // measure how long a liar lasts at the default fraction (on a job large enough).
    let verify = std::env::var("TILEFARM_LIAR_VERIFY").unwrap_or_else(|_| "0.2".into());
    let spp = std::env::var("TILEFARM_LIAR_SPP").unwrap_or_else(|_| "64".into());
    let job = [&JOB[..2], &["--spp", spp.as_str()], &JOB[4..]].concat();
    let coord = Coordinator::start(
        &dir.path("store"),
        &["--verify", &verify, "--lease-ms", "2000", "--heartbeat-ms", "500", "--speculate-after-ms", "60000"],
    );
    render(
        &scenes().join("cornell-box/scene.toml"),
        &reference,
        &[&job[..], &["--local-workers", "0"]].concat(),
        LIMIT,
    );
    let _honest = [coord.worker(1, &dir.path("cache-1")), coord.worker(1, &dir.path("cache-2"))];

    // The liar, in this process, on its own runtime.
    let (results, lies) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
    let liar = Liar { pool: RenderPool::new(1).unwrap(), results: Arc::clone(&results), lies: Arc::clone(&lies) };
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(None);
    let url = coord.url.clone();
    let cache = dir.path("cache-liar");
    let liar_thread = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build().unwrap();
        rt.block_on(async move {
            let link =
                worker::GrpcLink::connect(&url, &Default::default(), &cache, Duration::from_millis(200)).unwrap();
            let settings = worker::Settings {
                coordinator: url.clone(),
                threads: 1,
                max_backoff: Duration::from_millis(200),
                give_up_after: Some(Duration::from_secs(5)),
            };
            // Refused once quarantined: an error here is the expected end.
            let _ = worker::drive(link, Arc::new(liar), settings, stop_rx).await;
        })
    });
    // All three at work before the job comes: on a fast machine two workers alone may
    // finish it before the liar has registered.
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    let registered = || {
        rt.block_on(async {
            let mut jobs = proto::jobs_client::JobsClient::connect(coord.url.clone()).await.unwrap();
            jobs.list_workers(proto::ListRequest {}).await.unwrap().into_inner().workers.len()
        })
    };
    eventually("the two honest workers and the liar register", LIMIT, || registered() == 3);

    let out = dir.path("farm.exr");
    let started = Instant::now();
    let sub = coord.submit(
        &scenes().join("cornell-box/scene.toml"),
        &[&job[..], &["--wait", "-o", out.to_str().unwrap()]].concat(),
        LIMIT,
    );
    assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
    let farm_time = started.elapsed();
    let _ = stop_tx.send(Some(worker::Stop::Signal));

    let (workers, job) = rt.block_on(async {
        let mut jobs = proto::jobs_client::JobsClient::connect(coord.url.clone()).await.unwrap();
        let workers = jobs.list_workers(proto::ListRequest {}).await.unwrap().into_inner().workers;
        let job = jobs.list_jobs(proto::ListRequest {}).await.unwrap().into_inner().jobs.remove(0);
        (workers, job)
    });
    let quarantined: Vec<_> = workers.iter().filter(|w| w.quarantined).collect();
    println!(
        "the liar returned {} results ({} lies) before quarantine; {} units checked, {} discarded; farm time {:.2} s",
        results.load(Ordering::SeqCst),
        lies.load(Ordering::SeqCst),
        job.units_checked,
        job.units_discarded,
        farm_time.as_secs_f64()
    );
    assert!(lies.load(Ordering::SeqCst) > 0, "the liar lied at least once");
    assert_eq!(quarantined.len(), 1, "exactly the liar is quarantined: {workers:?}");
    assert!(job.warnings.iter().any(|w| w.contains("quarantined")), "status shows the event: {:?}", job.warnings);
    assert!(job.units_checked > 0);
    assert_same_bits(&read_exr(&out), &read_exr(&reference), "a farm with a lying worker");
    liar_thread.join().unwrap();
}
