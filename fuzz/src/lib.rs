//! What each fuzz target does with its input: parse it the way tilefarm parses a scene
//! file, an OBJ, an MTL, a checkpoint or a message from the network, and let anything but
//! a clear error (a panic, an abort, a hang, memory running out) surface.
//!
//! The fuzz targets (fuzz_targets/) call these; so does the workspace's regression
//! test (tests/tests/fuzz_regressions.rs, which includes this file), on every input kept
//! in fuzz/regressions/ and on the seed corpora, so a crash once found stays fixed.

use std::path::PathBuf;
use std::sync::OnceLock;

use prost::Message;

/// A folder of this process's with nothing in it: where relative references of the
/// parsed files resolve (to nothing).
fn empty_dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("tilefarm-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("a temporary folder");
        d
    })
}

/// A scene file's text (`scene.toml`).
pub fn scene_toml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = tracer::scene::scene_from_toml(text, "fuzz.toml", empty_dir());
    }
}

/// A Wavefront OBJ file's text.
pub fn obj(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = tracer::scene::obj::load_obj_from_str(text, empty_dir(), "fuzz.obj");
    }
}

/// An MTL file (read from disk, as the loader always reads one).
pub fn mtl(data: &[u8]) {
    let path = empty_dir().join("fuzz.mtl");
    std::fs::write(&path, data).expect("writing the input");
    let _ = tracer::scene::obj::load_mtl(&path);
    let _ = std::fs::remove_file(&path);
}

/// A checkpoint file, as `serve --checkpoint` and `resume` read it.
pub fn checkpoint(data: &[u8]) {
    if let Ok(s) = coordinator::farm::checkpoint::decode(data) {
        // What decodes must encode back to a file that decodes the same.
        let again = coordinator::farm::checkpoint::decode(&coordinator::farm::checkpoint::encode(&s))
            .expect("a checkpoint that decoded re-encodes");
        assert_eq!(again, s);
    }
}

/// A message from the network: the first byte says which, the rest is its encoding,
/// decoded by prost and then checked by the one wire mapping.
pub fn wire(data: &[u8]) {
    let Some((&which, bytes)) = data.split_first() else { return };
    match which % 6 {
        0 => {
            if let Ok(m) = proto::UnitResult::decode(bytes) {
                let _ = proto::wire::result_from_proto(m);
            }
        }
        1 => {
            if let Ok(m) = proto::Unit::decode(bytes) {
                let _ = proto::wire::unit_from_proto(m);
            }
        }
        2 => {
            let _ = proto::wire::job_from_bytes(bytes);
        }
        3 => {
            if let Ok(m) = proto::SubmitJobRequest::decode(bytes) {
                let _ = proto::wire::submission_from_proto(m.scene, m.assets, m.settings.as_ref(), m.group);
            }
        }
        4 => {
            if let Ok(m) = proto::JobStatus::decode(bytes) {
                let _ = coordinator::edge::wire::status_from_proto(m);
            }
        }
        _ => {
            if let Ok(m) = proto::SubmitResultsReply::decode(bytes) {
                let _ = proto::wire::outcomes_from_proto(m);
            }
        }
    }
}
