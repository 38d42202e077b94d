//! Renders small scenes end to end through the library and checks them against
//! analytic answers, orientation and determinism.

mod common;

use common::{TempDir, bundled};

use glam::{Vec2, Vec3};
use tracer::film::{Accumulation, SampleRange, Tile};
use tracer::integrator::Integrator;
use tracer::render::{render_image, render_unit};
use tracer::scene::{Scene, scene_from_toml};

fn scene(dir: &TempDir, toml: &str) -> Scene {
    scene_from_toml(toml, "test.toml", &dir.0).unwrap()
}

const PLANE_OBJ: &str = "mtllib plane.mtl\nv -10 0 -10\nv 10 0 -10\nv 10 0 10\nv -10 0 10\nusemtl white\nf 1 4 3 2\n";

#[test]
fn lambertian_plane_under_point_light_matches_analytic_radiance() {
    let dir = TempDir::new("plane");
    dir.write("plane.mtl", "newmtl white\nKd 0.6 0.5 0.4\n");
    dir.write("plane.obj", PLANE_OBJ);
    let (w, h, spp) = (40u32, 30u32, 64u32);
    let s = scene(
        &dir,
        &format!(
            r#"
[camera]
position = [0.0, 3.0, -4.0]
look_at = [0.0, 0.0, 0.5]
fov = 50
width = {w}
height = {h}
[render]
spp = {spp}
max_depth = 2
[[mesh]]
obj = "plane.obj"
[[light]]
type = "point"
position = [0.5, 2.0, 1.0]
intensity = [10.0, 20.0, 30.0]
"#
        ),
    );
    let kd = Vec3::new(0.6, 0.5, 0.4);
    let light = Vec3::new(0.5, 2.0, 1.0);
    let intensity = Vec3::new(10.0, 20.0, 30.0);
    // Radiance seen along a camera ray: kd/π · I·cosθ/r² where it hits the plane y = 0.
    let analytic = |film: Vec2| -> Vec3 {
        let r = s.camera.generate_ray(film, Vec2::ZERO);
        if r.dir.y >= 0.0 {
            return Vec3::ZERO;
        }
        let p = r.at(-r.origin.y / r.dir.y);
        if p.x.abs() > 10.0 || p.z.abs() > 10.0 {
            return Vec3::ZERO;
        }
        let d = light - p;
        let r2 = d.length_squared();
        let cos = d.y / r2.sqrt();
        kd / std::f32::consts::PI * intensity * cos / r2
    };
    let (img, stats) = render_image(&s, Integrator::Path, SampleRange::new(0, spp), 8, &|_| {});
    assert_eq!(stats.nonfinite, 0);
    let (mut sum_est, mut sum_ref) = (0.0f64, 0.0f64);
    for y in 0..h {
        for x in 0..w {
            // Pixel average and spread of the analytic radiance over the box filter.
            let n = 16;
            let vals: Vec<Vec3> = (0..n * n)
                .map(|k| {
                    let o = Vec2::new((k % n) as f32 + 0.5, (k / n) as f32 + 0.5) / n as f32;
                    analytic(Vec2::new(x as f32, y as f32) + o)
                })
                .collect();
            let mean = vals.iter().copied().sum::<Vec3>() / vals.len() as f32;
            let var = vals.iter().map(|v| (*v - mean) * (*v - mean)).sum::<Vec3>() / vals.len() as f32;
            let est = img.at(x, y);
            for c in 0..3 {
                // Five standard errors of the jitter-only estimator, plus quadrature slack.
                let bound = 5.0 * (var[c] / spp as f32).sqrt() + 2e-3 * mean[c] + 1e-6;
                assert!(
                    (est[c] - mean[c]).abs() <= bound,
                    "pixel ({x},{y}) channel {c}: {} vs analytic {} (bound {bound})",
                    est[c],
                    mean[c]
                );
                sum_est += est[c] as f64;
                sum_ref += mean[c] as f64;
            }
        }
    }
    assert!(sum_ref > 0.0);
    // Over the whole image a 1% bias would stand far outside this.
    assert!((sum_est / sum_ref - 1.0).abs() < 2e-3, "ratio {}", sum_est / sum_ref);
}

