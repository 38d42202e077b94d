//! A farm's metrics and health: `/metrics` read by a Prometheus text-format parser, its
//! counters equal to the job's own totals at the end; `/healthz`, `/readyz` and the gRPC
//! health service; the admin token guarding metrics. Real processes on 127.0.0.1.

use std::collections::HashMap;
use std::time::Duration;

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(180);

/// The samples of a scrape by name and labels (`name{k=v,…}`, labels sorted), for the
/// counters and gauges; each histogram by its name, as its `+Inf` bucket's count.
fn parse(text: &str) -> HashMap<String, f64> {
    let scrape = prometheus_parse::Scrape::parse(text.lines().map(|l| Ok(l.to_string()))).expect("Prometheus text");
    let mut out = HashMap::new();
    for s in scrape.samples {
        let key = if s.labels.is_empty() { s.metric.clone() } else { format!("{}{{{}}}", s.metric, s.labels) };
        let v = match s.value {
            prometheus_parse::Value::Counter(v)
            | prometheus_parse::Value::Gauge(v)
            | prometheus_parse::Value::Untyped(v) => v,
            prometheus_parse::Value::Histogram(buckets) => {
                buckets.iter().find(|b| b.less_than.is_infinite()).map_or(0.0, |b| b.count)
            }
            prometheus_parse::Value::Summary(_) => continue,
        };
        out.insert(key, v);
    }
    out
}

#[test]
fn metrics_count_what_the_job_did_and_health_answers() {
    let dir = TempDir::new("metrics");
    let http = format!("127.0.0.1:{}", free_port());
    let coord = Coordinator::start(&dir.path("store"), &["--http", &http]);
    let _w1 = coord.worker(1, &dir.path("cache-1"));
    let _w2 = coord.worker(1, &dir.path("cache-2"));
    eventually("the HTTP side answering", LIMIT, || std::net::TcpStream::connect(&http).is_ok());
    assert_eq!(http_get(&http, "/healthz", None, LIMIT), (200, "ok\n".into()));
    assert_eq!(http_get(&http, "/readyz", None, LIMIT), (200, "ready\n".into()));

    let out = dir.path("out.exr");
    let args = ["--width", "64", "--spp", "32", "--tile", "16", "--batch-spp", "8", "--wait", "-o"];
    let sub =
        coord.submit(&scenes().join("cornell-box/scene.toml"), &[&args[..], &[out.to_str().unwrap()]].concat(), LIMIT);
    assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
    let job = list_jobs(&coord.url).into_iter().next().expect("the job is listed");
    assert_eq!(job.state, proto::JobState::Done as i32);

    let (code, text) = http_get(&http, "/metrics", None, LIMIT);
    assert_eq!(code, 200, "{text}");
    let m = parse(&text);
    let get = |k: &str| *m.get(k).unwrap_or_else(|| panic!("{k} is not in the scrape:\n{text}"));
    println!(
        "units: {} leased, {} completed, {} verified; merges observed {}; bytes in {}, out {}",
        get("tilefarm_units_leased_total"),
        get("tilefarm_units_completed_total"),
        get("tilefarm_units_verified_total"),
        get("tilefarm_merge_seconds"),
        get("tilefarm_bytes_in_total"),
        get("tilefarm_bytes_out_total")
    );
    assert_eq!(get("tilefarm_units_completed_total"), job.units_total as f64, "each unit merged once");
    assert_eq!(get("tilefarm_units_verified_total"), job.units_checked as f64);
    assert!(get("tilefarm_units_verified_total") >= 4.0, "each worker's first results are checked");
    assert!(get("tilefarm_units_leased_total") >= get("tilefarm_units_completed_total"));
    assert_eq!(get("tilefarm_units_rejected_total"), 0.0);
    assert_eq!(get("tilefarm_units_mismatched_total"), 0.0);
    assert_eq!(get("tilefarm_jobs{state=\"done\"}"), 1.0);
    assert_eq!(get("tilefarm_jobs{state=\"running\"}"), 0.0);
    assert_eq!(get("tilefarm_workers{state=\"idle\"}"), 2.0);
    assert_eq!(get("tilefarm_units_queued"), 0.0);
    let merges = get("tilefarm_merge_seconds");
    assert!(merges > 0.0 && merges <= get("tilefarm_units_completed_total"), "{merges}");
    // Results in: at least the sums and counts of every pixel of every unit merged.
    let pixels_units = 64.0 * 64.0 * (job.units_total as f64 / 16.0);
    assert!(get("tilefarm_bytes_in_total") >= pixels_units * 52.0);
    assert!(get("tilefarm_bytes_out_total") > 0.0, "the workers downloaded the scene, submit the image");

    // The gRPC health service: open to any caller, SERVING.
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    rt.block_on(async {
        use tonic_health::pb::HealthCheckRequest;
        use tonic_health::pb::health_client::HealthClient;
        let channel = tonic::transport::Endpoint::from_shared(coord.url.clone()).unwrap().connect().await.unwrap();
        let mut h = HealthClient::new(channel);
        for service in ["", "tilefarm.v1.Farm", "tilefarm.v1.Jobs"] {
            let r = h.check(HealthCheckRequest { service: service.into() }).await.unwrap().into_inner();
            assert_eq!(r.status, tonic_health::pb::health_check_response::ServingStatus::Serving as i32, "{service}");
        }
    });
}

