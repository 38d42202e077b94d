//! Warping functions from the unit square [0,1)² to the domains the renderer samples
//! (disk, hemisphere, sphere, cone, power-cosine lobe, triangle), each with its pdf.
//!
//! Directions are in a local frame whose z axis is the lobe/cone axis (use
//! [`crate::geometry::frame::Frame`] to go to world space). Solid-angle pdfs are per
//! steradian; the disk pdf is per unit area of the unit disk. Every function is total:
//! inputs on the closed square \[0,1\]² and degenerate parameters give finite results.

use std::f32::consts::{FRAC_PI_4, PI};

use glam::{Vec2, Vec3};

use crate::math;

pub const INV_PI: f32 = std::f32::consts::FRAC_1_PI;
pub const INV_2PI: f32 = 0.5 * std::f32::consts::FRAC_1_PI;
pub const INV_4PI: f32 = 0.25 * std::f32::consts::FRAC_1_PI;

/// `if cond { a } else { b }`, by bit masks that the compiler cannot turn back into a
/// branch: the warps below choose between two formulas by a coin flip of the random
/// sample, which a branch mispredicts half the time. LLVM turned both
/// `select_unpredictable` and plain bit masks into branches there (a division in one
/// arm makes it prefer a branch); the mask passes through an empty `asm!`, which it
/// cannot see through. The result is the chosen value, bit for bit.
#[inline(always)]
pub(crate) fn select(cond: bool, a: f32, b: f32) -> f32 {
    f32::from_bits(select_bits(cond, a.to_bits(), b.to_bits()))
}

/// [`select`] for integers.
#[inline(always)]
pub(crate) fn select_bits(cond: bool, a: u32, b: u32) -> u32 {
    #[allow(unused_mut)]
    let mut mask = u32::from(cond).wrapping_neg();
    #[cfg(target_arch = "x86_64")]
    // SAFETY: an empty instruction sequence that leaves the register as it is.
    unsafe {
        std::arch::asm!("/* {0:e} */", inout(reg) mask, options(pure, nomem, nostack, preserves_flags));
    }
    #[cfg(not(target_arch = "x86_64"))]
    let mask = std::hint::black_box(mask);
    (a & mask) | (b & !mask)
}

/// `sin x` and `cos x` for `|x| <= π/4`: Cephes' single-precision minimax polynomials
/// (`sinf`, `cosf`), within 2 ulp there, in plain `f32` arithmetic in a fixed order, so
/// the same bits on every machine. The warps use these rather than CORE-MATH's
/// correctly rounded `sincosf` (`math.rs`): a direction needs no last-bit accuracy,
/// and, unlike the C function, the polynomial vectorises across the eight-path
/// integrator's lanes (`sampling::wide`), where `sincosf` ran lane by lane.
#[inline(always)]
pub fn sin_cos_octant(x: f32) -> (f32, f32) {
    let z = x * x;
    let sin = x + x * z * (-1.666_665_5e-1 + z * (8.332_161e-3 + z * -1.951_529_6e-4));
    let cos = 1.0 - 0.5 * z + z * z * (4.166_664_6e-2 + z * (-1.388_731_6e-3 + z * 2.443_315_7e-5));
    (sin, cos)
}

/// `sin 2πt` and `cos 2πt` for `t` in turns (`[0, 1]` and a little beyond): the octant
/// `k = ⌊8t⌋` and the offset in it are exact, [`sin_cos_octant`] gives the rest, and the
/// octant's symmetries (by selects: the octant of a random angle is random) swap and
/// negate.
#[inline]
pub fn sin_cos_turns(t: f32) -> (f32, f32) {
    let t8 = 8.0 * t;
    let k = t8.floor();
    let octant = (k as i32 & 7) as u32;
    // Odd octants run backwards from their upper end.
    let r = select(octant & 1 != 0, 1.0 - (t8 - k), t8 - k);
    let (s, c) = sin_cos_octant(r * FRAC_PI_4);
    let swap = matches!(octant, 1 | 2 | 5 | 6);
    let (s, c) = (select(swap, c, s), select(swap, s, c));
    (select(octant >= 4, -s, s), select(matches!(octant, 2..=5), -c, c))
}

