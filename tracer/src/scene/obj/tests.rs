// Tests may use the C library's functions: they check values, not platform-free bits.
#![allow(clippy::disallowed_methods)]

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};

use super::*;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/obj")
}

fn load_str(text: &str) -> ObjModel {
    match load_obj_from_str(text, &fixtures(), "test.obj") {
        Ok(m) => m,
        Err(e) => panic!("unexpected error: {e}"),
    }
}

fn load_err(text: &str) -> ObjError {
    match load_obj_from_str(text, &fixtures(), "test.obj") {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(e) => e,
    }
}

fn tri_area(mesh: &TriangleMesh, i: usize) -> f32 {
    let [a, b, c] = mesh.corners(i);
    0.5 * (b - a).cross(c - a).length()
}

fn tri_normal(mesh: &TriangleMesh, i: usize) -> Vec3 {
    let [a, b, c] = mesh.corners(i);
    (b - a).cross(c - a).normalize()
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).length() < 1e-5
}

const TRIANGLE_V: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
const TRIANGLE_VT: &str = "vt 0 0\nvt 1 0\nvt 0 1\n";
const TRIANGLE_VN: &str = "vn 0 0 1\n";

#[test]
fn every_index_form() {
    let cases = [
        (format!("{TRIANGLE_V}f 1 2 3\n"), false, false),
        (format!("{TRIANGLE_V}{TRIANGLE_VT}f 1/1 2/2 3/3\n"), true, false),
        (format!("{TRIANGLE_V}{TRIANGLE_VN}f 1//1 2//1 3//1\n"), false, true),
        (format!("{TRIANGLE_V}{TRIANGLE_VT}{TRIANGLE_VN}f 1/1/1 2/2/1 3/3/1\n"), true, true),
    ];
    for (text, has_uv, has_n) in cases {
        let m = load_str(&text);
        assert_eq!(m.mesh.tris.len(), 1, "{text}");
        let t = m.mesh.tris[0];
        assert_eq!(m.mesh.corners(0), [Vec3::ZERO, Vec3::X, Vec3::Y]);
        assert_eq!(t.uv != [NONE; 3], has_uv, "{text}");
        assert_eq!(t.n != [NONE; 3], has_n, "{text}");
        if has_uv {
            assert_eq!(t.uv.map(|i| m.mesh.uvs[i as usize]), [Vec2::ZERO, Vec2::X, Vec2::Y]);
        }
        if has_n {
            assert!(t.n.iter().all(|&i| m.mesh.normals[i as usize] == Vec3::Z));
        }
        // No usemtl: the default grey material, added because it is used.
        assert_eq!(m.materials, vec![MaterialDesc::default_grey(DEFAULT_MATERIAL_NAME)]);
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    }
}

#[test]
fn negative_indices_match_positive_ones() {
    let positive = load_str(&format!("{TRIANGLE_V}{TRIANGLE_VT}{TRIANGLE_VN}v 5 5 5\nf 1/1/1 2/2/1 3/3/1\n"));
    let negative = load_str(&format!("{TRIANGLE_V}{TRIANGLE_VT}{TRIANGLE_VN}v 5 5 5\nf -4/-3/-1 -3/-2/-1 -2/-1/-1\n"));
    assert_eq!(positive.mesh.corners(0), negative.mesh.corners(0));
    let uvs = |m: &ObjModel| m.mesh.tris[0].uv.map(|i| m.mesh.uvs[i as usize]);
    assert_eq!(uvs(&positive), uvs(&negative));
    // Relative to the vertices defined so far, not the whole file.
    let m = load_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 9 9 9\n");
    assert_eq!(m.mesh.corners(0), [Vec3::ZERO, Vec3::X, Vec3::Y]);
}

