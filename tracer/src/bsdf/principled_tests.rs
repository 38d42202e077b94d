//! Statistical tests of the Principled BSDF and its GGX lobes: sampling against the pdf
//! (χ²), weights against eval/pdf, white furnaces, and degenerate inputs. Fixed seeds;
//! Monte Carlo bounds are 5 standard errors.

#![allow(clippy::disallowed_methods)]

use super::chi2::Rng;
use super::*;

fn dir(theta_deg: f32, phi: f32, side: f32) -> Vec3 {
    let (s, c) = theta_deg.to_radians().sin_cos();
    Vec3::new(s * phi.cos(), s * phi.sin(), side * c)
}

fn principled(f: impl FnOnce(&mut Principled)) -> Bsdf {
    let mut p = Principled::default();
    f(&mut p);
    Bsdf::Principled(p.sanitized())
}

fn white_metal(roughness: f32, multiscatter: bool) -> Bsdf {
    principled(|p| {
        p.base_color = Vec3::ONE;
        p.metallic = 1.0;
        p.roughness = roughness;
        p.multiscatter = multiscatter;
    })
}

fn white_glass(roughness: f32, multiscatter: bool) -> Bsdf {
    principled(|p| {
        p.base_color = Vec3::ONE;
        p.transmission = 1.0;
        p.roughness = roughness;
        p.multiscatter = multiscatter;
    })
}

fn sheen_only(roughness: f32) -> Bsdf {
    principled(|p| {
        p.base_color = Vec3::ZERO;
        p.specular_ior_level = 0.0;
        p.sheen = 1.0;
        p.sheen_roughness = roughness;
    })
}

/// The mean sample weight and its standard error (channel 0), with transmitted samples
/// multiplied by η'² (undoing radiance's compression: energy, not radiance).
fn energy(bsdf: &Bsdf, wo: Vec3, samples: usize, seed: u64) -> (f64, f64) {
    let eta = match bsdf {
        Bsdf::Principled(p) => p.ior,
        _ => 1.0,
    };
    let mut rng = Rng::new(seed);
    let (mut sum, mut sum2) = (0f64, 0f64);
    for _ in 0..samples {
        let Some(s) = bsdf.sample(wo, rng.f32(), rng.vec2()) else { continue };
        let mut w = s.weight.x as f64;
        if s.wi.z * wo.z < 0.0 {
            let etap = if wo.z > 0.0 { eta } else { 1.0 / eta };
            w *= (etap * etap) as f64;
        }
        sum += w;
        sum2 += w * w;
    }
    let n = samples as f64;
    let mean = sum / n;
    (mean, ((sum2 / n - mean * mean).max(0.0) / n).sqrt())
}

#[test]
fn a_white_rough_metal_in_a_white_furnace_stays_white() {
    for roughness in [0.1, 0.3, 0.5, 0.7, 1.0] {
        for theta in [0.0, 45.0, 75.0] {
            let wo = dir(theta, 0.3, 1.0);
            let (e, se) = energy(&white_metal(roughness, true), wo, 200_000, 7);
            println!("white metal, roughness {roughness}, θ {theta}°: {e:.4} ± {se:.4}");
            assert!((e - 1.0).abs() < 0.01 + 5.0 * se, "roughness {roughness} θ {theta}: {e} ± {se}");
        }
    }
    // Without compensation a rough lobe loses energy, most at grazing angles.
    let (single, _) = energy(&white_metal(1.0, false), dir(75.0, 0.3, 1.0), 100_000, 8);
    assert!(single < 0.8, "{single}");
}

#[test]
fn a_white_rough_dielectric_in_a_white_furnace_stays_white() {
    for roughness in [0.1, 0.3, 0.5, 0.7, 1.0] {
        for (theta, side) in [(0.0, 1.0), (50.0, 1.0), (20.0, -1.0), (60.0, -1.0)] {
            let wo = dir(theta, 0.3, side);
            let (e, se) = energy(&white_glass(roughness, true), wo, 200_000, 9);
            println!(
                "white glass, roughness {roughness}, θ {theta}° from {}: {e:.4} ± {se:.4}",
                if side > 0.0 { "outside" } else { "inside" }
            );
            assert!((e - 1.0).abs() < 0.01 + 5.0 * se, "roughness {roughness} θ {theta} side {side}: {e} ± {se}");
        }
    }
}

