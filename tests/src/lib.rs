//! Harness for the end-to-end tests: locating the real binaries, running them on
//! loopback with OS-assigned ports, bounding every wait, and killing every child process
//! when a test ends — also when it fails.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use tracer::film::Image;

pub mod tls;

/// Says that a test cannot run here, and why, on the process's stderr itself: the test
/// harness hides what a passing test prints with `println!` or `eprintln!`, so a skip
/// would look like a pass.
pub fn skipped(why: impl std::fmt::Display) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "SKIPPED: {why}");
}

/// The workspace's target folder for this build profile: the test executable lives in
/// `<target>/<profile>/deps/`, the binaries one level up.
pub fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let dir = exe.parent().and_then(Path::parent).expect("target profile folder");
    let p = dir.join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    assert!(p.is_file(), "{} not built: run `cargo build --release` (or the README's test command)", p.display());
    p
}

pub fn scenes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes")
}

/// A scratch folder, removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> Self {
        let d = std::env::temp_dir().join(format!("tilefarm-e2e-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("temp dir");
        Self(d)
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Our processes log at warn level in tests unless RUST_LOG says otherwise.
fn quiet(cmd: &mut Command) {
    if std::env::var_os("RUST_LOG").is_none() {
        cmd.env("RUST_LOG", "warn");
    }
}

/// A child process killed (and reaped) when dropped.
pub struct Proc {
    pub child: Child,
    pub name: String,
}

impl Proc {
    pub fn spawn(name: &str, cmd: &mut Command) -> Self {
        quiet(cmd);
        let child = cmd.spawn().unwrap_or_else(|e| panic!("starting {name}: {e}"));
        Self { child, name: name.to_string() }
    }

    /// Waits up to `limit` for the process to exit; panics (killing it) past that.
    pub fn wait(&mut self, limit: Duration) -> std::process::ExitStatus {
        let end = Instant::now() + limit;
        loop {
            if let Some(s) = self.child.try_wait().expect("try_wait") {
                return s;
            }
            if Instant::now() > end {
                let _ = self.child.kill();
                panic!("{} did not finish within {limit:?}", self.name);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `coordinator serve` on 127.0.0.1 with an OS-assigned port.
pub struct Coordinator {
    pub proc: Proc,
    pub url: String,
}

/// A free loopback port, for a coordinator that must come back on the same address.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").expect("bind").local_addr().expect("addr").port()
}

impl Coordinator {
    pub fn start(store: &Path, extra: &[&str]) -> Self {
        let mut args = vec!["--listen", "127.0.0.1:0", "--store", store.to_str().expect("utf-8 path")];
        args.extend_from_slice(extra);
        Self::serve(&args)
    }

    /// `coordinator serve ARGS…`, waiting for its address.
    pub fn serve(args: &[&str]) -> Self {
        Self::serve_with(args, |_| {})
    }

    /// As [`Coordinator::serve`], with `setup` adjusting the command first (its
    /// environment, limits).
    pub fn serve_with(args: &[&str], setup: impl FnOnce(&mut Command)) -> Self {
        let mut cmd = Command::new(bin("coordinator"));
        cmd.arg("serve").args(args).stdout(Stdio::piped()).stderr(Stdio::inherit());
        setup(&mut cmd);
        let mut proc = Proc::spawn("coordinator serve", &mut cmd);
        let stdout = proc.child.stdout.take().expect("stdout");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut lines = BufReader::new(stdout).lines();
            if let Some(Ok(line)) = lines.next() {
                let _ = tx.send(line);
            }
            for _ in lines {}
        });
        let line = rx.recv_timeout(Duration::from_secs(30)).expect("coordinator printed its address");
        let url = line.strip_prefix("listening on ").expect("listening line").trim().to_string();
        assert!(url.starts_with("http://127.0.0.1:") || url.starts_with("https://127.0.0.1:"), "{url}");
        Self { proc, url }
    }

    pub fn worker(&self, threads: usize, cache: &Path) -> Proc {
        let mut cmd = Command::new(bin("worker"));
        cmd.args(["--coordinator", &self.url, "--threads", &threads.to_string(), "--cache"])
            .arg(cache)
            .stdin(Stdio::null());
        Proc::spawn("worker", &mut cmd)
    }

    /// A one-thread worker that retries every 200 ms at most while this coordinator is
    /// away (for tests that restart it on the same address).
    pub fn retrying_worker(&self, cache: &Path) -> Proc {
        let mut cmd = Command::new(bin("worker"));
        cmd.args(["--coordinator", &self.url, "--threads", "1", "--max-backoff-ms", "200", "--cache"]).arg(cache);
        Proc::spawn("worker", &mut cmd)
    }

    /// Submits `scene` and returns the job's id (panics, with the error, if refused).
    pub fn submit_id(&self, scene: &Path, args: &[&str], limit: Duration) -> String {
        let sub = self.submit(scene, args, limit);
        assert!(sub.status.success(), "{}", String::from_utf8_lossy(&sub.stderr));
        String::from_utf8_lossy(&sub.stdout).trim().to_string()
    }

    /// `coordinator submit SCENE --coordinator URL ARGS…` run to completion (bounded).
    pub fn submit(&self, scene: &Path, args: &[&str], limit: Duration) -> Output {
        let mut cmd = Command::new(bin("coordinator"));
        cmd.arg("submit").arg(scene).args(["--coordinator", &self.url, "-q"]).args(args);
        run(&mut cmd, limit)
    }
}

/// The last line of a script's standard output that is a JSON object (where the
/// comparison scripts print their figures), also printed with `label` for the log.
pub fn figures_of(out: &Output, label: &str) -> String {
    let said = String::from_utf8_lossy(&out.stdout);
    let figures = said.lines().rev().find(|l| l.starts_with('{')).unwrap_or("").to_string();
    println!("{label}: {figures}");
    figures
}

/// Runs a command to completion within `limit`, capturing its output.
pub fn run(cmd: &mut Command, limit: Duration) -> Output {
    quiet(cmd);
    let child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("spawn");
    let pid = child.id();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    match rx.recv_timeout(limit) {
        Ok(out) => out.expect("wait"),
        Err(_) => {
            let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
            panic!("command did not finish within {limit:?}");
        }
    }
}

/// Polls `f` until it is true, within `limit`.
pub fn eventually(what: &str, limit: Duration, mut f: impl FnMut() -> bool) {
    let start = Instant::now();
    while !f() {
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The farm's jobs, as `status` lists them.
pub fn list_jobs(url: &str) -> Vec<proto::JobStatus> {
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
    rt.block_on(async {
        let mut c = proto::jobs_client::JobsClient::connect(url.to_string()).await.expect("connect");
        c.list_jobs(proto::ListRequest {}).await.expect("list_jobs").into_inner().jobs
    })
}

/// Polls (within `limit`) until the first job has done at least `fraction` of its units.
pub fn wait_for_progress(url: &str, fraction: f64, limit: Duration) -> proto::JobStatus {
    let start = Instant::now();
    loop {
        assert!(start.elapsed() < limit, "no progress");
        if let Some(j) = list_jobs(url).into_iter().next()
            && j.units_total > 0
            && j.units_done as f64 >= fraction * j.units_total as f64
        {
            return j;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

pub fn read_exr(p: &Path) -> Image {
    tracer::output::read_exr(p).unwrap_or_else(|e| panic!("reading {}: {e}", p.display()))
}

/// Bit-for-bit equality of two images' pixels and sample counts.
pub fn assert_same_bits(a: &Image, b: &Image, what: &str) {
    assert_eq!((a.width, a.height), (b.width, b.height), "{what}: size");
    assert_eq!(a.counts, b.counts, "{what}: sample counts");
    for (i, (p, q)) in a.pixels.iter().zip(&b.pixels).enumerate() {
        assert!(
            p.x.to_bits() == q.x.to_bits() && p.y.to_bits() == q.y.to_bits() && p.z.to_bits() == q.z.to_bits(),
            "{what}: pixel {i} differs: {p} vs {q}"
        );
    }
}

/// `coordinator render` of `scene` with extra arguments, to `out` (bounded).
pub fn render(scene: &Path, out: &Path, args: &[&str], limit: Duration) -> Output {
    let mut cmd = Command::new(bin("coordinator"));
    cmd.arg("render").arg(scene).arg("-q").arg("-o").arg(out).args(args);
    let o = run(&mut cmd, limit);
    assert!(o.status.success(), "render failed: {}", String::from_utf8_lossy(&o.stderr));
    o
}

/// A well-formed result for `unit` as `worker` of `job` would send it, every sum `value`
/// (what a forger sends: the right shape, the wrong content).
pub fn forged_result(worker: u64, job: &str, unit: &proto::Unit, value: i128) -> proto::UnitResult {
    let tile = unit.tile.expect("a leased unit has a tile");
    let n = (tile.width * tile.height) as usize;
    proto::UnitResult {
        worker_id: worker,
        job_id: job.to_string(),
        unit_id: unit.unit_id,
        tile: Some(tile),
        sample_start: unit.sample_start,
        sample_end: unit.sample_end,
        sums: value.to_le_bytes().repeat(3 * n),
        counts: vec![unit.sample_end - unit.sample_start; n],
        layers: Vec::new(),
        nonfinite: 0,
        rays: 0,
        render_seconds: 0.0,
    }
}

/// `GET path` on `addr` over plain HTTP/1.1 (with `Authorization: Bearer TOKEN` when
/// given): the status code and the body. Bounded by `limit`.
pub fn http_get(addr: &str, path: &str, token: Option<&str>, limit: Duration) -> (u16, String) {
    let (code, _, body) = http_get_bytes(addr, path, token, limit);
    (code, String::from_utf8_lossy(&body).into_owned())
}

/// `GET path` from `addr` over plain HTTP/1.1 (bounded by `limit`): the status, the
/// head (status line and headers) and the body as bytes, its chunks joined.
pub fn http_get_bytes(addr: &str, path: &str, token: Option<&str>, limit: Duration) -> (u16, String, Vec<u8>) {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).unwrap_or_else(|e| panic!("connecting to {addr}: {e}"));
    s.set_read_timeout(Some(limit)).expect("timeout");
    let auth = token.map(|t| format!("Authorization: Bearer {t}\r\n")).unwrap_or_default();
    write!(s, "GET {path} HTTP/1.1\r\nHost: {addr}\r\n{auth}Connection: close\r\n\r\n").expect("request");
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).expect("response");
    let split = raw.windows(4).position(|w| w == b"\r\n\r\n").unwrap_or(raw.len());
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let body = raw.get(split + 4..).unwrap_or_default();
    let code = head.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    // Chunked bodies (axum streams larger ones): join the chunks.
    let body = if head.to_ascii_lowercase().contains("transfer-encoding: chunked") {
        let mut out = Vec::new();
        let mut rest = body;
        while let Some(end) = rest.windows(2).position(|w| w == b"\r\n") {
            let size = String::from_utf8_lossy(&rest[..end]);
            let n = usize::from_str_radix(size.trim(), 16).unwrap_or(0);
            let tail = &rest[end + 2..];
            if n == 0 || tail.len() < n {
                break;
            }
            out.extend_from_slice(&tail[..n]);
            rest = tail[n..].strip_prefix(b"\r\n").unwrap_or(&tail[n..]);
        }
        out
    } else {
        body.to_vec()
    };
    (code, head, body)
}