#[test]
fn object_right_and_above_lands_in_right_top_quadrant() {
    let dir = TempDir::new("orient");
    // Camera at the origin looking along +z with up +y: right = forward × up = -x.
    let s = scene(
        &dir,
        r#"
[camera]
position = [0.0, 0.0, 0.0]
look_at = [0.0, 0.0, 1.0]
up = [0.0, 1.0, 0.0]
fov = 60
width = 32
height = 32
[[sphere]]
center = [-2.0, 1.5, 10.0]
radius = 0.8
kd = [1.0, 1.0, 1.0]
"#,
    );
    let (img, _) = render_image(&s, Integrator::Albedo, SampleRange::new(0, 4), 8, &|_| {});
    let mut covered = 0;
    for y in 0..32 {
        for x in 0..32 {
            if img.at(x, y).x > 0.0 {
                covered += 1;
                assert!(x >= 16 && y < 16, "sphere seen at pixel ({x},{y})");
            }
        }
    }
    assert!(covered > 4, "the sphere is visible");
}

fn small_cornell() -> Scene {
    let mut s = tracer::scene::load_scene(&bundled("cornell-box")).unwrap();
    s.camera.width = 24;
    s.camera.height = 24;
    s
}

#[test]
fn same_seed_same_bits_and_sample_ranges_merge_exactly() {
    let s = small_cornell();
    let tile = Tile::new(4, 6, 13, 11);
    let whole = render_unit(&s, Integrator::Path, tile, SampleRange::new(0, 16));
    assert_eq!(whole, render_unit(&s, Integrator::Path, tile, SampleRange::new(0, 16)));
    let mut merged: Accumulation = render_unit(&s, Integrator::Path, tile, SampleRange::new(8, 16));
    merged.merge(&render_unit(&s, Integrator::Path, tile, SampleRange::new(0, 8))).unwrap();
    assert_eq!(merged, whole);
    // Tiles are independent too: a sub-tile equals the corresponding part of the tile.
    let sub = render_unit(&s, Integrator::Path, Tile::new(5, 6, 1, 1), SampleRange::new(0, 16));
    assert_eq!(sub.sums[0], whole.sums[1]);
    // A different seed gives a different image.
    let mut other = small_cornell();
    other.settings.seed = 1;
    assert_ne!(render_unit(&other, Integrator::Path, tile, SampleRange::new(0, 16)), whole);
}

/// `clamp` bounds every pixel (the mean of samples each at most the limit), leaves
/// pixels whose samples stay below it alone, and a limit no sample reaches changes no bits.
#[test]
fn clamp_bounds_samples_and_changes_nothing_below_it() {
    let tile = Tile::new(0, 0, 24, 24);
    let samples = SampleRange::new(0, 8);
    let mut s = small_cornell();
    let free = render_unit(&s, Integrator::Path, tile, samples);
    let brightest = (0..tile.pixel_count()).map(|i| free.mean(i).max_element()).fold(0.0, f32::max);
    assert!(brightest > 2.0, "the lamp is in view ({brightest})");
    s.settings.clamp = Some(1e30);
    assert_eq!(render_unit(&s, Integrator::Path, tile, samples), free, "a limit no sample reaches");
    s.settings.clamp = Some(1.0);
    let clamped = render_unit(&s, Integrator::Path, tile, samples);
    let mut unchanged = 0;
    for i in 0..tile.pixel_count() {
        let (c, f) = (clamped.mean(i), free.mean(i));
        assert!(c.max_element() <= 1.0 + 1e-6, "pixel {i}: {c} above the clamp");
        assert!(c.cmple(f + 1e-6).all(), "pixel {i}: clamping brightened {f} to {c}");
        unchanged += usize::from(f.max_element() < 0.2 && clamped.sums[i] == free.sums[i]);
    }
    assert!(unchanged > 0, "dim pixels whose samples never reach the limit keep their bits");
}

#[test]
fn a_clamp_must_be_positive_and_names_its_field() {
    let dir = TempDir::new("clamp-field");
    dir.write("plane.obj", PLANE_OBJ);
    dir.write("plane.mtl", "newmtl white\nKd 0.8 0.8 0.8\n");
    for bad in ["0.0", "-1.0", "nan", "inf"] {
        let toml = format!(
            "[render]\nclamp = {bad}\n[camera]\nposition = [0.0, 3.0, -4.0]\nlook_at = [0.0, 0.0, 0.5]\nfov = 50\nwidth = 8\nheight = 8\n[[mesh]]\nobj = \"plane.obj\"\n"
        );
        let err = scene_from_toml(&toml, "test.toml", &dir.0).err().expect(bad).to_string();
        assert!(err.contains("render.clamp") && err.contains("above 0"), "{bad}: {err}");
    }
}
