//! The AOV layers a render keeps beside the beauty pass (`[render] aovs`): first-hit
//! albedo, normal and depth against a scene whose answers are known, and the variance
//! estimate against the samples it summarises.

mod common;

use common::{TempDir, bundled};

use glam::Vec3;
use tracer::film::{SampleRange, Tile};
use tracer::integrator::Integrator;
use tracer::render::render_unit;
use tracer::scene::scene_from_toml;

/// A white Lambertian wall (Kd 1) filling the view, its normal towards the camera, 4
/// units away on the axis; a point light behind the camera.
fn white_wall(dir: &TempDir) -> tracer::scene::Scene {
    dir.write("wall.mtl", "newmtl white\nKd 1 1 1\n");
    dir.write("wall.obj", "mtllib wall.mtl\nv -50 -50 0\nv 50 -50 0\nv 50 50 0\nv -50 50 0\nusemtl white\nf 1 2 3 4\n");
    let toml = r#"
[camera]
position = [0.0, 0.0, -4.0]
look_at = [0.0, 0.0, 0.0]
fov = 40
width = 16
height = 16
[render]
spp = 8
aovs = true
[[mesh]]
obj = "wall.obj"
[[light]]
type = "point"
position = [0.0, 0.0, -6.0]
intensity = [10.0, 10.0, 10.0]
"#;
    scene_from_toml(toml, "wall.toml", &dir.0).unwrap()
}

#[test]
fn a_white_wall_has_albedo_one_its_normal_and_its_distance() {
    let dir = TempDir::new("layers-wall");
    let mut scene = white_wall(&dir);
    let tile = Tile::new(0, 0, 16, 16);
    let acc = render_unit(&scene, Integrator::Path, tile, SampleRange::new(0, 8));
    assert!(acc.has_layers());
    for i in 0..tile.pixel_count() {
        let l = acc.layers_at(i).unwrap();
        assert!((l.albedo - Vec3::ONE).abs().max_element() < 1e-6, "pixel {i}: albedo {}", l.albedo);
        // The wall's normal, either way round (the OBJ's winding decides), averaged
        // over samples that all see the same plane: a unit vector along z.
        assert!((l.normal.z.abs() - 1.0).abs() < 1e-5 && l.normal.x.abs() < 1e-5, "pixel {i}: {}", l.normal);
        // Distance to the plane z = 0 from (0, 0, -4): 4 on the axis, up to
        // 4 · √(1 + 2 tan² 20°) = 4.499 in the corners.
        assert!((4.0..4.5).contains(&l.depth), "pixel {i}: depth {}", l.depth);
        assert!(l.variance.is_finite() && l.variance.min_element() >= 0.0);
    }
    let centre = acc.layers_at(8 * 16 + 8).unwrap();
    assert!((centre.depth - 4.0).abs() < 0.01, "centre depth {}", centre.depth);

    // The layers change no bit of the beauty pass.
    scene.settings.aovs = false;
    let beauty = render_unit(&scene, Integrator::Path, tile, SampleRange::new(0, 8));
    assert!(!beauty.has_layers());
    assert_eq!((beauty.sums, beauty.counts), (acc.sums.clone(), acc.counts.clone()));
}

/// The variance layer is the unbiased sample variance of the pixel's samples over their
/// count: rendering each sample alone gives the samples, and their variance computed
/// directly must match the layer of the render of all of them (and of any grouping).
#[test]
fn the_variance_layer_is_the_variance_of_the_pixel_mean() {
    let mut scene = tracer::scene::load_scene(&bundled("cornell-box")).unwrap();
    (scene.camera.width, scene.camera.height, scene.settings.aovs) = (12, 12, true);
    let tile = Tile::new(3, 2, 6, 5);
    let n = 24u32;
    let whole = render_unit(&scene, Integrator::Path, tile, SampleRange::new(0, n));
    let mut grouped = render_unit(&scene, Integrator::Path, tile, SampleRange::new(13, n));
    grouped.merge(&render_unit(&scene, Integrator::Path, tile, SampleRange::new(0, 13))).unwrap();
    assert_eq!(grouped, whole, "layers merge exactly");
    let singles: Vec<_> =
        (0..n).map(|s| render_unit(&scene, Integrator::Path, tile, SampleRange::new(s, s + 1))).collect();
    let mut noisy = 0;
    for i in 0..tile.pixel_count() {
        let got = whole.layers_at(i).unwrap().variance;
        for k in 0..3 {
            let xs: Vec<f64> = singles.iter().map(|a| a.mean(i)[k] as f64).collect();
            let mean = xs.iter().sum::<f64>() / n as f64;
            let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n as f64 - 1.0) / n as f64;
            assert!((got[k] as f64 - var).abs() <= 1e-4 * var + 1e-9, "pixel {i} channel {k}: {} vs {var}", got[k]);
            noisy += usize::from(var > 1e-4);
        }
    }
    assert!(noisy > 0, "some pixels are noisy, so the comparison means something");
}

/// `[render] noise` turns adaptive sampling on, which keeps the layers; a target that is
/// not a positive number is refused, naming its field.
#[test]
fn a_noise_target_keeps_layers_and_must_be_positive() {
    let dir = TempDir::new("noise-field");
    dir.write("wall.mtl", "newmtl white\nKd 1 1 1\n");
    dir.write("wall.obj", "mtllib wall.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nusemtl white\nf 1 2 3\n");
    let toml = |noise: &str| {
        format!(
            "[render]\nnoise = {noise}\n[camera]\nposition = [0.0, 0.0, -4.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 40\n\
             width = 8\nheight = 8\n[[mesh]]\nobj = \"wall.obj\"\n"
        )
    };
    let s = scene_from_toml(&toml("0.02"), "n.toml", &dir.0).unwrap();
    assert_eq!((s.settings.noise, s.settings.aovs), (Some(0.02), true));
    for bad in ["0.0", "-0.1", "nan", "inf"] {
        let err = scene_from_toml(&toml(bad), "n.toml", &dir.0).err().expect(bad).to_string();
        assert!(err.contains("render.noise") && err.contains("above 0"), "{bad}: {err}");
    }
}
