//! The `coordinator` binary as a user runs it: the README's render command (on a small
//! image), and clear errors for bad input.

use std::io::Write;
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
    // A child forked by another test while the copy was open for writing holds it open
    // for a moment ("text file busy", ETXTBSY): try again briefly.
    let run = || {
        Command::new(&exe)
            .current_dir(&dir.0)
            .args(["render", "-q", "--spp", "2", "--width", "16", "--local-workers", "2", "-o", "cornell.exr"])
            .output()
    };
    let mut out = run();
    for _ in 0..100 {
        match &out {
            Err(e) if e.raw_os_error() == Some(26) => {
                std::thread::sleep(std::time::Duration::from_millis(20));
                out = run();
            }
            _ => break,
        }
    }
    let out = out.unwrap();
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

/// A quad facing +z at the origin, textured by a file that does not exist.
fn write_quad_with_missing_texture(dir: &std::path::Path) -> PathBuf {
    std::fs::write(
        dir.join("quad.obj"),
        "mtllib quad.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
         usemtl m\nf 1/1 2/2 3/3 4/4\n",
    )
    .unwrap();
    std::fs::write(dir.join("quad.mtl"), "newmtl m\nKd 0.8 0.1 0.1\nmap_Kd tex/missing.png\n").unwrap();
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        "[camera]\nposition = [0.0, 0.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\nwidth = 16\nheight = 16\n\
         [render]\nspp = 4\n[[mesh]]\nobj = \"quad.obj\"\n\
         [[light]]\ntype = \"point\"\nposition = [0.0, 0.0, 3.0]\nintensity = [5.0, 5.0, 5.0]\n",
    )
    .unwrap();
    scene
}

/// One warning for the job, naming the texture as the MTL file names it (not a copy in
/// a temporary folder), and the material keeps its own Kd: the quad renders red.
#[test]
fn a_missing_texture_is_warned_about_once_with_the_users_path_and_keeps_kd() {
    let dir = TempDir::new("missing-tex");
    let scene = write_quad_with_missing_texture(&dir.0);
    let exr = dir.0.join("quad.exr");
    let out = coordinator()
        .args(["render", "-q", "--local-workers", "2", "-o"])
        .arg(&exr)
        .arg(&scene)
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.contains("missing.png")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].starts_with("warning: quad.mtl: material 'm': map_Kd texture 'tex/missing.png'"), "{err}");
    assert!(!err.contains("tilefarm-render-") && !err.contains("os error"), "{err}");
    assert!(!err.contains('\x1b'), "no colour codes in a pipe: {err}");
    let img = tracer::output::read_exr(&exr).unwrap();
    let centre = img.pixels[(8 * 16 + 8) as usize];
    assert!(centre.x > 4.0 * centre.y && centre.x > 0.05, "Kd kept, not grey: {centre}");
}

#[test]
fn zero_counts_and_sizes_are_refused() {
    for flag in ["--spp", "--width", "--height", "--tile", "--batch-spp"] {
        let out = coordinator().args(["render", "-q", flag, "0", "-o", "never.exr"]).output().unwrap();
        assert!(!out.status.success(), "{flag} 0 was accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(flag) && err.contains("'0'"), "{flag}: {err}");
    }
}

/// A typo in -o is found before rendering, not after: this render would take minutes.
#[test]
fn a_bad_output_path_fails_before_anything_is_rendered() {
    let dir = TempDir::new("bad-out");
    std::fs::create_dir_all(dir.0.join("d.exr")).unwrap();
    for (path, expect) in [
        (dir.0.join("no-such-folder/out.exr"), "does not exist"),
        (dir.0.join("out.jpg"), ".exr or .png"),
        (dir.0.join("d.exr"), "is a folder"),
    ] {
        let start = std::time::Instant::now();
        let out = coordinator().args(["render", "-q", "--spp", "100000", "-o"]).arg(&path).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(expect), "{}: {err}", path.display());
        assert!(start.elapsed() < std::time::Duration::from_secs(5), "took {:?}", start.elapsed());
    }
}

