//! Statistical and analytic tests of the BSDFs. Fixed seeds; every Monte Carlo bound is
//! 5 standard errors (estimated from the samples) plus the quadrature tolerance, which
//! for the sample counts used is well under 1% of the quantity tested.

// Tests may use the C library's functions: they check values, not platform-free bits.
#![allow(clippy::disallowed_methods)]

use super::chi2::{Rng, chi2_sphere, integrate_sphere, sidak_alpha};
use super::dielectric::{fresnel_dielectric, refract};
use super::*;

const EXPONENTS: [f32; 5] = [0.0, 1.0, 10.0, 100.0, 1000.0];

/// Unit direction at polar angle `theta_deg` from the normal, on side `side` (±1).
fn dir(theta_deg: f32, phi: f32, side: f32) -> Vec3 {
    let (s, c) = theta_deg.to_radians().sin_cos();
    Vec3::new(s * phi.cos(), s * phi.sin(), side * c)
}

fn glossy(kd: f32, ks: f32, exponent: f32) -> Bsdf {
    Bsdf::Glossy { kd: Vec3::splat(kd), ks: Vec3::splat(ks), exponent }
}

/// Directional albedo ∫ f |cos θi| dωi estimated as the mean sample weight, with its
/// standard error, per channel (failed samples count as 0).
fn albedo_estimate(bsdf: &Bsdf, wo: Vec3, samples: usize, seed: u64) -> (Vec3, Vec3, f32) {
    let mut rng = Rng::new(seed);
    let (mut sum, mut sum2) = ([0f64; 3], [0f64; 3]);
    let mut max_weight = 0f32;
    for _ in 0..samples {
        let Some(s) = bsdf.sample(wo, rng.f32(), rng.vec2()) else { continue };
        assert!(s.weight.is_finite() && s.wi.is_finite() && s.pdf > 0.0, "{bsdf:?} wo={wo}: {s:?}");
        max_weight = max_weight.max(s.weight.max_element());
        for k in 0..3 {
            sum[k] += s.weight[k] as f64;
            sum2[k] += (s.weight[k] as f64).powi(2);
        }
    }
    let n = samples as f64;
    let mean = Vec3::from_array(sum.map(|s| (s / n) as f32));
    let stderr = Vec3::from_array(std::array::from_fn(|k| {
        let m = sum[k] / n;
        ((sum2[k] / n - m * m).max(0.0) / n).sqrt() as f32
    }));
    (mean, stderr, max_weight)
}

/// Azimuth of the mirror direction of `wo`, where the quadrature concentrates its nodes.
fn mirror_azimuth(wo: Vec3) -> f64 {
    (-wo.y as f64).atan2(-wo.x as f64)
}

/// ∫ eval dωi by quadrature (the grid resolves the n = 1000 lobe at 89° to ~1e-5).
fn albedo_quadrature(bsdf: &Bsdf, wo: Vec3) -> Vec3 {
    Vec3::from_array(std::array::from_fn(|k| {
        integrate_sphere(&|wi: Vec3| bsdf.eval(wo, wi)[k] as f64, 96, 128, mirror_azimuth(wo)) as f32
    }))
}

#[test]
fn bsdf_is_small_and_copy() {
    fn is_copy<T: Copy>() {}
    is_copy::<Bsdf>();
    // The Principled BSDF's inputs make up the largest variant; the others stay at 32.
    assert!(std::mem::size_of::<Bsdf>() <= 96, "{}", std::mem::size_of::<Bsdf>());
}

#[test]
fn lambert_albedo_is_kd() {
    let kd = Vec3::new(0.8, 0.5, 0.1);
    let bsdf = Bsdf::Diffuse { kd };
    for (theta, side) in [(0.0, 1.0), (45.0, 1.0), (89.0, 1.0), (30.0, -1.0), (89.9, -1.0)] {
        let wo = dir(theta, 0.7, side);
        let (mean, _, max_weight) = albedo_estimate(&bsdf, wo, 20_000, 11);
        // Cosine sampling makes every weight exactly kd.
        assert!((mean - kd).abs().max_element() < 1e-6, "θ={theta}: {mean}");
        assert!(max_weight <= kd.max_element() + 1e-6);
        let quad = albedo_quadrature(&bsdf, wo);
        assert!((quad - kd).abs().max_element() < 1e-4, "θ={theta}: quadrature {quad}");
    }
    assert!(!bsdf.is_delta() && bsdf.albedo() == kd);
}

