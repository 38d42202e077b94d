//! The `coordinator` binary as a user runs it: the README's render command (on a small
//! image), and clear errors for bad input.

use std::path::PathBuf;
use std::process::Command;

fn coordinator() -> Command {
    Command::new(env!("CARGO_BIN_EXE_coordinator"))
}

struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let d = std::env::temp_dir().join(format!("tilefarm-cli-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[test]
fn readme_render_command_writes_an_exr_of_the_builtin_cornell_box() {
    let dir = TempDir::new("render");
    let out = dir.0.join("cornell.exr");
    // The README's command is `coordinator render -o cornell.exr`; smaller here for speed.
    let status = coordinator().args(["render", "-q", "--spp", "4", "--width", "48", "-o"]).arg(&out).status().unwrap();
    assert!(status.success());
    let img = tracer::output::read_exr(&out).unwrap();
    assert_eq!((img.width, img.height), (48, 48));
    assert!(img.counts.iter().all(|&c| c == 4));
    assert!(img.pixels.iter().all(|p| p.is_finite()));
    // The light is visible and the walls are lit: a mean well above zero.
    let mean = img.pixels.iter().map(|p| p.x + p.y + p.z).sum::<f32>() / img.pixels.len() as f32;
    assert!(mean > 0.05, "mean {mean}");
}

/// The README's run command on a fresh clone builds only `coordinator` (cargo run -p
/// coordinator): a render must need nothing beside it. A copy of the binary alone in an
/// empty folder renders with local worker processes.
#[test]
fn the_binary_alone_in_an_empty_folder_renders_with_local_workers() {
    let dir = TempDir::new("alone");
    let exe = dir.0.join("coordinator");
    std::fs::copy(env!("CARGO_BIN_EXE_coordinator"), &exe).unwrap();
    let out = Command::new(&exe)
        .current_dir(&dir.0)
        .args(["render", "-q", "--spp", "2", "--width", "16", "--local-workers", "2", "-o", "cornell.exr"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let img = tracer::output::read_exr(&dir.0.join("cornell.exr")).unwrap();
    assert!(img.counts.iter().all(|&c| c == 2));
}

#[test]
fn bad_scenes_fail_with_a_message_naming_the_problem() {
    let dir = TempDir::new("bad");
    let scene = dir.0.join("typo.toml");
    std::fs::write(&scene, "[camera]\nposition = [0,0,0]\nlook_at = [0,0,1]\nfovv = 30\n").unwrap();
    let out = coordinator().args(["render", "-q", "-o"]).arg(dir.0.join("x.exr")).arg(&scene).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("typo.toml") && err.contains("fovv") && err.contains("line 4"), "{err}");
    assert!(!err.contains("panicked"), "{err}");

    let missing = dir.0.join("missing.toml");
    std::fs::write(&missing, "[camera]\nposition = [0,0,0]\nlook_at = [0,0,1]\n[[mesh]]\nobj = \"nope.obj\"\n")
        .unwrap();
    let out = coordinator().args(["render", "-q", "-o"]).arg(dir.0.join("x.exr")).arg(&missing).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("nope.obj"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}