#[test]
fn a_file_that_is_not_a_scene_is_said_to_be_so() {
    let dir = TempDir::new("not-scene");
    let png = dir.0.join("photo.png");
    std::fs::write(&png, [0x89, b'P', b'N', b'G', 0, 0, 0xff]).unwrap();
    for path in [png, dir.0.clone()] {
        let out = coordinator().args(["render", "-q", "-o"]).arg(dir.0.join("x.exr")).arg(&path).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains("not a scene file"), "{err}");
        assert!(!err.contains("UTF-8"), "{err}");
    }
}

/// A scene value's error names the file and line, once, without a doubled prefix.
#[test]
fn scene_value_errors_name_the_line() {
    let dir = TempDir::new("value");
    let scene = dir.0.join("s.toml");
    std::fs::write(&scene, "[camera]\nposition = [0,0,0]\nlook_at = [0,0,1]\nwidth = 0\n[render]\nspp = 4\n").unwrap();
    let out = coordinator().args(["render", "-q", "-o"]).arg(dir.0.join("x.exr")).arg(&scene).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("s.toml:4: camera.width: must be at least 1"), "{err}");
    assert_eq!(err.matches("camera.width").count(), 1, "reported once: {err}");
    assert!(!err.contains("camera: camera"), "{err}");
}

