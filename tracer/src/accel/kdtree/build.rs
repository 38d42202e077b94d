//! SAH kd-tree build with perfect (clipped) splits.
//!
//! (One file of ~670 lines: the recursion, its SAH kernels and its scratch space share
//! the private `Ref`, `Split` and `Ctx`, which a split would have to expose.)
//!
//! Every node holds its primitives as references: the primitive's index and its extent
//! in the node's cell. A straddling primitive is re-bounded by clipping it to each child
//! ("perfect splits", Havran; Wald & Havran 2006), so the SAH sees the geometry as it is.
//!
//! Split planes are chosen two ways (after Shevtsov et al. 2007 and Wald 2007):
//! - Nodes of more than `EXACT_MAX_PRIMS` references use a binned SAH: the cost is
//!   evaluated at `k - 1` equally spaced planes per axis (`bins_for`) from counts of extents
//!   starting and ending in each bin. That is O(n) with a small constant and no sorting.
//! - Smaller nodes evaluate the SAH exactly, at every extent boundary, choosing the
//!   plane Wald & Havran's sorted sweep would (flat primitives lying in a candidate plane
//!   go to whichever side the SAH prefers; a test keeps the sweep as the reference). With
//!   at most 16 references per node, counting each candidate's sides directly over
//!   fixed-size arrays (vectorised, no data-dependent branches) is cheaper than sorting
//!   the events and sweeping them (which dominated the build's profile), and gives the
//!   same tree. Binning more of the tree is faster;
//!   the bin counts (`bins_for`) are chosen so that its planes cost little SAH quality
//!   against the exact sweep.
//!
//! The top levels run on the rayon pool (children by `rayon::join`, binning by chunks
//! with exact integer sums, so the tree does not depend on the thread count). Below
//! them each task builds its subtree serially with no allocation per node: references
//! live in one growing scratch stack, children's lists pushed on top of their parent's
//! (the right child's written over the parent's in place as it is partitioned).
//!
//! The counting loops of both SAH variants (candidates' sides, bins) use SSE2
//! intrinsics on x86_64, where the compiler's own vectorisation kept the counts in
//! memory; other targets use the scalar loops. Tests hold the binning to the scalar
//! `bin` and the exact SAH to the sorted sweep.
//!
//! Primitive extents are padded by a small absolute margin (`Ctx::pad`) on their
//! non-flat axes. The intersection routines decide hits on rounded coordinates, so they
//! can report a hit for a ray that passes a rounding error outside a primitive; padding
//! makes every cell within that error of a primitive list it, so the tree finds exactly
//! the hits the brute-force loop finds. Axes on which a primitive is exactly flat need no
//! padding (its points lie exactly on the plane) and keep the planar handling above.

use glam::Vec3;
use rayon::prelude::*;

use super::{BuildParams, Node};
use crate::accel::Primitives;
use crate::accel::exact::{PAD_REL, pad_by};
use crate::geometry::Aabb;

/// Nodes with at least this many primitive references build their children in parallel
/// (above it the `rayon::join` overhead is negligible against the work).
const PAR_MIN_PRIMS: usize = 4096;
/// Parallel recursion stops at this depth: 2^8 tasks keep any thread count busy, and
/// each parallel level costs one copy of its subtrees' nodes when they are stitched.
const PAR_MAX_DEPTH: u32 = 8;
/// Binning is spread over the rayon pool, in chunks of this many references, above it.
const PAR_BIN_CHUNK: usize = 32 * 1024;
/// Nodes of at most this many references get the exact SAH.
const EXACT_MAX_PRIMS: usize = 16;
/// Most bins per axis of the binned SAH.
const MAX_BINS: usize = 256;

/// Bins per axis for a node of `n` references: about as many as the node has extent
/// boundaries (so nodes just above `EXACT_MAX_PRIMS` lose little against the exact
/// sweep), at most `MAX_BINS` (the SAH costs behind the choice: `bench/RESULTS.md`).
fn bins_for(n: usize) -> usize {
    (2 * n).clamp(16, MAX_BINS)
}

