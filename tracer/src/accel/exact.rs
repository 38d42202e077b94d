//! Exact answers from a tree walk: the bookkeeping that makes a hierarchy's queries
//! bit-identical to [`brute_force_intersect`] / [`brute_force_occluded`], shared by the
//! kd-tree (`kdtree/`) and the BVH (`bvh8/`).
//!
//! The brute-force loop visits primitives in index order and accepts a hit when the
//! primitive's test passes with the current `tmax`. A tree visits them in another order,
//! so it must not simply keep "the smallest t":
//! * Ties and near-ties. Two primitives can be hit at the same or nearly the same `t`
//!   (shared edges and vertices, coplanar overlaps). The watertight test's acceptance of
//!   `t < tmax` is decided on `t·det`, so a hit with a smaller `t` can still be rejected
//!   when `tmax` is only an ulp or two above it. A query therefore collects every hit
//!   within a small margin of the nearest one (`bound`, [`Closest`]), and when more than
//!   one is that close it replays the brute-force loop over just those, in index order,
//!   from the query's `tmax`. Hits farther away than the margin cannot change that replay
//!   (each close primitive accepts any `tmax` that far above its own `t`), and once a
//!   close hit is accepted no far one can be. A hit is only final once the walk has
//!   passed `bound`.
//! * A primitive may be listed in several leaves (the kd-tree's) and its hit may lie
//!   outside the leaf being visited; candidates are deduplicated by index, and the walk
//!   goes on until no unvisited node can hold a hit below `bound`.
//! * Rounding in the plane distances and in the hit distances is covered by an absolute
//!   slack (in units of t) derived from the ray's distance to the scene ([`clip_to_cell`]),
//!   by which node intervals are widened; together with the padding of primitive extents
//!   ([`pad_extent`]), every leaf that could hold a reported hit is visited.
//!
//! [`brute_force_intersect`]: crate::accel::brute_force_intersect
//! [`brute_force_occluded`]: crate::accel::brute_force_occluded

use glam::Vec3;

#[cfg(target_arch = "x86_64")]
use super::block_test::{Gathered, LANES, Lanes, gather_avx2, gathered_test_avx2};
use super::{Hit, PrimHit, Primitives, RayPrecomp, brute_force_intersect};
use crate::geometry::{Aabb, Ray};

/// Padding relative to the largest coordinate magnitude of the scene: 2^-16 is 128 ulps,
/// far above the rounding of the triangle and sphere tests for ray origins up to ~30×
/// the scene's extent away, and far below any primitive size that matters.
pub(in crate::accel) const PAD_REL: f32 = 1.0 / 65536.0;

/// Pads the non-flat axes of extent `b` by `pad`.
pub(in crate::accel) fn pad_by(b: Aabb, pad: f32) -> Aabb {
    let mut r = b;
    for a in 0..3 {
        if b.min[a] < b.max[a] {
            r.min[a] -= pad;
            r.max[a] += pad;
        }
    }
    r
}

/// A primitive's extent padded as the kd-tree pads it, in a scene whose largest
/// coordinate magnitude is `magnitude` (`kdtree/build.rs` says why): what every
/// hierarchy over the same tests needs.
pub(in crate::accel) fn pad_extent(b: Aabb, magnitude: f32) -> Aabb {
    pad_by(b, magnitude * PAD_REL)
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
        if AVX2 && gathers(corners, ids) {
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

    /// [`Closest::leaf`] for a leaf of two to eight primitives already loaded in `g`
    /// (from the same triangles `leaf` would gather): the rays of a packet that reach a
    /// leaf test it from one load.
    ///
    /// # Safety
    /// AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(in crate::accel) unsafe fn leaf_gathered<P: Primitives>(
        &mut self,
        prims: &P,
        g: &Gathered,
        ids: &[u32],
        ray: &Ray,
        pre: &RayPrecomp,
    ) -> f32 {
        let c = &mut self.c;
        let mut lanes = Lanes::default();
        // SAFETY: AVX2 (this function's feature).
        unsafe {
            gathered_lanes(prims, g, ids, ray, pre, c.bound, &mut lanes, &mut |id, h| {
                c.record(id, h);
                if c.overflow { f32::NAN } else { c.bound }
            })
        };
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
    if AVX2 && gathers(corners, ids) {
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

/// [`any_leaf`] for a leaf of two to eight primitives already loaded in `g`, as
/// [`Closest::leaf_gathered`].
///
/// # Safety
/// AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(in crate::accel) unsafe fn any_leaf_gathered<P: Primitives>(
    prims: &P,
    g: &Gathered,
    ids: &[u32],
    ray: &Ray,
    pre: &RayPrecomp,
    tmax: f32,
    hit: &mut bool,
) -> f32 {
    let mut lanes = Lanes::default();
    // SAFETY: AVX2 (this function's feature).
    unsafe {
        gathered_lanes(prims, g, ids, ray, pre, tmax, &mut lanes, &mut |_, _| {
            *hit = true;
            f32::NAN
        })
    };
    if *hit { f32::NAN } else { tmax }
}

/// Whether a leaf of `ids` is tested eight at a time ([`Closest::leaf`], [`any_leaf`]),
/// its corners loaded by [`gather_avx2`].
#[inline(always)]
pub(in crate::accel) fn gathers(corners: &[[glam::Vec3; 3]], ids: &[u32]) -> bool {
    ids.len() >= GATHER_MIN_PRIMS && !corners.is_empty()
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
            let g = unsafe { gather_avx2(corners, group) };
            // SAFETY: as above.
            tmax = unsafe { gathered_lanes(prims, &g, group, ray, pre, tmax, &mut lanes, &mut hit) };
            if tmax.is_nan() {
                return;
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (prims, corners, ids, ray, pre, tmax, &mut hit);
        unreachable!("the eight-lane leaf test runs on x86_64 only");
    }
}

/// Tests one group of primitives `group` (at most eight) loaded in `g` ([`gather_avx2`]),
/// as [`leaf_lanes`] does each group; returns the `tmax` to go on with, NaN to stop.
///
/// # Safety
/// AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
#[allow(clippy::too_many_arguments)]
unsafe fn gathered_lanes<P: Primitives>(
    prims: &P,
    g: &Gathered,
    group: &[u32],
    ray: &Ray,
    pre: &RayPrecomp,
    mut tmax: f32,
    lanes: &mut Lanes,
    hit: &mut impl FnMut(u32, PrimHit) -> f32,
) -> f32 {
    let (keep, zero, other) = gathered_test_avx2(g, &pre.shear, tmax, lanes);
    let scalar = zero | other;
    let mut m = keep | other;
    while m != 0 {
        let lane = m.trailing_zeros() as usize;
        m &= m - 1;
        let id = group[lane];
        let h = if scalar & (1 << lane) != 0 { prims.intersect(id, ray, pre, tmax) } else { lanes.finish(lane, tmax) };
        if let Some(h) = h {
            tmax = hit(id, h);
            if tmax.is_nan() {
                return tmax;
            }
        }
    }
    tmax
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
