//! Tests of `treelet.rs`.

use super::*;
use crate::accel::kdtree::tests::Rng;

/// A pick from `x`.
fn pick<T: Copy>(r: &mut Rng, x: &[T]) -> T {
    x[(r.next() % x.len() as u64) as usize]
}

/// Everything a step leaves: the nearest child and the pushed entries, as bits.
fn drain(next: Option<(u32, f32, f32)>, st: &mut Stack) -> Vec<(u32, u32, u32)> {
    let bits = |(r, lo, hi): (u32, f32, f32)| (r, lo.to_bits(), hi.to_bits());
    next.into_iter().chain(std::iter::from_fn(|| st.pop())).map(bits).collect()
}

/// What the scalar step leaves, from an empty stack.
fn scalar_step(t: &Treelet, ray: &RayAxes, lo: f32, hi: f32, reach: f32) -> Vec<(u32, u32, u32)> {
    let mut st = Stack::new();
    let next = st.step(t, ray, lo, hi, reach);
    drain(next, &mut st)
}

/// A random treelet and ray with the special cases: planes at infinity
/// (placeholders), rays in a plane (`0 · ∞`), zero direction components of both
/// signs, empty children, `reach` below `hi`.
fn case(r: &mut Rng) -> (Treelet, RayAxes, f32, f32, f32) {
    let one_of = |r: &mut Rng, special: &[f32], lo: f32, hi: f32| {
        let x = r.range(lo, hi);
        if r.next().is_multiple_of(2) { x } else { pick(r, special) }
    };
    let o = [0; 3].map(|_| one_of(r, &[0.0, 0.5], -2.0, 2.0));
    let split = [0; 7].map(|_| one_of(r, &[f32::INFINITY, 0.0, 0.5], -2.0, 2.0));
    let d = [0; 3].map(|_| one_of(r, &[0.0, -0.0], -1.0, 1.0));
    let child = [0; 8].map(|_| ((r.next() as u32 % 1000) << 2) | pick(r, &[TREELET, LEAF, ONE, EMPTY]));
    let axes = (0..7).fold(0, |a, k| a | ((r.next() as u32 % 3) << (2 * k)));
    let lo = one_of(r, &[0.0], 0.0, 2.0);
    let hi = lo + one_of(r, &[f32::INFINITY], 0.0, 3.0);
    let reach = one_of(r, &[f32::INFINITY, hi], lo, lo + 2.0);
    let ray = RayAxes { o, inv: d.map(|x| 1.0 / x), neg: d.map(|x| x.is_sign_negative()), slack: r.range(0.0, 1e-3) };
    (Treelet { split, axes, child }, ray, lo, hi, reach)
}

#[test]
fn eight_lane_step_is_the_scalar_step() {
    #[cfg(target_arch = "x86_64")]
    {
        crate::simd::tests::require_avx2();
        let mut r = Rng(3);
        for _ in 0..200_000 {
            let (t, ray, lo, hi, reach) = case(&mut r);
            let scalar = scalar_step(&t, &ray, lo, hi, reach);
            let mut b = Stack::new();
            // SAFETY: AVX2 was detected.
            let next = unsafe { step_avx2(&mut b, &t, &RayLanes::new(&ray), lo, hi, reach, (0, 0)) };
            assert_eq!(scalar, drain(next, &mut b), "{t:?} {lo} {hi} {reach}");
        }
    }
}

/// The scalar step keeps exactly the children the binary walk visits, with the same
/// intervals, nearest first.
#[test]
fn step_is_three_binary_steps() {
    let mut r = Rng(5);
    for _ in 0..100_000 {
        let (t, ray, lo, hi, reach) = case(&mut r);
        let got = scalar_step(&t, &ray, lo, hi, reach);
        // The binary walk's descent from node k with interval [lo, hi], children in
        // the order the ray meets them.
        fn descend(t: &Treelet, r: &RayAxes, k: usize, lo: f32, hi: f32, reach: f32, out: &mut Vec<(u32, u32, u32)>) {
            if k >= 7 {
                let c = t.child[k - 7];
                if c & 3 != EMPTY {
                    out.push((c, lo.to_bits(), hi.to_bits()));
                }
                return;
            }
            let a = ((t.axes >> (2 * k)) & 3) as usize;
            let tp = (t.split[k] - r.o[a]) * r.inv[a];
            let (below, above) = (2 * k + 1, 2 * k + 2);
            let (first, second) = if r.neg[a] { (above, below) } else { (below, above) };
            let f_hi = fmin(tp + r.slack, hi);
            let s_lo = fmax(tp - r.slack, lo);
            if lo <= f_hi {
                descend(t, r, first, lo, f_hi, reach, out);
            }
            if s_lo <= fmin(hi, reach) {
                descend(t, r, second, s_lo, hi, reach, out);
            }
        }
        let mut want = Vec::new();
        if lo <= reach {
            descend(&t, &ray, 0, lo, hi, reach, &mut want);
        }
        assert_eq!(got, want, "{t:?} {lo} {hi} {reach}");
    }
}
