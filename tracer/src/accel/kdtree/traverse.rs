//! Front-to-back traversal (pbrt-style, fixed-size stack) with the bookkeeping that makes
//! the answers bit-identical to [`brute_force_intersect`] / [`brute_force_occluded`].
//!
//! Exactness. The brute-force loop visits primitives in index order and accepts a hit
//! when the primitive's test passes with the current `tmax`. The tree visits them in
//! another order, so it must not simply keep "the smallest t":
//! * Ties and near-ties. Two primitives can be hit at the same or nearly the same `t`
//!   (shared edges and vertices, coplanar overlaps). The watertight test's acceptance of
//!   `t < tmax` is decided on `t·det`, so a hit with a smaller `t` can still be rejected
//!   when `tmax` is only an ulp or two above it. The tree therefore collects every hit
//!   within a small margin of the nearest one (`bound`), and when more than one is that
//!   close it replays the brute-force loop over just those, in index order, from the
//!   query's `tmax`. Hits farther away than the margin cannot change that replay (each
//!   close primitive accepts any `tmax` that far above its own `t`), and once a close
//!   hit is accepted no far one can be. A hit is only final once traversal has passed
//!   `bound`.
//! * A primitive is listed in every leaf its (clipped) extent overlaps and its hit may lie
//!   outside the leaf being visited; candidates are deduplicated by index, and traversal
//!   continues until no unvisited node can hold a hit below `bound`.
//! * Rounding in the split-plane distances and in the hit distances is covered by an
//!   absolute slack (in units of t) derived from the ray's distance to the scene, by
//!   which node intervals are widened; together with the build's padding of primitive
//!   extents, every leaf that could hold a reported hit is visited.
//!
//! [`brute_force_intersect`]: crate::accel::brute_force_intersect
//! [`brute_force_occluded`]: crate::accel::brute_force_occluded

use glam::Vec3;

use super::KdTree;
use super::treelet::{EMPTY, LEAF, ONE, RayAxes, Stack, TREELET, Treelet};
#[cfg(target_arch = "x86_64")]
use super::treelet::{RayLanes, step_avx2};
#[cfg(target_arch = "x86_64")]
use crate::accel::block_test::{LANES, Lanes, gather_test_avx2};
use crate::accel::{Hit, PrimHit, Primitives, RayPrecomp, brute_force_intersect};
use crate::geometry::{Aabb, Ray};