/// Specular-only albedo at normal incidence: E[cos 2θh] over h ~ (n+1) c^n dc with
/// c = cos θh > 1/√2 (reflections below the horizon are lost), in closed form.
fn specular_albedo_normal(n: f64) -> f64 {
    2.0 * (n + 1.0) / (n + 3.0) * (1.0 - 2f64.powf(-(n + 3.0) / 2.0)) - (1.0 - 2f64.powf(-(n + 1.0) / 2.0))
}

#[test]
fn glossy_albedo_matches_closed_form_at_normal_incidence() {
    for n in EXPONENTS {
        let (mean, stderr, max_weight) = albedo_estimate(&glossy(0.0, 1.0, n), Vec3::Z, 2_000_000, 21);
        let exact = specular_albedo_normal(n as f64) as f32;
        assert!((mean.x - exact).abs() < 5.0 * stderr.x + 1e-5, "n={n}: {} vs {exact} ± {}", mean.x, stderr.x);
        assert!(max_weight <= 1.0 + 1e-5, "n={n}: specular weight {max_weight} > ks");
    }
}

#[test]
fn glossy_conserves_energy_for_all_wo_and_exponents() {
    let mixes: [(Vec3, Vec3); 5] = [
        (Vec3::ZERO, Vec3::ONE),
        (Vec3::splat(0.5), Vec3::splat(0.5)),
        (Vec3::new(0.7, 0.2, 0.0), Vec3::new(0.3, 0.8, 1.0)), // kd + ks = 1 per channel
        (Vec3::new(0.6, 0.3, 0.1), Vec3::new(0.05, 0.1, 0.2)),
        (Vec3::new(0.9, 0.8, 1.0), Vec3::new(0.9, 0.4, 1.0)), // kd + ks > 1: rescaled
    ];
    let mut seed = 100;
    for (kd, ks) in mixes {
        for n in EXPONENTS {
            let bsdf = Bsdf::Glossy { kd, ks, exponent: n };
            let bound = bsdf.albedo();
            assert!(bound.max_element() <= 1.0 + 1e-6, "{bsdf:?}: kd + ks = {bound}");
            for (theta, side) in [(0.0, 1.0), (30.0, 1.0), (60.0, -1.0), (80.0, 1.0), (89.0, 1.0), (89.0, -1.0)] {
                seed += 1;
                let wo = dir(theta, 2.1, side);
                let (mean, stderr, _) = albedo_estimate(&bsdf, wo, 50_000, seed);
                let limit = bound + 5.0 * stderr + Vec3::splat(1e-6);
                assert!(mean.cmple(limit).all(), "{bsdf:?} θ={theta}: albedo {mean} > {bound} ± {stderr}");
            }
        }
    }
}

#[test]
fn glossy_sampling_albedo_matches_quadrature() {
    // An independent check of the whole sampling chain (half-vector warp, Jacobian,
    // mixture weights): the mean weight equals ∫ eval dωi computed on a grid.
    let mut seed = 300;
    for n in EXPONENTS {
        for (kd, ks) in [(0.0, 1.0), (0.4, 0.5)] {
            let bsdf = glossy(kd, ks, n);
            for theta in [0.0, 50.0, 85.0] {
                seed += 1;
                let wo = dir(theta, -0.4, 1.0);
                let (mean, stderr, _) = albedo_estimate(&bsdf, wo, 200_000, seed);
                let quad = albedo_quadrature(&bsdf, wo);
                let diff = (mean.x - quad.x).abs();
                assert!(
                    diff < 5.0 * stderr.x + 1e-3,
                    "{bsdf:?} θ={theta}: sampled {} vs quadrature {}",
                    mean.x,
                    quad.x
                );
            }
        }
    }
}

