//! Tests of `simd.rs`.

use super::*;

/// The twin tests compare the AVX2 path with its scalar original, so on x86_64 they
/// need a CPU with AVX2 (elsewhere the wide types are lane loops and always run). A
/// CPU without it fails the test, saying why, rather than letting it pass unchecked.
/// Returns the capability the test's lane values need.
pub(crate) fn require_avx2() -> Simd {
    Simd::detect()
        .expect("this CPU has no AVX2: the test of the eight-lane path against its scalar twin cannot run here")
}

/// Every operation gives, lane by lane, the scalar operation's bits, on ordinary
/// values and on zeros of both signs, infinities, NaN and subnormals.
#[test]
fn operations_are_the_scalar_operations() {
    let simd = require_avx2();
    let special = [0.0, -0.0, 1.0, -1.0, 0.5, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 1e-40, -3e-39, 7.25, -1e30];
    let mut h = 7u64;
    let mut next = || {
        h = h.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let r = (h >> 33) as u32;
        if r.is_multiple_of(4) {
            special[(r / 4) as usize % special.len()]
        } else {
            f32::from_bits(r.rotate_left(3) & 0xbf7f_ffff)
        }
    };
    let bits = |x: f32| x.to_bits();
    let same = |a: F8, f: &dyn Fn(usize) -> f32, what: &str| {
        for l in 0..W {
            let e = f(l);
            assert!(bits(a.0[l]) == bits(e) || (a.0[l].is_nan() && e.is_nan()), "{what} lane {l}: {} vs {e}", a.0[l]);
        }
    };
    let mask = |m: M8, f: &dyn Fn(usize) -> bool, what: &str| {
        for l in 0..W {
            assert_eq!(m.0[l] != 0, f(l), "{what} lane {l}");
        }
    };
    for _ in 0..2000 {
        let a = simd.f8(std::array::from_fn(|_| next()));
        let b = simd.f8(std::array::from_fn(|_| next()));
        same(a + b, &|l| a.0[l] + b.0[l], "+");
        same(a - b, &|l| a.0[l] - b.0[l], "-");
        same(a * b, &|l| a.0[l] * b.0[l], "*");
        same(a / b, &|l| a.0[l] / b.0[l], "/");
        same(-a, &|l| -a.0[l], "neg");
        same(a.sqrt(), &|l| a.0[l].sqrt(), "sqrt");
        same(a.abs(), &|l| a.0[l].abs(), "abs");
        same(a.floor(), &|l| a.0[l].floor(), "floor");
        same(a.copysign(b), &|l| a.0[l].copysign(b.0[l]), "copysign");
        same(a.signum(), &|l| a.0[l].signum(), "signum");
        same(a.clamp(-0.5, 2.0), &|l| a.0[l].clamp(-0.5, 2.0), "clamp");
        // max and min: equal unless the operands are zeros of opposite signs.
        let zeros = |l: usize| a.0[l] == 0.0 && b.0[l] == 0.0;
        let skip = |x: F8, e: f32, l: usize| if zeros(l) { e } else { x.0[l] };
        let mx = a.max(b);
        same(simd.f8(std::array::from_fn(|l| skip(mx, a.0[l].max(b.0[l]), l))), &|l| a.0[l].max(b.0[l]), "max");
        let mn = a.min(b);
        same(simd.f8(std::array::from_fn(|l| skip(mn, a.0[l].min(b.0[l]), l))), &|l| a.0[l].min(b.0[l]), "min");
        mask(a.lt(b), &|l| a.0[l] < b.0[l], "<");
        mask(a.le(b), &|l| a.0[l] <= b.0[l], "<=");
        mask(a.gt(b), &|l| a.0[l] > b.0[l], ">");
        mask(a.ge(b), &|l| a.0[l] >= b.0[l], ">=");
        mask(a.eq(b), &|l| a.0[l] == b.0[l], "==");
        mask(a.ne(b), &|l| a.0[l] != b.0[l], "!=");
        mask(a.is_finite(), &|l| a.0[l].is_finite(), "is_finite");
        mask(a.is_nan(), &|l| a.0[l].is_nan(), "is_nan");
        mask(a.is_infinite(), &|l| a.0[l].is_infinite(), "is_infinite");
        let m = a.lt(b);
        same(m.select(a, b), &|l| if a.0[l] < b.0[l] { a.0[l] } else { b.0[l] }, "select");
        assert_eq!(m.bits(), (0..W).fold(0, |s, l| s | (u32::from(a.0[l] < b.0[l]) << l)));
        assert_eq!(simd.mask(m.bits()), m);
        let (x, y) = (simd.u8(a.0.map(f32::to_bits)), simd.u8(b.0.map(f32::to_bits)));
        mask(x.ge(y), &|l| x.0[l] >= y.0[l], "u32 >=");
        mask(x.eq(x), &|_| true, "u32 ==");
    }
}
