//! tilefarm's materials against Mitsuba 3 (PyPI's `mitsuba`, variant `scalar_rgb`;
//! `.ci/run` installs it in a virtual environment and names its Python in
//! TILEFARM_MITSUBA_PYTHON; without that variable the test says SKIPPED).
//! `tests/mitsuba/compare_materials.py` builds each case's sphere on one stage as a
//! tilefarm scene and as a Mitsuba scene, renders both at the same spp, and compares
//! the channel means (within 1 %) and 8 × 8-pixel blocks (within their noise).

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(600);

/// Every case of the script: a diffuse sphere, white GGX metal of roughness 0.1 and
/// 0.3, rough glass.
const CASES: &str = "a,b,c,d";

#[test]
fn spheres_of_diffuse_metal_and_glass_render_like_mitsuba() {
    let Some(python) = std::env::var_os("TILEFARM_MITSUBA_PYTHON") else {
        skipped("TILEFARM_MITSUBA_PYTHON is not set (.ci/run sets it to a virtual environment with PyPI's mitsuba)");
        return;
    };
    // Set but unusable is a failure, not a skip: CI sets it.
    match Command::new(&python).args(["-c", "import mitsuba, numpy"]).output() {
        Err(e) => panic!("TILEFARM_MITSUBA_PYTHON={python:?} does not run: {e}"),
        Ok(o) if !o.status.success() => panic!(
            "TILEFARM_MITSUBA_PYTHON={python:?} cannot import mitsuba and numpy:\n{}",
            String::from_utf8_lossy(&o.stderr)
        ),
        Ok(_) => {}
    }
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = TempDir::new("mitsuba");
    let mut cmd = Command::new(&python);
    cmd.arg(here.join("mitsuba/compare_materials.py")).arg(bin("coordinator")).arg(dir.path("work"));
    cmd.args(["--cases", CASES]);
    let out = run(&mut cmd, LIMIT);
    let said = String::from_utf8_lossy(&out.stdout);
    let figures = figures_of(&out, "figures");
    assert!(
        out.status.success(),
        "the Mitsuba comparison failed:\n{}\n{}",
        said.lines().rev().take(30).collect::<Vec<_>>().join("\n"),
        String::from_utf8_lossy(&out.stderr)
    );
    for case in CASES.split(',') {
        assert!(figures.contains(&format!("\"{case}\": {{")), "case {case} ran: {figures}");
    }
}