#[test]
fn mirror_reflects_with_weight_ks() {
    let ks = Vec3::new(0.9, 0.6, 0.3);
    let bsdf = Bsdf::Mirror { ks };
    assert!(bsdf.is_delta());
    for wo in [dir(0.0, 0.0, 1.0), dir(40.0, 1.0, 1.0), dir(89.0, 2.0, -1.0)] {
        let s = bsdf.sample(wo, 0.3, Vec2::new(0.2, 0.9)).unwrap();
        assert!(s.delta && s.weight == ks && s.pdf == 1.0);
        assert!((s.wi - Vec3::new(-wo.x, -wo.y, wo.z)).length() < 1e-6);
        // The mirror direction makes equal angles with the normal, in the plane of incidence.
        assert!((s.wi.z - wo.z).abs() < 1e-6 && (s.wi + wo).truncate().length() < 1e-6);
        assert_eq!(bsdf.eval(wo, s.wi), Vec3::ZERO);
        assert_eq!(bsdf.pdf(wo, s.wi), 0.0);
    }
    assert!(bsdf.sample(Vec3::X, 0.5, Vec2::splat(0.5)).is_none());
}

const GLASS_ETAS: [f32; 4] = [1.0, 1.33, 1.5, 2.4];

/// (η on wo's side) / (η on the other side) for an interface of relative IOR `eta`.
fn eta_ratio(wo: Vec3, eta: f32) -> f32 {
    if wo.z > 0.0 { eta } else { 1.0 / eta }
}

#[test]
fn glass_energy_is_one_per_sample() {
    for eta in GLASS_ETAS {
        let bsdf = Bsdf::Glass { eta, tint: Vec3::ONE };
        assert!(bsdf.is_delta());
        let mut rng = Rng::new(eta.to_bits() as u64);
        for _ in 0..20_000 {
            let wo = rng.direction();
            let Some(s) = bsdf.sample(wo, rng.f32(), rng.vec2()) else {
                panic!("glass sample failed for wo={wo}");
            };
            assert!(s.delta && s.pdf > 0.0 && s.pdf <= 1.0 && (s.wi.length() - 1.0).abs() < 1e-5);
            // Undo the radiance scaling 1/η'²: each sample carries exactly the energy it
            // received (F/F for reflection, T/T for transmission).
            let energy = if s.wi.z * wo.z > 0.0 {
                s.weight
            } else {
                let etap = eta_ratio(wo, eta);
                s.weight * etap * etap
            };
            assert!((energy - Vec3::ONE).abs().max_element() < 1e-5, "η={eta} wo={wo}: {s:?}");
            assert_eq!(bsdf.eval(wo, s.wi), Vec3::ZERO);
            assert_eq!(bsdf.pdf(wo, s.wi), 0.0);
        }
    }
}

#[test]
fn glass_tint_and_radiance_scaling() {
    let tint = Vec3::new(0.9, 0.8, 0.5);
    let bsdf = Bsdf::Glass { eta: 1.5, tint };
    // u_lobe = 0.99 is above F = 0.04 at normal incidence: transmission.
    let entering = bsdf.sample(Vec3::Z, 0.99, Vec2::ZERO).unwrap();
    assert!((entering.wi + Vec3::Z).length() < 1e-6);
    assert!((entering.weight - tint / (1.5 * 1.5)).abs().max_element() < 1e-6);
    assert!((entering.pdf - 0.96).abs() < 1e-6);
    let leaving = bsdf.sample(-Vec3::Z, 0.99, Vec2::ZERO).unwrap();
    assert!((leaving.wi - Vec3::Z).length() < 1e-6);
    assert!((leaving.weight - tint * (1.5 * 1.5)).abs().max_element() < 1e-5);
    // Reflection is not tinted.
    let reflected = bsdf.sample(Vec3::Z, 0.01, Vec2::ZERO).unwrap();
    assert!(reflected.weight == Vec3::ONE && (reflected.wi - Vec3::Z).length() < 1e-6);
    assert!(bsdf.albedo() == tint);
}

