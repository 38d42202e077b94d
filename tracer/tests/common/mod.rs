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

/// Renders `s` with `integrator` at `spp`, checking that every sample was finite.
#[allow(dead_code)]
pub fn render(s: &tracer::scene::Scene, integrator: tracer::integrator::Integrator, spp: u32) -> tracer::film::Image {
    let range = tracer::film::SampleRange::new(0, spp);
    let (img, stats) = tracer::render::render_image(s, integrator, range, 8, &|_| {});
    assert_eq!(stats.nonfinite, 0, "non-finite samples");
    img
}

/// Mean and standard error of the mean of independent estimates.
#[allow(dead_code)]
pub fn mean_stderr(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}