/// Unit vector with polar angle given by (`sin_theta`, `cos_theta`) and azimuth
/// `2π · phi_turns`.
#[inline]
pub fn spherical_direction(sin_theta: f32, cos_theta: f32, phi_turns: f32) -> Vec3 {
    let (sin_phi, cos_phi) = sin_cos_turns(phi_turns);
    Vec3::new(sin_theta * cos_phi, sin_theta * sin_phi, cos_theta)
}

/// Shirley–Chiu concentric map of the square onto the unit disk: uniform in area, low
/// distortion, so stratification of `u` survives (used by cosine sampling and the lens).
#[inline]
pub fn sample_uniform_disk_concentric(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    // The same values as choosing the wedge by a branch, but by selects: which wedge a
    // random point falls in is a coin flip, which a branch mispredicts half the time.
    // In the wedge |x| > |y| the angle is q = π/4 · y/x; in the other it is π/2 - q'
    // with q' = π/4 · x/y, whose cosine and sine are q's sine and cosine.
    let wide = o.x.abs() > o.y.abs();
    let (r, other) = (select(wide, o.x, o.y), select(wide, o.y, o.x));
    let (sin, cos) = sin_cos_octant(FRAC_PI_4 * (other / r));
    Vec2::new(r * select(wide, cos, sin), r * select(wide, sin, cos))
}

/// Short name for [`sample_uniform_disk_concentric`] (the camera lens uses this one).
#[inline]
pub fn concentric_disk(u: Vec2) -> Vec2 {
    sample_uniform_disk_concentric(u)
}

/// Area density of [`sample_uniform_disk_concentric`] on the unit disk.
#[inline]
pub fn uniform_disk_pdf() -> f32 {
    INV_PI
}

/// Cosine-weighted hemisphere about +z (Malley's method: lift the concentric disk).
#[inline]
pub fn sample_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = sample_uniform_disk_concentric(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

/// pdf = cos θ / π on the upper hemisphere, 0 below.
#[inline]
pub fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    cos_theta.max(0.0) * INV_PI
}

/// Uniform direction on the unit sphere.
#[inline]
pub fn sample_uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    spherical_direction(r, z, u.y)
}

/// pdf = 1 / (4π).
#[inline]
pub fn uniform_sphere_pdf() -> f32 {
    INV_4PI
}

/// Uniform direction on the upper hemisphere (z ≥ 0).
#[inline]
pub fn sample_uniform_hemisphere(u: Vec2) -> Vec3 {
    let z = u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    spherical_direction(r, z, u.y)
}

/// pdf = 1 / (2π) on the upper hemisphere.
#[inline]
pub fn uniform_hemisphere_pdf() -> f32 {
    INV_2PI
}

/// Uniform direction inside the cone about +z of half-angle θmax (`cos_theta_max` in
/// [-1, 1]; -1 is the whole sphere). Works from 1 − cos θ so tiny cones (distant
/// spherical lights) keep their precision.
#[inline]
pub fn sample_uniform_cone(u: Vec2, cos_theta_max: f32) -> Vec3 {
    let one_minus_cos = u.x * (1.0 - cos_theta_max.clamp(-1.0, 1.0));
    let cos_theta = 1.0 - one_minus_cos;
    // sin²θ = (1 − cos θ)(1 + cos θ), without the cancellation of 1 − cos²θ.
    let sin_theta = (one_minus_cos * (2.0 - one_minus_cos)).max(0.0).sqrt();
    spherical_direction(sin_theta, cos_theta, u.y)
}

/// pdf = 1 / (2π (1 − cos θmax)) inside the cone. A degenerate cone (cos θmax = 1) is a
/// delta direction: callers must treat it as such; 0 is returned rather than ∞.
#[inline]
pub fn uniform_cone_pdf(cos_theta_max: f32) -> f32 {
    let solid_angle = 2.0 * PI * (1.0 - cos_theta_max.clamp(-1.0, 1.0));
    if solid_angle > 0.0 { 1.0 / solid_angle } else { 0.0 }
}

/// Power-cosine lobe about +z: density ∝ cos^n θ per solid angle (n ≥ 0; n = 0 is the
/// uniform hemisphere). Inverting the cdf gives cos θ = u^(1/(n+1)); sin²θ is taken from
/// expm1 so that sharp lobes (n up to 10⁴) keep their precision near the axis.
#[inline]
pub fn sample_power_cosine(u: Vec2, exponent: f32) -> Vec3 {
    let inv_np1 = 1.0 / (exponent.max(0.0) + 1.0);
    let log_cos = math::ln(u.x) * inv_np1; // ln cos θ, −∞ for u.x = 0 (θ = π/2)
    let cos_theta = math::exp(log_cos);
    let sin_theta = (-math::exp_m1(2.0 * log_cos)).clamp(0.0, 1.0).sqrt();
    spherical_direction(sin_theta, cos_theta, u.y)
}

