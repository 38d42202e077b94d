//! Trust per identity, end to end on a farm with TLS and tokens, against the project's
//! own hostile client (a gRPC client written against `proto/tilefarm.proto` with a real
//! worker certificate): one certificate with several worker ids cannot forge an image
//! or get honest workers quarantined, its ban outlives a restart until an admin lifts
//! it, malformed results ban their identity, and one identity's registrations are
//! capped.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use tilefarm_e2e::tls::{bearer, certs_init, channel, register_request, token, worker};
use tilefarm_e2e::*;
use tonic::transport::Channel;

const LIMIT: Duration = Duration::from_secs(240);
/// 64×64 in 16² tiles × 4 batches of 4 spp: 64 units.
const JOB: [&str; 8] = ["--width", "64", "--spp", "16", "--tile", "16", "--batch-spp", "4"];

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

fn cornell() -> PathBuf {
    scenes().join("cornell-box/scene.toml")
}

/// `certs init` with four worker certificates and user alice, then `serve --tls` on it.
fn tls_farm(dir: &TempDir) -> (Coordinator, PathBuf) {
    let tls = dir.path("tls");
    certs_init(&tls, &["--workers", "4", "--users", "alice"]);
    (serve(dir, &tls), tls)
}

fn serve(dir: &TempDir, tls: &Path) -> Coordinator {
    let store = dir.path("store");
    Coordinator::serve(&[
        "--listen",
        "127.0.0.1:0",
        "--tls",
        tls.to_str().unwrap(),
        "--store",
        store.to_str().unwrap(),
        "--lease-ms",
        "2000",
        "--heartbeat-ms",
        "500",
    ])
}

/// A channel to the farm presenting worker certificate `name` (or none).
async fn connect(url: &str, tls: &Path, name: Option<&str>) -> Channel {
    channel(url, tls, name).await.unwrap()
}

fn admin<T>(tls: &Path, msg: T) -> tonic::Request<T> {
    bearer(tonic::Request::new(msg), &token(tls, "admin"))
}

fn list_workers(url: &str, tls: &Path) -> proto::ListWorkersReply {
    runtime().block_on(async {
        let mut jobs = proto::jobs_client::JobsClient::new(connect(url, tls, None).await);
        jobs.list_workers(admin(tls, proto::ListRequest {})).await.unwrap().into_inner()
    })
}

/// What the hostile client does with every unit it leases.
#[derive(Clone, Copy)]
enum Attack {
    /// Answers black at once, rendering nothing.
    Black,
    /// Answers with one sample too many in every count.
    Malformed,
}

