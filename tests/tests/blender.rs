//! The Blender exporter (`blender/tilefarm_blender`) against Cycles, with PyPI's `bpy`
//! (`.ci/run` installs it in a virtual environment and names its Python in
//! TILEFARM_BPY_PYTHON; without one that can `import bpy`, the test says SKIPPED).
//! `blender/tests/compare_cycles.py` builds the scenes in `bpy`, exports them, renders
//! them with tilefarm and Cycles and compares them; here it also gets a farm (a
//! coordinator and a worker), for the add-on's render operator.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(600);

/// The Python to run with, if it has `bpy` (and PyPI's OpenEXR, which the script reads
/// EXRs with); else why not.
fn python_with_bpy() -> Result<String, String> {
    let python = std::env::var("TILEFARM_BPY_PYTHON").unwrap_or_else(|_| "python3".into());
    let probe = Command::new(&python).args(["-c", "import bpy, OpenEXR"]).output();
    match probe {
        Ok(o) if o.status.success() => Ok(python),
        _ => Err(format!("{python} cannot import bpy and OpenEXR (.ci/run installs them; set TILEFARM_BPY_PYTHON)")),
    }
}

#[test]
fn blender_scenes_export_and_render_like_cycles() {
    let python = match python_with_bpy() {
        Ok(p) => p,
        Err(why) => {
            println!("SKIPPED: {why}");
            return;
        }
    };
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = TempDir::new("blender");
    let coord = Coordinator::start(&dir.path("store"), &[]);
    let _worker = coord.worker(2, &dir.path("cache"));
    let mut cmd = Command::new(&python);
    cmd.arg(here.join("../blender/tests/compare_cycles.py"))
        .arg(bin("coordinator"))
        .arg(dir.path("work"))
        .arg("256")
        .env("TILEFARM_COORDINATOR", &coord.url)
        .env("TILEFARM_COORDINATOR_EXE", bin("coordinator"))
        // Blender keeps its preferences and installed extensions under HOME.
        .env("HOME", dir.path("home"));
    let out = run(&mut cmd, LIMIT);
    let said = String::from_utf8_lossy(&out.stdout);
    let figures = said.lines().rev().find(|l| l.starts_with('{')).unwrap_or("");
    println!("figures: {figures}");
    assert!(
        out.status.success(),
        "the Blender comparison failed:\n{}\n{}",
        said.lines().rev().take(30).collect::<Vec<_>>().join("\n"),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(figures.contains("\"farm\": \"same bits as a local render\""), "the farm check ran: {figures}");
    assert!(figures.contains("\"extension\": \"bl_ext.user_default.tilefarm\""), "the extension installed: {figures}");
}