/// Hints the cache to load `p`'s line (no effect on results; nothing is dereferenced).
#[inline(always)]
pub(in crate::accel) fn prefetch<T>(p: *const T) {
    // SAFETY: a prefetch is a hint; it never faults and reads no memory into the
    // program, whatever the address (SSE is part of the x86_64 baseline).
    #[cfg(target_arch = "x86_64")]
    unsafe {
        core::arch::x86_64::_mm_prefetch::<{ core::arch::x86_64::_MM_HINT_T0 }>(p.cast())
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// Slack relative to the ray's reach across the scene (128 ulps): covers the relative
/// error of the split distances (3 roundings) and the watertight test's `t` error
/// (about 20 ulps of the largest vertex depth).
const SLACK_REL: f32 = 1.0 / 65536.0;

/// Relative margin above the nearest hit within which hits are collected (512 ulps).
const NEAR_REL: f32 = 1.0 / 16384.0;

/// A primitive accepts any `tmax >= t · (1 + ACCEPT_REL)` (+ `TINY`): for the
/// watertight triangle test `t·det` vs `tmax·det` differ by a few roundings.
const ACCEPT_REL: f32 = 16.0 * f32::EPSILON;
const TINY: f32 = 1e-30;

/// Most close hits kept; more (a ray through a vertex of very high valence) falls back
/// to the brute-force loop.
const CANDIDATES: usize = 16;

pub(in crate::accel) struct Setup {
    pub(in crate::accel) lo: f32,
    pub(in crate::accel) hi: f32,
    pub(in crate::accel) slack: f32,
}

/// Clips the ray to `cell` (the primitives' padded extents), widened by the slack
/// that covers the rounding of plane distances and hit distances.
#[inline(always)]
pub(in crate::accel) fn clip_to_cell(b: &Aabb, ray: &Ray, inv: Vec3, tmax: f32) -> Option<Setup> {
    let t0 = (b.min - ray.origin) * inv;
    let t1 = (b.max - ray.origin) * inv;
    let (mut near, mut far) = (f32::NEG_INFINITY, f32::INFINITY);
    for a in 0..3 {
        // NaN (0 · inf): the ray lies in a face's plane and never leaves the slab.
        let (n, f) = if t0[a] <= t1[a] {
            (t0[a], t1[a])
        } else if t1[a] < t0[a] {
            (t1[a], t0[a])
        } else {
            continue;
        };
        near = near.max(n);
        far = far.min(f);
    }
    let reach = (b.min - ray.origin).abs().max((b.max - ray.origin).abs()).max_element();
    // 1 / max|d| as min|1/d| (the same value: reciprocals are monotone): no division.
    let slack = SLACK_REL * reach * inv.abs().min_element();
    let lo = (near - slack).max(0.0);
    let hi = far.min(tmax) + slack;
    (lo <= hi).then_some(Setup { lo, hi, slack })
}

impl KdTree {
    /// Clips the ray to the root cell, widened by the slack.
    #[inline(always)]
    pub(super) fn setup(&self, ray: &Ray, inv: Vec3, tmax: f32) -> Option<Setup> {
        if self.root & 3 == EMPTY {
            return None;
        }
        clip_to_cell(&self.cell, ray, inv, tmax)
    }

    /// Walks the tree front to back, a treelet (three levels) per step, calling `leaf`
    /// with each leaf's primitives; `leaf` returns the new bound (nodes starting beyond
    /// `bound + slack` are skipped) or NaN to stop. `AVX2`: take the treelet steps in
    /// eight lanes.
    ///
    /// Every child is checked against the bound when its parent's step keeps it, and
    /// again when it is popped, as `bound` only changes at leaves. The nearest child is
    /// taken at once, the others pushed.
    #[inline(always)]
    fn walk<const AVX2: bool>(
        &self,
        ray: &Ray,
        inv: Vec3,
        s: &Setup,
        mut bound: f32,
        mut leaf: impl FnMut(&[u32]) -> f32,
    ) {
        let slack = s.slack;
        let mut reach = bound + slack;
        if !(s.lo <= reach) {
            return;
        }
        let axes = RayAxes {
            o: ray.origin.to_array(),
            inv: inv.to_array(),
            // By the sign bit, so that -0 and +0 agree with the sign of `inv`. A plane
            // behind the origin needs no case of its own: the near side gets nothing
            // unless the plane is within the slack.
            neg: ray.dir.to_array().map(|x| x.is_sign_negative()),
            slack,
        };
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `AVX2` is set only on the paths `InstructionSet::Avx2` selects.
        let lanes = AVX2.then(|| unsafe { RayLanes::new(&axes) });
        #[cfg(not(target_arch = "x86_64"))]
        let lanes: Option<std::convert::Infallible> = None;
        let mut st = Stack::new();
        let bases = (self.treelets.as_ptr() as usize, self.leaves.as_ptr() as usize);
        let (mut r, mut lo, mut hi) = (self.root, s.lo, s.hi);
        loop {
            let at = (r >> 2) as usize;
            let next = match r & 3 {
                TREELET => {
                    let t = &self.treelets[at];
                    match &lanes {
                        #[cfg(target_arch = "x86_64")]
                        // SAFETY: `lanes` exists only on the AVX2 paths.
                        Some(lanes) => unsafe { step_avx2(&mut st, t, lanes, lo, hi, reach, bases) },
                        _ => {
                            Self::prefetch_children(t, bases);
                            st.step(t, &axes, lo, hi, reach)
                        }
                    }
                }
                kind => {
                    // One call of `leaf`, so that it inlines.
                    let one = [r >> 2];
                    let ids: &[u32] = match kind {
                        LEAF => &self.leaves[at + 1..at + 1 + self.leaves[at] as usize],
                        ONE => &one,
                        _ => &[],
                    };
                    if !ids.is_empty() {
                        bound = leaf(ids);
                        if bound.is_nan() {
                            return;
                        }
                        reach = bound + slack;
                    }
                    None
                }
            };
            match next {
                Some(n) => (r, lo, hi) = n,
                None => loop {
                    let Some(e) = st.pop() else { return };
                    if e.1 <= reach {
                        (r, lo, hi) = e;
                        break;
                    }
                },
            }
        }
    }

    /// Starts loading the lines of all of `t`'s children, before the step decides which
    /// are needed: the nearest one is needed right after it, and waiting for that load
    /// is most of a walk's time on a large tree; prefetching all children beats
    /// prefetching only the pushed ones (`bench/RESULTS.md`). Branch-free: the
    /// kinds are unpredictable, and the other kinds fetch the first treelet's line, which
    /// is in the cache. (The eight-lane step does the same in vector registers.)
    #[inline(always)]
    fn prefetch_children(t: &Treelet, (tb, lb): (usize, usize)) {
        for &c in &t.child {
            let i = (c >> 2) as usize;
            let a = match c & 3 {
                TREELET => tb.wrapping_add(64 * i),
                LEAF => lb.wrapping_add(4 * i),
                _ => tb,
            };
            prefetch(a as *const u8);
        }
    }

    // The whole query is compiled for AVX2, not just the leaf test, so that the test
    // inlines into the walk. Only wider registers, never fused multiply-adds (Rust does
    // not contract `a * b + c`): the bits are the baseline's.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn intersect_avx2<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        self.intersect_impl::<P, true>(prims, ray, tmax)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn occluded_avx2<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        self.occluded_impl::<P, true>(prims, ray, tmax)
    }

    #[inline(always)]
    pub(super) fn intersect_impl<P: Primitives, const AVX2: bool>(
        &self,
        prims: &P,
        ray: &Ray,
        tmax: f32,
    ) -> Option<Hit> {
        let pre = RayPrecomp::new(ray);
        let s = self.setup(ray, pre.inv_dir, tmax)?;
        let mut c = Closest::new(tmax, s.slack);
        let corners = gatherable(prims);
        self.walk::<AVX2>(ray, pre.inv_dir, &s, tmax, |ids| c.leaf::<P, AVX2>(prims, corners, ids, ray, &pre));
        c.finish(prims, ray, &pre, tmax)
    }

    #[inline(always)]
    pub(super) fn occluded_impl<P: Primitives, const AVX2: bool>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        let pre = RayPrecomp::new(ray);
        let Some(s) = self.setup(ray, pre.inv_dir, tmax) else { return false };
        let corners = gatherable(prims);
        let mut hit = false;
        self.walk::<AVX2>(ray, pre.inv_dir, &s, tmax, |ids| {
            any_leaf::<P, AVX2>(prims, corners, ids, ray, &pre, tmax, &mut hit)
        });
        hit
    }
}

