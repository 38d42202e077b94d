//! Tests of `build.rs`.

use proptest::prelude::*;

/// Proptest settings for CI: a fixed seed, so a run is repeatable (a new failure is
/// hunted with `PROPTEST_RNG_SEED=<n>`, which this leaves in charge).
fn pinned(cases: u32) -> ProptestConfig {
    let mut c = ProptestConfig { cases, failure_persistence: None, ..ProptestConfig::default() };
    if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
        c.rng_seed = proptest::test_runner::RngSeed::Fixed(0x7469_6c65_6661_726d);
    }
    c
}

use super::*;
use crate::accel::{PrimHit, RayPrecomp};
use crate::geometry::Ray;

struct NoPrims;

impl Primitives for NoPrims {
    fn len(&self) -> usize {
        0
    }
    fn bounds(&self, _: u32) -> Aabb {
        Aabb::EMPTY
    }
    fn intersect(&self, _: u32, _: &Ray, _: &RayPrecomp, _: f32) -> Option<PrimHit> {
        None
    }
}

/// The sorted sweep of Wald & Havran the exact SAH is specified by: events as keys
/// (position as order-preserving bits, kind end < planar < start, index), sorted,
/// swept with the counts updated per position.
fn sweep_split<P: Primitives>(ctx: &Ctx<'_, P>, cell: &Aabb, refs: &[Ref]) -> Option<Split> {
    let key = |pos: f32, kind: u64, i: usize| {
        let b = (pos + 0.0).to_bits();
        let ord = if b >> 31 == 1 { !b } else { b | 0x8000_0000 };
        ((ord as u64) << 32) | (kind << 30) | i as u64
    };
    let key_pos = |key: u64| {
        let ord = (key >> 32) as u32;
        f32::from_bits(if ord >> 31 == 1 { ord & 0x7fff_ffff } else { !ord })
    };
    let mut best: Option<Split> = None;
    for axis in 0..3 {
        let mut keys = Vec::new();
        for (i, r) in refs.iter().enumerate() {
            let (lo, hi) = (r.b.min[axis], r.b.max[axis]);
            if lo == hi {
                keys.push(key(lo, 1, i));
            } else {
                keys.push(key(lo, 2, i));
                keys.push(key(hi, 0, i));
            }
        }
        keys.sort_unstable();
        let d = cell.diagonal();
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        let (cap, rim) = (d[b] * d[c], d[b] + d[c]);
        let (lo, hi) = (cell.min[axis], cell.max[axis]);
        let (mut best_c, mut found) = (f32::INFINITY, (0.0, 0, 0, true));
        let (mut nl, mut nr) = (0u32, refs.len() as u32);
        let mut i = 0;
        while i < keys.len() {
            let at = keys[i] >> 32;
            let p = key_pos(keys[i]);
            let mut count = [0u32; 3];
            while i < keys.len() && keys[i] >> 32 == at {
                count[((keys[i] >> 30) & 3) as usize] += 1;
                i += 1;
            }
            let [ends, planars, starts] = count;
            nr -= ends + planars;
            if p > lo && p < hi {
                let (al, ar) = (cap + (p - lo) * rim, cap + (hi - p) * rim);
                let (c, l, r) = if planars == 0 {
                    (ctx.relative_cost(al, ar, nl, nr), nl, nr)
                } else {
                    let left = ctx.relative_cost(al, ar, nl + planars, nr);
                    let right = ctx.relative_cost(al, ar, nl, nr + planars);
                    if left <= right { (left, nl + planars, nr) } else { (right, nl, nr + planars) }
                };
                if c < best_c {
                    (best_c, found) = (c, (p, l, r, l != nl || planars == 0));
                }
            }
            nl += starts + planars;
        }
        if best_c < f32::INFINITY {
            let (pos, nl, nr, planar_left) = found;
            let s = Split { cost: ctx.cost(cell, axis, pos, nl, nr), axis, pos, planar_left };
            if best.is_none_or(|b| s.cost < b.cost) {
                best = Some(s);
            }
        }
    }
    best
}

