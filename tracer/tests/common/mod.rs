//! Shared by the tracer's integration tests.

use std::path::{Path, PathBuf};

/// A scratch directory removed on drop (also when a test fails).
// Each test binary compiles this module; not all of them use every helper.
#[allow(dead_code)]
pub struct TempDir(pub PathBuf);

#[allow(dead_code)]
impl TempDir {
    pub fn new(tag: &str) -> Self {
        let d = std::env::temp_dir().join(format!("tilefarm-test-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }

    pub fn write(&self, name: &str, text: &str) {
        std::fs::write(self.0.join(name), text).unwrap();
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A bundled scene's file.
// Each test binary compiles this module; not all of them use every helper.
#[allow(dead_code)]
pub fn bundled(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(name).join("scene.toml")
}