/// One ray's closest-hit query across the leaves a walk visits: the candidates and the
/// mailbox.
pub(in crate::accel) struct Closest {
    c: Candidates,
    mb: Mailbox,
}

impl Closest {
    #[inline(always)]
    pub(in crate::accel) fn new(tmax: f32, slack: f32) -> Self {
        Self { c: Candidates::new(tmax, slack), mb: Mailbox::new() }
    }

    /// Tests a leaf's primitives `ids`; returns the walk's new bound, or NaN to stop.
    #[inline(always)]
    pub(in crate::accel) fn leaf<P: Primitives, const AVX2: bool>(
        &mut self,
        prims: &P,
        corners: &[[glam::Vec3; 3]],
        ids: &[u32],
        ray: &Ray,
        pre: &RayPrecomp,
    ) -> f32 {
        let c = &mut self.c;
        if AVX2 && ids.len() >= GATHER_MIN_PRIMS && !corners.is_empty() {
            // Eight at a time; a hit already recorded comes back the same and is
            // dropped by `record`, so the mailbox is not needed here.
            leaf_lanes(prims, corners, ids, ray, pre, c.bound, |g, h| {
                c.record(g, h);
                if c.overflow { f32::NAN } else { c.bound }
            });
        } else {
            prefetch_all(prims, ids);
            for &g in ids {
                if self.mb.seen(g) {
                    continue;
                }
                if let Some(h) = prims.intersect(g, ray, pre, c.bound) {
                    c.record(g, h);
                }
            }
        }
        if c.overflow { f32::NAN } else { c.bound }
    }

    /// The answer once the walk is over.
    #[inline(always)]
    pub(in crate::accel) fn finish<P: Primitives>(
        &mut self,
        prims: &P,
        ray: &Ray,
        pre: &RayPrecomp,
        tmax: f32,
    ) -> Option<Hit> {
        if self.c.overflow {
            return brute_force_intersect(prims, ray, tmax);
        }
        self.c.resolve(prims, ray, pre, tmax)
    }
}

