//! Tests of `sampler.rs`.

use super::*;

const SEED: u64 = 0x7469_6c65_6661_726d; // "tilefarm"

/// Draws slot `d` (consuming `d` earlier slots as 2D) of sample `index`.
fn point(seed: u64, x: u32, y: u32, index: u32, d: u32) -> Vec2 {
    let mut s = Sampler::new(seed, x, y, index);
    for _ in 0..d {
        s.next_2d();
    }
    s.next_2d()
}

/// Unscrambled Sobol dimension 1 as a fraction, for reference checks.
fn sobol1(index: u32) -> f64 {
    f64::from(sobol1_reversed(index).reverse_bits()) / 2f64.powi(32)
}

fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    sab / (saa * sbb).sqrt()
}

/// Eight lanes drawing under random masks give, lane by lane, the scalar sampler's
/// numbers, also past the Sobol slots (the hash fallback).
#[test]
fn lanes_draw_what_the_scalar_sampler_draws() {
    let simd = crate::simd::tests::require_avx2();
    let mut lanes = SamplerLanes::new(simd);
    let mut scalar: Vec<Sampler> = (0..W as u32).map(|l| Sampler::new(SEED, 3 + l, 7 * l, l * 1000 + 5)).collect();
    for (l, s) in scalar.iter().enumerate() {
        lanes.set(l, s);
    }
    let mut h = 12345u32;
    for step in 0..200 {
        h = h.wrapping_mul(0x9e37_79b9).wrapping_add(0x7f4a_7c15);
        let bits = (h >> 7) & 0xff;
        let mask = simd.mask(bits);
        if step % 3 == 0 {
            let u = lanes.next_1d(mask);
            for l in crate::simd::each(bits) {
                assert_eq!(u.0[l].to_bits(), scalar[l].next_1d().to_bits(), "step {step} lane {l}");
            }
        } else {
            let u = lanes.next_2d(mask);
            for l in crate::simd::each(bits) {
                let v = scalar[l].next_2d();
                assert_eq!(
                    (u.x.0[l].to_bits(), u.y.0[l].to_bits()),
                    (v.x.to_bits(), v.y.to_bits()),
                    "step {step} lane {l}"
                );
            }
        }
        for (l, s) in scalar.iter().enumerate() {
            assert_eq!(lanes.get(l).dimension(), s.dimension(), "step {step} lane {l}");
        }
    }
    assert!(scalar.iter().all(|s| s.dimension() > SOBOL_DIMENSIONS), "the fallback is reached");
}

#[test]
fn sobol_dimension_one_matches_reference() {
    // Sobol dimension 2 in natural (not Gray-code) order, as in pbrt-v4's SobolMatrices32.
    let expected = [0.0, 0.5, 0.75, 0.25, 0.625, 0.125, 0.375, 0.875];
    for (i, &e) in expected.iter().enumerate() {
        assert_eq!(sobol1(i as u32), e, "index {i}");
    }
    let columns = sobol1_columns();
    assert_eq!(&columns[..5], &[0x8000_0000, 0xc000_0000, 0xa000_0000, 0xf000_0000, 0x8800_0000]);
    // The transform equals the bit-serial matrix-vector product.
    let mut h = 1u32;
    let more = (0..10_000).map(|_| {
        h = h.wrapping_mul(0x9e37_79b9).wrapping_add(0x7f4a_7c15);
        h ^ (h >> 15)
    });
    for index in [1u32, 0xdead_beef, u32::MAX, 0x8000_0001, 12345].into_iter().chain(more) {
        let mut r = 0u32;
        for (bit, column) in columns.iter().enumerate() {
            if index & (1 << bit) != 0 {
                r ^= column;
            }
        }
        assert_eq!(sobol1_reversed(index), r.reverse_bits());
    }
}

#[test]
fn owen_scramble_is_a_nested_uniform_permutation() {
    // Bit i of the output depends only on bits >= i of the input: values sharing their top m
    // bits stay together, and the 2^(32-m) values of a block are permuted among themselves.
    for seed in [0u32, 1, 0x9e37_79b9, 0xffff_ffff] {
        for m in [24u32, 28] {
            let block = 0xabcd_ef12u32 >> (32 - m) << (32 - m);
            let mut seen = vec![false; 1 << (32 - m)];
            for low in 0..(1u32 << (32 - m)) {
                let s = nested_uniform_scramble(block | low, seed);
                let target = nested_uniform_scramble(block, seed) >> (32 - m);
                assert_eq!(s >> (32 - m), target);
                seen[(s & ((1 << (32 - m)) - 1)) as usize] = true;
            }
            assert!(seen.iter().all(|&b| b));
        }
    }
}