fn key(s: Option<Split>) -> Option<(u32, usize, u32, bool)> {
    s.map(|s| (s.cost.to_bits(), s.axis, s.pos.to_bits(), s.planar_left))
}

proptest! {
    /// The vectorised binning counts what the scalar definition does, also on cells
    /// flat on an axis (infinite scale: NaN and infinite positions).
    #[test]
    fn count_bins_is_the_scalar_binning(
        k in 16usize..=MAX_BINS,
        flat_axis in 0usize..4,
        coords in prop::collection::vec((-1.5f32..1.5, -1.5f32..1.5), 3 * 40),
    ) {
        let mut cell = Aabb::new(Vec3::splat(-1.0), Vec3::new(1.0, 0.5, 2.0));
        if flat_axis < 3 {
            cell.max[flat_axis] = cell.min[flat_axis];
        }
        let refs: Vec<Ref> = (0..40)
            .map(|i| {
                let mut b = Aabb::EMPTY;
                for a in 0..3 {
                    let (u, v) = coords[3 * i + a];
                    let (lo, hi) = (cell.min[a], cell.max[a]);
                    b.min[a] = u.min(v).clamp(lo, hi);
                    b.max[a] = u.max(v).clamp(lo, hi);
                }
                Ref { id: i as u32, b }
            })
            .collect();
        let (lo, scale) = (cell.min, Vec3::splat(k as f32) / cell.diagonal());
        let mut got = vec![0u32; 6 * k];
        count_bins(&refs, lo, scale, k, &mut got);
        let mut want = vec![0u32; 6 * k];
        let last = (k - 1) as f32;
        for r in &refs {
            let s = ((r.b.min - lo) * scale).to_array();
            let e = ((r.b.max - lo) * scale).to_array();
            for a in 0..3 {
                want[2 * a * k + bin(s[a], last)] += 1;
                want[(2 * a + 1) * k + bin(e[a], last)] += 1;
            }
        }
        prop_assert_eq!(got, want);
    }
}

proptest! {
    #![proptest_config(pinned(4000))]
    /// The counting exact SAH picks exactly the sweep's plane, on extents whose
    /// coordinates come from a coarse grid (ties, shared boundaries, flat extents,
    /// extents touching the cell's faces, ±0.0) or are arbitrary.
    #[test]
    fn exact_split_is_the_sorted_sweep(
        n in 1usize..=EXACT_MAX_PRIMS,
        coords in prop::collection::vec((0u8..9, 0u8..9, -2.0f32..2.0, 0u8..4), 6 * EXACT_MAX_PRIMS),
        empty_bonus in prop::sample::select(vec![0.0f32, 0.2, 0.5]),
    ) {
        let ctx = Ctx {
            prims: &NoPrims,
            traversal_cost: 1.0,
            intersection_cost: 0.35,
            empty_bonus,
            max_depth: 30,
            max_leaf_prims: 1,
            pad: 0.0,
        };
        let cell = Aabb::new(Vec3::splat(-1.0), Vec3::new(1.0, 0.5, 2.0));
        let refs: Vec<Ref> = (0..n)
            .map(|i| {
                let mut b = Aabb::EMPTY;
                for a in 0..3 {
                    let (g0, g1, x, mode) = coords[6 * i + 2 * a];
                    let (lo, hi) = (cell.min[a], cell.max[a]);
                    let grid = |g: u8| {
                        let v = lo + (hi - lo) * g as f32 / 8.0;
                        if v == 0.0 && x < 0.0 { -0.0 } else { v }
                    };
                    let (u, v) = match mode {
                        0 => (grid(g0), grid(g1)),
                        1 => (grid(g0), grid(g0)),
                        2 => (grid(g0), x.clamp(lo, hi)),
                        _ => (x.clamp(lo, hi), coords[6 * i + 2 * a + 1].2.clamp(lo, hi)),
                    };
                    b.min[a] = u.min(v);
                    b.max[a] = u.max(v);
                }
                Ref { id: i as u32, b }
            })
            .collect();
        prop_assert_eq!(key(ctx.exact_split(&cell, &refs)), key(sweep_split(&ctx, &cell, &refs)));
    }
}
