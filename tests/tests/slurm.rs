//! Workers as a Slurm array job, on a real single-node Slurm cluster that this test
//! starts on 127.0.0.1 (Debian's `slurm-wlm` and `munge`, installed by `.ci/run`): two
//! array tasks of `deploy/slurm/tilefarm-workers.sbatch` join a coordinator and render
//! a job whose image is bit-identical to the in-process render.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(240);

fn missing() -> Option<String> {
    for tool in ["/usr/sbin/slurmctld", "/usr/sbin/slurmd", "/usr/sbin/munged", "/usr/bin/sbatch", "/usr/bin/scancel"] {
        if !Path::new(tool).exists() {
            return Some(format!("no {tool} (Debian's slurm-wlm and munge; .ci/run installs them)"));
        }
    }
    let uid = Command::new("id").arg("-u").output().map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string());
    if uid.ok().as_deref() != Some("0") {
        return Some("a Slurm cluster of its own needs root here (its daemons run as root and as munge)".into());
    }
    None
}

/// munged (as the munge user), slurmctld and slurmd, with their files in `dir`; killed
/// on drop.
struct Cluster {
    conf: PathBuf,
    daemons: Vec<Proc>,
    munged_pid: PathBuf,
}

impl Cluster {
    fn start(dir: &Path) -> Self {
        let sh = |script: &str| {
            let o = run(Command::new("sh").arg("-c").arg(script), LIMIT);
            assert!(o.status.success(), "{script}: {}", String::from_utf8_lossy(&o.stderr));
        };
        let d = dir.display();
        // munge: a key of this cluster's own, its socket in the test's folder.
        sh(&format!(
            "mkdir -p {d}/munge {d}/munge-key {d}/state {d}/spool && chmod 755 {d} && \
             dd if=/dev/urandom of={d}/munge-key/munge.key bs=1024 count=1 2>/dev/null && \
             chown -R munge:munge {d}/munge {d}/munge-key && chmod 755 {d}/munge && chmod 700 {d}/munge-key && \
             chmod 400 {d}/munge-key/munge.key && \
             runuser -u munge -- /usr/sbin/munged --key-file={d}/munge-key/munge.key --socket={d}/munge/munge.socket \
               --pid-file={d}/munge/munged.pid --seed-file={d}/munge/seed --log-file={d}/munge/log"
        ));
        let host =
            String::from_utf8_lossy(&Command::new("hostname").arg("-s").output().unwrap().stdout).trim().to_string();
        let (ctld, slurmd) = (free_port(), free_port());
        let conf = dir.join("slurm.conf");
        std::fs::write(
            &conf,
            format!(
                "ClusterName=tilefarmtest\nSlurmctldHost={host}(127.0.0.1)\nSlurmctldPort={ctld}\nSlurmdPort={slurmd}\n\
                 AuthType=auth/munge\nAuthInfo=socket={d}/munge/munge.socket\nCredType=cred/munge\n\
                 ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\nSchedulerType=sched/builtin\n\
                 SelectType=select/cons_tres\nSelectTypeParameters=CR_Core\nSlurmUser=root\nSlurmdUser=root\n\
                 StateSaveLocation={d}/state\nSlurmdSpoolDir={d}/spool\nSlurmctldPidFile={d}/slurmctld.pid\n\
                 SlurmdPidFile={d}/slurmd.pid\nSlurmctldLogFile={d}/slurmctld.log\nSlurmdLogFile={d}/slurmd.log\n\
                 MpiDefault=none\nJobAcctGatherType=jobacct_gather/none\nAccountingStorageType=accounting_storage/none\n\
                 ReturnToService=2\nNodeName=tfnode NodeAddr=127.0.0.1 CPUs=2 RealMemory=2048 State=UNKNOWN\n\
                 PartitionName=test Nodes=tfnode Default=YES MaxTime=INFINITE State=UP\n"
            ),
        )
        .unwrap();
        let daemon = |name: &str, args: &[&str]| {
            let mut cmd = Command::new(name);
            cmd.args(["-D", "-f"]).arg(&conf).args(args).env("SLURM_CONF", &conf);
            Proc::spawn(name, &mut cmd)
        };
        let daemons = vec![daemon("/usr/sbin/slurmctld", &["-i"]), daemon("/usr/sbin/slurmd", &["-N", "tfnode"])];
        let cluster = Cluster { conf, daemons, munged_pid: dir.join("munge/munged.pid") };
        eventually("the Slurm node idle", LIMIT, || {
            let o = Command::new("sinfo").args(["-h", "-o", "%T"]).env("SLURM_CONF", &cluster.conf).output();
            o.is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "idle")
        });
        cluster
    }

    fn command(&self, name: &str) -> Command {
        let mut c = Command::new(name);
        c.env("SLURM_CONF", &self.conf);
        c
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = self.command("scancel").arg("--partition=test").status();
        // Let slurmd see its steps end before it goes, so that none outlives the test.
        let start = std::time::Instant::now();
        while start.elapsed() < Duration::from_secs(15) {
            let q = self.command("squeue").arg("-h").output();
            if q.is_ok_and(|o| o.stdout.is_empty()) {
                break;
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        std::thread::sleep(Duration::from_millis(500));
        self.daemons.clear();
        if let Ok(pid) = std::fs::read_to_string(&self.munged_pid) {
            let _ = Command::new("kill").arg(pid.trim()).status();
        }
    }
}

#[test]
fn two_slurm_array_tasks_render_the_in_process_bits() {
    if let Some(why) = missing() {
        skipped(why);
        return;
    }
    let dir = TempDir::new("slurm");
    let job_args = ["--width", "64", "--spp", "32", "--tile", "16", "--batch-spp", "4"];
    let reference = dir.path("reference.exr");
    render(
        &scenes().join("cornell-box/scene.toml"),
        &reference,
        &[&job_args[..], &["--local-workers", "0"]].concat(),
        LIMIT,
    );

    let cluster = Cluster::start(&dir.0);
    let coord = Coordinator::start(&dir.path("store"), &[]);

    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/slurm/tilefarm-workers.sbatch");
    let mut sbatch = cluster.command("sbatch");
    sbatch
        .args(["--parsable", "--array=0-1", "--cpus-per-task=1", "--mem-per-cpu=256M", "--time=10"])
        .arg(format!("--output={}/worker-%a.log", dir.0.display()))
        .arg(format!("--chdir={}", dir.0.display()))
        .env("TILEFARM_COORDINATOR", &coord.url)
        .env("TILEFARM_WORKER", bin("worker"))
        .env("TILEFARM_CACHE", dir.path("cache"))
        .arg(&script);
    let o = run(&mut sbatch, LIMIT);
    assert!(o.status.success(), "sbatch: {}", String::from_utf8_lossy(&o.stderr));
    let array = String::from_utf8_lossy(&o.stdout).trim().to_string();
    let workers_of = |url: &str| {
        tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap().block_on(async {
            let mut c = proto::jobs_client::JobsClient::connect(url.to_string()).await.unwrap();
            c.list_workers(proto::ListRequest {}).await.unwrap().into_inner().workers
        })
    };
    // The job goes in once both tasks have joined, so that both take units.
    eventually("both array tasks joined the farm", LIMIT, || workers_of(&coord.url).len() == 2);
    let job = coord.submit_id(&scenes().join("cornell-box/scene.toml"), &job_args, LIMIT);

    let out = dir.path("slurm.exr");
    let mut fetch = Command::new(bin("coordinator"));
    fetch.arg("fetch").arg(&job).args(["--coordinator", &coord.url, "-q", "-o"]).arg(&out);
    let f = run(&mut fetch, LIMIT);
    let logs: String = (0..2)
        .map(|a| std::fs::read_to_string(dir.path(&format!("worker-{a}.log"))).unwrap_or_default())
        .collect::<Vec<_>>()
        .join("\n");
    assert!(f.status.success(), "fetch: {}\nworker logs:\n{logs}", String::from_utf8_lossy(&f.stderr));
    assert_same_bits(&read_exr(&out), &read_exr(&reference), "two Slurm array tasks");

    // Both tasks joined as workers, and both rendered.
    let workers = workers_of(&coord.url);
    println!(
        "array job {array}: workers {:?}",
        workers.iter().map(|w| (w.worker_id, w.units_done)).collect::<Vec<_>>()
    );
    assert_eq!(workers.len(), 2, "two array tasks, two workers:\n{logs}");
    assert!(workers.iter().all(|w| w.units_done > 0), "both tasks rendered: {workers:?}");
    assert!(logs.contains("array task 0") && logs.contains("array task 1"), "{logs}");
    let _ = cluster.command("scancel").arg(&array).status();
}