#[test]
fn purity() {
    let draw = |seed, x, y, index| {
        let mut s = Sampler::new(seed, x, y, index);
        let mut v = Vec::new();
        for i in 0..(2 * SOBOL_DIMENSIONS + 8) {
            if i % 3 == 0 {
                v.push(s.next_1d());
            } else {
                let p = s.next_2d();
                v.extend([p.x, p.y]);
            }
        }
        v
    };
    let base = draw(SEED, 17, 42, 1000);
    assert_eq!(base, draw(SEED, 17, 42, 1000));
    assert_eq!(Sampler::new(SEED, 17, 42, 1000).clone().next_2d(), Sampler::new(SEED, 17, 42, 1000).next_2d());
    for other in [
        draw(SEED ^ 1, 17, 42, 1000),
        draw(SEED, 18, 42, 1000),
        draw(SEED, 17, 43, 1000),
        draw(SEED, 42, 17, 1000),
        draw(SEED, 17, 42, 1001),
        draw(0, 0, 0, 0),
    ] {
        // Different streams: (almost) no value in common position-wise.
        let same = base.iter().zip(&other).filter(|(a, b)| a == b).count();
        assert!(same <= 1, "{same} equal values");
    }
    // Different slots of one sample differ, in the Sobol range and in the fallback range.
    for d in [0, 1, 7, SOBOL_DIMENSIONS - 1, SOBOL_DIMENSIONS, SOBOL_DIMENSIONS + 5] {
        assert_ne!(point(SEED, 3, 4, 77, d), point(SEED, 3, 4, 77, d + 1), "slot {d}");
    }
    // Seed 0, pixel (0, 0), index 0 is not a degenerate all-zero stream.
    assert!(draw(0, 0, 0, 0).iter().filter(|&&v| v == 0.0).count() <= 1);
}

#[test]
fn values_in_unit_interval() {
    let indices =
        (0..4096u32).chain(u32::MAX - 4096..=u32::MAX).chain((0..4096u32).map(|i| i.wrapping_mul(0x9e37_79b9)));
    for (n, index) in indices.enumerate() {
        let pixel = n as u32 % 7;
        let mut s = Sampler::new(SEED.wrapping_add(n as u64 % 3), pixel, u32::MAX - pixel, index);
        for _ in 0..(SOBOL_DIMENSIONS + 4) {
            let p = s.next_2d();
            let q = s.next_1d();
            for v in [p.x, p.y, q] {
                assert!((0.0..1.0).contains(&v), "{v} at index {index}");
            }
        }
    }
    assert!(unit_f32(u32::MAX) < 1.0);
    assert_eq!(unit_f32(u32::MAX), ONE_MINUS_EPSILON);
    assert_eq!(ONE_MINUS_EPSILON, f32::from_bits(0x3f7f_ffff));
    assert_eq!(unit_f32(0), 0.0);
}

/// Checks that `points` (2^k of them) have one point in every elementary interval of area 2^-k.
fn assert_net(points: &[Vec2], k: u32, what: &str) {
    assert_eq!(points.len(), 1 << k);
    for a in 0..=k {
        let (nx, ny) = (1u32 << a, 1u32 << (k - a));
        let mut cells = vec![0u8; 1 << k];
        for p in points {
            // Exact: points have 24-bit mantissas and cell counts are powers of two <= 2^10.
            let cx = (p.x * nx as f32) as u32;
            let cy = (p.y * ny as f32) as u32;
            cells[(cy * nx + cx) as usize] += 1;
        }
        assert!(cells.iter().all(|&c| c == 1), "{what}: k={k}, grid {nx}x{ny} not stratified");
    }
}

#[test]
fn first_power_of_two_samples_are_stratified() {
    for (pixel, d) in [((0, 0), 0), ((5, 9), 0), ((5, 9), 1), ((123, 4), 3), ((1, 1), SOBOL_DIMENSIONS - 1)] {
        for k in 2..=10u32 {
            let points: Vec<Vec2> = (0..1u32 << k).map(|i| point(SEED, pixel.0, pixel.1, i, d)).collect();
            assert_net(&points, k, &format!("pixel {pixel:?} slot {d}"));
        }
    }
}

#[test]
fn aligned_index_ranges_are_stratified() {
    // A farm worker rendering samples [m 2^k, (m+1) 2^k) also gets a (0,k,2)-net: the index
    // shuffle maps aligned blocks to aligned blocks.
    for (start, k) in [(1024u32, 10u32), (3 << 20, 8), (u32::MAX - 255, 8), (4096 + 64, 6)] {
        let points: Vec<Vec2> = (start..=start + ((1 << k) - 1)).map(|i| point(SEED, 7, 7, i, 2)).collect();
        assert_net(&points, k, &format!("indices from {start}"));
    }
    // 1D requests are stratified too: one value per interval of length 2^-k.
    for k in 2..=10u32 {
        let mut cells = vec![0u8; 1 << k];
        for i in 0..1u32 << k {
            let mut s = Sampler::new(SEED, 2, 3, i);
            s.next_2d();
            cells[(s.next_1d() * (1 << k) as f32) as usize] += 1;
        }
        assert!(cells.iter().all(|&c| c == 1), "1D k={k}");
    }
}

