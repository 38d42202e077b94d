//! Test support for the Monte Carlo code: a deterministic RNG, quadrature over the sphere
//! and a χ² goodness-of-fit test of a direction sampler against its pdf (after Mitsuba's
//! `chi2` test: bin the sphere in (cos θ, φ), integrate the pdf over every cell, pool the
//! cells with small expected counts, turn the statistic into a p-value).

use crate::geometry::frame::Frame;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::f64::consts::PI;

/// SplitMix64: tiny, fast, statistically fine for tests, and fully deterministic.
pub(crate) struct Rng(u64);

impl Rng {
    pub(crate) fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1) with 24 random bits (every value exactly representable).
    pub(crate) fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    pub(crate) fn vec2(&mut self) -> Vec2 {
        Vec2::new(self.f32(), self.f32())
    }

    /// Uniform direction on the sphere.
    pub(crate) fn direction(&mut self) -> Vec3 {
        crate::sampling::sample_uniform_sphere(self.vec2())
    }
}

/// Per-test significance level so that `tests` independent tests together reject a
/// correct implementation with probability 1% (Šidák correction).
pub(crate) fn sidak_alpha(tests: usize) -> f64 {
    1.0 - 0.99f64.powf(1.0 / tests as f64)
}

/// 5-point Gauss–Legendre nodes and weights on [-1, 1]: exact for degree 9, and never
/// evaluates the integrand on a cell boundary (where pdfs are often discontinuous).
const GL_NODES: [f64; 5] =
    [-0.906_179_845_938_664, -0.538_469_310_105_683_1, 0.0, 0.538_469_310_105_683_1, 0.906_179_845_938_664];
const GL_WEIGHTS: [f64; 5] = [
    0.236_926_885_056_189_1,
    0.478_628_670_499_366_5,
    0.568_888_888_888_888_9,
    0.478_628_670_499_366_5,
    0.236_926_885_056_189_1,
];

/// Gauss–Legendre rule on [a, b] split into `parts` equal pieces: (abscissa, weight) pairs.
fn gauss_legendre(a: f64, b: f64, parts: usize) -> impl Iterator<Item = (f64, f64)> {
    let h = (b - a) / parts as f64;
    (0..parts).flat_map(move |k| {
        let mid = a + (k as f64 + 0.5) * h;
        GL_NODES.iter().zip(GL_WEIGHTS).map(move |(x, w)| (mid + 0.5 * h * x, 0.5 * h * w))
    })
}

fn direction(cos_theta: f64, phi: f64) -> Vec3 {
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    Vec3::new((sin_theta * phi.cos()) as f32, (sin_theta * phi.sin()) as f32, cos_theta as f32)
}

/// ∫ f dω over the sphere by Gauss–Legendre in (θ, φ), `theta_cells` per hemisphere
/// so the horizon (where BSDFs are discontinuous) is a cell boundary.
///
/// Glossy lobes seen from grazing angles are very narrow in azimuth (the half-vector
/// Jacobian squeezes them by cos θo), so φ = `phi_focus` + π s³ with s uniform on
/// [-1, 1]: a smooth substitution that packs the nodes around the azimuth of the lobe.
pub(crate) fn integrate_sphere(
    f: &(impl Fn(Vec3) -> f64 + Sync + ?Sized),
    theta_cells: usize,
    phi_cells: usize,
    phi_focus: f64,
) -> f64 {
    let thetas: Vec<(f64, f64)> =
        gauss_legendre(0.0, 0.5 * PI, theta_cells).chain(gauss_legendre(0.5 * PI, PI, theta_cells)).collect();
    let phis: Vec<(f64, f64)> =
        gauss_legendre(-1.0, 1.0, phi_cells).map(|(s, w)| (phi_focus + PI * s * s * s, w * 3.0 * PI * s * s)).collect();
    thetas
        .par_iter()
        .map(|&(theta, wt)| {
            let (sin_theta, cos_theta) = theta.sin_cos();
            let row: f64 = phis.iter().map(|&(phi, wp)| wp * f(direction(cos_theta, phi))).sum();
            wt * sin_theta * row
        })
        .sum()
}

