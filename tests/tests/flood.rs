//! Idle connections cannot lock a farm out: a coordinator limited to systemd's default
//! number of open files, holding more idle connections on each of its ports than that,
//! still answers `/healthz` and an authenticated `ListJobs` over TLS; and connections
//! that never authenticate or send a request are closed after the timeouts. Real
//! processes on 127.0.0.1.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::time::{Duration, Instant};

use tilefarm_e2e::tls::{bearer, certs_init, channel, token};
use tilefarm_e2e::*;
use tonic::transport::Endpoint;

const LIMIT: Duration = Duration::from_secs(60);
/// How fast the farm must answer while flooded.
const ANSWER: Duration = Duration::from_secs(10);
/// Idle connections opened to each port: more than the coordinator's file limit.
const FLOOD: usize = 1100;
const FILE_LIMIT: u64 = 1024;
/// `serve`'s default --max-pending-connections.
const MAX_PENDING: usize = 256;

/// Raises this process's soft limit on open files to at least `needed` (within its
/// hard limit), for the flood's sockets.
fn raise_own_file_limit(needed: u64) {
    let mut lim = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: getrlimit and setrlimit only read and write the struct given.
    unsafe {
        assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim), 0, "getrlimit");
        if lim.rlim_cur < needed {
            lim.rlim_cur = needed.min(lim.rlim_max);
            assert_eq!(libc::setrlimit(libc::RLIMIT_NOFILE, &lim), 0, "setrlimit");
        }
    }
    assert!(lim.rlim_cur >= needed, "this test needs {needed} open files; the hard limit is {}", lim.rlim_max);
}