#[test]
fn dimensions_and_pixels_are_decorrelated() {
    const N: u32 = 4096;
    // Independent samples give |r| ~ N^-1/2 = 0.016; 0.07 is 4.5 sigma, so the ~90 checks below
    // pass for any healthy hash, while a shared scramble between slots or pixels gives |r| ~ 1.
    const BOUND: f64 = 0.07;
    let series = |x: u32, y: u32, d: u32| -> [Vec<f64>; 2] {
        let pts: Vec<Vec2> = (0..N).map(|i| point(SEED, x, y, i, d)).collect();
        [pts.iter().map(|p| f64::from(p.x)).collect(), pts.iter().map(|p| f64::from(p.y)).collect()]
    };
    for d in [0, 1, 2, 5, SOBOL_DIMENSIONS - 1, SOBOL_DIMENSIONS, SOBOL_DIMENSIONS + 1] {
        let a = series(10, 20, d);
        let b = series(10, 20, d + 1);
        let right = series(11, 20, d);
        let below = series(10, 21, d);
        for u in &a {
            for v in b.iter().chain(&right).chain(&below) {
                let r = pearson(u, v);
                assert!(r.abs() < BOUND, "slot {d}: r = {r}");
            }
        }
        let r = pearson(&a[0], &a[1]);
        assert!(r.abs() < BOUND, "slot {d} x vs y: r = {r}");
    }
    // Mixed 1D/2D requests: a 1D slot against the 2D slot that follows it.
    let mut u = Vec::new();
    let mut v = Vec::new();
    for i in 0..N {
        let mut s = Sampler::new(SEED, 3, 3, i);
        u.push(f64::from(s.next_1d()));
        v.push(f64::from(s.next_2d().x));
    }
    let r = pearson(&u, &v);
    assert!(r.abs() < BOUND, "1D vs 2D: r = {r}");
}

/// A named integrand over the unit square with its exact integral.
type Integrand = (&'static str, fn(f64, f64) -> f64, f64);

/// Integrands with known integrals over the unit square.
fn integrands() -> [Integrand; 2] {
    fn bump_1d(t: f64) -> f64 {
        (-(t - 0.4) * (t - 0.4) / (2.0 * 0.15 * 0.15)).exp()
    }
    fn bump(x: f64, y: f64) -> f64 {
        bump_1d(x) * bump_1d(y)
    }
    // Separable, so its integral is the square of a 1D Simpson integral (error ~1e-16).
    let n = 20_000;
    let h = 1.0 / n as f64;
    let simpson: f64 = (0..=n)
        .map(|i| {
            let w = if i == 0 || i == n {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            w * bump_1d(i as f64 * h)
        })
        .sum::<f64>()
        * h
        / 3.0;
    [("x*y", |x, y| x * y, 0.25), ("gaussian bump", bump, simpson * simpson)]
}

fn estimate(f: fn(f64, f64) -> f64, n: u32, mut sample: impl FnMut(u32) -> Vec2) -> f64 {
    (0..n).map(&mut sample).map(|p| f(f64::from(p.x), f64::from(p.y))).sum::<f64>() / f64::from(n)
}

/// Independent-random reference: the counter-based hash of the fallback path.
fn random_point(x: u32, index: u32) -> Vec2 {
    point(SEED, x, 0, index, SOBOL_DIMENSIONS)
}

#[test]
fn converges_faster_than_random_sampling() {
    const N: u32 = 1024;
    const PIXELS: u32 = 16;
    for (name, f, exact) in integrands() {
        let rms = |sample: &dyn Fn(u32, u32) -> Vec2| {
            let mse: f64 = (0..PIXELS).map(|x| (estimate(f, N, |i| sample(x, i)) - exact).powi(2)).sum::<f64>()
                / f64::from(PIXELS);
            mse.sqrt()
        };
        let sobol = rms(&|x, i| point(SEED, x, 0, i, 4));
        let random = rms(&random_point);
        // Scrambled nets have error O(N^-3/2) for smooth integrands vs O(N^-1/2) for random
        // sampling: at N = 1024 that is a factor of ~1000 in theory; demand 30.
        assert!(sobol * 30.0 < random, "{name}: sobol rms {sobol:e}, random rms {random:e}");
    }
}

#[test]
fn estimator_is_unbiased() {
    const N: u32 = 1024;
    const PIXELS: u32 = 256;
    for (name, f, exact) in integrands() {
        for d in [0, 9] {
            let errors: Vec<f64> =
                (0..PIXELS).map(|p| estimate(f, N, |i| point(SEED, p % 16, p / 16, i, d)) - exact).collect();
            let n = f64::from(PIXELS);
            let mean = errors.iter().sum::<f64>() / n;
            let var = errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0);
            // Each pixel is an independent scramble, so the mean error is ~ N(0, var / n).
            let bound = 4.0 * (var / n).sqrt();
            assert!(mean.abs() < bound, "{name} slot {d}: mean error {mean:e}, bound {bound:e}");
        }
    }
}
