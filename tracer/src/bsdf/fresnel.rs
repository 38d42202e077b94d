//! Fresnel terms of the Principled BSDF, in the forms Blender's Cycles uses: exact
//! dielectric Fresnel remapped between a tinted F0 and 1, and the F82-tint model for
//! metals (Kutz et al., "Novel aspects of the Adobe Standard Material", 2021).

use glam::Vec3;

pub use super::dielectric::fresnel_dielectric;

/// Normal-incidence reflectance of a dielectric interface of relative IOR `eta`.
#[inline]
pub fn f0_from_ior(eta: f32) -> f32 {
    let r = (eta - 1.0) / (eta + 1.0);
    r * r
}

/// The IOR (≥ 1) whose normal-incidence reflectance is `f0` (held below 0.99).
#[inline]
pub fn ior_from_f0(f0: f32) -> f32 {
    let s = f0.clamp(0.0, 0.99).sqrt();
    (1.0 + s) / (1.0 - s)
}

/// A dielectric's Fresnel reflectance with its normal-incidence value replaced by `f0`:
/// the exact curve's position between its own F0 and 1 is kept, and applied between `f0`
/// and 1 (Cycles' "generalized Schlick" with a negative exponent, the Principled BSDF's
/// specular tint and IOR level). `cos` is wo·h on `wo`'s side; `eta` the IOR seen from there.
#[inline]
pub fn tinted_dielectric(cos: f32, eta: f32, f0: Vec3) -> Vec3 {
    let real = fresnel_dielectric(cos, eta);
    let real0 = f0_from_ior(eta);
    let s = if real0 < 1.0 { ((real - real0) / (1.0 - real0)).clamp(0.0, 1.0) } else { 1.0 };
    f0.lerp(Vec3::ONE, s)
}

/// The F82-tint model's `b` for reflectance `f0` and edge tint `tint`: Schlick's curve
/// scaled by `tint` at cos θ = 1/7 (about 82°).
#[inline]
pub fn f82_b(f0: Vec3, tint: Vec3) -> Vec3 {
    if tint == Vec3::ONE {
        return Vec3::ZERO;
    }
    let f = 6.0f32 / 7.0;
    let f5 = f * f * f * f * f;
    f0.lerp(Vec3::ONE, f5) * (7.0 / (f5 * f)) * (Vec3::ONE - tint)
}

/// The F82-tint reflectance at `cos` (Schlick's with a cos (1 − cos)⁶ dip), in [0, 1].
#[inline]
pub fn f82(cos: f32, f0: Vec3, b: Vec3) -> Vec3 {
    let s = (1.0 - cos).clamp(0.0, 1.0);
    let s5 = s * s * s * s * s;
    (f0.lerp(Vec3::ONE, s5) - b * (cos * s5 * s)).clamp(Vec3::ZERO, Vec3::ONE)
}

/// The cosine-weighted hemispherical average of [`f82`] (∫ 2μ F(μ) dμ, in closed form).
#[inline]
pub fn f82_average(f0: Vec3, b: Vec3) -> Vec3 {
    f0.lerp(Vec3::ONE, 1.0 / 21.0) - b * (1.0 / 126.0)
}

/// The cosine-weighted average of the exact dielectric Fresnel reflectance (∫ 2μ F dμ),
/// by the fit of Kulla & Conty 2017 that Cycles uses.
#[inline]
pub fn dielectric_average(eta: f32) -> f32 {
    if eta < 1.0 {
        0.997_118 + eta * (0.1014 - eta * (0.965_241 + eta * 0.130_607))
    } else {
        (eta - 1.0) / (4.085_67 + 1.000_71 * eta)
    }
}

#[cfg(test)]
// Tests may use the C library's functions: they check values, not platform-free bits.
#[allow(clippy::disallowed_methods)]
mod tests {
    use super::*;

    fn average(f: impl Fn(f32) -> f32) -> f32 {
        let n = 20_000;
        (0..n).map(|i| (i as f32 + 0.5) / n as f32).map(|mu| 2.0 * mu * f(mu)).sum::<f32>() / n as f32
    }

    #[test]
    fn ior_and_f0_are_inverse() {
        for eta in [1.1f32, 1.33, 1.5, 2.4] {
            assert!((ior_from_f0(f0_from_ior(eta)) - eta).abs() < 1e-4);
        }
        assert!((f0_from_ior(1.5) - 0.04).abs() < 1e-7);
    }

    #[test]
    fn untinted_dielectric_is_the_exact_fresnel() {
        for eta in [1.33f32, 1.5, 1.0 / 1.5] {
            for cos in [0.05f32, 0.3, 0.7, 1.0] {
                let f = tinted_dielectric(cos, eta, Vec3::splat(f0_from_ior(eta)));
                assert!((f.x - fresnel_dielectric(cos, eta)).abs() < 1e-6, "η {eta} cos {cos}");
            }
        }
    }

    #[test]
    fn f82_tint_scales_the_82_degree_value_and_averages_in_closed_form() {
        let (f0, tint) = (Vec3::new(1.0, 0.78, 0.34), Vec3::new(0.5, 0.9, 1.0));
        let b = f82_b(f0, tint);
        let schlick = |cos: f32| f0.lerp(Vec3::ONE, (1.0 - cos).powi(5));
        let at82 = f82(1.0 / 7.0, f0, b);
        assert!((at82 - schlick(1.0 / 7.0) * tint).abs().max_element() < 1e-5, "{at82}");
        assert_eq!(f82(1.0, f0, b), f0);
        for k in 0..3 {
            let numeric = average(|mu| f82(mu, f0, b)[k]);
            assert!((numeric - f82_average(f0, b)[k]).abs() < 2e-4, "{numeric} vs {}", f82_average(f0, b)[k]);
        }
    }

    #[test]
    fn the_average_fit_is_within_a_percent_of_the_integral() {
        for eta in [1.2f32, 1.5, 2.0, 1.0 / 1.5] {
            let numeric = average(|mu| fresnel_dielectric(mu, eta));
            assert!(
                (numeric - dielectric_average(eta)).abs() < 0.01,
                "η {eta}: {numeric} vs {}",
                dielectric_average(eta)
            );
        }
    }
}