/// The bin of a position scaled to `0..=last` (NaN, from a flat cell, gives bin 0).
/// (What `count_bins` computes; its x86_64 version does it in vector registers.)
#[cfg(any(test, not(target_arch = "x86_64")))]
#[inline(always)]
fn bin(x: f32, last: f32) -> usize {
    // `max` and `min` return the non-NaN operand, so the value is finite and in range.
    let x = x.max(0.0).min(last);
    // SAFETY: `x` is finite and in 0..=last < MAX_BINS, representable as u32. (The
    // checked cast's saturation logic was the most expensive part of binning.)
    unsafe { x.to_int_unchecked::<u32>() as usize }
}

/// For each candidate position `pos[k]`: how many of the extents `mins[j]..maxs[j]`
/// start before it (`mins[j] < pos[k]`) and how many end after it (`maxs[j] > pos[k]`).
#[inline(always)]
fn count_sides<const K: usize>(mins: &[f32], maxs: &[f32], pos: &[f32; K]) -> ([u32; K], [u32; K]) {
    let (mut nl, mut nr) = ([0u32; K], [0u32; K]);
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        const { assert!(K.is_multiple_of(16)) };
        // 16 candidates at a time, their counts kept in registers across the references
        // (the compiler's own vectorisation of the loop below keeps them in memory). A
        // compare's all-ones lanes are -1: subtracting the mask counts.
        for g in (0..K).step_by(16) {
            // SAFETY: SSE2 is part of the x86_64 baseline; every load and store is of
            // four lanes at `g + 4 t + 3 < K`, inside `pos`, `nl` and `nr`.
            unsafe {
                let p: [__m128; 4] = std::array::from_fn(|t| _mm_loadu_ps(pos.as_ptr().add(g + 4 * t)));
                let (mut l, mut r) = ([_mm_setzero_si128(); 4], [_mm_setzero_si128(); 4]);
                for (&min, &max) in mins.iter().zip(maxs) {
                    let (min, max) = (_mm_set1_ps(min), _mm_set1_ps(max));
                    for t in 0..4 {
                        l[t] = _mm_sub_epi32(l[t], _mm_castps_si128(_mm_cmplt_ps(min, p[t])));
                        r[t] = _mm_sub_epi32(r[t], _mm_castps_si128(_mm_cmpgt_ps(max, p[t])));
                    }
                }
                for t in 0..4 {
                    _mm_storeu_si128(nl.as_mut_ptr().add(g + 4 * t).cast(), l[t]);
                    _mm_storeu_si128(nr.as_mut_ptr().add(g + 4 * t).cast(), r[t]);
                }
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    for (&min, &max) in mins.iter().zip(maxs) {
        for k in 0..K {
            nl[k] += u32::from(min < pos[k]);
            nr[k] += u32::from(max > pos[k]);
        }
    }
    (nl, nr)
}

/// Adds to `c` the binned SAH's counts of `chunk`: `c[2 a k + i]` extents starting in bin
/// `i` of axis `a`, `c[(2 a + 1) k + i]` ending in it, the bin of `x` being
/// `bin((x - lo[a]) * scale[a], k - 1)`.
#[inline(always)]
fn count_bins(chunk: &[Ref], lo: Vec3, scale: Vec3, k: usize, c: &mut [u32]) {
    assert!(c.len() == 6 * k && k <= MAX_BINS);
    let last = (k - 1) as f32;
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // The same operations as `bin` on the three axes at once (`max` and `min` also
        // turn NaN into 0); the bins of a reference's starts and ends, offset to their
        // counts, in two vectors.
        // SAFETY: SSE2 is part of the x86_64 baseline. Bins are in 0..=k - 1 and the
        // offsets at most 5 k, so the indices are below `6 k = c.len()` (bounds checks
        // cost a fifth of binning).
        unsafe {
            let ki = k as i32;
            let (lov, sv) = (_mm_setr_ps(lo.x, lo.y, lo.z, 0.0), _mm_setr_ps(scale.x, scale.y, scale.z, 0.0));
            let (zero, lastv) = (_mm_setzero_ps(), _mm_set1_ps(last));
            let (os, oe) = (_mm_setr_epi32(0, 2 * ki, 4 * ki, 0), _mm_setr_epi32(ki, 3 * ki, 5 * ki, 0));
            let bins = |v: __m128, offset: __m128i| {
                let x = _mm_min_ps(_mm_max_ps(_mm_mul_ps(_mm_sub_ps(v, lov), sv), zero), lastv);
                let mut i = [0i32; 4];
                _mm_storeu_si128(i.as_mut_ptr().cast(), _mm_add_epi32(_mm_cvttps_epi32(x), offset));
                i
            };
            for r in chunk {
                let s = bins(_mm_setr_ps(r.b.min.x, r.b.min.y, r.b.min.z, 0.0), os);
                let e = bins(_mm_setr_ps(r.b.max.x, r.b.max.y, r.b.max.z, 0.0), oe);
                for a in 0..3 {
                    *c.get_unchecked_mut(s[a] as usize) += 1;
                    *c.get_unchecked_mut(e[a] as usize) += 1;
                }
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    for r in chunk {
        let s = ((r.b.min - lo) * scale).to_array();
        let e = ((r.b.max - lo) * scale).to_array();
        for a in 0..3 {
            c[2 * a * k + bin(s[a], last)] += 1;
            c[(2 * a + 1) * k + bin(e[a], last)] += 1;
        }
    }
}

/// The first lowest of `costs` and its index (`None` if all are infinite or NaN): what
/// scanning for `c < best` finds, in two vectorised passes (the lowest value, then
/// its first position) instead of one branch per plane.
fn first_min(costs: &[f32]) -> Option<(usize, f32)> {
    // Eight running minima: `if c < m { c } else { m }` is `minps`, so the lanes
    // vectorise; NaN never wins, as in the scan.
    let mut m = [f32::INFINITY; 8];
    let chunks = costs.chunks_exact(8);
    let tail = chunks.remainder();
    for ch in chunks {
        for l in 0..8 {
            m[l] = if ch[l] < m[l] { ch[l] } else { m[l] };
        }
    }
    let low = tail.iter().chain(&m).fold(f32::INFINITY, |m, &c| if c < m { c } else { m });
    if !(low < f32::INFINITY) {
        return None;
    }
    // `low` is one of the costs, so it has a first position.
    costs.iter().position(|&c| c == low).map(|j| (j, low))
}

/// A primitive and its extent in the current cell.
#[derive(Clone, Copy, Debug)]
struct Ref {
    id: u32,
    b: Aabb,
}

#[derive(Clone, Copy, Debug)]
struct Split {
    cost: f32,
    axis: usize,
    pos: f32,
    planar_left: bool,
}

struct Ctx<'a, P> {
    prims: &'a P,
    traversal_cost: f32,
    intersection_cost: f32,
    empty_bonus: f32,
    max_depth: u32,
    max_leaf_prims: usize,
    pad: f32,
}

/// Output of a (sub)tree build: nodes in depth-first order with the below child right
/// after its parent, and the shared primitive-index array of the multi-primitive leaves.
#[derive(Default)]
pub(super) struct Out {
    pub(super) nodes: Vec<Node>,
    pub(super) ids: Vec<u32>,
}

impl Out {
    /// Appends a subtree built separately. Child links are relative so interior nodes
    /// move unchanged; only leaf offsets into `ids` shift.
    fn append(&mut self, sub: Out) {
        let base = self.ids.len() as u32;
        self.nodes.extend(sub.nodes.into_iter().map(|n| n.shifted(base)));
        self.ids.extend_from_slice(&sub.ids);
    }
}

pub(super) struct Built {
    pub(super) out: Out,
    /// Union of the primitives' exact bounds.
    pub(super) bounds: Aabb,
    /// The root cell: union of the padded extents.
    pub(super) cell: Aabb,
    pub(super) max_depth: u32,
}

/// Default maximum depth (pbrt's `8 + 1.3 log2 N`), capped by the traversal stack.
pub(super) fn default_max_depth(n: usize) -> u32 {
    (8.0 + 1.3 * (n.max(1) as f64).log2()).round() as u32
}

pub(super) fn build<P: Primitives>(prims: &P, params: &BuildParams) -> Built {
    let n = prims.len();
    assert!(n < 1 << 30, "kd-tree: at most 2^30 primitives");
    let bounds: Vec<Aabb> = (0..n as u32).into_par_iter().map(|i| prims.bounds(i)).collect();
    let valid = |b: &Aabb| !b.is_empty() && b.min.is_finite() && b.max.is_finite();
    let scene = bounds.iter().filter(|b| valid(b)).fold(Aabb::EMPTY, |a, b| a.union(*b));
    let max_depth = params.max_depth.unwrap_or_else(|| default_max_depth(n)).min(super::MAX_DEPTH);
    let mut out = Out::default();
    if scene.is_empty() {
        return Built { out, bounds: Aabb::EMPTY, cell: Aabb::EMPTY, max_depth };
    }
    let magnitude = scene.min.abs().max(scene.max.abs()).max_element();
    let ctx = Ctx {
        prims,
        traversal_cost: params.traversal_cost,
        intersection_cost: params.intersection_cost,
        empty_bonus: params.empty_bonus.clamp(0.0, 1.0),
        max_depth,
        max_leaf_prims: params.max_leaf_prims,
        pad: magnitude * PAD_REL,
    };

    let refs: Vec<Ref> = (0..n as u32)
        .filter(|&i| valid(&bounds[i as usize]))
        .map(|i| Ref { id: i, b: ctx.padded(bounds[i as usize]) })
        .collect();
    drop(bounds);
    let cell = refs.iter().fold(Aabb::EMPTY, |a, r| a.union(r.b));
    build_rec(&ctx, cell, refs, 0, &mut out);
    Built { out, bounds: scene, cell, max_depth }
}

impl<P: Primitives> Ctx<'_, P> {
    /// Pads the non-flat axes of an extent (see the module comment).
    fn padded(&self, b: Aabb) -> Aabb {
        pad_by(b, self.pad)
    }

    /// Extent of primitive `g` in `cell`: the primitive clipped to the cell grown by the
    /// padding, padded, and cut back to the cell. Contains every point of the cell within
    /// the padding of the primitive; empty when the primitive stays farther away.
    fn region(&self, g: u32, cell: &Aabb) -> Aabb {
        let grown = Aabb::new(cell.min - Vec3::splat(self.pad), cell.max + Vec3::splat(self.pad));
        let c = self.prims.clipped_bounds(g, &grown);
        if c.is_empty() {
            return Aabb::EMPTY;
        }
        let r = self.padded(c).intersection(*cell);
        if r.is_empty() { Aabb::EMPTY } else { r }
    }

    /// The SAH cost of splitting `cell` at `pos` on `axis` with `nl`, `nr` references
    /// on the sides.
    fn cost(&self, cell: &Aabb, axis: usize, pos: f32, nl: u32, nr: u32) -> f32 {
        let d = cell.diagonal();
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        let (cap, rim) = (d[b] * d[c], d[b] + d[c]);
        let scale = 2.0 / cell.surface_area();
        let (al, ar) = (cap + (pos - cell.min[axis]) * rim, cap + (cell.max[axis] - pos) * rim);
        self.traversal_cost + self.intersection_cost * scale * self.relative_cost(al, ar, nl, nr)
    }

    /// The part of the cost that differs between planes of one axis, given the
    /// children's half areas without their common factor: the sweeps compare this and
    /// compute the full cost of the winner only.
    #[inline(always)]
    fn relative_cost(&self, al: f32, ar: f32, nl: u32, nr: u32) -> f32 {
        // (Counts are below 2^30: converting them through i32 is exact and one
        // instruction, also in vector code; u32's and usize's conversions are not.)
        let bonus = if nl == 0 || nr == 0 { 1.0 - self.empty_bonus } else { 1.0 };
        bonus * (al * nl as i32 as f32 + ar * nr as i32 as f32)
    }

    /// Exact SAH over every extent boundary on every axis, for nodes of at most
    /// `EXACT_MAX_PRIMS` references: on the axis with the lowest cost (the first on ties)
    /// the plane that the sorted sweep of Wald & Havran would pick.
    fn exact_split(&self, cell: &Aabb, refs: &[Ref]) -> Option<Split> {
        let mut best: Option<Split> = None;
        for axis in 0..3 {
            let s = if refs.len() <= EXACT_MAX_PRIMS / 2 {
                self.exact_axis::<{ EXACT_MAX_PRIMS / 2 }, EXACT_MAX_PRIMS>(cell, axis, refs)
            } else {
                self.exact_axis::<EXACT_MAX_PRIMS, { 2 * EXACT_MAX_PRIMS }>(cell, axis, refs)
            };
            if let Some(s) = s
                && best.is_none_or(|b| s.cost < b.cost)
            {
                best = Some(s);
            }
        }
        best
    }

    /// The exact SAH on one axis for at most `M` references, with `K = 2 M` candidate
    /// planes: every extent's start and end. Instead of sorting the events and sweeping
    /// them (as in Wald & Havran), each candidate counts the extents on its sides
    /// directly, in fixed-size arrays the compiler vectorises; at this size that is
    /// cheaper than sorting and has no data-dependent branches. The result is the
    /// sweep's: the counts at `p` are those the sweep has there (`nl`: extents starting
    /// before `p`, flat ones included; `nr`: extents ending after it; `np`: flat ones in
    /// it, sent to the cheaper side, left on ties), the costs are computed by the same
    /// expressions, and of equal costs the lowest position wins (the sweep's first).
    #[inline(always)]
    fn exact_axis<const M: usize, const K: usize>(&self, cell: &Aabb, axis: usize, refs: &[Ref]) -> Option<Split> {
        const { assert!(K == 2 * M) };
        let n = refs.len();
        assert!(n <= M);
        let d = cell.diagonal();
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        let cap = d[b] * d[c];
        let rim = d[b] + d[c];
        let (lo, hi) = (cell.min[axis], cell.max[axis]);
        // Candidates: starts in lanes 0..n, ends in M..M + n; unused lanes hold `lo`,
        // which is never a candidate (planes must lie strictly inside the cell).
        let mut pos = [lo; K];
        let mut flat = false;
        for (i, r) in refs.iter().enumerate() {
            let (min, max) = (r.b.min.as_ref()[axis], r.b.max.as_ref()[axis]);
            pos[i] = min;
            pos[M + i] = max;
            flat |= min == max;
        }
        let (mins, maxs) = (&pos[..n], &pos[M..M + n]);
        let (nl, nr) = count_sides(mins, maxs, &pos);
        let mut np = [0u32; K];
        if flat {
            for (&min, _) in mins.iter().zip(maxs).filter(|(min, max)| min == max) {
                for k in 0..K {
                    np[k] += u32::from(min == pos[k]);
                }
            }
        }
        // Costs; with no flat extent in the plane (np = 0) both sides' costs are the
        // plain one, and the left is taken.
        let mut cost = [f32::INFINITY; K];
        for k in 0..K {
            let p = pos[k];
            let (al, ar) = (cap + (p - lo) * rim, cap + (hi - p) * rim);
            let left = self.relative_cost(al, ar, nl[k] + np[k], nr[k]);
            let right = self.relative_cost(al, ar, nl[k], nr[k] + np[k]);
            let c = if left <= right { left } else { right };
            cost[k] = if p > lo && p < hi { c } else { f32::INFINITY };
        }
        let best_c = cost.iter().fold(f32::INFINITY, |m, &c| if c < m { c } else { m });
        if best_c == f32::INFINITY {
            return None;
        }
        let best_p = (0..K).fold(f32::INFINITY, |m, k| if cost[k] == best_c && pos[k] < m { pos[k] } else { m });
        let k = (0..K).find(|&k| cost[k] == best_c && pos[k] == best_p)?;
        let p = pos[k];
        let (al, ar) = (cap + (p - lo) * rim, cap + (hi - p) * rim);
        let left = self.relative_cost(al, ar, nl[k] + np[k], nr[k]);
        let right = self.relative_cost(al, ar, nl[k], nr[k] + np[k]);
        let (l, r, planar_left) =
            if left <= right { (nl[k] + np[k], nr[k], true) } else { (nl[k], nr[k] + np[k], false) };
        // `+ 0.0`: the sweep's positions had -0.0 normalised to +0.0.
        let pos = p + 0.0;
        Some(Split { cost: self.cost(cell, axis, pos, l, r), axis, pos, planar_left })
    }

    /// SAH evaluated at `bins_for(n) - 1` equally spaced planes per axis, from per-bin counts
    /// of extent starts and ends. The counts only estimate the sides (an extent ending
    /// exactly on a plane counts on both); the partition then uses the exact rules.
    fn binned_split(&self, cell: &Aabb, refs: &[Ref], scratch: &mut BinScratch) -> Option<Split> {
        let d = cell.diagonal();
        let lo = cell.min;
        let k = bins_for(refs.len());
        let scale = Vec3::splat(k as f32) / d;
        // counts[(2 * axis) * k + bin]: extents starting in the bin; [(2 * axis + 1) * k
        // + bin]: ending in it.
        let count = |chunk: &[Ref], c: &mut [u32]| count_bins(chunk, lo, scale, k, c);
        let counts = &mut scratch.counts;
        counts.clear();
        if refs.len() >= 2 * PAR_BIN_CHUNK {
            *counts = refs
                .par_chunks(PAR_BIN_CHUNK)
                .map(|chunk| {
                    let mut c = vec![0u32; 6 * k];
                    count(chunk, &mut c);
                    c
                })
                .reduce(
                    || vec![0u32; 6 * k],
                    |mut a, b| {
                        a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                        a
                    },
                );
        } else {
            counts.resize(6 * k, 0);
            count(refs, counts);
        }
        let n = refs.len() as u32;
        let costs = &mut scratch.costs;
        let (mut best_c, mut best) = (f32::INFINITY, (0, 0.0, 0, 0));
        for axis in 0..3 {
            let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
            let cap = d[b] * d[c];
            let rim = d[b] + d[c];
            let (lo, hi) = (cell.min[axis], cell.max[axis]);
            let step = d[axis] / k as f32;
            let (starts, ends) = counts[2 * axis * k..][..2 * k].split_at_mut(k);
            // Prefix sums: the plane between bins i - 1 and i has starts[i - 1]
            // extents starting left of it and n - ends[i - 1] ending right of it.
            // (Running sums in registers: `x[i] += x[i - 1]` waits on the store of the
            // step before, and was a sixth of choosing splits.)
            let (mut sum_s, mut sum_e) = (0u32, 0u32);
            for (s, e) in starts.iter_mut().zip(ends.iter_mut()) {
                sum_s += *s;
                *s = sum_s;
                sum_e += *e;
                *e = sum_e;
            }
            // The costs of all planes first (a loop the compiler vectorises), then the
            // first lowest; the same expressions and order as one loop doing both.
            // (The plane index goes through i32: exact, and a vector instruction.)
            costs.clear();
            costs.resize(k - 1, 0.0);
            let mut i = 0i32;
            for ((cost, &nl), &e) in costs.iter_mut().zip(&starts[..k - 1]).zip(&ends[..k - 1]) {
                i += 1;
                let p = lo + i as f32 * step;
                let c = self.relative_cost(cap + (p - lo) * rim, cap + (hi - p) * rim, nl, n - e);
                *cost = if p > lo && p < hi { c } else { f32::INFINITY };
            }
            if let Some((j, c)) = first_min(costs)
                && c < best_c
            {
                best_c = c;
                best = (axis, lo + (j as i32 + 1) as f32 * step, starts[j], n - ends[j]);
            }
        }
        (best_c < f32::INFINITY).then(|| {
            let (axis, pos, nl, nr) = best;
            Split { cost: self.cost(cell, axis, pos, nl, nr), axis, pos, planar_left: true }
        })
    }

    fn find_split(&self, cell: &Aabb, refs: &[Ref], scratch: &mut BinScratch) -> Option<Split> {
        if !(cell.surface_area() > 0.0) {
            return None;
        }
        if refs.len() <= EXACT_MAX_PRIMS {
            self.exact_split(cell, refs)
        } else {
            self.binned_split(cell, refs, scratch)
        }
    }

    /// Sends each reference to the side(s) of the plane its extent reaches, calling
    /// `left` and `right` in order; straddlers are clipped to each child's cell and go
    /// only where something is left of them.
    fn partition(&self, cell: &Aabb, refs: &[Ref], s: Split, mut left: impl FnMut(Ref), mut right: impl FnMut(Ref)) {
        let (lcell, rcell) = Self::child_cells(cell, s);
        for &x in refs {
            let (l, r) = self.route(x, s, &lcell, &rcell);
            if let Some(l) = l {
                left(l);
            }
            if let Some(r) = r {
                right(r);
            }
        }
    }

    /// [`Ctx::partition`] of `refs[start..]` that writes the right child's list over
    /// it, from `start`, and pushes the left child's to `left`. Each reference read
    /// gives at most one right reference, so the writes never overtake the reads; the
    /// vector ends with the right child's list. (Saves copying that list.)
    fn partition_in_place(&self, cell: &Aabb, refs: &mut Vec<Ref>, start: usize, s: Split, left: &mut Vec<Ref>) {
        let (lcell, rcell) = Self::child_cells(cell, s);
        let mut w = start;
        for i in start..refs.len() {
            let (l, r) = self.route(refs[i], s, &lcell, &rcell);
            if let Some(l) = l {
                left.push(l);
            }
            if let Some(r) = r {
                refs[w] = r;
                w += 1;
            }
        }
        refs.truncate(w);
    }

    /// Where one reference goes: its extent on the left and on the right of the plane.
    #[inline(always)]
    fn route(&self, x: Ref, s: Split, lcell: &Aabb, rcell: &Aabb) -> (Option<Ref>, Option<Ref>) {
        let (min, max) = (x.b.min.as_ref()[s.axis], x.b.max.as_ref()[s.axis]);
        // The sweep's rules: an extent ending on the plane is left, one starting on
        // it right, a flat one in it goes to `planar_left`'s side.
        if min == max {
            if min < s.pos || (min == s.pos && s.planar_left) { (Some(x), None) } else { (None, Some(x)) }
        } else if max <= s.pos {
            (Some(x), None)
        } else if min >= s.pos {
            (None, Some(x))
        } else {
            let lb = self.region(x.id, lcell);
            let rb = self.region(x.id, rcell);
            ((!lb.is_empty()).then_some(Ref { id: x.id, b: lb }), (!rb.is_empty()).then_some(Ref { id: x.id, b: rb }))
        }
    }

    fn child_cells(cell: &Aabb, s: Split) -> (Aabb, Aabb) {
        let mut l = *cell;
        l.max[s.axis] = s.pos;
        let mut r = *cell;
        r.min[s.axis] = s.pos;
        (l, r)
    }

    /// The split to make, or `None` for a leaf.
    fn decide(&self, cell: &Aabb, refs: &[Ref], depth: u32, scratch: &mut BinScratch) -> Option<Split> {
        let n = refs.len();
        if n <= self.max_leaf_prims || depth >= self.max_depth {
            return None;
        }
        // Automatic termination: a leaf costs `intersection_cost · n`; split only if cheaper.
        self.find_split(cell, refs, scratch).filter(|s| s.cost < self.intersection_cost * n as f32)
    }
}

/// Per-task scratch for serial subtree builds.
#[derive(Default)]
struct Scratch {
    /// Stack of reference lists: a node's list on top, its children's pushed above it.
    refs: Vec<Ref>,
    /// The left child's list while the node's is partitioned.
    left: Vec<Ref>,
    bins: BinScratch,
    ids: Vec<u32>,
}

/// Scratch of the binned SAH: per-bin counts, per-plane costs.
#[derive(Default)]
struct BinScratch {
    counts: Vec<u32>,
    costs: Vec<f32>,
}

fn leaf(refs: &[Ref], ids: &mut Vec<u32>, out: &mut Out) {
    ids.clear();
    ids.extend(refs.iter().map(|r| r.id));
    out.nodes.push(Node::leaf(ids, &mut out.ids));
}

/// Builds the subtree of a node that owns its reference list: in parallel near the
/// root, serially on a scratch stack below.
fn build_rec<P: Primitives>(ctx: &Ctx<'_, P>, cell: Aabb, refs: Vec<Ref>, depth: u32, out: &mut Out) {
    let n = refs.len();
    if n < PAR_MIN_PRIMS || depth >= PAR_MAX_DEPTH {
        let mut s = Scratch { refs, ..Default::default() };
        build_serial(ctx, cell, 0, depth, out, &mut s);
        return;
    }
    let Some(split) = ctx.decide(&cell, &refs, depth, &mut BinScratch::default()) else {
        leaf(&refs, &mut Vec::new(), out);
        return;
    };
    let (mut l, mut r) = (Vec::with_capacity(n), Vec::with_capacity(n));
    ctx.partition(&cell, &refs, split, |x| l.push(x), |x| r.push(x));
    drop(refs);
    let (lcell, rcell) = Ctx::<P>::child_cells(&cell, split);
    let at = out.nodes.len();
    out.nodes.push(Node::default());
    // The below child's nodes follow this node directly, so that subtree is written
    // in place; only the above child's is built apart and copied after it.
    let ((), ro) = rayon::join(
        || build_rec(ctx, lcell, l, depth + 1, out),
        || {
            let mut o = Out::default();
            build_rec(ctx, rcell, r, depth + 1, &mut o);
            o
        },
    );
    let above = out.nodes.len();
    out.append(ro);
    out.nodes[at] = Node::interior(split.axis, split.pos, (above - at) as u32);
}

/// Builds the subtree of the node whose references are the top of the stack,
/// `s.refs[start..]`, and pops them.
fn build_serial<P: Primitives>(ctx: &Ctx<'_, P>, cell: Aabb, start: usize, depth: u32, out: &mut Out, s: &mut Scratch) {
    let Some(split) = ctx.decide(&cell, &s.refs[start..], depth, &mut s.bins) else {
        leaf(&s.refs[start..], &mut s.ids, out);
        s.refs.truncate(start);
        return;
    };
    // The node's list is no longer needed: the right child's replaces it and the left
    // child's goes on top, to be built (and popped) first.
    s.left.clear();
    ctx.partition_in_place(&cell, &mut s.refs, start, split, &mut s.left);
    let mid = s.refs.len();
    s.refs.extend_from_slice(&s.left);
    let (lcell, rcell) = Ctx::<P>::child_cells(&cell, split);
    let at = out.nodes.len();
    out.nodes.push(Node::default());
    build_serial(ctx, lcell, mid, depth + 1, out, s);
    let above = out.nodes.len();
    build_serial(ctx, rcell, start, depth + 1, out, s);
    out.nodes[at] = Node::interior(split.axis, split.pos, (above - at) as u32);
}

#[cfg(test)]
mod tests;