/// `coordinator serve ARGS…` limited to [`FILE_LIMIT`] open files, as under systemd's
/// default.
fn serve_limited(args: &[&str]) -> Coordinator {
    let coord = Coordinator::serve_with(args, |cmd| {
        // SAFETY: setrlimit is async-signal-safe, as a pre_exec hook requires.
        unsafe {
            cmd.pre_exec(|| {
                let lim = libc::rlimit { rlim_cur: FILE_LIMIT, rlim_max: FILE_LIMIT };
                if libc::setrlimit(libc::RLIMIT_NOFILE, &lim) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    });
    let limits = std::fs::read_to_string(format!("/proc/{}/limits", coord.proc.pid())).expect("/proc limits");
    let line = limits.lines().find(|l| l.starts_with("Max open files")).expect("Max open files");
    assert_eq!(line.split_whitespace().nth(3), Some(FILE_LIMIT.to_string().as_str()), "{line}");
    coord
}

fn open_files(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd")).expect("/proc fd").count()
}

fn grpc_addr(coord: &Coordinator) -> SocketAddr {
    coord.url.trim_start_matches("https://").trim_start_matches("http://").parse().expect("address")
}

/// `ListJobs` over TLS as the bearer of `token`, bounded by [`ANSWER`]: how long it took.
fn list_jobs_tls(url: &str, tls: &Path, token: &str) -> Duration {
    let start = Instant::now();
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    rt.block_on(async {
        let call = async {
            let ch = channel(url, tls, None).await?;
            let req = bearer(tonic::Request::new(proto::ListRequest {}), token);
            let jobs = proto::jobs_client::JobsClient::new(ch).list_jobs(req).await?;
            Ok::<_, Box<dyn std::error::Error>>(jobs.into_inner().jobs)
        };
        match tokio::time::timeout(ANSWER, call).await {
            Ok(Ok(jobs)) => assert!(jobs.is_empty(), "{jobs:?}"),
            Ok(Err(e)) => panic!("ListJobs over TLS failed: {e}"),
            Err(_) => panic!("ListJobs over TLS did not answer within {ANSWER:?}"),
        }
    });
    start.elapsed()
}

/// `count` idle connections to `addr` (nothing is ever sent on them).
fn flood(addr: SocketAddr, count: usize) -> Vec<TcpStream> {
    (0..count)
        .map(|i| {
            TcpStream::connect_timeout(&addr, ANSWER)
                .unwrap_or_else(|e| panic!("idle connection {i} of {count} to {addr}: {e}"))
        })
        .collect()
}

/// How many of `conns` the server has closed.
fn closed_by_server(conns: &[TcpStream]) -> usize {
    conns
        .iter()
        .filter(|s| {
            let mut s: &TcpStream = s;
            s.set_nonblocking(true).expect("nonblocking");
            match s.read(&mut [0u8; 1]) {
                Ok(0) => true,
                Ok(_) => false,
                Err(e) => e.kind() != ErrorKind::WouldBlock,
            }
        })
        .count()
}

#[test]
fn a_flood_of_idle_connections_locks_out_neither_probes_nor_users() {
    raise_own_file_limit(2 * FLOOD as u64 + 256);
    let dir = TempDir::new("flood");
    let tls = dir.path("tls");
    certs_init(&tls, &["--users", "alice"]);
    let alice = token(&tls, "alice");
    let http = format!("127.0.0.1:{}", free_port());
    let store = dir.path("store");
    let mut coord = serve_limited(&[
        "--listen",
        "127.0.0.1:0",
        "--tls",
        tls.to_str().unwrap(),
        "--http",
        &http,
        "--store",
        store.to_str().unwrap(),
        // Timeouts longer than the test: only the cap on pending connections keeps the
        // flood from taking every file.
        "--handshake-timeout-ms",
        "600000",
        "--header-timeout-ms",
        "600000",
    ]);
    eventually("the HTTP side answering", LIMIT, || TcpStream::connect(&http).is_ok());
    assert_eq!(http_get(&http, "/healthz", None, ANSWER), (200, "ok\n".into()));
    list_jobs_tls(&coord.url, &tls, &alice);
    let before = open_files(coord.proc.pid());

    let start = Instant::now();
    let grpc_flood = flood(grpc_addr(&coord), FLOOD);
    let http_flood = flood(http.parse().unwrap(), FLOOD);
    let opened = start.elapsed();

    // While every one of them is open on this side, the farm answers.
    let start = Instant::now();
    assert_eq!(http_get(&http, "/healthz", None, ANSWER), (200, "ok\n".into()));
    let healthz = start.elapsed();
    assert!(healthz < ANSWER, "/healthz took {healthz:?}");
    let list = list_jobs_tls(&coord.url, &tls, &alice);
    assert!(list < ANSWER, "ListJobs took {list:?}");

    // The coordinator holds at most the cap of pending connections per port: the
    // oldest idle ones were closed to make room, and its open files stay well inside
    // the limit.
    let mut closed = (0, 0);
    eventually("the oldest idle connections closed", ANSWER, || {
        closed = (closed_by_server(&grpc_flood), closed_by_server(&http_flood));
        closed.0 >= FLOOD - MAX_PENDING && closed.1 >= FLOOD - MAX_PENDING
    });
    let during = open_files(coord.proc.pid());
    assert!(during <= before + 2 * MAX_PENDING + 32, "{during} open files with the flood ({before} before)");
    assert!(coord.proc.child.try_wait().unwrap().is_none(), "the coordinator exited");
    eprintln!(
        "flood: {FLOOD} idle connections to each port opened in {opened:?}; /healthz in {healthz:?}, ListJobs over \
         TLS in {list:?}; closed by the coordinator: {} gRPC, {} HTTP; its open files {before} before, {during} \
         during",
        closed.0, closed.1
    );
    drop((grpc_flood, http_flood));
    assert_eq!(http_get(&http, "/healthz", None, ANSWER), (200, "ok\n".into()));
}

/// Waits (bounded) for the server to close `s`, which sent `sent`; how long it took.
fn time_to_close(mut s: TcpStream, sent: &[u8]) -> Duration {
    let start = Instant::now();
    s.write_all(sent).expect("send");
    s.set_read_timeout(Some(LIMIT)).expect("timeout");
    let mut got = Vec::new();
    match s.read_to_end(&mut got) {
        Ok(_) => {}
        Err(e) => assert!(
            matches!(e.kind(), ErrorKind::ConnectionReset | ErrorKind::BrokenPipe),
            "the connection was not closed: {e}"
        ),
    }
    let took = start.elapsed();
    if !sent.is_empty() {
        let text = String::from_utf8_lossy(&got);
        assert!(text.starts_with("HTTP/1.1 200") && text.ends_with("ok\n"), "{text}");
    }
    took
}

fn assert_about(took: Duration, timeout: Duration, what: &str) {
    assert!(took >= timeout.mul_f64(0.8) && took <= timeout + Duration::from_secs(5), "{what}: closed after {took:?}");
}

#[test]
fn connections_that_never_authenticate_or_ask_are_closed_after_the_timeouts() {
    let dir = TempDir::new("flood-timeouts");
    let tls = dir.path("tls");
    certs_init(&tls, &["--users", "alice"]);
    let http = format!("127.0.0.1:{}", free_port());
    let store = dir.path("store");
    let timeout = Duration::from_millis(1500);
    let ms = timeout.as_millis().to_string();
    let coord = Coordinator::serve(&[
        "--listen",
        "127.0.0.1:0",
        "--tls",
        tls.to_str().unwrap(),
        "--http",
        &http,
        "--store",
        store.to_str().unwrap(),
        "--handshake-timeout-ms",
        &ms,
        "--header-timeout-ms",
        &ms,
    ]);
    eventually("the HTTP side answering", LIMIT, || TcpStream::connect(&http).is_ok());
    // No TLS handshake on the gRPC port.
    let took = time_to_close(TcpStream::connect(grpc_addr(&coord)).unwrap(), b"");
    assert_about(took, timeout, "a connection without a TLS handshake");
    // No request on the HTTP port.
    let took = time_to_close(TcpStream::connect(&http).unwrap(), b"");
    assert_about(took, timeout, "an HTTP connection without a request");
    // One request, then an idle kept-alive connection: closed too.
    let request = format!("GET /healthz HTTP/1.1\r\nHost: {http}\r\n\r\n");
    let took = time_to_close(TcpStream::connect(&http).unwrap(), request.as_bytes());
    assert_about(took, timeout, "an idle kept-alive HTTP connection");

    // Without TLS, a connection that makes no authenticated call is closed after
    // --idle-timeout-ms.
    let plain = Coordinator::serve(&[
        "--listen",
        "127.0.0.1:0",
        "--store",
        dir.path("store-plain").to_str().unwrap(),
        "--idle-timeout-ms",
        &ms,
    ]);
    let took = time_to_close(TcpStream::connect(grpc_addr(&plain)).unwrap(), b"");
    assert_about(took, timeout, "a gRPC connection without an authenticated call");
    // One that has made one stays open past it.
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    rt.block_on(async {
        let ch = Endpoint::from_shared(plain.url.clone()).unwrap().connect().await.expect("connect");
        let mut jobs = proto::jobs_client::JobsClient::new(ch);
        jobs.list_jobs(proto::ListRequest {}).await.expect("list_jobs");
        let held = open_files(plain.proc.pid());
        tokio::time::sleep(timeout * 2).await;
        assert_eq!(open_files(plain.proc.pid()), held, "the coordinator closed a connection");
        jobs.list_jobs(proto::ListRequest {}).await.expect("list_jobs again");
    });
}
