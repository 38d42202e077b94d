//! Normal and bump maps against analytic answers: a Lambertian quad lit by a directional
//! light (no other surface, two path segments) has radiance `kd/π · E · max(0, n·l) · s`
//! for its shading normal n, with s Cycles' shadowing of a tilted diffuse normal (Chiang
//! et al. 2019: g = (y·l) / ((n·l)(y·n)) for the quad's own normal y; s = 1 for g ≥ 1,
//! else −g³ + g² + g). A normal map or a height map that tilts n by a known amount must
//! give exactly that, through the MikkTSpace tangents, mirrored texture coordinates and
//! placed (rotated, mirrored) copies of the mesh.

mod common;

use common::TempDir;
use glam::Vec3;
use tracer::film::SampleRange;
use tracer::integrator::Integrator;
use tracer::render::render_image;
use tracer::scene::scene_from_toml;

const KD: f32 = 0.8;

/// A 2 × 2 quad in the y = 0 plane facing +y; u along +x (or −x with `mirror_u`), v along
/// −z. Its MikkTSpace tangent is ∂p/∂u, its bitangent ∂p/∂v = −z.
fn quad_obj(mirror_u: bool) -> String {
    let u = |x: f32| if mirror_u { 1.0 - x } else { x };
    format!(
        "mtllib quad.mtl\nusemtl m\nv -1 0 1\nv 1 0 1\nv 1 0 -1\nv -1 0 -1\n\
         vt {} 0\nvt {} 0\nvt {} 1\nvt {} 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n",
        u(0.0),
        u(1.0),
        u(1.0),
        u(0.0)
    )
}

/// A tangent-space normal map of one colour, as 8-bit PNG bytes would hold it; returns
/// the tangent-space vector that colour decodes to (2 · rgb − 1, not normalized).
fn flat_normal_map(dir: &TempDir, name: &str, n: Vec3) -> Vec3 {
    let byte = |x: f32| ((0.5 + 0.5 * x) * 255.0).round() as u8;
    let rgb = [byte(n.x), byte(n.y), byte(n.z)];
    image::RgbImage::from_pixel(4, 4, image::Rgb(rgb)).save(dir.0.join(name)).unwrap();
    Vec3::new(rgb[0] as f32, rgb[1] as f32, rgb[2] as f32) / 255.0 * 2.0 - Vec3::ONE
}

/// Renders `mesh` (the `[[mesh]]` table's body) lit from `-dir`; the mean of the middle
/// of the image, where the quad is seen.
fn centre_radiance(dir: &TempDir, mesh: &str, light_dir: Vec3) -> f32 {
    let d = light_dir;
    let text = format!(
        "[camera]\nposition = [0, 4, 1.5]\nlook_at = [0, 0, 0]\nfov = 20\nwidth = 16\nheight = 16\n\
         [render]\nmax_depth = 2\nseed = 1\n\
         [[light]]\ntype = \"directional\"\ndirection = [{}, {}, {}]\nirradiance = [1, 1, 1]\n\
         [[mesh]]\n{mesh}\n",
        d.x, d.y, d.z
    );
    let scene = scene_from_toml(&text, "quad.toml", &dir.0).unwrap();
    let image = render_image(&scene, Integrator::Path, SampleRange::new(0, 4), 4, &|_| {}).0;
    let (mut sum, mut n) = (0.0, 0);
    for y in 4..12 {
        for x in 4..12 {
            sum += image.pixels[y * 16 + x].y;
            n += 1;
        }
    }
    sum / n as f32
}

/// `kd/π · E · max(0, n·l) · s` for a light travelling along `light_dir` (see the top).
fn lambert(n: Vec3, light_dir: Vec3) -> f32 {
    let (n, l) = (n.normalize(), -light_dir.normalize());
    let g = Vec3::Y.dot(l) / (n.dot(l) * Vec3::Y.dot(n));
    let s = if g >= 1.0 { 1.0 } else { -g * g * g + g * g + g };
    KD / std::f32::consts::PI * n.dot(l).max(0.0) * s
}

fn assert_close(got: f32, want: f32, what: &str) {
    println!("{what}: {got:.5} (analytic {want:.5})");
    assert!((got - want).abs() <= 2e-3 * want.max(0.05), "{what}: rendered {got}, analytic {want}");
}

/// Writes the quad (mirrored in u or not) with a normal map of tangent-space normal `t`.
fn normal_mapped_quad(dir: &TempDir, mirror_u: bool, t: Vec3, strength: f32) -> Vec3 {
    let decoded = flat_normal_map(dir, "n.png", t);
    dir.write("quad.obj", &quad_obj(mirror_u));
    dir.write("quad.mtl", &format!("newmtl m\nKd {KD} {KD} {KD}\nnorm -bm {strength} n.png\n"));
    decoded
}