#[test]
fn quad_and_pentagon_fans_cover_the_polygon() {
    let quad = load_str("v 0 0 0\nv 2 0 0\nv 2 3 0\nv 0 3 0\nf 1 2 3 4\n");
    assert_eq!(quad.mesh.tris.len(), 2);
    let area: f32 = (0..2).map(|i| tri_area(&quad.mesh, i)).sum();
    assert!((area - 6.0).abs() < 1e-5);
    assert!((0..2).all(|i| close(tri_normal(&quad.mesh, i), Vec3::Z)), "CCW winding kept");

    let mut text = String::new();
    for k in 0..5 {
        let a = std::f32::consts::TAU * k as f32 / 5.0;
        text.push_str(&format!("v {} {} 0\n", a.cos(), a.sin()));
    }
    text.push_str("f 1 2 3 4 5\n");
    let pent = load_str(&text);
    assert_eq!(pent.mesh.tris.len(), 3);
    let area: f32 = (0..3).map(|i| tri_area(&pent.mesh, i)).sum();
    let exact = 2.5 * (std::f32::consts::TAU / 5.0).sin();
    assert!((area - exact).abs() < 1e-5, "{area} vs {exact}");
    assert!((0..3).all(|i| close(tri_normal(&pent.mesh, i), Vec3::Z)));
    // The fan uses the polygon's own vertices, 5 of them.
    assert_eq!(pent.mesh.positions.len(), 5);

    // A hexagon with vt and vn on every corner.
    let hex = load_str(
        "v 0 0 0\nv 1 0 0\nv 2 1 0\nv 1 2 0\nv 0 2 0\nv -1 1 0\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1 4/1/1 5/1/1 6/1/1\n",
    );
    assert_eq!(hex.mesh.tris.len(), 4);
    let area: f32 = (0..4).map(|i| tri_area(&hex.mesh, i)).sum();
    assert!((area - 4.0).abs() < 1e-5, "{area}");
}

#[test]
fn cube_in_one_smoothing_group_has_averaged_normals() {
    let m = load_obj(&fixtures().join("cube_s1.obj")).expect("cube loads");
    assert_eq!(m.mesh.tris.len(), 12);
    assert_eq!(m.mesh.positions.len(), 8);
    assert_eq!(m.mesh.normals.len(), 8, "one normal per position in the single group");
    for t in &m.mesh.tris {
        for k in 0..3 {
            let p = m.mesh.positions[t.v[k] as usize];
            let n = m.mesh.normals[t.n[k] as usize];
            assert!(close(n, (p - Vec3::splat(0.5)).normalize()), "{p} {n}");
        }
        // Outward winding.
        let [a, b, c] = [t.v[0], t.v[1], t.v[2]].map(|i| m.mesh.positions[i as usize]);
        let centre = (a + b + c) / 3.0 - Vec3::splat(0.5);
        assert!((b - a).cross(c - a).dot(centre) > 0.0);
    }
    assert_eq!(m.materials.len(), 1);
    assert_eq!(m.materials[0].name, "white");
    assert_eq!(m.materials[0].kd, Vec3::splat(0.8));
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
}

#[test]
fn smoothing_off_or_absent_is_flat() {
    let text = std::fs::read_to_string(fixtures().join("cube_s1.obj")).expect("fixture");
    for replacement in ["s off", "s 0", ""] {
        let m = load_str(&text.replace("s 1", replacement));
        assert_eq!(m.mesh.tris.len(), 12);
        assert!(m.mesh.tris.iter().all(|t| t.n == [NONE; 3]), "{replacement:?}");
        assert!(m.mesh.normals.is_empty());
    }
    // Groups switched off mid-file.
    let text = text.replace("f 1 2 6 5", "s off\nf 1 2 6 5\ns 1");
    let m = load_str(&text);
    let flat = m.mesh.tris.iter().filter(|t| t.n == [NONE; 3]).count();
    assert_eq!(flat, 2);
}

const FOLD: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 -1\nv 1 0 -1\n";

#[test]
fn two_smoothing_groups_keep_a_crease() {
    // Quad A faces +z, quad B faces -y; they share the edge v1-v2.
    let one = load_str(&format!("{FOLD}s 1\nf 1 2 3 4\nf 1 5 6 2\n"));
    let edge = (Vec3::new(0.0, -1.0, 1.0)).normalize();
    let normal_at = |m: &ObjModel, tri: usize, pos: Vec3| -> Vec3 {
        let t = m.mesh.tris[tri];
        let k = (0..3).find(|&k| m.mesh.positions[t.v[k] as usize] == pos).expect("corner");
        m.mesh.normals[t.n[k] as usize]
    };
    assert!(close(normal_at(&one, 0, Vec3::ZERO), edge));
    assert!(close(normal_at(&one, 2, Vec3::ZERO), edge));
    assert!(close(normal_at(&one, 1, Vec3::new(0.0, 1.0, 0.0)), Vec3::Z), "not on the edge");

    let two = load_str(&format!("{FOLD}s 1\nf 1 2 3 4\ns 2\nf 1 5 6 2\n"));
    for tri in 0..2 {
        for k in 0..3 {
            let t = two.mesh.tris[tri];
            assert!(close(two.mesh.normals[t.n[k] as usize], Vec3::Z));
        }
    }
    for tri in 2..4 {
        for k in 0..3 {
            let t = two.mesh.tris[tri];
            assert!(close(two.mesh.normals[t.n[k] as usize], -Vec3::Y));
        }
    }
    // The shared positions stay shared; only the normals split.
    assert_eq!(two.mesh.positions.len(), 6);
}

