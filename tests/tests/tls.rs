//! A farm over TLS with access control, end to end: `certs init`, `serve --tls`, workers
//! with certificates, users with tokens. Every refusal is checked against the running
//! coordinator, which stays up and renders the honest job bit for bit.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::tls::{bearer, certs_init, channel, register_request, token, worker};
use tilefarm_e2e::*;
use tonic::Code;
use tonic::transport::Endpoint;

const LIMIT: Duration = Duration::from_secs(180);
const JOB: [&str; 8] = ["--width", "48", "--spp", "8", "--tile", "16", "--batch-spp", "4"];

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

fn cornell() -> PathBuf {
    scenes().join("cornell-box/scene.toml")
}

fn register() -> proto::RegisterRequest {
    register_request("rogue")
}

/// `coordinator CMD … --coordinator URL --tls DIR` as user `who`.
fn client(coord: &Coordinator, tls: &Path, who: &str, args: &[&str]) -> std::process::Output {
    let mut cmd = Command::new(bin("coordinator"));
    cmd.args(args).args(["--coordinator", &coord.url, "--tls"]).arg(tls).env("TILEFARM_TOKEN", token(tls, who));
    run(&mut cmd, LIMIT)
}

#[test]
fn a_tls_farm_renders_for_its_users_and_refuses_everyone_else() {
    let dir = TempDir::new("tls-farm");
    let tls = dir.path("tls");
    certs_init(&tls, &["--workers", "2", "--users", "alice,bob"]);
    let other_farm = dir.path("other-tls");
    certs_init(&other_farm, &[]);
    let coord = Coordinator::serve(&[
        "--listen",
        "127.0.0.1:0",
        "--tls",
        tls.to_str().unwrap(),
        "--store",
        dir.path("store").to_str().unwrap(),
    ]);
    assert!(coord.url.starts_with("https://"), "{}", coord.url);
    let _workers =
        [worker(&coord, &tls, "worker-1", &dir.path("c1")), worker(&coord, &tls, "worker-2", &dir.path("c2"))];

    // Alice renders over TLS; the image is the in-process one, bit for bit.
    let reference = dir.path("reference.exr");
    render(&cornell(), &reference, &[&JOB[..], &["--local-workers", "0"]].concat(), LIMIT);
    let out = dir.path("alice.exr");
    let sub = client(
        &coord,
        &tls,
        "alice",
        &[&["submit", cornell().to_str().unwrap(), "-q", "--wait", "-o", out.to_str().unwrap()], &JOB[..]].concat(),
    );
    assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
    assert_same_bits(&read_exr(&out), &read_exr(&reference), "a render over TLS");
    let job = "job-1";

    // Bob sees none of Alice's jobs, and may neither fetch nor cancel them.
    let status = client(&coord, &tls, "bob", &["status"]);
    assert!(!String::from_utf8_lossy(&status.stdout).contains(job), "{}", String::from_utf8_lossy(&status.stdout));
    for cmd in [&["cancel", job][..], &["fetch", job, "-o", dir.path("bob.exr").to_str().unwrap()]] {
        let o = client(&coord, &tls, "bob", cmd);
        assert!(!o.status.success());
        assert!(
            String::from_utf8_lossy(&o.stderr).contains("not one of your jobs"),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    // The admin may.
    let o = client(&coord, &tls, "admin", &["fetch", job, "-q", "-o", dir.path("admin.exr").to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // A group's stored frames are named only to their owner (and admins): Bob's
    // `fetch clip` learns no frame of it.
    let src = cornell().parent().unwrap().to_path_buf();
    for f in ["cbox.obj", "cbox.mtl"] {
        std::fs::copy(src.join(f), dir.path(f)).unwrap();
    }
    for i in 1..=2 {
        std::fs::copy(cornell(), dir.path(&format!("clip.{i:04}.toml"))).unwrap();
    }
    let pattern = dir.path("clip.####.toml");
    let sub = client(
        &coord,
        &tls,
        "alice",
        &[&["submit", pattern.to_str().unwrap(), "--frames", "1-2", "-q"], &JOB[..]].concat(),
    );
    assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
    let stored = |who: &str| {
        let token = token(&tls, who);
        runtime().block_on(async {
            let ch = channel(&coord.url, &tls, None).await.unwrap();
            let req = bearer(tonic::Request::new(proto::GroupRequest { name: "clip".into() }), &token);
            proto::jobs_client::JobsClient::new(ch).stored_frames(req).await.unwrap().into_inner().jobs
        })
    };
    eventually("alice's frames are stored", LIMIT, || stored("alice").len() == 2);
    assert_eq!(stored("admin").len(), 2);
    assert!(stored("bob").is_empty(), "bob was told of alice's frames");
    // Asked by its id, a stored frame is described to its owner and refused to Bob.
    let frame = stored("alice")[0].job_id.clone();
    let stored_job = |who: &str| {
        let token = token(&tls, who);
        runtime().block_on(async {
            let ch = channel(&coord.url, &tls, None).await.unwrap();
            let req = bearer(tonic::Request::new(proto::JobRequest { job_id: frame.clone() }), &token);
            proto::jobs_client::JobsClient::new(ch).stored_job(req).await.map(|r| r.into_inner())
        })
    };
    let mine = stored_job("alice").expect("alice's own frame");
    assert_eq!((mine.state, mine.owner.as_str()), (proto::JobState::Done as i32, "alice"), "{mine:?}");
    assert_eq!(stored_job("bob").unwrap_err().code(), Code::PermissionDenied);
    let o = client(&coord, &tls, "bob", &["fetch", "clip", "-o", dir.path("bob.####.exr").to_str().unwrap()]);
    assert!(!o.status.success() && !dir.path("bob.0001.exr").exists());
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(said.contains("clip is not one of your jobs") && !said.contains("job-"), "{said}");

    runtime().block_on(async {
        use proto::farm_client::FarmClient;
        use proto::jobs_client::JobsClient;
        let list = || proto::ListRequest {};
        // No token: refused.
        let ch = channel(&coord.url, &tls, None).await.unwrap();
        let e = JobsClient::new(ch.clone()).list_jobs(list()).await.unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
        // A wrong token: refused.
        let e =
            JobsClient::new(ch.clone()).list_jobs(bearer(tonic::Request::new(list()), "0123abcd")).await.unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
        // A user token may not join as a worker.
        let e = FarmClient::new(ch.clone())
            .register(bearer(tonic::Request::new(register()), &token(&tls, "alice")))
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
        // A worker certificate may not submit, list or cancel.
        let w1 = channel(&coord.url, &tls, Some("worker-1")).await.unwrap();
        let e = JobsClient::new(w1.clone()).list_jobs(list()).await.unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
        let e = JobsClient::new(w1.clone()).cancel_job(proto::JobRequest { job_id: job.into() }).await.unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
        // A worker id belongs to the certificate that registered it.
        let mine = FarmClient::new(w1.clone()).register(register()).await.unwrap().into_inner().worker_id;
        let w2 = channel(&coord.url, &tls, Some("worker-2")).await.unwrap();
        let e = FarmClient::new(w2).lease(proto::LeaseRequest { worker_id: mine, max_units: 1 }).await.unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
        assert!(e.message().contains("another identity"), "{e:?}");
        // Another farm's certificates are refused by the TLS layer itself.
        let stranger = channel(&coord.url, &other_farm, Some("worker")).await;
        match stranger {
            Err(_) => {}
            Ok(ch) => {
                assert!(FarmClient::new(ch).register(register()).await.is_err(), "another CA's worker was let in")
            }
        }
        // Plain text is not spoken.
        let plain = coord.url.replace("https://", "http://");
        let plain = Endpoint::from_shared(plain).unwrap().connect().await;
        if let Ok(ch) = plain {
            assert!(JobsClient::new(ch).list_jobs(list()).await.is_err());
        }
    });
    // After all that, the farm is up and still renders Alice's next job.
    let again = dir.path("again.exr");
    let sub = client(
        &coord,
        &tls,
        "alice",
        &[&["submit", cornell().to_str().unwrap(), "-q", "--wait", "-o", again.to_str().unwrap()], &JOB[..]].concat(),
    );
    assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
    assert_same_bits(&read_exr(&again), &read_exr(&reference), "after the attacks");
}

#[test]
fn certs_init_never_overwrites_a_farm_s_keys() {
    let dir = TempDir::new("tls-init");
    let tls = dir.path("tls");
    certs_init(&tls, &[]);
    let before = std::fs::read(tls.join("ca.key")).unwrap();
    let out = run(Command::new(bin("coordinator")).args(["certs", "init"]).arg(&tls), LIMIT);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("not empty"));
    assert_eq!(std::fs::read(tls.join("ca.key")).unwrap(), before);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        for secret in ["ca.key", "server.key", "worker.key", "admin.token", "user.token"] {
            let mode = std::fs::metadata(tls.join(secret)).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode, 0o600, "{secret}");
        }
    }
}