#[test]
fn glass_normal_incidence_reflects_with_probability_f() {
    for eta in GLASS_ETAS {
        let f = ((eta - 1.0) / (eta + 1.0)).powi(2);
        for wo in [Vec3::Z, -Vec3::Z] {
            assert!((fresnel_dielectric(wo.z, eta) - f).abs() < 1e-6, "η={eta}");
            // Sweep u_lobe over a uniform grid: the reflected fraction is F to 1/N.
            let bsdf = Bsdf::Glass { eta, tint: Vec3::ONE };
            let n = 100_000;
            let mut reflected = 0;
            for i in 0..n {
                let s = bsdf.sample(wo, (i as f32 + 0.5) / n as f32, Vec2::ZERO).unwrap();
                if s.wi.z * wo.z > 0.0 {
                    reflected += 1;
                    assert!((s.pdf - f).abs() < 1e-6);
                } else {
                    assert!((s.pdf - (1.0 - f)).abs() < 1e-6);
                }
            }
            assert!((reflected as f32 / n as f32 - f).abs() < 2.0 / n as f32, "η={eta}: {reflected}/{n} vs F={f}");
        }
    }
}

#[test]
fn glass_total_internal_reflection() {
    for eta in [1.33f32, 1.5, 2.4] {
        let critical = (1.0 / eta).asin().to_degrees();
        let bsdf = Bsdf::Glass { eta, tint: Vec3::ONE };
        for theta in [critical + 0.1, (critical + 90.0) / 2.0, 89.99] {
            let wo = dir(theta, 0.3, -1.0); // inside the medium
            assert_eq!(fresnel_dielectric(wo.z, eta), 1.0);
            assert!(refract(wo, eta).is_none());
            for u in [0.0, 0.5, 0.999_999, 1.0] {
                let s = bsdf.sample(wo, u, Vec2::ZERO).unwrap();
                assert!(s.wi.z < 0.0 && s.pdf == 1.0 && s.weight == Vec3::ONE, "η={eta} θ={theta}: {s:?}");
                assert!((s.wi - Vec3::new(-wo.x, -wo.y, wo.z)).length() < 1e-6);
            }
        }
        // Just inside the critical angle refraction is still possible (and F < 1).
        let wo = dir(critical - 0.5, 0.3, -1.0);
        assert!(fresnel_dielectric(wo.z, eta) < 1.0 && refract(wo, eta).is_some());
        // Rays entering from outside never undergo TIR.
        assert!(fresnel_dielectric(dir(89.9, 0.0, 1.0).z, eta) < 1.0);
    }
}

#[test]
fn glass_refraction_obeys_snell() {
    let mut rng = Rng::new(77);
    for eta in GLASS_ETAS {
        for _ in 0..2000 {
            let wo = rng.direction();
            let Some((wi, etap)) = refract(wo, eta) else { continue };
            assert!((wi.length() - 1.0).abs() < 1e-5 && wi.z * wo.z <= 0.0);
            assert!((etap - eta_ratio(wo, eta)).abs() < 1e-6);
            // η_o sin θo = η_i sin θi with η_o/η_i = etap, and wi lies in the plane of
            // incidence on the far side of the normal.
            let (sin_o, sin_i) = (wo.truncate().length(), wi.truncate().length());
            assert!((etap * sin_i - sin_o).abs() < 1e-5, "η={eta} wo={wo} wi={wi}");
            assert!(wo.truncate().perp_dot(wi.truncate()).abs() < 1e-5 && wo.truncate().dot(wi.truncate()) <= 1e-6);
            // Reciprocity of the interface: the reverse path has the same Fresnel
            // reflectance and refracts back to wo. (Within 1° of grazing the f32 cos θt
            // of the reverse path is ill-conditioned, 1 − sin²θt cancelling.)
            if wo.z.abs().min(wi.z.abs()) < 0.02 {
                continue;
            }
            assert!(
                (fresnel_dielectric(wo.z, eta) - fresnel_dielectric(wi.z, eta)).abs() < 1e-4,
                "η={eta} wo={wo} wi={wi}: F {} vs {}",
                fresnel_dielectric(wo.z, eta),
                fresnel_dielectric(wi.z, eta)
            );
            let (back, _) = refract(wi, eta).unwrap();
            assert!((back - wo).length() < 1e-4, "η={eta}: {wo} → {wi} → {back}");
        }
    }
}