/// A Z-up model (a 1 × 1 × 8 emissive box along +z, with the stray 2-vertex faces and
/// `l` lines of real files) stands upright with --up z: taller than wide in the image.
#[test]
fn a_z_up_obj_renders_upright_and_stray_elements_are_skipped() {
    let dir = TempDir::new("zup");
    let mut obj = String::from("mtllib glow.mtl\nusemtl glow\n");
    for z in [0.0, 8.0] {
        for (x, y) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
            obj += &format!("v {x} {y} {z}\n");
        }
    }
    // Outward (counter-clockwise seen from outside) faces of the box.
    obj += "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\nf 1 2\nl 1 5\n";
    std::fs::write(dir.0.join("pole.obj"), obj).unwrap();
    std::fs::write(dir.0.join("glow.mtl"), "newmtl glow\nKd 0 0 0\nKe 1 1 1\n").unwrap();
    let extent = |up: &str| {
        let exr = dir.0.join(format!("pole-{up}.exr"));
        let out = coordinator()
            .args(["render", "-q", "--local-workers", "0", "--spp", "1", "--width", "64", "--up", up, "-o"])
            .arg(&exr)
            .arg(dir.0.join("pole.obj"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{err}");
        assert!(err.contains("skipped 1 faces with fewer than 3 vertices and 1 line or point"), "{err}");
        let img = tracer::output::read_exr(&exr).unwrap();
        let lit: Vec<(u32, u32)> = (0..img.height)
            .flat_map(|y| (0..img.width).map(move |x| (x, y)))
            .filter(|&(x, y)| img.pixels[(y * img.width + x) as usize].x > 0.5)
            .collect();
        let (xs, ys): (Vec<u32>, Vec<u32>) = lit.into_iter().unzip();
        let span = |v: &[u32]| v.iter().max().unwrap() - v.iter().min().unwrap() + 1;
        (span(&xs), span(&ys))
    };
    let (w, h) = extent("z");
    assert!(h > 2 * w, "upright with --up z: {w}×{h} pixels");
    let (w, h) = extent("y");
    assert!(h < 2 * w, "lying on its side without: {w}×{h} pixels");
}

/// The EXR records what made it, in standard attributes where OpenEXR has them.
#[test]
fn the_exr_header_records_how_the_image_was_made() {
    let dir = TempDir::new("header");
    let exr_path = dir.0.join("cornell.exr");
    let out = coordinator()
        .args(["render", "-q", "--spp", "2", "--width", "24", "--max-depth", "5", "--seed", "7", "-o"])
        .arg(&exr_path)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let meta = exr::meta::MetaData::read_from_file(&exr_path, false).unwrap();
    let header = &meta.headers[0];
    let own = &header.own_attributes;
    let software = own.software_name.as_ref().unwrap().to_string();
    assert!(software.starts_with("tilefarm ") && software.contains(env!("CARGO_PKG_VERSION")), "{software}");
    let c = header.shared_attributes.chromaticities.unwrap();
    assert_eq!((c.red.0, c.red.1, c.white.0), (0.64, 0.33, 0.3127), "Rec. 709 / sRGB, D65");
    let w2c = own.world_to_camera.unwrap();
    assert_eq!(w2c[15], 1.0);
    let w2ndc = own.world_to_normalized_device.unwrap();
    assert!(w2ndc.iter().any(|&v| v != 0.0));
    use exr::meta::attribute::AttributeValue;
    let attr = |k: &str| own.other.get(&exr::meta::attribute::Text::from(k)).cloned();
    assert_eq!(attr("tilefarm/spp"), Some(AttributeValue::I32(2)));
    assert_eq!(attr("tilefarm/sppReached"), Some(AttributeValue::I32(2)));
    assert_eq!(attr("tilefarm/maxDepth"), Some(AttributeValue::I32(5)));
    assert_eq!(attr("tilefarm/seed"), Some(AttributeValue::Text("7".into())));
    assert_eq!(attr("tilefarm/integrator"), Some(AttributeValue::Text("path".into())));
    assert_eq!(attr("tilefarm/scene"), Some(AttributeValue::Text("scene.toml".into())));
    assert!(matches!(attr("tilefarm/renderSeconds"), Some(AttributeValue::F64(s)) if s > 0.0));
    assert_eq!(attr("tilefarm/clamp"), None, "no clamp unless asked for");
    // The camera matrix maps the camera's own position to the origin of camera space.
    // (The built-in scene is the bundled Cornell box.)
    let bundled = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box/scene.toml");
    let cam = tracer::scene::load_scene(&bundled).unwrap().camera;
    let m = glam::Mat4::from_cols_array(&w2c);
    assert!(m.transform_point3(cam.position).length() < 1e-3);
}

/// `--clamp` reaches the workers, bounds every pixel and is recorded in the EXR; a limit
/// that is not a positive number is refused before anything starts.
#[test]
fn clamp_bounds_the_image_and_is_recorded() {
    let dir = TempDir::new("clamp");
    let exr_path = dir.0.join("clamped.exr");
    let out = coordinator()
        .args(["render", "-q", "--spp", "4", "--width", "24", "--local-workers", "1", "--clamp", "0.5", "-o"])
        .arg(&exr_path)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let img = tracer::output::read_exr(&exr_path).unwrap();
    let brightest = img.pixels.iter().map(|p| p.max_element()).fold(0.0, f32::max);
    assert!(brightest <= 0.5 + 1e-6 && brightest > 0.25, "brightest pixel {brightest}");
    let meta = exr::meta::MetaData::read_from_file(&exr_path, false).unwrap();
    let key = exr::meta::attribute::Text::from("tilefarm/clamp");
    assert_eq!(meta.headers[0].own_attributes.other.get(&key), Some(&exr::meta::attribute::AttributeValue::F32(0.5)));
    for bad in ["0", "-1", "nan", "inf", "abc"] {
        let out = coordinator().args(["render", "-q", "--clamp", bad, "-o"]).arg(dir.0.join("x.exr")).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains("--clamp"), "{bad}: {err}");
        assert!(!dir.0.join("x.exr").exists());
    }
}