#[test]
fn metrics_need_the_admin_token_and_plain_http_stays_on_loopback() {
    let dir = TempDir::new("metrics-auth");
    std::fs::write(dir.path("admin.token"), "s3cret-admin-token\n").unwrap();
    let http = format!("127.0.0.1:{}", free_port());
    let token_file = dir.path("admin.token");
    let _coord =
        Coordinator::start(&dir.path("store"), &["--http", &http, "--token-file", token_file.to_str().unwrap()]);
    eventually("the HTTP side answering", LIMIT, || std::net::TcpStream::connect(&http).is_ok());
    assert_eq!(http_get(&http, "/metrics", None, LIMIT).0, 401);
    assert_eq!(http_get(&http, "/metrics", Some("wrong"), LIMIT).0, 401);
    let (code, text) = http_get(&http, "/metrics", Some("s3cret-admin-token"), LIMIT);
    assert_eq!(code, 200);
    assert!(parse(&text).contains_key("tilefarm_units_leased_total"));
    assert_eq!(http_get(&http, "/healthz", None, LIMIT).0, 200, "probes need no token");

    // Plain HTTP on an address other machines reach: refused without --insecure.
    let mut cmd = std::process::Command::new(bin("coordinator"));
    cmd.args(["serve", "--listen", "127.0.0.1:0", "--http", "0.0.0.0:0", "--store"]).arg(dir.path("store2"));
    let o = run(&mut cmd, LIMIT);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--http 0.0.0.0:0") && err.contains("--insecure"), "{err}");
}

/// The dashboard's event streams poll the farm, so their number is bounded; a stream
/// whose page went away ends (and frees its place) even when nothing changes.
#[test]
fn dashboard_event_streams_are_bounded_and_end_with_their_page() {
    use std::io::{Read, Write};
    let dir = TempDir::new("events");
    let http = format!("127.0.0.1:{}", free_port());
    let _coord = Coordinator::start(&dir.path("store"), &["--http", &http]);
    eventually("the HTTP side answering", LIMIT, || std::net::TcpStream::connect(&http).is_ok());
    let open = |n: usize| -> Vec<std::net::TcpStream> {
        (0..n)
            .map(|_| {
                let mut s = std::net::TcpStream::connect(&http).unwrap();
                write!(s, "GET /api/events HTTP/1.1\r\nHost: {http}\r\n\r\n").unwrap();
                s.set_read_timeout(Some(LIMIT)).unwrap();
                let mut head = [0u8; 12];
                s.read_exact(&mut head).unwrap();
                assert_eq!(&head, b"HTTP/1.1 200", "an event stream opens");
                s
            })
            .collect()
    };
    let pages = open(256);
    assert_eq!(http_get(&http, "/api/events", None, LIMIT).0, 503, "the 257th is refused");
    drop(pages);
    // The streams notice within their poll (150 ms) and give their places back.
    eventually("closed streams freeing their places", LIMIT, || {
        let mut s = std::net::TcpStream::connect(&http).unwrap();
        write!(s, "GET /api/events HTTP/1.1\r\nHost: {http}\r\nConnection: close\r\n\r\n").unwrap();
        let mut head = [0u8; 12];
        s.read_exact(&mut head).is_ok() && &head == b"HTTP/1.1 200"
    });
}