/// pdf = (n + 1)/(2π) cos^n θ on the upper hemisphere, 0 below.
#[inline]
pub fn power_cosine_pdf(cos_theta: f32, exponent: f32) -> f32 {
    if cos_theta <= 0.0 {
        return 0.0;
    }
    let n = exponent.max(0.0);
    (n + 1.0) * INV_2PI * math::powf(cos_theta.min(1.0), n)
}

/// Uniform point on a triangle as barycentrics (b0, b1, b2), pdf = 1 / area. Heitz's
/// low-distortion map (as pbrt-v4): keeps the stratification of `u`.
#[inline]
pub fn sample_uniform_triangle(u: Vec2) -> [f32; 3] {
    // By selects: which half `u` falls in is a coin flip, which a branch mispredicts
    // half the time. The same values as the branches `(0.5 x, y - 0.5 x)` and
    // `(x - 0.5 y, 0.5 y)`.
    let lower = u.x < u.y;
    let half = 0.5 * select(lower, u.x, u.y);
    let rest = select(lower, u.y, u.x) - half;
    let (b0, b1) = (select(lower, half, rest), select(lower, rest, half));
    [b0, b1, (1.0 - b0 - b1).max(0.0)]
}

/// Veach's power heuristic (β = 2) weight of strategy f taken `nf` times against g taken
/// `ng` times. An infinite pdf (delta) wins outright.
#[inline]
pub fn power_heuristic(nf: f32, f_pdf: f32, ng: f32, g_pdf: f32) -> f32 {
    let f = nf * f_pdf;
    let g = ng * g_pdf;
    if f.is_infinite() {
        return 1.0;
    }
    let (f2, g2) = (f * f, g * g);
    if f2 + g2 > 0.0 && (f2 + g2).is_finite() { f2 / (f2 + g2) } else { 0.0 }
}

/// The warps of the eight-path integrator: each is its scalar namesake (without
/// `_wide`) lane by lane, with the same operations in the same order (see `simd.rs`).
pub(crate) mod wide {
    use std::f32::consts::FRAC_PI_4;

    use super::{INV_2PI, INV_PI};
    use crate::math;
    use crate::simd::{F8, M8, V2w, V3w, lanes};

    #[inline(always)]
    pub fn sin_cos_octant(x: F8) -> (F8, F8) {
        let z = x * x;
        let sin = x + x * z * (-1.666_665_5e-1 + z * (8.332_161e-3 + z * -1.951_529_6e-4));
        let cos = 1.0 - 0.5 * z + z * z * (4.166_664_6e-2 + z * (-1.388_731_6e-3 + z * 2.443_315_7e-5));
        (sin, cos)
    }

    #[inline(always)]
    pub fn sin_cos_turns(t: F8) -> (F8, F8) {
        let t8 = 8.0 * t;
        let k = t8.floor();
        let simd = t.simd();
        let octant = simd.u8(lanes(|l| k.0[l] as i32 as u32));
        // Octants 1, 3, 5, 7; 1, 2, 5, 6; 4 to 7; 2 to 5 (as `matches!` in the scalar).
        let bit = |add: u32, bit: u32| simd.mask_from_bools(lanes(|l| (octant.0[l].wrapping_add(add) >> bit) & 1 != 0));
        let r = bit(0, 0).select(1.0 - (t8 - k), t8 - k);
        let (s, c) = sin_cos_octant(r * FRAC_PI_4);
        let swap = bit(1, 1);
        let (s, c) = (swap.select(c, s), swap.select(s, c));
        (bit(0, 2).select(-s, s), bit(2, 2).select(-c, c))
    }

    #[inline(always)]
    pub fn spherical_direction(sin_theta: F8, cos_theta: F8, phi_turns: F8) -> V3w {
        let (sin_phi, cos_phi) = sin_cos_turns(phi_turns);
        V3w::new(sin_theta * cos_phi, sin_theta * sin_phi, cos_theta)
    }