/// Every non-delta configuration the χ² and pdf tests run over.
fn chi2_cases() -> Vec<(Bsdf, Vec3)> {
    let mut cases = Vec::new();
    for (theta, side) in [(0.0, 1.0), (45.0, 1.0), (70.0, -1.0)] {
        cases.push((Bsdf::Diffuse { kd: Vec3::splat(0.5) }, dir(theta, 0.3, side)));
    }
    for n in EXPONENTS {
        for (kd, ks) in [(0.0, 1.0), (0.3, 0.6)] {
            for (theta, side) in [(0.0, 1.0), (40.0, 1.0), (80.0, -1.0)] {
                // At normal incidence the n = 1000 lobe is narrower than the polar
                // cells' quadrature resolves; it is covered by the other tests there.
                if n >= 1000.0 && theta == 0.0 {
                    continue;
                }
                cases.push((glossy(kd, ks, n), dir(theta, 1.2, side)));
            }
        }
    }
    cases
}

/// Sharp lobes seen through a zoom: the cone of half-angle 0.3 rad (n = 100) or
/// 0.1 rad (n = 1000) about the mirror direction, binned finely.
fn chi2_zoom_cases() -> Vec<(Bsdf, Vec3, (Vec3, f64))> {
    let mut cases = Vec::new();
    for (n, half_angle) in [(100.0, 0.3f64), (1000.0, 0.1)] {
        for (kd, ks) in [(0.0, 1.0), (0.3, 0.6)] {
            for (theta, side) in [(0.0, 1.0), (40.0, -1.0), (75.0, 1.0)] {
                let wo = dir(theta, 1.2, side);
                cases.push((glossy(kd, ks, n), wo, (reflect(wo), half_angle.cos())));
            }
        }
    }
    cases
}

#[test]
fn sampling_matches_pdf_chi2() {
    let zoomed = chi2_zoom_cases().into_iter().map(|(bsdf, wo, cap)| (bsdf, wo, Some(cap)));
    let cases: Vec<_> = chi2_cases().into_iter().map(|(bsdf, wo)| (bsdf, wo, None)).chain(zoomed).collect();
    assert_sampling_matches_pdf(cases, 500_000, 1000);
}

/// A BSDF, a wo, and a zoom (axis, cos of its half-angle) for narrow lobes.
pub(super) type Chi2Case = (Bsdf, Vec3, Option<(Vec3, f64)>);

/// The χ² test of every case's sampling against its pdf (32 × 64 cells, `samples` draws,
/// case k seeded `seed + k`), at a Šidák-corrected level for all cases together.
pub(super) fn assert_sampling_matches_pdf(cases: Vec<Chi2Case>, samples: usize, seed: u64) {
    let alpha = sidak_alpha(cases.len());
    for (k, (bsdf, wo, cap)) in cases.into_iter().enumerate() {
        let r = chi2_sphere(
            |rng| bsdf.sample(wo, rng.f32(), rng.vec2()).map(|s| s.wi),
            |wi| bsdf.pdf(wo, wi) as f64,
            32,
            64,
            samples,
            seed + k as u64,
            cap,
        );
        assert!(
            r.p_value > alpha,
            "{bsdf:?} wo={wo} cap={cap:?}: χ² = {:.1} with {} dof, p = {:.2e} < {alpha:.2e}",
            r.statistic,
            r.dof,
            r.p_value
        );
    }
}

