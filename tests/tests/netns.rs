//! Across hosts: the coordinator and two workers in separate network namespaces joined
//! by veth pairs (test hosts this test creates and removes itself); one worker's link is
//! cut mid-render and restored, and the image must come out identical. Skipped, with a
//! message, where network namespaces are not available (not root, no `ip`).

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(240);

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip").args(args).output().map_err(|e| format!("ip {}: {e}", args.join(" ")))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!("ip {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim()))
    }
}

/// The namespaces of one test run; removed (with their veth links) when dropped.
struct Hosts {
    names: Vec<String>,
}

impl Hosts {
    /// `c` (coordinator) linked to `w1` over 10.231.1.0/24 and to `w2` over 10.231.2.0/24.
    fn create() -> Result<Self, String> {
        let tag = std::process::id() % 100_000;
        let hosts = Hosts { names: vec![format!("tfc{tag}"), format!("tfa{tag}"), format!("tfb{tag}")] };
        for n in &hosts.names {
            ip(&["netns", "add", n])?;
            ip(&["-n", n, "link", "set", "lo", "up"])?;
        }
        for (k, w) in [(1, &hosts.names[1]), (2, &hosts.names[2])] {
            let (cside, wside) = (format!("tfc{k}x{tag}"), format!("tfw{k}x{tag}"));
            ip(&["link", "add", &cside, "netns", &hosts.names[0], "type", "veth", "peer", "name", &wside, "netns", w])?;
            ip(&["-n", &hosts.names[0], "addr", "add", &format!("10.231.{k}.1/24"), "dev", &cside])?;
            ip(&["-n", w, "addr", "add", &format!("10.231.{k}.2/24"), "dev", &wside])?;
            ip(&["-n", &hosts.names[0], "link", "set", &cside, "up"])?;
            ip(&["-n", w, "link", "set", &wside, "up"])?;
        }
        Ok(hosts)
    }

    fn worker_link(&self, k: u32) -> (String, String) {
        let tag = std::process::id() % 100_000;
        (self.names[k as usize].clone(), format!("tfw{k}x{tag}"))
    }
}

impl Drop for Hosts {
    fn drop(&mut self) {
        for n in &self.names {
            let _ = ip(&["netns", "del", n]);
        }
    }
}

fn in_ns(ns: &str, program: &std::path::Path) -> Command {
    let mut c = Command::new("ip");
    c.args(["netns", "exec", ns]).arg(program);
    c
}

#[test]
fn a_worker_whose_link_is_cut_and_restored_still_gives_the_same_bits() {
    let hosts = match Hosts::create() {
        Ok(h) => h,
        Err(e) => {
            skipped(format_args!("network namespaces are not available here ({e})"));
            return;
        }
    };
    let dir = TempDir::new("netns");
    let scene = scenes().join("cornell-box/scene.toml");
    let job = ["--width", "96", "--spp", "64", "--tile", "16", "--batch-spp", "4"];
    let reference = dir.path("reference.exr");
    render(&scene, &reference, &[&job[..], &["--local-workers", "0"]].concat(), LIMIT);

    let port = 7878;
    let mut serve = in_ns(&hosts.names[0], &bin("coordinator"));
    serve
        .args([
            "serve",
            "--insecure",
            "--listen",
            &format!("0.0.0.0:{port}"),
            "--lease-ms",
            "1000",
            "--heartbeat-ms",
            "250",
            "--store",
        ])
        .arg(dir.path("store"))
        .stdout(Stdio::null());
    let _coordinator = Proc::spawn("coordinator in its namespace", &mut serve);
    let mut workers = Vec::new();
    for k in [1u32, 2] {
        let mut w = in_ns(&hosts.names[k as usize], &bin("worker"));
        w.args(["--coordinator", &format!("http://10.231.{k}.1:{port}"), "--threads", "1", "--max-backoff-ms", "200"])
            .arg("--cache")
            .arg(dir.path(&format!("cache{k}")));
        workers.push(Proc::spawn("worker in its namespace", &mut w));
    }
    let out = dir.path("farm.exr");
    let mut submit = in_ns(&hosts.names[0], &bin("coordinator"));
    submit
        .arg("submit")
        .arg(&scene)
        .args(["--coordinator", &format!("http://127.0.0.1:{port}"), "--wait", "-q", "-o"])
        .arg(&out)
        .args(job);
    // The coordinator may take a moment to listen: retry the submission briefly.
    let start = Instant::now();
    let mut submitter = loop {
        let mut p = Proc::spawn("submit --wait", &mut submit);
        std::thread::sleep(Duration::from_millis(500));
        match p.child.try_wait().unwrap() {
            Some(s) if !s.success() && start.elapsed() < Duration::from_secs(20) => continue,
            _ => break p,
        }
    };
    // Cut worker 1's link mid-render (past its lease), then restore it.
    std::thread::sleep(Duration::from_millis(800));
    let (ns, link) = hosts.worker_link(1);
    ip(&["-n", &ns, "link", "set", &link, "down"]).unwrap();
    std::thread::sleep(Duration::from_millis(2500));
    ip(&["-n", &ns, "link", "set", &link, "up"]).unwrap();
    assert!(submitter.wait(LIMIT).success(), "the render completed");
    assert_same_bits(&read_exr(&out), &read_exr(&reference), "across namespaces with a cut link");
}