/// `--aovs` writes the AOV layers into the same EXR, through a worker process, under the
/// names compositors read; the beauty channels are the same bits as without them.
#[test]
fn aovs_are_layers_of_the_same_exr() {
    let dir = TempDir::new("aovs");
    let render = |name: &str, extra: &[&str]| {
        let path = dir.0.join(name);
        let out = coordinator()
            .args(["render", "-q", "--spp", "4", "--width", "24", "--local-workers", "1"])
            .args(extra)
            .arg("-o")
            .arg(&path)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        path
    };
    let layered = render("layered.exr", &["--aovs"]);
    let plain = render("plain.exr", &[]);
    let meta = exr::meta::MetaData::read_from_file(&layered, false).unwrap();
    let mut names: Vec<String> = meta.headers[0].channels.list.iter().map(|c| c.name.to_string()).collect();
    names.sort();
    let mut expected = [
        "A",
        "B",
        "G",
        "N.X",
        "N.Y",
        "N.Z",
        "R",
        "Z",
        "albedo.B",
        "albedo.G",
        "albedo.R",
        "samples",
        "variance.B",
        "variance.G",
        "variance.R",
    ]
    .map(String::from)
    .to_vec();
    expected.sort();
    assert_eq!(names, expected);
    let (a, b) = (tracer::output::read_exr(&layered).unwrap(), tracer::output::read_exr(&plain).unwrap());
    assert_eq!((&a.pixels, &a.counts), (&b.pixels, &b.counts), "the beauty pass is unchanged by the layers");
    assert!(b.layers.is_empty() && a.layers.len() == a.pixels.len());
    // The Cornell box is closed: every camera ray hits a wall at a finite distance, with
    // an albedo in [0, 1] and a unit normal.
    for (i, l) in a.layers.iter().enumerate() {
        assert!(l.depth.is_finite() && l.depth > 0.0, "pixel {i}: Z {}", l.depth);
        assert!(l.albedo.min_element() >= 0.0 && l.albedo.max_element() <= 1.0, "pixel {i}: {}", l.albedo);
        assert!(l.normal.length() <= 1.0 + 1e-5 && l.variance.min_element() >= 0.0, "pixel {i}: {l:?}");
    }
    assert!(a.layers.iter().any(|l| l.normal.length() > 0.99), "flat walls have unit normals");
}

/// `--denoise` adds a denoised layer beside the raw beauty (which keeps its bits) and
/// records the denoiser; a PNG shows the denoised image. A build without the denoiser
/// refuses `--denoise` before rendering, saying how to get one.
#[test]
fn denoise_adds_a_layer_beside_the_raw_image() {
    let dir = TempDir::new("denoise");
    let run = |name: &str, extra: &[&str]| {
        let path = dir.0.join(name);
        let out = coordinator()
            .args(["render", "-q", "--spp", "4", "--width", "32", "--local-workers", "1"])
            .args(extra)
            .arg("-o")
            .arg(&path)
            .output()
            .unwrap();
        (path, out)
    };
    if !tracer::denoise::AVAILABLE {
        let (path, out) = run("d.exr", &["--denoise"]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains("--features denoise"), "{err}");
        assert!(!path.exists(), "nothing rendered");
        // On stderr itself: the harness hides a passing test's println!.
        let _ = writeln!(
            std::io::stderr(),
            "SKIPPED: denoising itself: built without the `denoise` feature; `.ci/run` builds it"
        );
        return;
    }
    let (denoised, out) = run("d.exr", &["--denoise"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (raw, out) = run("r.exr", &["--aovs"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (d, r) = (tracer::output::read_exr(&denoised).unwrap(), tracer::output::read_exr(&raw).unwrap());
    assert_eq!((&d.pixels, &d.layers), (&r.pixels, &r.layers), "the raw beauty and layers are kept as they were");
    assert_eq!(d.denoised.len(), d.pixels.len());
    assert!(d.denoised.iter().all(|p| p.is_finite()) && d.denoised != d.pixels);
    let meta = exr::meta::MetaData::read_from_file(&denoised, false).unwrap();
    let key = exr::meta::attribute::Text::from("tilefarm/denoiser");
    assert!(meta.headers[0].own_attributes.other.contains_key(&key));
    let (png, out) = run("d.png", &["--denoise"]);
    assert!(out.status.success() && png.exists(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// A render that was killed never ran its cleanup: the next render removes its folder.
#[test]
fn a_killed_renders_temporary_folder_is_removed_by_the_next_render() {
    // Above any Linux pid_max, so no process has this id.
    let stale = std::env::temp_dir().join("tilefarm-render-4294967294");
    std::fs::create_dir_all(stale.join("cache")).unwrap();
    let dir = TempDir::new("stale");
    let out = coordinator()
        .args(["render", "-q", "--spp", "1", "--width", "8", "--local-workers", "0", "-o"])
        .arg(dir.0.join("x.exr"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(!stale.exists(), "the dead render's folder is gone");
}