    #[inline(always)]
    pub fn sample_uniform_sphere(u: V2w) -> V3w {
        let z = 1.0 - 2.0 * u.x;
        let r = (1.0 - z * z).max(0.0).sqrt();
        spherical_direction(r, z, u.y)
    }

    #[inline(always)]
    pub fn sample_uniform_disk_concentric(u: V2w) -> V2w {
        let o = V2w { x: 2.0 * u.x - 1.0, y: 2.0 * u.y - 1.0 };
        let center = o.x.eq(0.0) & o.y.eq(0.0);
        let wide = o.x.abs().gt(o.y.abs());
        let (r, other) = (wide.select(o.x, o.y), wide.select(o.y, o.x));
        let (sin, cos) = sin_cos_octant(FRAC_PI_4 * (other / r));
        let (x, y) = (r * wide.select(cos, sin), r * wide.select(sin, cos));
        let zero = u.x.simd().zero();
        V2w { x: center.select(zero, x), y: center.select(zero, y) }
    }

    #[inline(always)]
    pub fn sample_cosine_hemisphere(u: V2w) -> V3w {
        let d = sample_uniform_disk_concentric(u);
        let z = (1.0 - (d.x * d.x + d.y * d.y)).max(0.0).sqrt();
        V3w::new(d.x, d.y, z)
    }

    #[inline(always)]
    pub fn cosine_hemisphere_pdf(cos_theta: F8) -> F8 {
        cos_theta.max(0.0) * INV_PI
    }

    /// Barycentrics `[b0, b1, b2]`.
    #[inline(always)]
    pub fn sample_uniform_triangle(u: V2w) -> [F8; 3] {
        let lower = u.x.lt(u.y);
        let half = 0.5 * lower.select(u.x, u.y);
        let rest = lower.select(u.y, u.x) - half;
        let (b0, b1) = (lower.select(half, rest), lower.select(rest, half));
        [b0, b1, (1.0 - b0 - b1).max(0.0)]
    }

    #[inline(always)]
    pub fn power_heuristic(nf: f32, f_pdf: F8, ng: f32, g_pdf: F8) -> F8 {
        let f = nf * f_pdf;
        let g = ng * g_pdf;
        let (f2, g2) = (f * f, g * g);
        let sum = f2 + g2;
        let ok = sum.gt(0.0) & sum.is_finite();
        let simd = f.simd();
        f.is_infinite().select(simd.one(), ok.select(f2 / sum, simd.zero()))
    }

    /// For the lanes of `mask` (the others' values are unspecified).
    #[inline(always)]
    pub fn power_cosine_pdf(cos_theta: F8, exponent: F8, mask: M8) -> F8 {
        let n = exponent.max(0.0);
        let c = cos_theta.min(1.0);
        let simd = c.simd();
        let pow = simd.f8(lanes(|l| if mask.0[l] != 0 { math::powf(c.0[l], n.0[l]) } else { 0.0 }));
        cos_theta.le(0.0).select(simd.zero(), (n + 1.0) * INV_2PI * pow)
    }