/// The hostile client: `ids` registrations of worker certificate `cert`, each leasing
/// and answering every unit as `attack` says, until the farm refuses it or `stop`.
/// Returns (results sent, results accepted, the error that ended it).
fn hostile(
    url: String,
    tls: PathBuf,
    cert: &'static str,
    ids: usize,
    attack: Attack,
    stop: Arc<AtomicBool>,
    sent: Arc<AtomicU64>,
) -> std::thread::JoinHandle<(u64, String)> {
    std::thread::spawn(move || {
        runtime().block_on(async move {
            let mut farm = proto::farm_client::FarmClient::new(connect(&url, &tls, Some(cert)).await);
            let mut workers = Vec::new();
            for _ in 0..ids {
                workers.push(farm.register(register_request("hostile")).await.unwrap().into_inner().worker_id);
            }
            let mut accepted = 0;
            while !stop.load(Ordering::SeqCst) {
                for &w in &workers {
                    let lease = proto::LeaseRequest { worker_id: w, max_units: 2 };
                    let units = match farm.lease(lease).await {
                        Ok(r) => r.into_inner().units,
                        Err(e) => return (accepted, e.message().to_string()),
                    };
                    for u in units {
                        let job = u.job.as_ref().map(|j| j.job_id.clone()).unwrap_or_default();
                        let mut r = forged_result(w, &job, &u, 0);
                        if let Attack::Malformed = attack {
                            r.counts.iter_mut().for_each(|c| *c += 1);
                        }
                        sent.fetch_add(1, Ordering::SeqCst);
                        if farm.submit_result(r).await.is_ok_and(|a| a.into_inner().accepted) {
                            accepted += 1;
                        }
                    }
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            (accepted, "stopped".into())
        })
    })
}

fn submit(coord: &Coordinator, tls: &Path, out: &Path) {
    let mut cmd = Command::new(bin("coordinator"));
    cmd.args(["submit", cornell().to_str().unwrap(), "-q", "--wait", "-o", out.to_str().unwrap()])
        .args(JOB)
        .args(["--coordinator", &coord.url, "--tls"])
        .arg(tls)
        .env("TILEFARM_TOKEN", token(tls, "alice"));
    let sub = run(&mut cmd, LIMIT);
    assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
}

fn admin_command(coord: &Coordinator, tls: &Path, args: &[&str]) -> std::process::Output {
    let mut cmd = Command::new(bin("coordinator"));
    cmd.args(args).args(["--coordinator", &coord.url, "--tls"]).arg(tls).env("TILEFARM_TOKEN", token(tls, "admin"));
    run(&mut cmd, LIMIT)
}

#[test]
fn one_certificate_with_three_ids_cannot_forge_an_image_and_stays_banned() {
    let dir = TempDir::new("trust-forgery");
    let reference = dir.path("reference.exr");
    render(&cornell(), &reference, &[&JOB[..], &["--local-workers", "0"]].concat(), LIMIT);
    let (coord, tls) = tls_farm(&dir);
    let _honest =
        [worker(&coord, &tls, "worker-1", &dir.path("c1")), worker(&coord, &tls, "worker-2", &dir.path("c2"))];
    let (stop, sent) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicU64::new(0)));
    let forger = hostile(coord.url.clone(), tls.clone(), "worker-3", 3, Attack::Black, stop.clone(), sent.clone());
    eventually("two honest workers and three forged ids register", LIMIT, || {
        list_workers(&coord.url, &tls).workers.len() == 5
    });

    let out = dir.path("farm.exr");
    submit(&coord, &tls, &out);
    stop.store(true, Ordering::SeqCst);
    let (accepted, ended) = forger.join().unwrap();
    let list = list_workers(&coord.url, &tls);
    let banned: Vec<_> = list.identities.iter().filter(|i| i.banned).collect();
    let quarantined: Vec<_> = list.workers.iter().filter(|w| w.quarantined).collect();
    println!(
        "the forger sent {} black results, {accepted} accepted before its ban ({ended}); banned: {:?}",
        sent.load(Ordering::SeqCst),
        banned.iter().map(|i| (&i.name, &i.ban_reason)).collect::<Vec<_>>()
    );
    assert!(sent.load(Ordering::SeqCst) > 0, "the forger got work and lied");
    assert_same_bits(&read_exr(&out), &read_exr(&reference), "a farm with a forging certificate");
    assert_eq!(banned.len(), 1, "only the forging identity is banned: {:?}", list.identities);
    assert_eq!(quarantined.len(), 3, "its three ids, and no honest worker: {:?}", list.workers);
    assert!(quarantined.iter().all(|w| w.identity == banned[0].name && w.hostname == "hostile"));
    let forger_identity = banned[0].name.clone();

    // It cannot come back under a new registration, nor after a restart (once the ban
    // is on disk: serve writes bans at its next turn, within a quarter second).
    let bans = dir.path("store").join("bans.json");
    eventually("the ban is written", LIMIT, || {
        std::fs::read_to_string(&bans).is_ok_and(|t| t.contains(&forger_identity))
    });
    drop(coord);
    let coord = serve(&dir, &tls);
    let refused = runtime().block_on(async {
        let mut farm = proto::farm_client::FarmClient::new(connect(&coord.url, &tls, Some("worker-3")).await);
        farm.register(register_request("hostile")).await.unwrap_err()
    });
    assert!(refused.message().contains("banned"), "{}", refused.message());
    let listed = admin_command(&coord, &tls, &["workers"]);
    let text = String::from_utf8_lossy(&listed.stdout);
    assert!(text.contains(&forger_identity) && text.contains("BANNED"), "{text}");

    // An admin lifts the ban; the certificate registers again.
    let lifted = admin_command(&coord, &tls, &["unban", &forger_identity]);
    assert!(lifted.status.success(), "{}", String::from_utf8_lossy(&lifted.stderr));
    runtime().block_on(async {
        let mut farm = proto::farm_client::FarmClient::new(connect(&coord.url, &tls, Some("worker-3")).await);
        farm.register(register_request("hostile")).await.expect("registers once the ban is lifted");
    });
}