#[test]
fn given_vn_overrides_smoothing() {
    let text = std::fs::read_to_string(fixtures().join("cube_s1.obj")).expect("fixture");
    let text = text.replace("v 0 1 1\n", "v 0 1 1\nvn 0 0 2\n").replace("f 1 4 3 2", "f 1//1 4//1 3//1 2//1");
    let m = load_str(&text);
    // The bottom face uses the given (normalised) vn, the others stay smooth.
    for t in &m.mesh.tris[..2] {
        assert!(t.n.iter().all(|&i| m.mesh.normals[i as usize] == Vec3::Z));
    }
    // The front face's corner at the origin also touches the bottom face, which still counts
    // in the average.
    let t = m.mesh.tris[4];
    let p = m.mesh.positions[t.v[0] as usize];
    assert_eq!(p, Vec3::ZERO);
    assert!(close(m.mesh.normals[t.n[0] as usize], Vec3::splat(-1.0).normalize()));
}

#[test]
fn missing_mtl_gives_a_warning_and_grey() {
    let m = load_obj(&fixtures().join("missing_mtl.obj")).expect("loads anyway");
    assert_eq!(m.mesh.tris.len(), 1);
    assert!(m.warnings.iter().any(|w| w.contains("nope.mtl")), "{:?}", m.warnings);
    assert!(m.warnings.iter().any(|w| w.contains("'red'")), "{:?}", m.warnings);
    assert_eq!(m.materials, vec![MaterialDesc::default_grey("red")]);
    assert_eq!(m.mesh.tris[0].material, 0);
}

#[test]
fn unknown_material_gives_a_warning_and_grey() {
    let m = load_str(&format!("mtllib cube.mtl\n{TRIANGLE_V}usemtl white\nf 1 2 3\nusemtl nosuch\nf 1 3 2\nf 2 1 3\n"));
    assert_eq!(m.materials.len(), 2);
    assert_eq!(m.materials[0].name, "white");
    assert_eq!(m.materials[1], MaterialDesc::default_grey("nosuch"));
    assert_eq!(m.mesh.tris.iter().map(|t| t.material).collect::<Vec<_>>(), [0, 1, 1]);
    assert_eq!(m.warnings.len(), 1, "{:?}", m.warnings);
    assert!(m.warnings[0].contains("test.obj:7") && m.warnings[0].contains("'nosuch'"), "{:?}", m.warnings);
}

#[test]
fn groups_merge_and_materials_follow_usemtl() {
    let m = load_str(&format!(
        "mtllib cube.mtl\n{TRIANGLE_V}g a\nf 1 2 3\no b\nusemtl white\nf 1 2 3\ng c\nf 3 2 1\nusemtl\nf 1 2 3\n"
    ));
    assert_eq!(m.mesh.tris.len(), 4);
    assert_eq!(m.mesh.positions.len(), 3, "vertices shared across groups");
    assert_eq!(m.mesh.tris.iter().map(|t| t.material).collect::<Vec<_>>(), [0, 1, 1, 0]);
    assert_eq!(m.materials[0].name, DEFAULT_MATERIAL_NAME);
    assert_eq!(m.materials[1].name, "white");
}

#[test]
fn texture_is_loaded_once_and_sampled_linear() {
    let m = load_obj(&fixtures().join("textured.obj")).expect("loads");
    assert_eq!(m.mesh.tris.len(), 3);
    assert_eq!(m.textures.len(), 1, "two materials share checker.png");
    assert_eq!(m.materials.len(), 3);
    assert_eq!(m.materials[0].map_kd, Some(0));
    assert_eq!(m.materials[1].map_kd, Some(0), "map_Kd options are skipped");
    let tex = &m.textures[0];
    assert_eq!((tex.width, tex.height), (2, 2));
    // Row 0 (top, v = 1) is red, green; row 1 is blue, sRGB 128 grey.
    assert!(close(tex.sample(Vec2::new(0.25, 0.75)), Vec3::X));
    assert!(close(tex.sample(Vec2::new(0.75, 0.75)), Vec3::Y));
    assert!(close(tex.sample(Vec2::new(0.25, 0.25)), Vec3::Z));
    assert!(close(tex.sample(Vec2::new(0.75, 0.25)), Vec3::splat(0.215_860_5)));
    // The material whose texture is missing: one warning, its own Kd, no texture.
    let lost = &m.materials[2];
    assert_eq!(lost.name, "lost_texture");
    assert_eq!(lost.map_kd, None);
    assert_eq!(lost.kd, Vec3::ONE);
    assert_eq!(m.warnings.iter().filter(|w| w.contains("does_not_exist.png") && w.contains("lost_texture")).count(), 1);
    // -bm is skipped, and said so with the line.
    assert!(m.warnings.iter().any(|w| w.contains("textured.mtl:7") && w.contains("-bm 1")), "{:?}", m.warnings);
    // uvs come through.
    let t = m.mesh.tris[0];
    assert_eq!(t.uv.map(|i| m.mesh.uvs[i as usize]), [Vec2::ZERO, Vec2::X, Vec2::ONE]);
}