#[test]
fn a_normal_map_tilts_the_normal_along_the_tangent_and_the_bitangent() {
    let dir = TempDir::new("normal-map-axes");
    let s30 = Vec3::new(0.5, 0.0, 0.866_025_4);
    // Red: towards the tangent, +x.
    let t = normal_mapped_quad(&dir, false, s30, 1.0);
    let l = Vec3::new(-1.0, -1.0, 0.0);
    let flat = lambert(Vec3::Y, l);
    let got = centre_radiance(&dir, "obj = \"quad.obj\"", l);
    assert_close(got, lambert(Vec3::new(t.x, t.z, -t.y), l), "tilted towards the tangent");
    assert!(got > 1.3 * flat, "the tilt must show: {got} against the flat {flat}");

    // Green: towards the bitangent, ∂p/∂v = −z.
    let t = normal_mapped_quad(&dir, false, Vec3::new(0.0, 0.5, 0.866_025_4), 1.0);
    let l = Vec3::new(0.0, -1.0, 1.0);
    let got = centre_radiance(&dir, "obj = \"quad.obj\"", l);
    assert_close(got, lambert(Vec3::new(t.x, t.z, -t.y), l), "tilted towards the bitangent");
}

#[test]
fn mirrored_texture_coordinates_turn_the_tangent_around() {
    let dir = TempDir::new("normal-map-mirrored");
    let t = normal_mapped_quad(&dir, true, Vec3::new(0.5, 0.0, 0.866_025_4), 1.0);
    // u now runs along −x: the tilt goes to −x.
    let l = Vec3::new(1.0, -1.0, 0.0);
    let got = centre_radiance(&dir, "obj = \"quad.obj\"", l);
    assert_close(got, lambert(Vec3::new(-t.x, t.z, -t.y), l), "mirrored in u");
}

#[test]
fn strength_scales_the_tilt_as_blender_does() {
    let dir = TempDir::new("normal-map-strength");
    let t = normal_mapped_quad(&dir, false, Vec3::new(0.5, 0.0, 0.866_025_4), 0.5);
    // Blender: x and y scaled by the strength, z blended towards 1.
    let c = t;
    let raw = Vec3::new(c.x * 0.5, c.y * 0.5, 1.0 + (c.z - 1.0) * 0.5);
    let l = Vec3::new(-1.0, -1.0, 0.0);
    let got = centre_radiance(&dir, "obj = \"quad.obj\"", l);
    assert_close(got, lambert(Vec3::new(raw.x, raw.z, -raw.y), l), "strength 0.5");
}

/// Placed copies (instances): the tangent turns with a rotation, and a mirroring copy
/// keeps the bitangent's meaning (∂p/∂v), not its handedness.
#[test]
fn placed_copies_carry_their_tangents_along() {
    let dir = TempDir::new("normal-map-instances");
    // Each mesh placed twice (so it is instanced); the second copy far out of view.
    let copies =
        |first: &str| format!("obj = \"quad.obj\"\ninstance = [ {{ {first} }}, {{ translate = [0, -50, 0] }} ]");

    let t = normal_mapped_quad(&dir, false, Vec3::new(0.5, 0.0, 0.866_025_4), 1.0);
    // A quarter turn about +y takes the tangent +x to −z.
    let l = Vec3::new(0.0, -1.0, 1.0);
    let got = centre_radiance(&dir, &copies("rotate_y = 90"), l);
    assert_close(got, lambert(Vec3::new(0.0, t.z, -t.x), l), "rotated copy");

    let t = normal_mapped_quad(&dir, false, Vec3::new(0.0, 0.5, 0.866_025_4), 1.0);
    let l = Vec3::new(0.0, -1.0, 1.0);
    let got = centre_radiance(&dir, &copies("scale = [-1, 1, 1]"), l);
    assert_close(got, lambert(Vec3::new(0.0, t.z, -t.y), l), "mirrored copy, tilted along v");
}

#[test]
fn a_bump_map_tilts_against_the_slope_of_its_height() {
    let dir = TempDir::new("bump-ramp");
    // Height rising by 1/255 per texel over 256 texels along u: slope 256/255 per unit
    // of u, i.e. 128/255 per unit of x on the 2-wide quad (times the distance).
    let ramp = image::RgbImage::from_fn(256, 4, |x, _| image::Rgb([x as u8; 3]));
    ramp.save(dir.0.join("h.png")).unwrap();
    dir.write("quad.obj", &quad_obj(false));
    for distance in [0.5f32, 1.0] {
        let toml_material = format!(
            "[materials.m]\nbase_color = [{KD}, {KD}, {KD}]\nspecular_ior_level = 0\nroughness = 1\n\
             bump_map = {{ file = \"h.png\", distance = {distance} }}\n"
        );
        dir.write("quad.mtl", "newmtl m\nKd 0.5 0.5 0.5\n");
        let slope = distance * 128.0 / 255.0;
        let l = Vec3::new(-1.0, -1.0, 0.0);
        let mesh = format!("obj = \"quad.obj\"\n{toml_material}");
        let got = centre_radiance(&dir, &mesh, l);
        assert_close(got, lambert(Vec3::new(-slope, 1.0, 0.0), l), &format!("bump, distance {distance}"));
    }
}