#[test]
fn pdf_integrates_to_one_minus_lost_mass() {
    for (k, (bsdf, wo)) in chi2_cases().into_iter().enumerate() {
        let Bsdf::Glossy { exponent, .. } = bsdf else {
            let integral = integrate_sphere(&|wi: Vec3| bsdf.pdf(wo, wi) as f64, 64, 128, 0.0);
            assert!((integral - 1.0).abs() < 1e-4, "{bsdf:?}: ∫pdf = {integral}");
            continue;
        };
        let integral = integrate_sphere(&|wi: Vec3| bsdf.pdf(wo, wi) as f64, 96, 128, mirror_azimuth(wo));
        // The specular lobe's reflections below the horizon are dropped by `sample`,
        // so ∫pdf = P(sample succeeds) ≤ 1.
        let samples = 400_000;
        let mut rng = Rng::new(5000 + k as u64);
        let ok = (0..samples).filter(|_| bsdf.sample(wo, rng.f32(), rng.vec2()).is_some()).count();
        let frac = ok as f64 / samples as f64;
        let sigma = (frac * (1.0 - frac) / samples as f64).sqrt();
        assert!(integral <= 1.0 + 1e-3, "{bsdf:?} wo={wo}: ∫pdf = {integral}");
        assert!((integral - frac).abs() < 5.0 * sigma + 1e-3, "{bsdf:?} wo={wo}: ∫pdf = {integral}, success {frac}");
        if wo.z.abs() == 1.0 {
            // At normal incidence h is lost iff θh > 45°: P = (1/√2)^(n+1) in closed form.
            let Bsdf::Glossy { kd, ks, .. } = bsdf else { unreachable!() };
            let spec_prob = (ks.x / (kd.x + ks.x)) as f64;
            let expected = 1.0 - spec_prob * 0.5f64.powf((exponent as f64 + 1.0) / 2.0);
            assert!((integral - expected).abs() < 1e-3, "{bsdf:?}: ∫pdf = {integral} vs {expected}");
        }
    }
}

#[test]
fn sample_weight_is_eval_over_pdf() {
    let mut rng = Rng::new(99);
    let mut bsdfs = vec![Bsdf::Diffuse { kd: Vec3::new(0.2, 0.5, 0.9) }];
    for n in EXPONENTS {
        bsdfs.push(Bsdf::Glossy { kd: Vec3::new(0.2, 0.5, 0.1), ks: Vec3::new(0.3, 0.1, 0.8), exponent: n });
        bsdfs.push(glossy(0.0, 0.7, n));
    }
    for bsdf in bsdfs {
        for _ in 0..20_000 {
            let wo = rng.direction();
            let Some(s) = bsdf.sample(wo, rng.f32(), rng.vec2()) else { continue };
            assert!(!s.delta && s.wi.z * wo.z > 0.0 && (s.wi.length() - 1.0).abs() < 1e-5);
            let (f, pdf) = (bsdf.eval(wo, s.wi), bsdf.pdf(wo, s.wi));
            assert!((pdf - s.pdf).abs() <= 1e-5 * pdf, "{bsdf:?}: pdf {pdf} vs {}", s.pdf);
            let expected = f / pdf;
            assert!((s.weight - expected).abs().max_element() <= 1e-5 * expected.max_element().max(1.0));
        }
    }
}

#[test]
fn eval_is_reciprocal() {
    let mut rng = Rng::new(123);
    let mut bsdfs = vec![Bsdf::Diffuse { kd: Vec3::new(0.2, 0.5, 0.9) }];
    for n in EXPONENTS {
        bsdfs.push(Bsdf::Glossy { kd: Vec3::new(0.2, 0.5, 0.1), ks: Vec3::new(0.3, 0.1, 0.8), exponent: n });
    }
    for bsdf in bsdfs {
        for i in 0..20_000 {
            let wo = rng.direction();
            // Half the pairs near the specular configuration, where the lobe is large.
            let wi = if i % 2 == 0 { rng.direction() } else { (reflect(wo) + 0.05 * rng.direction()).normalize() };
            let f_forward = bsdf.eval(wo, wi) / wi.z.abs();
            let f_reverse = bsdf.eval(wi, wo) / wo.z.abs();
            if !(f_forward.is_finite() && f_reverse.is_finite()) {
                continue; // |cos θ| = 0 in the division above, not in eval
            }
            let scale = f_forward.max_element().max(f_reverse.max_element()).max(1e-6);
            assert!((f_forward - f_reverse).abs().max_element() <= 1e-4 * scale, "{bsdf:?} {wo} {wi}");
            assert!(bsdf.eval(wo, wi).min_element() >= 0.0);
        }
    }
}