#[test]
fn malformed_results_ban_their_identity_and_registrations_are_capped() {
    let dir = TempDir::new("trust-malformed");
    let reference = dir.path("reference.exr");
    render(&cornell(), &reference, &[&JOB[..], &["--local-workers", "0"]].concat(), LIMIT);
    let (coord, tls) = tls_farm(&dir);
    let _honest = worker(&coord, &tls, "worker-1", &dir.path("c1"));
    let (stop, sent) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicU64::new(0)));
    let broken = hostile(coord.url.clone(), tls.clone(), "worker-2", 1, Attack::Malformed, stop.clone(), sent.clone());
    eventually("both register", LIMIT, || list_workers(&coord.url, &tls).workers.len() == 2);
    let out = dir.path("farm.exr");
    submit(&coord, &tls, &out);
    stop.store(true, Ordering::SeqCst);
    let (accepted, ended) = broken.join().unwrap();
    let sent = sent.load(Ordering::SeqCst);
    println!("the broken worker sent {sent} malformed results ({accepted} accepted) and was told: {ended}");
    assert_eq!(accepted, 0);
    assert!((1..=5).contains(&sent), "banned within 5 malformed results, sent {sent}");
    assert!(ended.contains("quarantined"), "{ended}");
    let list = list_workers(&coord.url, &tls);
    assert_eq!(list.identities.iter().filter(|i| i.banned).count(), 1, "{:?}", list.identities);
    assert_same_bits(&read_exr(&out), &read_exr(&reference), "a farm with a broken worker");

    // One certificate holds at most 8 live registrations.
    let refused = runtime().block_on(async {
        let mut farm = proto::farm_client::FarmClient::new(connect(&coord.url, &tls, Some("worker-4")).await);
        for _ in 0..8 {
            farm.register(register_request("hostile")).await.unwrap();
        }
        farm.register(register_request("hostile")).await.unwrap_err()
    });
    assert!(refused.message().contains("--max-workers-per-identity 8"), "{}", refused.message());
}

