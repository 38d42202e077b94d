//! Instancing through the scene file: an OBJ placed more than once is stored once, and
//! its images equal those of the same copies stored triangle by triangle, within the
//! rounding of moving rays instead of triangles.

mod common;

use common::TempDir;
use tracer::film::{Image, SampleRange};
use tracer::integrator::Integrator;
use tracer::render::render_image;
use tracer::scene::generate::displaced_sphere;
use tracer::scene::scene_from_toml;

/// A displaced sphere as OBJ text: the first half of its faces with material `m`, the
/// rest with `g`.
fn blob_obj(triangles: usize, seed: u64) -> String {
    let mesh = displaced_sphere(triangles, seed);
    let mut s = String::from("mtllib blob.mtl\nusemtl m\n");
    for p in &mesh.positions {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for (i, t) in mesh.tris.iter().enumerate() {
        if i == mesh.tris.len() / 2 {
            s += "usemtl g\n";
        }
        s += &format!("f {} {} {}\n", t.v[0] + 1, t.v[1] + 1, t.v[2] + 1);
    }
    s
}

/// Glossy on one half, glass on the other: glass tells a face's front from its back, so
/// a copy that turned its faces inside out would refract the wrong way.
const BLOB_MTL: &str = "newmtl m\nKd 0.7 0.5 0.3\nKs 0.2 0.2 0.2\nNs 40\nnewmtl g\nNi 1.5\nillum 7\n";
const FLOOR: &str =
    "mtllib floor.mtl\nusemtl f\nv -8 -1.2 -8\nv 8 -1.2 -8\nv 8 -1.2 8\nv -8 -1.2 8\nf 1 3 2\nf 1 4 3\n";
const FLOOR_MTL: &str = "newmtl f\nKd 0.6 0.6 0.6\n";
const LAMP: &str = "mtllib lamp.mtl\nusemtl l\nv -1 4 -1\nv 1 4 -1\nv 1 4 1\nv -1 4 1\nf 1 2 3\nf 1 3 4\n";
const LAMP_MTL: &str = "newmtl l\nKe 12 12 12\n";

/// Six copies of the blob: moved, turned about a tilted axis, mirrored, sheared by a
/// matrix, and two more, which `shared` lists in one table's `instance` list and the
/// flat scene gives tables of their own (the same transforms, bit for bit). `name(k)`
/// is the OBJ of table `k`.
fn scene_text(shared: bool, name: &dyn Fn(usize) -> String) -> String {
    let mut placements = vec![
        "translate = [-2.2, 0, 0]".to_string(),
        "translate = [0, 0, 0]\nrotate = { axis = [1, 1, 0], degrees = 35 }".into(),
        "translate = [2.2, 0, 0]\nscale = [-1, 1.2, 1]".into(),
        "matrix = [[1, 0.3, 0, 0], [0, 1, 0, 0.1], [0.2, 0, 0.8, 2.2], [0, 0, 0, 1]]".into(),
    ];
    if shared {
        placements.push(
            "scale = 0.5\ninstance = [ { translate = [-1.5, -0.5, -2] }, { translate = [1.5, -0.5, -2], rotate_y = 70 } ]"
                .into(),
        );
    } else {
        placements.push("scale = 0.5\ntranslate = [-1.5, -0.5, -2]".into());
        placements.push("scale = 0.5\ntranslate = [1.5, -0.5, -2]\nrotate_y = 70".into());
    }
    let mut s = "[camera]\nposition = [0, 2.5, 7]\nlook_at = [0, 0, 0]\nfov = 45\nwidth = 40\nheight = 32\n\
                 [render]\nmax_depth = 8\nseed = 3\n\
                 [[mesh]]\nobj = \"floor.obj\"\n[[mesh]]\nobj = \"lamp.obj\"\n"
        .to_string();
    for (k, p) in placements.iter().enumerate() {
        s += &format!("[[mesh]]\nobj = \"{}\"\n{p}\n", name(k));
    }
    s += "[[light]]\ntype = \"directional\"\ndirection = [0.3, -1, -0.4]\nirradiance = [0.6, 0.6, 0.7]\n";
    s
}

fn render(scene: &tracer::scene::Scene, spp: u32) -> Image {
    render_image(scene, Integrator::Path, SampleRange::new(0, spp), 8, &|_| {}).0
}

fn luminance(i: &Image) -> Vec<f64> {
    i.pixels.iter().map(|p| f64::from(0.2126 * p.x + 0.7152 * p.y + 0.0722 * p.z)).collect()
}

/// The same copies, instanced (one OBJ placed six times) and stored triangle by
/// triangle (six OBJ files with the same text): the same random numbers drive both, so
/// a pixel differs only where rounding turns a ray. The difference of the two images has
/// zero mean within its own noise (a copy placed or shaded wrongly would not), and most
/// pixels are equal or nearly so.
#[test]
fn instanced_copies_render_as_the_flattened_scene() {
    let dir = TempDir::new("instancing");
    let blob = blob_obj(3000, 5);
    for k in 0..6 {
        dir.write(&format!("blob{k}.obj"), &blob);
    }
    dir.write("blob.obj", &blob);
    for (name, text) in [
        ("blob.mtl", BLOB_MTL),
        ("floor.obj", FLOOR),
        ("floor.mtl", FLOOR_MTL),
        ("lamp.obj", LAMP),
        ("lamp.mtl", LAMP_MTL),
    ] {
        dir.write(name, text);
    }
    let shared = scene_from_toml(&scene_text(true, &|_| "blob.obj".into()), "shared.toml", &dir.0).unwrap();
    let flat = scene_from_toml(&scene_text(false, &|k| format!("blob{k}.obj")), "flat.toml", &dir.0).unwrap();

    let inst = shared.instances.as_ref().expect("blob.obj is placed six times");
    assert_eq!((inst.set.meshes.len(), inst.set.list.len()), (1, 6));
    assert_eq!(shared.geometry.triangle_count(), 4, "the floor and the lamp, stored flat");
    assert!(flat.instances.is_none());
    assert_eq!(inst.triangles_seen() + 4, flat.geometry.triangle_count() as u64);
    assert_eq!(shared.lights.lights.len(), flat.lights.lights.len());
    assert!((shared.radius - flat.radius).abs() < 1e-3 * flat.radius);

    let spp = 32;
    let (a, b) = (luminance(&render(&shared, spp)), luminance(&render(&flat, spp)));
    let n = a.len() as f64;
    let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
    let mean_d = d.iter().sum::<f64>() / n;
    let sd_d = (d.iter().map(|x| (x - mean_d).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let mean_a = a.iter().sum::<f64>() / n;
    let same = a.iter().zip(&b).filter(|(x, y)| x == y).count();
    let close = a.iter().zip(&b).filter(|(x, y)| (*x - *y).abs() <= 0.001 * x.abs().max(y.abs()).max(0.05)).count();
    println!(
        "image mean {mean_a:.5}; difference mean {mean_d:.2e}, sd {sd_d:.2e}; {same} of {n} pixels the same bits, {close} within 0.1 %"
    );
    assert!(mean_a > 0.05, "the scene must be lit to test anything: {mean_a}");
    assert!(mean_d.abs() <= 4.0 * sd_d / n.sqrt() + 1e-4 * mean_a, "biased: {mean_d} (sd {sd_d})");
    assert!(close as f64 >= 0.98 * n, "only {close} of {n} pixels agree within 0.1 %");
}

/// A thousand copies of a 20k-triangle mesh (20M triangles seen) hold about one copy's
/// memory, and render.
#[test]
fn a_thousand_copies_cost_about_one() {
    let dir = TempDir::new("instancing-many");
    dir.write("blob.obj", &blob_obj(20_000, 9));
    dir.write("blob.mtl", BLOB_MTL);
    let mut text = "[camera]\nposition = [0, 60, 90]\nlook_at = [0, 0, 0]\nfov = 50\nwidth = 24\nheight = 16\n\
                    [[light]]\ntype = \"directional\"\ndirection = [0.3, -1, -0.4]\nirradiance = [1, 1, 1]\n\
                    [[mesh]]\nobj = \"blob.obj\"\ninstance = [\n"
        .to_string();
    for k in 0..1000 {
        let (x, z) = ((k % 40) as f32 * 3.0 - 60.0, (k / 40) as f32 * 3.0 - 37.5);
        text += &format!("  {{ translate = [{x}, 0, {z}], rotate_y = {} }},\n", k * 7 % 360);
    }
    text += "]\n";
    let scene = scene_from_toml(&text, "many.toml", &dir.0).unwrap();
    let inst = scene.instances.as_ref().unwrap();
    let one = inst.set.meshes[0].heap_bytes();
    let seen = inst.triangles_seen();
    assert!(seen >= 19_000_000, "{seen}");
    let all = inst.heap_bytes() + scene.geometry.bytes().total() + scene.accel.heap_bytes();
    println!("{seen} triangles seen; one copy {one} B, the whole scene {all} B");
    assert!(all < one + 1000 * 1024, "{all} B for the scene against {one} B for one copy");
    let image = render(&scene, 2);
    assert!(luminance(&image).iter().sum::<f64>() > 0.0);
}

#[test]
fn an_emitting_obj_placed_twice_is_stored_per_copy_with_a_warning() {
    let dir = TempDir::new("instancing-lamp");
    dir.write("lamp.obj", LAMP);
    dir.write("lamp.mtl", LAMP_MTL);
    let text = "[camera]\nposition = [0, 0, 7]\nlook_at = [0, 0, 0]\n\
                [[mesh]]\nobj = \"lamp.obj\"\n[[mesh]]\nobj = \"lamp.obj\"\ntranslate = [0, -3, 0]\n";
    let scene = scene_from_toml(text, "lamps.toml", &dir.0).unwrap();
    assert!(scene.instances.is_none());
    assert_eq!(scene.geometry.triangle_count(), 4);
    assert_eq!(scene.lights.lights.len(), 4, "every copy's triangles are lights");
    let w: Vec<&String> = scene.warnings.iter().filter(|w| w.contains("emits light")).collect();
    assert_eq!(w.len(), 1, "{:?}", scene.warnings);
    assert!(w[0].contains("lamp.obj") && w[0].contains("2 times"), "{}", w[0]);
}

#[test]
fn a_bad_copy_names_its_table_and_line() {
    let dir = TempDir::new("instancing-bad");
    dir.write("blob.obj", &blob_obj(100, 1));
    dir.write("blob.mtl", BLOB_MTL);
    let text = "[camera]\nposition = [0, 0, 7]\nlook_at = [0, 0, 0]\n\
                [[mesh]]\nobj = \"blob.obj\"\ninstance = [ { translate = [1, 0, 0] }, { matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 1]] } ]\n";
    let e = scene_from_toml(text, "bad.toml", &dir.0).err().expect("a matrix that is not affine").to_string();
    assert!(e.starts_with("bad.toml:4: mesh[0].instance[1].matrix: the last row must be"), "{e}");
}

#[test]
fn copies_are_bounded_before_anything_is_placed() {
    let dir = TempDir::new("instancing-bound");
    let copies = "{},".repeat(tracer::scene::placement::MAX_COPIES + 1);
    let text = format!(
        "[camera]\nposition = [0, 0, 7]\nlook_at = [0, 0, 0]\n[[mesh]]\nobj = \"absent.obj\"\ninstance = [{copies}]\n"
    );
    let e = scene_from_toml(&text, "many.toml", &dir.0).err().expect("too many copies").to_string();
    assert!(e.contains("mesh[0].instance: more than 1000000 placed meshes"), "{e}");
}