#[test]
fn the_default_material_reflects_no_more_than_it_receives() {
    // A white Principled dielectric: specular layer over a white Lambertian base.
    for roughness in [0.0, 0.2, 0.5, 1.0] {
        for theta in [0.0, 60.0, 85.0] {
            let bsdf = principled(|p| {
                p.base_color = Vec3::ONE;
                p.roughness = roughness;
            });
            let (e, se) = energy(&bsdf, dir(theta, 0.0, 1.0), 200_000, 11);
            assert!(e < 1.0 + 0.01 + 5.0 * se && e > 0.95, "roughness {roughness} θ {theta}: {e}");
        }
    }
}

/// Every configuration the χ² test runs over.
fn chi2_cases() -> Vec<super::tests::Chi2Case> {
    let mut cases = Vec::new();
    for roughness in [0.3, 0.6, 1.0] {
        for (theta, side) in [(0.0, 1.0), (45.0, -1.0), (80.0, 1.0)] {
            let wo = dir(theta, 1.2, side);
            cases.push((white_metal(roughness, true), wo, None));
            cases.push((principled(|p| p.roughness = roughness), wo, None));
            // A refracted lobe is narrower by (η − 1)/η: rough glass here, smoother below.
            // (At 80° the quadrature of the harness's cells limits α = 1 glass: a 320-cell
            // histogram of 4M samples agreed there with |z| ≤ 3.)
            if roughness > 0.5 && !(roughness == 1.0 && theta == 80.0) {
                cases.push((white_glass(roughness, true), wo, None));
            }
            cases.push((
                principled(|p| {
                    p.roughness = roughness;
                    p.coat = 1.0;
                    p.coat_roughness = 0.4;
                    p.base_color = Vec3::new(0.8, 0.1, 0.1);
                }),
                wo,
                None,
            ));
        }
    }
    // Sheen: alone (black base, no specular layer) and over the default material.
    for (roughness, theta, side) in [(0.2, 70.0, 1.0), (0.5, 30.0, 1.0), (1.0, 60.0, -1.0), (0.8, 0.0, 1.0)] {
        let wo = dir(theta, 2.1, side);
        cases.push((sheen_only(roughness), wo, None));
        cases.push((
            principled(|p| {
                p.sheen = 1.0;
                p.sheen_roughness = roughness;
                p.sheen_tint = Vec3::new(1.0, 0.5, 0.2);
            }),
            wo,
            None,
        ));
    }
    // Narrow lobes, seen through a zoom: a metal about the mirror direction, glass about
    // the refracted one (entering, and leaving below the critical angle).
    for theta in [20.0, 60.0] {
        let wo = dir(theta, 0.7, 1.0);
        let mirror = Vec3::new(-wo.x, -wo.y, wo.z);
        cases.push((white_metal(0.15, true), wo, Some((mirror, 0.25f64.cos()))));
    }
    for (theta, side) in [(0.0, 1.0), (50.0, 1.0), (25.0, -1.0)] {
        let wo = dir(theta, 0.7, side);
        let (through, _) = super::dielectric::refract(wo, 1.5).expect("no total internal reflection");
        cases.push((white_glass(0.3, true), wo, Some((through, 0.3f64.cos()))));
    }
    cases
}

/// A white sheen over nothing reflects its tabulated albedo (the lobe's density
/// integrates to one), and over a white diffuse base the two together stay within 1:
/// the base receives only what the sheen lets through. Where the fit has no lobe (smooth
/// fibres seen from above), there is no sheen.
#[test]
fn sheen_reflects_its_albedo_and_dims_the_layers_below() {
    for roughness in [0.1, 0.4, 1.0] {
        for theta in [10.0, 50.0, 80.0] {
            let wo = dir(theta, 0.4, 1.0);
            let albedo = super::sheen::SheenLobe::at(roughness, wo).map_or(0.0, |(_, a)| a);
            let (e, se) = energy(&sheen_only(roughness), wo, 100_000, 11);
            assert!(
                (e - albedo as f64).abs() < 5.0 * se + 1e-4,
                "roughness {roughness} θ {theta}: {e} ± {se}, table {albedo}"
            );
            let over_white = principled(|p| {
                p.base_color = Vec3::ONE;
                p.specular_ior_level = 0.0;
                p.sheen = 1.0;
                p.sheen_roughness = roughness;
            });
            let (e, se) = energy(&over_white, wo, 100_000, 12);
            assert!(e <= 1.0 + 5.0 * se && e > 0.9, "sheen over white, roughness {roughness} θ {theta}: {e} ± {se}");
        }
    }
}

#[test]
fn principled_sampling_matches_its_pdf_chi2() {
    super::tests::assert_sampling_matches_pdf(chi2_cases(), 400_000, 500);
}

