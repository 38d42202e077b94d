//! tilefarm against Mitsuba 3 (PyPI's `mitsuba`, variant `scalar_rgb`; `.ci/run`
//! installs it in a virtual environment and names its Python in
//! TILEFARM_MITSUBA_PYTHON; without that variable the tests say SKIPPED).
//! `tests/mitsuba/compare_materials.py` builds each case's sphere on one stage as a
//! tilefarm scene and as a Mitsuba scene, renders both at the same spp, and compares
//! the channel means (within 1 %) and 8 × 8-pixel blocks (within their noise);
//! `tests/mitsuba/compare_envmap.py` does the same for spheres lit only by an
//! environment map.

use std::ffi::OsString;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

use tilefarm_e2e::*;

const LIMIT: Duration = Duration::from_secs(600);

/// Every case of the script: a diffuse sphere, white GGX metal of roughness 0.1 and
/// 0.3, rough glass.
const CASES: &str = "a,b,c,d";

/// The Python of TILEFARM_MITSUBA_PYTHON, checked; `None` (the test says SKIPPED)
/// without the variable.
fn mitsuba_python() -> Option<OsString> {
    let Some(python) = std::env::var_os("TILEFARM_MITSUBA_PYTHON") else {
        skipped("TILEFARM_MITSUBA_PYTHON is not set (.ci/run sets it to a virtual environment with PyPI's mitsuba)");
        return None;
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
    Some(python)
}

#[test]
fn spheres_of_diffuse_metal_and_glass_render_like_mitsuba() {
    let Some(python) = mitsuba_python() else {
        return;
    };
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

/// Every case of `compare_envmap.py`: a diffuse sphere, white GGX metal of roughness
/// 0.5 and a mirror sphere over a diffuse floor, lit only by a sky with a sun off the
/// axes, and the diffuse sphere again under the map turned by `rotate = 90`.
const ENVMAP_CASES: &str = "a,b,c,d";

#[test]
fn environment_map_lights_like_mitsuba() {
    let Some(python) = mitsuba_python() else {
        return;
    };
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = TempDir::new("mitsuba-envmap");
    let mut cmd = Command::new(&python);
    cmd.arg(here.join("mitsuba/compare_envmap.py")).arg(bin("coordinator")).arg(dir.path("work"));
    cmd.args(["--cases", ENVMAP_CASES]);
    let out = run(&mut cmd, LIMIT);
    let said = String::from_utf8_lossy(&out.stdout);
    let figures = figures_of(&out, "envmap figures");
    assert!(
        out.status.success(),
        "the Mitsuba environment map comparison failed:\n{}\n{}",
        said.lines().rev().take(30).collect::<Vec<_>>().join("\n"),
        String::from_utf8_lossy(&out.stderr)
    );
    for case in ENVMAP_CASES.split(',') {
        assert!(figures.contains(&format!("\"{case}\": {{")), "case {case} ran: {figures}");
    }
}