#[test]
fn mtl_statements() {
    let m = load_obj(&fixtures().join("materials.obj")).expect("loads");
    let full = &m.materials[0];
    assert_eq!(full.name, "full");
    assert_eq!(full.ka, Vec3::new(0.1, 0.2, 0.3));
    assert_eq!(full.kd, Vec3::new(0.4, 0.5, 0.6));
    assert_eq!(full.ks, Vec3::new(0.7, 0.8, 0.9));
    assert_eq!(full.ke, Vec3::new(1.0, 2.0, 3.0));
    assert_eq!(full.tf, Vec3::new(0.25, 0.5, 0.75));
    assert_eq!((full.ns, full.ni, full.d, full.illum), (250.0, 1.5, 0.8, Some(7)));
    let one = &m.materials[1];
    assert_eq!(one.ks, Vec3::splat(0.5), "Ks with one value is grey");
    assert_eq!(one.kd, Vec3::splat(0.25));
    assert_eq!(one.tf, Vec3::splat(0.5));
    assert_eq!((one.ka, one.ke, one.ni, one.d, one.illum), (Vec3::ZERO, Vec3::ZERO, 1.0, 1.0, None));
    let tr = &m.materials[2];
    assert!((tr.d - 0.75).abs() < 1e-6, "Tr is 1 - d");
    assert_eq!(tr.tf, Vec3::ONE);
    // `Pr` (MTL's PBR extension) makes `full` a Principled material; `illum 7` makes it glass.
    let pbr = full.pbr.as_ref().expect("Pr makes a Principled material");
    assert_eq!((pbr.inputs.roughness, pbr.inputs.ior, pbr.inputs.transmission, pbr.alpha), (0.5, 1.5, 1.0, 1.0));
    assert!(m.warnings.iter().all(|w| !w.contains("Pr")), "Pr is supported: {:?}", m.warnings);

    let lib = load_mtl(&fixtures().join("textured.mtl")).expect("mtl loads");
    assert_eq!(lib.materials.len(), 3);
    assert_eq!(lib.textures.len(), 1);
}