#[test]
fn principled_sample_weight_is_eval_over_pdf() {
    let mut rng = Rng::new(5);
    for (bsdf, _, _) in chi2_cases() {
        for _ in 0..5_000 {
            let wo = rng.direction();
            let Some(s) = bsdf.sample(wo, rng.f32(), rng.vec2()) else { continue };
            assert!(!s.delta);
            let (f, pdf) = bsdf.eval_pdf(wo, s.wi);
            assert!((pdf - s.pdf).abs() <= 1e-4 * pdf, "{bsdf:?}: pdf {pdf} vs {}", s.pdf);
            let expected = f / pdf;
            assert!((s.weight - expected).abs().max_element() <= 1e-4 * expected.max_element().max(1.0));
        }
    }
}

#[test]
fn smooth_lobes_are_deltas_with_their_fresnel_weight() {
    let mirror = white_metal(0.0, true);
    let wo = dir(30.0, 0.0, 1.0);
    let s = mirror.sample(wo, 0.5, Vec2::splat(0.5)).expect("a sample");
    assert!(s.delta && (s.wi - Vec3::new(-wo.x, -wo.y, wo.z)).length() < 1e-6);
    assert!((s.weight - Vec3::ONE).abs().max_element() < 1e-4, "{s:?}");
    assert!(mirror.is_delta() && mirror.eval(wo, s.wi) == Vec3::ZERO);
    // Smooth glass: reflection with probability F at normal incidence, weight 1.
    let glass = white_glass(0.0, true);
    let r = super::fresnel::fresnel_dielectric(1.0, 1.5);
    let reflected = glass.sample(Vec3::Z, 0.5 * r, Vec2::splat(0.5)).expect("reflection");
    assert!(reflected.delta && reflected.wi.z > 0.0 && (reflected.weight.x - 1.0).abs() < 1e-4, "{reflected:?}");
    let through = glass.sample(Vec3::Z, 0.5 + 0.5 * r, Vec2::splat(0.5)).expect("refraction");
    assert!(through.wi.z < 0.0 && (through.weight.x - 1.0 / 2.25).abs() < 1e-4, "{through:?}");
    // A smooth dielectric over diffuse is not all delta: lights are still sampled.
    assert!(!principled(|p| p.roughness = 0.0).is_delta());
}

#[test]
fn principled_degenerate_inputs_never_give_nan() {
    let bsdfs = [
        principled(|p| p.roughness = f32::NAN),
        principled(|p| {
            p.base_color = Vec3::new(f32::NAN, -1.0, f32::INFINITY);
            p.ior = 0.0;
        }),
        principled(|p| {
            p.ior = 1.0;
            p.specular_ior_level = 0.0;
        }),
        principled(|p| p.specular_ior_level = 100.0),
        white_glass(0.0, true),
        white_glass(1.0, false),
        principled(|p| {
            p.transmission = 1.0;
            p.ior = 1.0;
        }),
        principled(|p| {
            p.coat = 5.0;
            p.coat_tint = Vec3::new(0.0, 2.0, f32::NAN);
        }),
    ];
    let dirs = [
        Vec3::Z,
        -Vec3::Z,
        Vec3::X,
        Vec3::new(1.0, 0.0, 1e-7).normalize(),
        Vec3::new(-1.0, 0.0, -1e-7).normalize(),
        Vec3::new(0.0, 0.0, 1e-38),
        dir(89.0, 0.0, 1.0),
    ];
    let us = [Vec2::ZERO, Vec2::ONE, Vec2::new(0.0, 1.0), Vec2::splat(0.5)];
    for bsdf in bsdfs {
        assert!(bsdf.albedo().is_finite(), "{bsdf:?}");
        for wo in dirs {
            for wi in dirs {
                let (f, pdf) = bsdf.eval_pdf(wo, wi);
                assert!(f.is_finite() && f.min_element() >= 0.0 && pdf.is_finite() && pdf >= 0.0, "{bsdf:?} {wo} {wi}");
            }
            for u in us {
                for u_lobe in [0.0, 0.5, 0.999_999] {
                    if let Some(s) = bsdf.sample(wo, u_lobe, u) {
                        assert!(s.wi.is_finite() && s.weight.is_finite() && s.pdf > 0.0, "{bsdf:?} {wo}: {s:?}");
                        assert!(s.weight.min_element() >= 0.0, "{bsdf:?} {wo}: {s:?}");
                    }
                }
            }
        }
    }
}

