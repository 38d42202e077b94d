//! The deployment files in `deploy/`: the Kubernetes manifests validate against the
//! Kubernetes API schemas offline (PyPI `kubernetes-validate`, installed by `.ci/run`),
//! and every flag the systemd units, the container image and the manifests pass to
//! `coordinator serve` and `worker` is one those commands take, so that the files cannot
//! drift from the binaries unnoticed.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(120);

fn deploy() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy")
}

fn validate(files: &[PathBuf]) -> std::process::Output {
    let mut cmd = Command::new("kubernetes-validate");
    cmd.args(["--strict", "-k", "1.30.0"]).args(files);
    run(&mut cmd, LIMIT)
}

#[test]
fn kubernetes_manifests_match_the_api_schemas() {
    if Command::new("kubernetes-validate").arg("--version").output().is_err() {
        skipped("kubernetes-validate is not installed (pip install kubernetes-validate; .ci/run does)");
        return;
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(deploy().join("kubernetes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .collect();
    files.sort();
    assert!(files.len() >= 3, "{files:?}");
    let out = validate(&files);
    let said = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{said}");
    for kind in ["statefulset", "service", "persistentvolumeclaim", "deployment", "horizontalpodautoscaler"] {
        assert!(said.contains(&format!("passed for resource {kind}/")), "{kind} was not checked:\n{said}");
    }
    // The validator does catch a mistake (else the check above proves nothing).
    let dir = TempDir::new("deploy");
    let bad = dir.path("bad.yaml");
    let text = std::fs::read_to_string(deploy().join("kubernetes/workers.yaml")).unwrap();
    std::fs::write(&bad, text.replace("replicas: 2", "replica: 2")).unwrap();
    assert!(!validate(&[bad]).status.success(), "a misspelt field must fail validation");
}

/// `--flags` in `text` (a command line, or a YAML/JSON list of arguments).
fn flags(text: &str) -> Vec<String> {
    text.split(|c: char| c.is_whitespace() || matches!(c, ',' | '[' | ']' | '"'))
        .filter(|w| w.starts_with("--") && w.len() > 2)
        .map(|w| w.split('=').next().unwrap().to_string())
        .collect()
}

fn help(args: &[&str]) -> String {
    let mut cmd = Command::new(bin("coordinator"));
    cmd.args(args).arg("--help");
    let out = run(&mut cmd, LIMIT);
    assert!(out.status.success());
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn deployment_files_use_only_real_flags() {
    let serve = help(&["serve"]);
    let worker = help(&["worker"]);
    let mut checked = 0;
    let mut check = |what: &str, used: Vec<String>, help: &str| {
        assert!(!used.is_empty(), "{what}: no flags found");
        for f in used {
            assert!(help.contains(&format!("{f} ")) || help.contains(&format!("{f}\n")), "{what}: {f} is not a flag");
            checked += 1;
        }
    };
    let unit = |name: &str| std::fs::read_to_string(deploy().join("systemd").join(name)).unwrap();
    let exec = |text: &str| {
        let start = text.find("ExecStart=").expect("ExecStart");
        let line: String = text[start..].lines().take_while(|l| !l.trim().is_empty()).collect::<Vec<_>>().join(" ");
        line.split("LoadCredential").next().unwrap().to_string()
    };
    check("tilefarm-coordinator.service", flags(&exec(&unit("tilefarm-coordinator.service"))), &serve);
    check("tilefarm-worker@.service", flags(&exec(&unit("tilefarm-worker@.service"))), &worker);
    let docker = std::fs::read_to_string(deploy().join("container/Dockerfile")).unwrap();
    let cmd = docker.lines().find(|l| l.starts_with("CMD [\"serve\"")).expect("the image's CMD");
    check("Dockerfile CMD", flags(cmd), &serve);
    let k8s = |name: &str| std::fs::read_to_string(deploy().join("kubernetes").join(name)).unwrap();
    let args = |text: &str| {
        let start = text.find("args: [").expect("args");
        text[start..text[start..].find(']').map(|e| start + e).unwrap()].to_string()
    };
    check("coordinator.yaml", flags(&args(&k8s("coordinator.yaml"))), &serve);
    check("workers.yaml", flags(&args(&k8s("workers.yaml"))), &worker);
    assert!(checked >= 20, "{checked} flags checked");
}

#[test]
fn systemd_units_verify() {
    if Command::new("systemd-analyze").arg("--version").output().is_err() {
        skipped("systemd-analyze is not installed (Debian's systemd; .ci/run installs it)");
        return;
    }
    let dir = TempDir::new("units");
    // The units name /usr/local/bin; verify checks that the programs exist, so point
    // them at the binaries just built. The worker template as one of its instances.
    for (unit, as_name) in [
        ("tilefarm-coordinator.service", "tilefarm-coordinator.service"),
        ("tilefarm-worker@.service", "tilefarm-worker@worker-3.service"),
    ] {
        let text = std::fs::read_to_string(deploy().join("systemd").join(unit)).unwrap();
        let text = text
            .replace("/usr/local/bin/coordinator", bin("coordinator").to_str().unwrap())
            .replace("/usr/local/bin/worker", bin("worker").to_str().unwrap());
        let path = dir.path(as_name);
        std::fs::write(&path, text).unwrap();
        let out = run(Command::new("systemd-analyze").arg("verify").arg(&path), LIMIT);
        let said = String::from_utf8_lossy(&out.stderr).to_string() + &String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success() && said.trim().is_empty(), "{unit}: {said}");
    }
}