#[test]
fn degenerate_inputs_never_give_nan() {
    let bsdfs = [
        Bsdf::Diffuse { kd: Vec3::ONE },
        glossy(0.5, 0.5, 0.0),
        glossy(0.0, 1.0, 1000.0),
        glossy(0.0, 1.0, 1e9),
        glossy(0.0, 1.0, f32::NAN),
        glossy(0.0, 1.0, -3.0),
        glossy(0.0, 0.0, 10.0),
        Bsdf::Glossy { kd: Vec3::new(f32::NAN, -1.0, 2.0), ks: Vec3::new(f32::INFINITY, 0.5, 3.0), exponent: 5.0 },
        Bsdf::Mirror { ks: Vec3::ONE },
        Bsdf::Glass { eta: 1.5, tint: Vec3::ONE },
        Bsdf::Glass { eta: 0.0, tint: Vec3::ONE },
        Bsdf::Glass { eta: f32::NAN, tint: Vec3::ONE },
    ];
    let dirs = [
        Vec3::Z,
        -Vec3::Z,
        Vec3::X,
        Vec3::Y,
        Vec3::new(1.0, 0.0, 1e-7).normalize(),
        Vec3::new(-1.0, 0.0, 1e-7).normalize(),
        Vec3::new(1.0, 0.0, -1e-30),
        Vec3::new(0.0, 0.0, 1e-38),
        dir(89.0, 0.0, 1.0),
        dir(89.0, std::f32::consts::PI, 1.0),
    ];
    let us = [Vec2::ZERO, Vec2::ONE, Vec2::new(0.0, 1.0), Vec2::new(1.0, 0.5), Vec2::splat(0.5)];
    for bsdf in bsdfs {
        assert!(bsdf.albedo().is_finite() && bsdf.albedo().max_element() <= 1.0, "{bsdf:?}");
        for wo in dirs {
            for wi in dirs {
                assert!(bsdf.eval(wo, wi).is_finite() && bsdf.eval(wo, wi).min_element() >= 0.0, "{bsdf:?} {wo} {wi}");
                assert!(bsdf.pdf(wo, wi).is_finite() && bsdf.pdf(wo, wi) >= 0.0, "{bsdf:?} {wo} {wi}");
            }
            for u in us {
                for u_lobe in [0.0, 0.5, 1.0] {
                    if let Some(s) = bsdf.sample(wo, u_lobe, u) {
                        assert!(
                            s.wi.is_finite() && s.weight.is_finite() && s.pdf.is_finite() && s.pdf > 0.0,
                            "{bsdf:?} wo={wo} u={u} u_lobe={u_lobe}: {s:?}"
                        );
                        assert!(s.weight.min_element() >= 0.0, "{bsdf:?} {wo}: {s:?}");
                    }
                }
            }
        }
    }
}

fn bits3(v: Vec3) -> [u32; 3] {
    v.to_array().map(f32::to_bits)
}

/// Eight lanes of random unit directions; every seventh a grazing one (z = 0), where the
/// BSDFs refuse to sample.
fn directions(rng: &mut Rng, k: usize) -> [Vec3; 8] {
    std::array::from_fn(|l| {
        if (k + l).is_multiple_of(7) {
            Vec3::new(0.6, 0.8, 0.0)
        } else {
            crate::sampling::sample_uniform_sphere(rng.vec2())
        }
    })
}