pub(crate) struct Chi2Result {
    pub statistic: f64,
    pub dof: usize,
    pub p_value: f64,
}

/// χ² test of `sample` (None = failed sample) against the solid-angle `pdf`, with
/// `samples` draws binned in `cos_bins` × `phi_bins` cells of equal solid angle.
/// Failed samples form one more category whose expected mass is 1 − ∫pdf, so a
/// sampler that loses mass its pdf claims is caught too.
///
/// With `cap = Some((axis, cos_max))` only the cone of directions within acos(cos_max)
/// of `axis` is binned (in coordinates about the axis) and everything outside it joins
/// the failed category: a zoom that gives sharp lobes enough cells to be tested.
// Long on purpose: A test harness: bin, integrate, pool and test, in order.
pub(crate) fn chi2_sphere(
    mut sample: impl FnMut(&mut Rng) -> Option<Vec3>,
    pdf: impl Fn(Vec3) -> f64 + Sync,
    cos_bins: usize,
    phi_bins: usize,
    samples: usize,
    seed: u64,
    cap: Option<(Vec3, f64)>,
) -> Chi2Result {
    const MIN_EXPECTED: f64 = 5.0;
    let frame = Frame::from_normal(cap.map_or(Vec3::Z, |(axis, _)| axis.normalize()));
    let cos_min = cap.map_or(-1.0, |(_, c)| c);
    let failed = cos_bins * phi_bins;
    let cell_of = |w: Vec3| {
        let w = frame.to_local(w);
        if (w.z as f64) < cos_min {
            return failed;
        }
        let c = ((w.z as f64 - cos_min) / (1.0 - cos_min) * cos_bins as f64) as usize;
        let mut phi = (w.y as f64).atan2(w.x as f64);
        if phi < 0.0 {
            phi += 2.0 * PI;
        }
        let p = (phi / (2.0 * PI) * phi_bins as f64) as usize;
        c.min(cos_bins - 1) * phi_bins + p.min(phi_bins - 1)
    };

    let mut observed = vec![0f64; cos_bins * phi_bins + 1];
    let mut rng = Rng::new(seed);
    for _ in 0..samples {
        match sample(&mut rng) {
            Some(w) if w.is_finite() && (w.length() - 1.0).abs() < 1e-3 => observed[cell_of(w)] += 1.0,
            Some(w) => panic!("sampler returned a non-unit direction {w}"),
            None => observed[failed] += 1.0,
        }
    }

    // dω = d(cos θ) dφ, so integrate the pdf over each cell in those coordinates; the
    // 3 × 3 × 25-point rule resolves lobes a few cells wide to well below 1e-4.
    let dc = (1.0 - cos_min) / cos_bins as f64;
    let dphi = 2.0 * PI / phi_bins as f64;
    let mut expected: Vec<f64> = (0..cos_bins * phi_bins)
        .into_par_iter()
        .map(|cell| {
            let (i, j) = (cell / phi_bins, cell % phi_bins);
            let c0 = cos_min + i as f64 * dc;
            let p0 = j as f64 * dphi;
            let mut sum = 0.0;
            for (c, wc) in gauss_legendre(c0, c0 + dc, 3) {
                for (phi, wp) in gauss_legendre(p0, p0 + dphi, 3) {
                    sum += wc * wp * pdf(frame.to_world(direction(c, phi)));
                }
            }
            sum * samples as f64
        })
        .collect();
    let total: f64 = expected.iter().sum();
    assert!(total <= samples as f64 * (1.0 + 1e-3), "pdf integrates to {} > 1", total / samples as f64);
    expected.push((samples as f64 - total).max(0.0));

    // Pool the cells with small expected counts (sorted ascending) until the pool is
    // itself large enough for the χ² approximation.
    let mut order: Vec<usize> = (0..expected.len()).collect();
    order.sort_by(|&a, &b| expected[a].total_cmp(&expected[b]));
    let (mut statistic, mut cells) = (0.0, 0usize);
    let (mut pooled_obs, mut pooled_exp) = (0.0, 0.0);
    for k in order {
        let (obs, exp) = (observed[k], expected[k]);
        if exp <= 0.0 {
            // A sample where the pdf says none can land is a hard failure (tiny slack
            // for the quadrature's view of cell edges).
            assert!(obs <= samples as f64 * 1e-5, "{obs} samples in cell {k} of zero probability");
        } else if exp < MIN_EXPECTED || (pooled_exp > 0.0 && pooled_exp < MIN_EXPECTED) {
            pooled_obs += obs;
            pooled_exp += exp;
        } else {
            statistic += (obs - exp) * (obs - exp) / exp;
            cells += 1;
        }
    }
    if pooled_exp > 0.0 {
        statistic += (pooled_obs - pooled_exp) * (pooled_obs - pooled_exp) / pooled_exp;
        cells += 1;
    }
    let dof = cells.saturating_sub(1).max(1);
    Chi2Result { statistic, dof, p_value: chi2_survival(statistic, dof) }
}