/// Tests a leaf's primitives `ids` for an any-hit query: sets `hit` and returns NaN (stop)
/// at the first hit, else `tmax`. No mailbox: the query ends at its first hit, so few
/// primitives come up twice and the bookkeeping would not pay.
#[inline(always)]
pub(in crate::accel) fn any_leaf<P: Primitives, const AVX2: bool>(
    prims: &P,
    corners: &[[glam::Vec3; 3]],
    ids: &[u32],
    ray: &Ray,
    pre: &RayPrecomp,
    tmax: f32,
    hit: &mut bool,
) -> f32 {
    if AVX2 && ids.len() >= GATHER_MIN_PRIMS && !corners.is_empty() {
        leaf_lanes(prims, corners, ids, ray, pre, tmax, |_, _| {
            *hit = true;
            f32::NAN
        });
    } else {
        prefetch_all(prims, ids);
        *hit = ids.iter().any(|&g| prims.occludes(g, ray, pre, tmax));
    }
    if *hit { f32::NAN } else { tmax }
}

/// Leaves with at least this many primitives test their triangles eight at a time.
const GATHER_MIN_PRIMS: usize = 2;

/// The set's triangles for the eight-lane leaf test, or nothing if it has none or too
/// many to address.
#[inline(always)]
pub(in crate::accel) fn gatherable<P: Primitives>(prims: &P) -> &[[glam::Vec3; 3]] {
    let c = prims.triangle_corners();
    if c.len() <= crate::accel::block_test::GATHER_MAX_TRIANGLES { c } else { &[] }
}