#[test]
fn malformed_lines_report_their_line() {
    let cases: &[(&str, usize, &str)] = &[
        ("v 1 2 3\nv 1 x 3\n", 2, "bad number 'x'"),
        ("v 1 2\n", 1, "vertex needs 3 coordinates"),
        ("v 0 0 0\n\nv inf 0 0\n", 3, "non-finite"),
        ("v NaN 0 0\n", 1, "non-finite"),
        ("v 1 1 1 0\n", 1, "w = 0"),
        ("vt\n", 1, "texture coordinate needs"),
        ("vn 0 1\n", 1, "normal needs 3"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", 4, "face index 4 out of range (3 vertices)"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 1 2\n", 4, "face index -4 out of range (3 vertices)"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", 4, "index 0 is invalid"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 x\n", 4, "bad index 'x'"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/1/1 2 3\n", 4, "bad face vertex"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf /1 2 3\n", 4, "no position index"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/2 2/1 3/1\n", 5, "texture coordinate index 2 out of range (1 texture"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n", 4, "texture coordinate index 1 out of range (0 texture"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//2 2//1 3//1\n", 5, "normal index 2 out of range (1 normals)"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\n# forward reference\nf 1 2 5\nv 1 1 1\nv 2 2 2\n", 5, "face index 5"),
        ("s\n", 1, "smoothing group needs"),
        ("s smooth\n", 1, "bad smoothing group"),
    ];
    for &(text, line, message) in cases {
        match load_err(text) {
            ObjError::Parse { path, line: l, message: m } => {
                assert_eq!(path, "test.obj");
                assert_eq!(l, line, "{text:?}: {m}");
                assert!(m.contains(message), "{text:?}: '{m}' lacks '{message}'");
            }
            e => panic!("{text:?}: wrong error {e}"),
        }
    }
}

#[test]
fn malformed_files_name_the_file() {
    let path = fixtures().join("bad_index.obj");
    let e = load_obj(&path).expect_err("bad index");
    assert_eq!(e.to_string(), format!("{}:17: face index 9 out of range (8 vertices)", path.display()));

    let missing = fixtures().join("no_such_file.obj");
    match load_obj(&missing) {
        Err(ObjError::Io { path, .. }) => assert_eq!(path, missing.display().to_string()),
        other => panic!("expected Io error, got {other:?}"),
    }

    // Non-UTF-8 garbage on line 3.
    let e = mtl::decode_utf8(b"v 0 0 0\nv 1 0 0\n\xff\xfe garbage\n".to_vec(), "bin.obj").expect_err("not UTF-8");
    assert!(matches!(e, ObjError::Parse { line: 3, .. }), "{e}");

    // A malformed MTL names the MTL file and line.
    let dir = std::env::temp_dir().join(format!("tilefarm-obj-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    std::fs::write(dir.join("bad.mtl"), "newmtl a\nKd 1 1 1\nKs 1 oops 1\n").expect("write");
    let e = load_obj_from_str(&format!("mtllib bad.mtl\n{TRIANGLE_V}usemtl a\nf 1 2 3\n"), &dir, "t.obj")
        .expect_err("bad MTL");
    assert!(e.to_string().ends_with("bad.mtl:3: bad number 'oops' in Ks"), "{e}");
    std::fs::write(dir.join("two.mtl"), "newmtl b\nKs 0.5 0.5\n").expect("write");
    let e = load_mtl(&dir.join("two.mtl")).expect_err("two values");
    assert!(e.to_string().contains("two.mtl:2: Ks needs 1 or 3 numbers"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn lenient_details() {
    // Comments, CRLF, tabs, BOM, vertex colours, `vt u`, `l` lines, multiple mtllib files.
    let m = load_str(
        "\u{feff}# header\r\nmtllib cube.mtl materials.mtl\r\nv 0 0 0 1 0 0\r\nv\t2 0 0 2 # w\r\nv 0 1 0\r\n\
         vt 0.5\r\nl 1 2 3\r\nusemtl one_value\r\nf 1/1 2/1 3/1 # comment\r\nusemtl white\r\nf 1 2 3\r\n",
    );
    assert_eq!(m.mesh.tris.len(), 2);
    assert_eq!(m.mesh.corners(0), [Vec3::ZERO, Vec3::X, Vec3::Y]);
    assert_eq!(m.mesh.uvs, vec![Vec2::new(0.5, 0.0)]);
    assert_eq!(m.materials[0].name, "one_value");
    assert_eq!(m.materials[1].name, "white");
    assert!(m.warnings.iter().any(|w| w.contains("1 line or point elements")), "{:?}", m.warnings);
}

/// Real models carry stray 2-vertex faces and `l`/`p` elements: they are skipped with one
/// warning that counts them, and the rest of the model loads.
#[test]
fn faces_without_area_and_line_elements_are_skipped_with_one_warning() {
    let m = load_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 1 2 3\nf 3\nl 1 2\np 1\nf 2 3\n");
    assert_eq!(m.mesh.tris.len(), 1);
    let w: Vec<&String> = m.warnings.iter().filter(|w| w.contains("skipped")).collect();
    assert_eq!(w.len(), 1, "{:?}", m.warnings);
    assert!(w[0].contains("3 faces with fewer than 3 vertices") && w[0].contains("2 line or point"), "{}", w[0]);
    assert!(w[0].contains("first on line 4"), "{}", w[0]);
}

#[test]
fn degenerate_triangles_are_dropped() {
    let m = load_str("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\nf 1 1 4\n");
    assert_eq!(m.mesh.tris.len(), 1);
    assert!(m.warnings.iter().any(|w| w.contains("dropped 2 degenerate")), "{:?}", m.warnings);
    // An empty file is an empty model.
    let empty = load_str("");
    assert!(empty.mesh.tris.is_empty() && empty.materials.is_empty());
}

#[test]
fn random_input_never_panics() {
    const WORDS: &[&str] = &[
        "v", "vt", "vn", "f", "s", "g", "o", "usemtl", "mtllib", "l", "1", "2", "3", "-1", "-2", "0", "1/1", "2//1",
        "3/1/1", "/", "//", "1/", "nan", "1e39", "-0", "x", "#", "off", "\t", "1.5", "white", "cube.mtl", "\u{0}",
    ];
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = |n: usize| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % n as u64) as usize
    };
    for _ in 0..3000 {
        let mut text = String::new();
        for _ in 0..next(12) {
            for _ in 0..next(6) {
                text.push_str(WORDS[next(WORDS.len())]);
                text.push(' ');
            }
            text.push('\n');
        }
        if let Err(e) = load_obj_from_str(&text, &fixtures(), "fuzz.obj") {
            let e = e.to_string();
            // Every error comes from the line scan, not from tobj or a disagreement with it.
            assert!(!e.contains("tobj") && !e.contains("internal"), "{e}\n{text}");
        }
    }
}

#[test]
fn map_kd_options_place_the_image_or_are_skipped_by_name() {
    let a = mtl::parse_map_arg("-s 2 3 1 -o 0.5 0.25 -clamp on -bm 0.3 -mm 0 1 wood grain.png").unwrap();
    assert_eq!(a.name, "wood grain.png");
    assert_eq!(a.map.scale, Vec2::new(2.0, 3.0));
    assert_eq!(a.map.offset, Vec2::new(0.5, 0.25));
    assert!(a.map.clamp);
    assert_eq!(a.skipped, ["-mm 0 1"]);
    assert_eq!(a.bm, Some(0.3), "-bm is kept for bump and normal maps");
    // As the MTL specification says, an omitted v scale is 1 (and an omitted offset 0).
    let b = mtl::parse_map_arg("-s 4 -o 0.5 tex.png").unwrap();
    assert_eq!((b.name.as_str(), b.map.scale, b.map.offset), ("tex.png", Vec2::new(4.0, 1.0), Vec2::new(0.5, 0.0)));
    assert!(mtl::parse_map_arg("-clamp off").is_none(), "no file name");
}

/// Every common format the `image` crate reads is a texture: GIF, TIFF and EXR too.
#[test]
fn gif_tiff_and_exr_textures_load() {
    let dir = std::env::temp_dir().join(format!("tilefarm-texformats-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let img =
        image::RgbImage::from_fn(2, 2, |x, _| if x == 0 { image::Rgb([255, 0, 0]) } else { image::Rgb([0, 0, 255]) });
    for ext in ["gif", "tiff", "png"] {
        img.save(dir.join(format!("t.{ext}"))).unwrap();
    }
    image::DynamicImage::ImageRgb8(img.clone()).to_rgb32f().save(dir.join("t.exr")).unwrap();
    for ext in ["gif", "tiff", "exr"] {
        std::fs::write(dir.join("m.mtl"), format!("newmtl m\nKd 1 1 1\nmap_Kd t.{ext}\n")).unwrap();
        let lib = load_mtl(&dir.join("m.mtl")).unwrap();
        assert!(lib.warnings.is_empty(), "{ext}: {:?}", lib.warnings);
        let tex = &lib.textures[0];
        assert_eq!((tex.width, tex.height), (2, 2), "{ext}");
        // 8-bit formats are sRGB-decoded and float EXR is linear: both give pure red here.
        assert!(close(tex.sample(Vec2::new(0.25, 0.5)), Vec3::X), "{ext}: {}", tex.sample(Vec2::new(0.25, 0.5)));
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn map_kd_offset_is_applied_when_rendering_uvs() {
    let dir = std::env::temp_dir().join(format!("tilefarm-texoffset-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    image::RgbImage::from_fn(2, 1, |x, _| if x == 0 { image::Rgb([255, 0, 0]) } else { image::Rgb([0, 255, 0]) })
        .save(dir.join("rg.png"))
        .unwrap();
    std::fs::write(dir.join("m.mtl"), "newmtl plain\nmap_Kd rg.png\nnewmtl moved\nmap_Kd -o 0.5 0 rg.png\n").unwrap();
    let lib = load_mtl(&dir.join("m.mtl")).unwrap();
    assert_eq!(lib.textures.len(), 2, "one decode, two placements");
    let at = |m: usize| lib.textures[lib.materials[m].map_kd.unwrap() as usize].sample(Vec2::new(0.25, 0.5));
    assert!(close(at(0), Vec3::X));
    assert!(close(at(1), Vec3::Y));
    std::fs::remove_dir_all(&dir).ok();
}