    /// For the lanes of `mask` (the others' values are unspecified).
    #[inline(always)]
    pub fn sample_power_cosine(u: V2w, exponent: F8, mask: M8) -> V3w {
        let inv_np1 = 1.0 / (exponent.max(0.0) + 1.0);
        let on = |f: fn(f32) -> f32, x: F8| x.simd().f8(lanes(|l| if mask.0[l] != 0 { f(x.0[l]) } else { 0.0 }));
        let log_cos = on(math::ln, u.x) * inv_np1;
        let cos_theta = on(math::exp, log_cos);
        let sin_theta = (-on(math::exp_m1, 2.0 * log_cos)).clamp(0.0, 1.0).sqrt();
        spherical_direction(sin_theta, cos_theta, u.y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::chi2::{Rng, chi2_sphere, integrate_sphere, sidak_alpha};

    /// Number of χ² tests in this module, for the Šidák correction.
    const CHI2_TESTS: usize = 8;

    fn assert_chi2(name: &str, sample: impl FnMut(&mut Rng) -> Option<Vec3>, pdf: impl Fn(Vec3) -> f64 + Sync) {
        let r = chi2_sphere(sample, pdf, 24, 48, 400_000, 0x5eed_0001, None);
        let alpha = sidak_alpha(CHI2_TESTS);
        assert!(
            r.p_value > alpha,
            "{name}: χ² = {:.1}, dof {}, p = {:.2e} < {alpha:.2e}",
            r.statistic,
            r.dof,
            r.p_value
        );
    }

    /// The polynomial sine and cosine are within 2 ulp of the exact values over whole
    /// turns (double precision reference), also at the octants' ends.
    #[test]
    #[allow(clippy::disallowed_methods)] // the f64 reference
    fn sin_cos_turns_is_accurate() {
        let mut worst = 0.0f64;
        let n = 1 << 20;
        let ends = (0..=64).map(|k| k as f32 / 64.0).flat_map(|t| [t, t.next_up(), t.next_down()]);
        for t in (0..n).map(|i| i as f32 / n as f32).chain(ends) {
            let (s, c) = sin_cos_turns(t);
            let a = std::f64::consts::TAU * t as f64;
            // Error in units of the result's magnitude near 1 (2^-24): absolute error of
            // a unit vector's components.
            let err = ((s as f64 - a.sin()).abs()).max((c as f64 - a.cos()).abs()) * (1u64 << 24) as f64;
            worst = worst.max(err);
            assert!(err <= 2.0, "t {t}: ({s}, {c}) against ({}, {})", a.sin(), a.cos());
        }
        assert!(worst > 0.1, "a test that cannot fail: worst error {worst}");
    }

    /// The eight-lane twins of the sine and cosine and of the warps give the scalar bits.
    #[test]
    fn wide_twins_are_the_scalar_functions() {
        let simd = crate::simd::tests::require_avx2();
        let mut rng = Rng::new(11);
        for k in 0..20_000 {
            let u: [Vec2; 8] = std::array::from_fn(|l| match (k + l) % 5 {
                0 => Vec2::new((k % 65) as f32 / 64.0, (k % 33) as f32 / 32.0),
                _ => rng.vec2(),
            });
            let uw = crate::simd::V2w {
                x: simd.f8(std::array::from_fn(|l| u[l].x)),
                y: simd.f8(std::array::from_fn(|l| u[l].y)),
            };
            let (s, c) = wide::sin_cos_turns(uw.x);
            let d = wide::sample_uniform_disk_concentric(uw);
            let h = wide::sample_cosine_hemisphere(uw);
            let sph = wide::sample_uniform_sphere(uw);
            for (l, &u) in u.iter().enumerate() {
                assert_eq!(
                    sph.get(l).to_array().map(f32::to_bits),
                    sample_uniform_sphere(u).to_array().map(f32::to_bits)
                );
                let (es, ec) = sin_cos_turns(u.x);
                assert_eq!((s.0[l].to_bits(), c.0[l].to_bits()), (es.to_bits(), ec.to_bits()), "turns {}", u.x);
                let e = sample_uniform_disk_concentric(u);
                assert_eq!((d.x.0[l].to_bits(), d.y.0[l].to_bits()), (e.x.to_bits(), e.y.to_bits()), "disk {}", u);
                assert_eq!(
                    h.get(l).to_array().map(f32::to_bits),
                    sample_cosine_hemisphere(u).to_array().map(f32::to_bits)
                );
            }
        }
    }

    /// The eight-lane twins of the triangle warp, the power heuristic and the power
    /// cosine lobe give the scalar bits, on ordinary values and on zeros, infinities and
    /// the edges of the unit square.
    #[test]
    fn more_wide_twins_are_the_scalar_functions() {
        let simd = crate::simd::tests::require_avx2();
        let mut rng = Rng::new(17);
        let special = [0.0f32, 1.0, f32::INFINITY, 1e-30, 0.999_999_94];
        let (mut lobes, mut heuristics) = (0, 0);
        for k in 0..20_000 {
            let pick = |rng: &mut Rng, l: usize| {
                if (k + l).is_multiple_of(7) { special[(k / 7 + l) % special.len()] } else { rng.f32() }
            };
            let u: [Vec2; 8] = std::array::from_fn(|l| Vec2::new(pick(&mut rng, l).min(1.0), rng.f32()));
            let (fp, gp): ([f32; 8], [f32; 8]) = (
                std::array::from_fn(|l| 3.0 * pick(&mut rng, l)),
                std::array::from_fn(|l| 2.0 * pick(&mut rng, l + 3)),
            );
            let exponent: [f32; 8] = std::array::from_fn(|_| 1.0 + 500.0 * rng.f32() * rng.f32());
            let cos: [f32; 8] = std::array::from_fn(|_| 2.0 * rng.f32() - 1.0);
            let uw = crate::simd::V2w {
                x: simd.f8(std::array::from_fn(|l| u[l].x)),
                y: simd.f8(std::array::from_fn(|l| u[l].y)),
            };
            let tri = wide::sample_uniform_triangle(uw);
            let heur = wide::power_heuristic(1.0, simd.f8(fp), 2.0, simd.f8(gp));
            let (n, c) = (simd.f8(exponent), simd.f8(cos));
            let mask = simd.mask((k as u32).wrapping_mul(0x9e37_79b9) >> 24);
            let pdf = wide::power_cosine_pdf(c, n, mask);
            let lobe = wide::sample_power_cosine(uw, n, mask);
            let cpdf = wide::cosine_hemisphere_pdf(c);
            let dir = wide::spherical_direction(uw.x, c, uw.y);
            for l in 0..8 {
                let bits3 = |v: Vec3| v.to_array().map(f32::to_bits);
                assert_eq!(
                    [tri[0].0[l], tri[1].0[l], tri[2].0[l]].map(f32::to_bits),
                    sample_uniform_triangle(u[l]).map(f32::to_bits),
                    "triangle {}",
                    u[l]
                );
                let h = power_heuristic(1.0, fp[l], 2.0, gp[l]);
                assert!(heur.0[l].to_bits() == h.to_bits(), "heuristic {} {}: {} vs {h}", fp[l], gp[l], heur.0[l]);
                heuristics += usize::from(h > 0.0 && h < 1.0);
                assert_eq!(cpdf.0[l].to_bits(), cosine_hemisphere_pdf(cos[l]).to_bits());
                assert_eq!(bits3(dir.get(l)), bits3(spherical_direction(u[l].x, cos[l], u[l].y)));
                if mask.0[l] != 0 {
                    assert_eq!(pdf.0[l].to_bits(), power_cosine_pdf(cos[l], exponent[l]).to_bits(), "lobe pdf");
                    assert_eq!(bits3(lobe.get(l)), bits3(sample_power_cosine(u[l], exponent[l])), "lobe {}", u[l]);
                    lobes += 1;
                }
            }
        }
        assert!(lobes > 50_000 && heuristics > 50_000, "{lobes} lobes, {heuristics} heuristics");
    }

    #[test]
    fn warps_match_their_pdfs_chi2() {
        assert_chi2(
            "cosine hemisphere",
            |r| Some(sample_cosine_hemisphere(r.vec2())),
            |w| cosine_hemisphere_pdf(w.z) as f64,
        );
        assert_chi2("uniform sphere", |r| Some(sample_uniform_sphere(r.vec2())), |_| uniform_sphere_pdf() as f64);
        assert_chi2(
            "uniform hemisphere",
            |r| Some(sample_uniform_hemisphere(r.vec2())),
            |w| {
                if w.z >= 0.0 { uniform_hemisphere_pdf() as f64 } else { 0.0 }
            },
        );
        for cos_max in [0.25f32, -0.5] {
            assert_chi2(
                "uniform cone",
                |r| Some(sample_uniform_cone(r.vec2(), cos_max)),
                |w| {
                    if w.z >= cos_max { uniform_cone_pdf(cos_max) as f64 } else { 0.0 }
                },
            );
        }
        // Cone edges on bin boundaries (cos θ bins of width 1/12): the cell quadrature
        // assumes a smooth pdf inside each cell.
        for n in [0.0f32, 1.0, 10.0] {
            assert_chi2(
                "power cosine",
                |r| Some(sample_power_cosine(r.vec2(), n)),
                |w| power_cosine_pdf(w.z, n) as f64,
            );
        }
    }

    #[test]
    fn pdfs_integrate_to_one() {
        type Pdf = fn(Vec3) -> f64;
        let cases: [(&str, Pdf); 6] = [
            ("cosine", |w| cosine_hemisphere_pdf(w.z) as f64),
            ("sphere", |_| uniform_sphere_pdf() as f64),
            ("power n=0", |w| power_cosine_pdf(w.z, 0.0) as f64),
            ("power n=7.5", |w| power_cosine_pdf(w.z, 7.5) as f64),
            ("power n=1000", |w| power_cosine_pdf(w.z, 1000.0) as f64),
            ("cone", |w| if w.z >= 0.9 { uniform_cone_pdf(0.9) as f64 } else { 0.0 }),
        ];
        for (name, pdf) in cases {
            // The cone's edge is not on a grid line, so it needs the finer grid to reach 1e-3.
            let integral = integrate_sphere(&pdf, 512, 64, 0.0);
            assert!((integral - 1.0).abs() < 1e-3, "{name}: ∫pdf = {integral}");
        }
    }

    #[test]
    fn tiny_cone_keeps_precision() {
        // A 0.01° cone: 1 − cos θmax ≈ 1.5e-8 is below f32 resolution at 1, so pass the
        // value the light code would compute from sin²θmax / 2.
        let cos_max = 1.0 - 1.5e-8f32;
        let mut rng = Rng::new(3);
        for _ in 0..1000 {
            let w = sample_uniform_cone(rng.vec2(), cos_max);
            assert!(w.is_finite() && (w.length() - 1.0).abs() < 1e-5 && w.z >= cos_max);
        }
    }

    #[test]
    fn disk_and_triangle_are_uniform() {
        // Disk: fraction of points within radius r is r²; mean of x and y is 0.
        let mut rng = Rng::new(7);
        let n = 200_000;
        let mut inside_half = 0usize;
        let mut mean = Vec2::ZERO;
        for _ in 0..n {
            let p = sample_uniform_disk_concentric(rng.vec2());
            assert!(p.length() <= 1.0 + 1e-6);
            inside_half += (p.length() < 0.5) as usize;
            mean += p / n as f32;
        }
        let frac = inside_half as f64 / n as f64;
        let sigma = (0.25f64 * 0.75 / n as f64).sqrt();
        assert!((frac - 0.25).abs() < 5.0 * sigma, "disk: P(r < 1/2) = {frac}");
        assert!(mean.length() < 5.0 * (0.25f32 / n as f32).sqrt(), "disk mean {mean}");

        // Triangle: each barycentric coordinate is Beta(1, 2): mean 1/3, P(b < 1/2) = 3/4.
        let mut sums = [0f64; 3];
        let mut below_half = [0usize; 3];
        for _ in 0..n {
            let b = sample_uniform_triangle(rng.vec2());
            assert!(b.iter().all(|&x| (0.0..=1.0).contains(&x)) && (b.iter().sum::<f32>() - 1.0).abs() < 1e-6);
            for k in 0..3 {
                sums[k] += b[k] as f64;
                below_half[k] += (b[k] < 0.5) as usize;
            }
        }
        let sigma_mean = (1.0f64 / 18.0 / n as f64).sqrt(); // Var Beta(1,2) = 1/18
        let sigma_frac = (0.75f64 * 0.25 / n as f64).sqrt();
        for k in 0..3 {
            assert!((sums[k] / n as f64 - 1.0 / 3.0).abs() < 5.0 * sigma_mean, "triangle mean b{k}");
            assert!((below_half[k] as f64 / n as f64 - 0.75).abs() < 5.0 * sigma_frac, "triangle P(b{k} < 1/2)");
        }
    }

    #[test]
    fn degenerate_inputs_stay_finite() {
        for u in [Vec2::ZERO, Vec2::ONE, Vec2::new(0.5, 0.5), Vec2::new(0.0, 1.0), Vec2::new(1.0, 0.0)] {
            assert!(sample_uniform_disk_concentric(u).is_finite());
            assert!(sample_cosine_hemisphere(u).is_finite());
            assert!(sample_uniform_sphere(u).is_finite());
            assert!(sample_uniform_cone(u, 1.0).is_finite());
            for n in [0.0, 1.0, 1000.0, 1e4] {
                let w = sample_power_cosine(u, n);
                assert!(w.is_finite() && (w.length() - 1.0).abs() < 1e-5, "power n={n} u={u}: {w}");
            }
        }
        assert_eq!(uniform_cone_pdf(1.0), 0.0);
        assert!(power_cosine_pdf(1.0, 1e4).is_finite());
        assert_eq!(power_heuristic(1.0, f32::INFINITY, 1.0, 1.0), 1.0);
        assert_eq!(power_heuristic(1.0, 0.0, 1.0, 0.0), 0.0);
        assert!((power_heuristic(1.0, 1.0, 1.0, 1.0) - 0.5).abs() < 1e-6);
    }
}
