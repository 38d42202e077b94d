//! Every input kept in fuzz/regressions/ (crashes once found, hostile inputs from the
//! security audit) and every seed the fuzzers start from (the bundled scenes' files)
//! through the fuzz targets' own bodies: each must end in a result or a clear error,
//! never a panic. The long searches are `fuzz/run.sh`'s (in CI, 30 s per target).

#[path = "../../fuzz/src/lib.rs"]
mod targets;

use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

fn files_in(dir: &Path, ext: Option<&str>, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            files_in(&p, ext, out);
        } else if ext.is_none_or(|x| p.extension().is_some_and(|e| e == x)) {
            out.push(p);
        }
    }
}

fn run(target: &str, body: fn(&[u8]), scene_ext: Option<&str>) {
    let mut inputs = Vec::new();
    files_in(&repo().join("fuzz/regressions").join(target), None, &mut inputs);
    if let Some(ext) = scene_ext {
        files_in(&repo().join("scenes"), Some(ext), &mut inputs);
    }
    assert!(!inputs.is_empty(), "{target}: no inputs found");
    for input in &inputs {
        let data = std::fs::read(input).unwrap();
        if std::panic::catch_unwind(|| body(&data)).is_err() {
            panic!("{target}: {} panicked", input.display());
        }
    }
    println!("{target}: {} inputs", inputs.len());
}

#[test]
fn scene_files() {
    run("scene_toml", targets::scene_toml, Some("toml"));
}

#[test]
fn obj_files() {
    run("obj", targets::obj, Some("obj"));
}

#[test]
fn mtl_files() {
    run("mtl", targets::mtl, Some("mtl"));
}

#[test]
fn checkpoints() {
    run("checkpoint", targets::checkpoint, None);
}

#[test]
fn wire_messages() {
    run("wire", targets::wire, None);
}