/// The eight-lane Lambertian and Blinn-Phong BSDFs give, lane by lane, their scalar
/// twins' bits: values, pdfs, sampled directions and weights, and which lanes sample.
#[test]
fn wide_bsdfs_are_their_scalar_twins() {
    use crate::bsdf::blinn_phong::BlinnPhongW;
    use crate::bsdf::lambert::LambertW;
    use crate::simd::V2w;
    let simd = crate::simd::tests::require_avx2();
    let mut rng = Rng::new(23);
    let mut sampled = 0;
    for k in 0..4000 {
        let (wo, wi) = (directions(&mut rng, k), directions(&mut rng, k + 3));
        let u: [Vec2; 8] = std::array::from_fn(|_| rng.vec2());
        let u_lobe: [f32; 8] = std::array::from_fn(|_| rng.f32());
        let colour = |rng: &mut Rng| Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 0.9;
        let kd: [Vec3; 8] = std::array::from_fn(|_| colour(&mut rng));
        let ks: [Vec3; 8] = std::array::from_fn(|_| colour(&mut rng));
        let exponent: [f32; 8] = std::array::from_fn(|_| 1.0 + 999.0 * rng.f32() * rng.f32());
        let (wov, wiv) = (simd.v3_from_fn(|l| wo[l]), simd.v3_from_fn(|l| wi[l]));
        let uv = V2w { x: simd.f8(std::array::from_fn(|l| u[l].x)), y: simd.f8(std::array::from_fn(|l| u[l].y)) };

        let lambert = LambertW { kd: simd.v3_from_fn(|l| kd[l]) };
        let (f, pdf) = (lambert.eval(wov, wiv), lambert.pdf(wov, wiv));
        let (swi, spdf, ok) = lambert.sample(wov, uv, simd.all());
        let phong = BlinnPhongW::from_fn(simd, |l| BlinnPhong::new(kd[l], ks[l], exponent[l]));
        let (pf, ppdf) = phong.eval_pdf(wov, wiv, simd.all());
        let (pwi, pweight, pspdf, pok) = phong.sample(wov, simd.f8(u_lobe), uv, simd.all());
        for l in 0..8 {
            let s = Lambert { kd: kd[l] };
            assert_eq!(bits3(f.get(l)), bits3(s.eval(wo[l], wi[l])), "lambert eval, lane {l}");
            assert_eq!(pdf.0[l].to_bits(), s.pdf(wo[l], wi[l]).to_bits(), "lambert pdf, lane {l}");
            match s.sample(wo[l], u[l]) {
                Some(x) => {
                    assert!(ok.0[l] != 0, "lambert sample: lane {l} should sample");
                    assert_eq!((bits3(swi.get(l)), spdf.0[l].to_bits()), (bits3(x.wi), x.pdf.to_bits()));
                    sampled += 1;
                }
                None => assert_eq!(ok.0[l], 0, "lambert sample: lane {l} should not sample"),
            }
            let p = BlinnPhong::new(kd[l], ks[l], exponent[l]);
            let (ef, epdf) = p.eval_pdf(wo[l], wi[l]);
            assert_eq!((bits3(pf.get(l)), ppdf.0[l].to_bits()), (bits3(ef), epdf.to_bits()), "phong, lane {l}");
            match p.sample(wo[l], u_lobe[l], u[l]) {
                Some(x) => {
                    assert!(pok.0[l] != 0, "phong sample: lane {l} should sample");
                    assert_eq!(
                        (bits3(pwi.get(l)), bits3(pweight.get(l)), pspdf.0[l].to_bits()),
                        (bits3(x.wi), bits3(x.weight), x.pdf.to_bits()),
                        "phong sample, lane {l}"
                    );
                }
                None => assert_eq!(pok.0[l], 0, "phong sample: lane {l} should not sample"),
            }
        }
    }
    assert!(sampled > 10_000, "{sampled}: the test must sample");
}

/// The eight-lane shading frame gives its scalar twin's bits.
#[test]
fn wide_frames_are_their_scalar_twin() {
    use crate::geometry::{Frame, FrameW};
    let simd = crate::simd::tests::require_avx2();
    let mut rng = Rng::new(29);
    for k in 0..4000 {
        let (n, v) = (directions(&mut rng, k), directions(&mut rng, k + 1));
        let fw = FrameW::from_normal(simd.v3_from_fn(|l| n[l]));
        let (local, world) = (fw.to_local(simd.v3_from_fn(|l| v[l])), fw.to_world(simd.v3_from_fn(|l| v[l])));
        for l in 0..8 {
            let f = Frame::from_normal(n[l]);
            assert_eq!(bits3(local.get(l)), bits3(f.to_local(v[l])), "to_local, lane {l}");
            assert_eq!(bits3(world.get(l)), bits3(f.to_world(v[l])), "to_world, lane {l}");
        }
    }
}