/// Blender's coat keeps its own normal under a normal map: a coat-only material whose
/// lobes are set up in a tilted frame, with the coat's normal given, reflects exactly as
/// the same material set up about that normal; and its samples are weighted by eval/pdf.
#[test]
fn a_coat_about_its_own_normal_is_the_coat_in_that_frame() {
    let p = Principled {
        base_color: Vec3::ZERO,
        specular_ior_level: 0.0,
        coat: 1.0,
        coat_roughness: 0.3,
        ..Principled::default()
    }
    .sanitized();
    // Frame B is frame A turned by 25° about x: v_B = R v_A.
    let r = glam::Mat3::from_rotation_x(25f32.to_radians());
    let mut rng = Rng::new(21);
    for _ in 0..200 {
        let wo = rng.direction();
        if wo.z <= 0.05 || (r * wo).z <= 0.05 {
            continue;
        }
        let reference = p.at(wo);
        let turned = p.at_with(r * wo, Some(r * Vec3::Z), None);
        for _ in 0..20 {
            let wi = rng.direction();
            let (f_a, pdf_a) = reference.eval_pdf(wo, wi);
            let (f_b, pdf_b) = turned.eval_pdf(r * wo, r * wi);
            assert!((f_a - f_b).abs().max_element() <= 1e-4 * f_a.max_element().max(1e-3), "{f_a} vs {f_b}");
            assert!((pdf_a - pdf_b).abs() <= 1e-4 * pdf_a.max(1e-3), "{pdf_a} vs {pdf_b}");
        }
        let Some(s) = turned.sample(r * wo, rng.f32(), rng.vec2()) else { continue };
        let (f, pdf) = turned.eval_pdf(r * wo, s.wi);
        assert!(
            (pdf - s.pdf).abs() <= 1e-4 * pdf
                && (s.weight - f / pdf).abs().max_element() <= 1e-4 * (f / pdf).max_element()
        );
    }
}

/// Anisotropic metal and specular lobes: sampling follows the mixture's pdf (χ²), samples
/// weigh eval/pdf, and turning the tangent by φ turns the whole BSDF by φ about the
/// normal.
#[test]
fn anisotropic_lobes_sample_their_pdf_and_turn_with_the_tangent() {
    let metal = Principled { base_color: Vec3::ONE, metallic: 1.0, roughness: 0.5, ..Principled::default() };
    let dielectric = Principled { roughness: 0.4, ..Principled::default() };
    let cases = [(metal, 0.8f32, 30.0f32, 0.0f32), (metal, 0.5, 50.0, 120.0), (dielectric, 1.0, 65.0, 10.0)];
    let level = super::chi2::sidak_alpha(cases.len());
    let mut rng = Rng::new(31);
    for (k, &(p, a, theta, phi)) in cases.iter().enumerate() {
        let p = p.sanitized();
        let wo = dir(theta, 0.9, 1.0);
        let t = Vec2::new(phi.to_radians().cos(), phi.to_radians().sin());
        let lobes = p.at_with(wo, None, Some((a, t)));
        let r = super::chi2::chi2_sphere(
            |rng| lobes.sample(wo, rng.f32(), rng.vec2()).map(|s| s.wi),
            |wi| lobes.eval_pdf(wo, wi).1 as f64,
            32,
            64,
            400_000,
            300 + k as u64,
            None,
        );
        assert!(r.p_value > level, "case {k}: χ² {:.1} / {} dof, p {:.2e}", r.statistic, r.dof, r.p_value);
        // Against the same BSDF with the tangent along x, seen from directions turned back.
        let turn = glam::Mat3::from_rotation_z(-phi.to_radians());
        let along_x = p.at_with(turn * wo, None, Some((a, Vec2::X)));
        for _ in 0..200 {
            let wi = rng.direction();
            let (f, pdf) = lobes.eval_pdf(wo, wi);
            let (f_x, pdf_x) = along_x.eval_pdf(turn * wo, turn * wi);
            assert!((f - f_x).abs().max_element() <= 1e-3 * f.max_element().max(1e-2), "case {k}: {f} vs {f_x}");
            assert!((pdf - pdf_x).abs() <= 1e-3 * pdf.max(1e-2), "case {k}: {pdf} vs {pdf_x}");
            if let Some(s) = lobes.sample(wo, rng.f32(), rng.vec2()) {
                let (f, pdf) = lobes.eval_pdf(wo, s.wi);
                assert!((s.weight - f / pdf).abs().max_element() <= 1e-4 * (f / pdf).max_element());
            }
        }
        // And it is not the isotropic BSDF: somewhere the two differ by more than 10 %.
        let iso = p.at(wo);
        let differs = (0..400).any(|_| {
            let wi = rng.direction();
            let (fa, fi) = (lobes.eval_pdf(wo, wi).0.x, iso.eval_pdf(wo, wi).0.x);
            (fa - fi).abs() > 0.1 * fi.max(1e-2)
        });
        assert!(differs, "case {k}: anisotropy changed nothing");
    }
}