/// P(X > x) for X ~ χ²(dof).
pub(crate) fn chi2_survival(x: f64, dof: usize) -> f64 {
    gamma_q(0.5 * dof as f64, 0.5 * x)
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7, 9 terms; ~1e-15 relative).
fn ln_gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection formula.
        return (PI / (PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let t = x + G + 0.5;
    let series = C[0] + C.iter().enumerate().skip(1).map(|(i, c)| c / (x + i as f64)).sum::<f64>();
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + series.ln()
}

/// Regularised upper incomplete gamma Q(a, x) = Γ(a, x)/Γ(a): the series for P below
/// x = a + 1, Lentz's continued fraction for Q above (each converges fast there).
pub(crate) fn gamma_q(a: f64, x: f64) -> f64 {
    assert!(a > 0.0 && x >= 0.0);
    if x == 0.0 {
        return 1.0;
    }
    let prefactor = (-x + a * x.ln() - ln_gamma(a)).exp();
    if x < a + 1.0 {
        let (mut term, mut sum, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..100_000 {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (1.0 - sum * prefactor).max(0.0)
    } else {
        const TINY: f64 = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / TINY;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..100_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < TINY {
                d = TINY;
            }
            c = b + an / c;
            if c.abs() < TINY {
                c = TINY;
            }
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < 1e-16 {
                break;
            }
        }
        (prefactor * h).clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn incomplete_gamma_matches_known_values() {
        // Q(1, x) = e^-x; χ²(2) survival is e^{-x/2}.
        for x in [0.01, 0.5, 1.0, 2.0, 5.0, 30.0] {
            assert!((gamma_q(1.0, x) - (-x).exp()).abs() < 1e-12, "Q(1,{x})");
        }
        // Γ(n) = (n-1)!, Γ(1/2) = √π.
        assert!((ln_gamma(10.0) - 362_880f64.ln()).abs() < 1e-12);
        assert!((ln_gamma(0.5) - PI.sqrt().ln()).abs() < 1e-12);
        // Tabulated χ² critical values: p = 0.05 at (dof 10, 18.307), p = 0.01 at
        // (dof 1, 6.635), p = 0.001 at (dof 100, 149.449).
        assert!((chi2_survival(18.307, 10) - 0.05).abs() < 1e-4);
        assert!((chi2_survival(6.635, 1) - 0.01).abs() < 1e-4);
        assert!((chi2_survival(149.449, 100) - 0.001).abs() < 1e-5);
        // Large dof: the median of χ²(k) is ≈ k(1 − 2/(9k))³.
        let k = 2000.0f64;
        assert!((chi2_survival(k * (1.0 - 2.0 / (9.0 * k)).powi(3), 2000) - 0.5).abs() < 1e-3);
    }

    #[test]
    fn chi2_rejects_a_wrong_sampler() {
        // Cosine-weighted samples tested against the uniform hemisphere pdf must fail.
        let r = chi2_sphere(
            |rng| Some(crate::sampling::sample_cosine_hemisphere(rng.vec2())),
            |w| if w.z > 0.0 { 1.0 / (2.0 * PI) } else { 0.0 },
            16,
            32,
            100_000,
            1,
            None,
        );
        assert!(r.p_value < 1e-10);
    }
}