/// The hoarder: `ids` registrations of worker certificate `cert` that lease all they
/// can and renew every lease by heartbeat, never answering, until `stop`. Returns the
/// most units it held at once.
fn hoarder(
    url: String,
    tls: PathBuf,
    cert: &'static str,
    ids: usize,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<usize> {
    std::thread::spawn(move || {
        runtime().block_on(async move {
            let mut farm = proto::farm_client::FarmClient::new(connect(&url, &tls, Some(cert)).await);
            let mut held: Vec<(u64, Vec<proto::UnitKey>)> = Vec::new();
            for _ in 0..ids {
                held.push((
                    farm.register(register_request("hostile")).await.unwrap().into_inner().worker_id,
                    Vec::new(),
                ));
            }
            let mut most = 0;
            while !stop.load(Ordering::SeqCst) {
                for (w, keys) in &mut held {
                    let lease = proto::LeaseRequest { worker_id: *w, max_units: 256 };
                    if let Ok(r) = farm.lease(lease).await {
                        let units = r.into_inner().units;
                        keys.extend(units.iter().map(|u| proto::UnitKey {
                            job_id: u.job.as_ref().map(|j| j.job_id.clone()).unwrap_or_default(),
                            unit_id: u.unit_id,
                        }));
                    }
                    let beat = proto::HeartbeatRequest { worker_id: *w, held: keys.clone() };
                    if let Ok(r) = farm.heartbeat(beat).await {
                        let gone = r.into_inner().abandon;
                        keys.retain(|k| !gone.contains(k));
                    }
                }
                most = most.max(held.iter().map(|(_, k)| k.len()).sum());
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            most
        })
    })
}

/// A hoarder with 8 ids of one certificate, leasing everything it may and renewing it
/// forever, delays a job by less than its own time: it holds only its share while
/// others are live, and spares of its units go to the others.
#[test]
fn a_hoarder_with_eight_ids_does_not_stall_a_job() {
    const BIG: [&str; 8] = ["--width", "256", "--spp", "64", "--tile", "32", "--batch-spp", "16"];
    let dir = TempDir::new("trust-hoarder");
    let reference = dir.path("reference.exr");
    render(&cornell(), &reference, &[&BIG[..], &["--local-workers", "0"]].concat(), LIMIT);
    let (coord, tls) = tls_farm(&dir);
    let _honest =
        [worker(&coord, &tls, "worker-1", &dir.path("c1")), worker(&coord, &tls, "worker-2", &dir.path("c2"))];
    eventually("the honest workers register", LIMIT, || list_workers(&coord.url, &tls).workers.len() == 2);
    let timed = |name: &str| {
        let out = dir.path(name);
        let mut cmd = Command::new(bin("coordinator"));
        cmd.args(["submit", cornell().to_str().unwrap(), "-q", "--wait", "-o", out.to_str().unwrap()])
            .args(BIG)
            .args(["--coordinator", &coord.url, "--tls"])
            .arg(&tls)
            .env("TILEFARM_TOKEN", token(&tls, "alice"));
        let t = std::time::Instant::now();
        let sub = run(&mut cmd, LIMIT);
        assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
        assert_same_bits(&read_exr(&out), &read_exr(&reference), name);
        t.elapsed().as_secs_f64()
    };
    timed("warm-up.exr"); // loads the scene and builds the honest identities' records
    let alone = timed("alone.exr");
    let stop = Arc::new(AtomicBool::new(false));
    let hoard = hoarder(coord.url.clone(), tls.clone(), "worker-3", 8, stop.clone());
    eventually("the hoarder's 8 ids register", LIMIT, || list_workers(&coord.url, &tls).workers.len() == 10);
    let hoarded = timed("hoarded.exr");
    stop.store(true, Ordering::SeqCst);
    let most = hoard.join().unwrap();
    println!(
        "job alone {alone:.2} s, beside a hoarder of 8 ids {hoarded:.2} s ({:.2}×); it held {most} units at most",
        hoarded / alone
    );
    assert!(most > 0, "the hoarder got units");
    assert!(hoarded <= 2.0 * alone, "{hoarded:.2} s against {alone:.2} s alone");
}

/// A user's jobs together may take at most `--max-user-memory-mb`: the third of three
/// jobs of the largest size fails as it starts, saying which limit, and the coordinator's
/// memory stays within the budget.
#[test]
fn a_users_third_largest_job_is_refused_and_memory_stays_in_budget() {
    let dir = TempDir::new("trust-budget");
    let tls = dir.path("tls");
    certs_init(&tls, &["--users", "alice"]);
    let store = dir.path("store");
    let limits = ["--max-job-memory-mb", "40", "--max-user-memory-mb", "90"];
    let coord = Coordinator::serve(
        &[
            &["--listen", "127.0.0.1:0", "--tls", tls.to_str().unwrap(), "--store", store.to_str().unwrap()],
            &limits[..],
        ]
        .concat(),
    );
    let rss = || {
        let status = std::fs::read_to_string(format!("/proc/{}/status", coord.proc.pid())).unwrap();
        let line = status.lines().find(|l| l.starts_with("VmRSS:")).unwrap().to_string();
        line.split_whitespace().nth(1).unwrap().parse::<u64>().unwrap() >> 10 // MiB
    };
    let before = rss();
    // 800×800 at 52 bytes a pixel: 31.7 MiB of sums, and its units; no workers, so
    // they stay running.
    let submit = || {
        let mut cmd = Command::new(bin("coordinator"));
        cmd.args(["submit", cornell().to_str().unwrap(), "-q", "--width", "800", "--height", "800", "--spp", "16"])
            .args(["--coordinator", &coord.url, "--tls"])
            .arg(&tls)
            .env("TILEFARM_TOKEN", token(&tls, "alice"));
        let out = run(&mut cmd, LIMIT);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).trim().to_string()
    };
    let state_of = |job: &str| {
        runtime().block_on(async {
            let mut jobs = proto::jobs_client::JobsClient::new(connect(&coord.url, &tls, None).await);
            let all = jobs.list_jobs(admin(&tls, proto::ListRequest {})).await.unwrap().into_inner().jobs;
            all.into_iter().find(|j| j.job_id == job).unwrap()
        })
    };
    let settled = |job: &str| {
        let mut last = None;
        eventually("the job starts or fails", LIMIT, || {
            let s = state_of(job);
            let done = matches!(s.state(), proto::JobState::Running | proto::JobState::Failed);
            last = Some(s);
            done
        });
        last.unwrap()
    };
    for _ in 0..2 {
        let job = submit();
        assert_eq!(settled(&job).state(), proto::JobState::Running);
    }
    let third = settled(&submit());
    assert_eq!(third.state(), proto::JobState::Failed, "{third:?}");
    assert!(third.error.contains("--max-user-memory-mb"), "{}", third.error);
    let after = rss();
    println!(
        "coordinator memory {before} MiB before, {after} MiB with two 32 MiB jobs running; the third: {}",
        third.error
    );
    assert!(after <= before + 90, "{after} MiB against {before} MiB before and a 90 MiB budget");
}