/// Tests a leaf's primitives `ids` in groups of eight: triangles by the eight-lane pass
/// (corners gathered by index), finished with the current `tmax`, the rest (and
/// triangles on an edge) by their own test. Each hit goes to `hit`, which returns the
/// `tmax` to go on with (never larger) or NaN to stop. The same hits as testing each
/// primitive in turn with the current `tmax`.
#[inline(always)]
fn leaf_lanes<P: Primitives>(
    prims: &P,
    corners: &[[glam::Vec3; 3]],
    ids: &[u32],
    ray: &Ray,
    pre: &RayPrecomp,
    mut tmax: f32,
    mut hit: impl FnMut(u32, PrimHit) -> f32,
) {
    #[cfg(target_arch = "x86_64")]
    {
        let mut lanes = Lanes::default();
        // The first group's gathers load their corners together; start the others'
        // loads now too, so that no group waits for its own misses.
        if ids.len() > LANES {
            prefetch_all(prims, &ids[LANES..]);
        }
        for group in ids.chunks(LANES) {
            // SAFETY: the callers run this only on the AVX2 paths `InstructionSet::Avx2` selects.
            let (keep, zero, other) = unsafe { gather_test_avx2(corners, group, &pre.shear, tmax, &mut lanes) };
            let scalar = zero | other;
            let mut m = keep | other;
            while m != 0 {
                let lane = m.trailing_zeros() as usize;
                m &= m - 1;
                let g = group[lane];
                let h = if scalar & (1 << lane) != 0 {
                    prims.intersect(g, ray, pre, tmax)
                } else {
                    lanes.finish(lane, tmax)
                };
                if let Some(h) = h {
                    tmax = hit(g, h);
                    if tmax.is_nan() {
                        return;
                    }
                }
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (prims, corners, ids, ray, pre, tmax, &mut hit);
        unreachable!("the eight-lane leaf test runs on x86_64 only");
    }
}

/// Starts loading every primitive of a leaf before the first test, so that the misses
/// overlap instead of each waiting for the previous test (whose branch mispredictions
/// would cancel loads issued speculatively).
#[inline(always)]
fn prefetch_all<P: Primitives>(prims: &P, ids: &[u32]) {
    if ids.len() > 1 {
        for &g in ids {
            prims.prefetch(g);
        }
    }
}

/// Slots of the [`Mailbox`].
const MAILBOX: usize = 32;

/// The primitives tested recently in this query, by index modulo [`MAILBOX`] (a later
/// one evicts an earlier one in its slot). A primitive listed in several leaves along
/// the ray (there are 2.7 listings per triangle on the 1M mesh) is tested once: the
/// test is a function of the primitive and `tmax`, and `tmax` only shrinks during a
/// query, so a primitive that missed misses again, and one that hit gives the same hit,
/// which the query has already seen. Forgetting one (eviction) only costs a test.
/// Closest-hit only: it keeps going past its first hits into the next leaves, which
/// list many of the same triangles.
struct Mailbox([u32; MAILBOX]);

impl Mailbox {
    /// Slot k starts with k + 1, which no index kept in slot k can equal.
    const EMPTY: [u32; MAILBOX] = {
        let mut m = [0; MAILBOX];
        let mut k = 0;
        while k < MAILBOX {
            m[k] = k as u32 + 1;
            k += 1;
        }
        m
    };

    #[inline(always)]
    fn new() -> Self {
        Self(Self::EMPTY)
    }

    /// Whether `g` was tested in this query (as far as remembered); remembers it.
    #[inline(always)]
    fn seen(&mut self, g: u32) -> bool {
        let slot = &mut self.0[g as usize % MAILBOX];
        let seen = *slot == g;
        *slot = g;
        seen
    }
}

/// The hits collected so far within `bound` of the nearest.
struct Candidates {
    n: usize,
    prim: [u32; CANDIDATES],
    hit: [PrimHit; CANDIDATES],
    tmin: f32,
    /// Hits are collected below this: `tmax`, or the nearest hit plus the margin.
    bound: f32,
    tmax: f32,
    slack: f32,
    overflow: bool,
}

impl Candidates {
    #[inline]
    fn new(tmax: f32, slack: f32) -> Self {
        let none = PrimHit { t: 0.0, u: 0.0, v: 0.0, sub: 0 };
        Self {
            n: 0,
            prim: [0; CANDIDATES],
            hit: [none; CANDIDATES],
            tmin: f32::INFINITY,
            bound: tmax,
            tmax,
            slack,
            overflow: false,
        }
    }

    #[inline]
    fn record(&mut self, g: u32, h: PrimHit) {
        // The same primitive listed in several leaves gives the same hit again.
        if !(h.t < self.bound) || self.prim[..self.n].contains(&g) {
            return;
        }
        if self.n == CANDIDATES {
            let mut k = 0;
            for i in 0..self.n {
                if self.hit[i].t < self.bound {
                    self.prim[k] = self.prim[i];
                    self.hit[k] = self.hit[i];
                    k += 1;
                }
            }
            self.n = k;
            if k == CANDIDATES {
                self.overflow = true;
                return;
            }
        }
        self.prim[self.n] = g;
        self.hit[self.n] = h;
        self.n += 1;
        if h.t < self.tmin {
            self.tmin = h.t;
            self.bound = self.tmax.min(h.t + self.slack + h.t * NEAR_REL);
        }
    }

    /// The brute-force answer from the collected hits (see the module comment).
    fn resolve<P: Primitives>(&mut self, prims: &P, ray: &Ray, pre: &RayPrecomp, tmax: f32) -> Option<Hit> {
        let n = self.n;
        if n == 0 {
            return None;
        }
        // Insertion sort by t: n is tiny.
        for i in 1..n {
            let mut j = i;
            while j > 0 && self.hit[j].t < self.hit[j - 1].t {
                self.hit.swap(j, j - 1);
                self.prim.swap(j, j - 1);
                j -= 1;
            }
        }
        // The close group: hits chained to the nearest by gaps within the acceptance
        // margin; the first larger gap separates it from hits that cannot matter.
        let mut near_max = self.hit[0].t;
        let mut k = 1;
        while k < n && self.hit[k].t <= near_max * (1.0 + ACCEPT_REL) + TINY {
            near_max = self.hit[k].t;
            k += 1;
        }
        // Hits not collected lie at or just below `bound`; they are harmless only if the
        // group accepts them as tmax, i.e. the group ends well below `bound`.
        if self.bound < tmax && near_max * (1.0 + 3.0 * ACCEPT_REL) + TINY >= self.bound {
            return brute_force_intersect(prims, ray, tmax);
        }
        if k == 1 {
            let h = self.hit[0];
            return Some(Hit { t: h.t, prim: prims.hit_prim(self.prim[0], &h), u: h.u, v: h.v });
        }
        let group = &mut self.prim[..k];
        group.sort_unstable();
        let mut best = None;
        let mut t = tmax;
        for &g in group.iter() {
            if let Some(h) = prims.intersect(g, ray, pre, t) {
                t = h.t;
                best = Some(Hit { t: h.t, prim: prims.hit_prim(g, &h), u: h.u, v: h.v });
            }
        }
        best
    }
}
