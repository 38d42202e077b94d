//! O(N log N) SAH build after Wald & Havran, "On building fast kd-trees for ray tracing,
//! and on doing that in O(N log N)" (2006): split events are sorted once per axis and
//! kept sorted while they are partitioned, straddling primitives are re-bounded by
//! clipping to each child ("perfect splits"), and flat primitives lying in a candidate
//! plane go to whichever side the SAH prefers.
//!
//! Primitive extents are padded by a small absolute margin (`Ctx::pad`) on their
//! non-flat axes. The intersection routines decide hits on rounded coordinates, so they
//! can report a hit for a ray that passes a rounding error outside a primitive; padding
//! makes every cell within that error of a primitive list it, so the tree finds exactly
//! the hits the brute-force loop finds. Axes on which a primitive is exactly flat need no
//! padding (its points lie exactly on the plane) and keep Wald–Havran's planar handling.

use glam::Vec3;
use rayon::prelude::*;

use super::{BuildParams, Node};
use crate::accel::Primitives;
use crate::geometry::Aabb;

const END: u32 = 0;
const PLANAR: u32 = 1;
const START: u32 = 2;
const IDX_BITS: u32 = 30;
const IDX_MASK: u32 = (1 << IDX_BITS) - 1;

/// Nodes with at least this many primitive references build their children in parallel
/// (above it the `rayon::join` overhead is negligible against the work).
const PAR_MIN_PRIMS: usize = 4096;
/// Parallel recursion stops at this depth: 2^8 tasks keep any thread count busy, and
/// each parallel level costs one copy of its subtrees' nodes when they are stitched.
const PAR_MAX_DEPTH: u32 = 8;
/// Per-node work (sweeps, partitioning) is spread over the three axes above this size.
const PAR_AXES_MIN_PRIMS: usize = 32 * 1024;

/// Padding relative to the largest coordinate magnitude of the scene: 2^-16 is 128 ulps,
/// far above the rounding of the triangle and sphere tests for ray origins up to ~30×
/// the scene's extent away, and far below any primitive size that matters.
const PAD_REL: f32 = 1.0 / 65536.0;

/// A split event: position and, packed in `code`, the kind (top 2 bits, ordered
/// end < planar < start as the sweep needs) and the primitive's index in its node.
#[derive(Clone, Copy, Debug)]
struct Event {
    pos: f32,
    code: u32,
}

impl Event {
    #[inline]
    fn new(pos: f32, kind: u32, idx: u32) -> Self {
        // `+ 0.0` turns -0.0 into +0.0 so equal positions have equal keys.
        Self { pos: pos + 0.0, code: (kind << IDX_BITS) | idx }
    }
    #[inline]
    fn kind(self) -> u32 {
        self.code >> IDX_BITS
    }
    #[inline]
    fn idx(self) -> usize {
        (self.code & IDX_MASK) as usize
    }
    /// Total order (position, kind, index): sorting by it is deterministic.
    #[inline]
    fn key(self) -> u64 {
        let b = self.pos.to_bits();
        let ord = if b >> 31 == 1 { !b } else { b | 0x8000_0000 };
        ((ord as u64) << 32) | self.code as u64
    }
}

/// A node under construction: its cell, its primitives (global ids; an event's index
/// refers to this list) and the sorted events of each axis.
struct Work {
    cell: Aabb,
    prims: Vec<u32>,
    events: [Vec<Event>; 3],
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
    assert!(n <= IDX_MASK as usize, "kd-tree: at most 2^30 primitives");
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

    let ids: Vec<u32> = (0..n as u32).filter(|&i| valid(&bounds[i as usize])).collect();
    let regions: Vec<Aabb> = ids.iter().map(|&i| ctx.padded(bounds[i as usize])).collect();
    drop(bounds);
    let cell = regions.iter().fold(Aabb::EMPTY, |a, b| a.union(*b));
    let events = per_axis(true, |axis| {
        let mut ev = Vec::with_capacity(2 * regions.len());
        for (i, r) in regions.iter().enumerate() {
            push_events_axis(&mut ev, r, axis, i as u32);
        }
        ev.par_sort_unstable_by_key(|e| e.key());
        ev
    });
    drop(regions);
    build_rec(&ctx, Work { cell, prims: ids, events }, 0, &mut out);
    Built { out, bounds: scene, cell, max_depth }
}

impl<P: Primitives> Ctx<'_, P> {
    /// Pads the non-flat axes of an extent (see the module comment).
    fn padded(&self, b: Aabb) -> Aabb {
        let mut r = b;
        for a in 0..3 {
            if b.min[a] < b.max[a] {
                r.min[a] -= self.pad;
                r.max[a] += self.pad;
            }
        }
        r
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

    fn sah(&self, cell: &Aabb, axis: usize, events: &[Event], n: usize) -> Option<Split> {
        let d = cell.diagonal();
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        let cap = d[b] * d[c];
        let rim = d[b] + d[c];
        let inv_sa = 1.0 / cell.surface_area();
        let (lo, hi) = (cell.min[axis], cell.max[axis]);
        let (ct, ci, eb) = (self.traversal_cost, self.intersection_cost, self.empty_bonus);
        let cost = |pl: f32, pr: f32, nl: usize, nr: usize| {
            let bonus = if nl == 0 || nr == 0 { 1.0 - eb } else { 1.0 };
            ct + ci * bonus * (pl * nl as f32 + pr * nr as f32)
        };
        let mut best: Option<Split> = None;
        let (mut nl, mut nr) = (0usize, n);
        let mut i = 0;
        while i < events.len() {
            let p = events[i].pos;
            // Events at one position come ordered end < planar < start.
            let mut count = [0usize; 3];
            while i < events.len() && events[i].pos == p {
                count[events[i].kind() as usize] += 1;
                i += 1;
            }
            let [ends, planars, starts] = count;
            nr -= ends + planars;
            if p > lo && p < hi {
                let pl = 2.0 * (cap + (p - lo) * rim) * inv_sa;
                let pr = 2.0 * (cap + (hi - p) * rim) * inv_sa;
                let (c, planar_left) = if planars == 0 {
                    (cost(pl, pr, nl, nr), true)
                } else {
                    let left = cost(pl, pr, nl + planars, nr);
                    let right = cost(pl, pr, nl, nr + planars);
                    if left <= right { (left, true) } else { (right, false) }
                };
                if best.is_none_or(|b| c < b.cost) {
                    best = Some(Split { cost: c, axis, pos: p, planar_left });
                }
            }
            nl += starts + planars;
        }
        best
    }

    fn find_split(&self, w: &Work) -> Option<Split> {
        if !(w.cell.surface_area() > 0.0) {
            return None;
        }
        let n = w.prims.len();
        let splits = per_axis(n >= PAR_AXES_MIN_PRIMS, |a| self.sah(&w.cell, a, &w.events[a], n));
        splits.into_iter().flatten().reduce(|a, b| if b.cost < a.cost { b } else { a })
    }

    fn split(&self, w: Work, s: Split) -> (Work, Work) {
        const LEFT: u8 = 1;
        const RIGHT: u8 = 2;
        const BOTH: u8 = 3;
        /// Straddlers re-bounded into one child only; their old events are dropped.
        const LEFT_NEW: u8 = 4;
        const RIGHT_NEW: u8 = 5;
        const NEITHER: u8 = 6;
        let n = w.prims.len();
        let mut side = vec![BOTH; n];
        for e in &w.events[s.axis] {
            let here = match e.kind() {
                END if e.pos <= s.pos => LEFT,
                START if e.pos >= s.pos => RIGHT,
                PLANAR if e.pos < s.pos || (e.pos == s.pos && s.planar_left) => LEFT,
                PLANAR => RIGHT,
                _ => continue,
            };
            side[e.idx()] = here;
        }
        let mut lcell = w.cell;
        lcell.max[s.axis] = s.pos;
        let mut rcell = w.cell;
        rcell.min[s.axis] = s.pos;

        let mut lnew = Vec::new();
        let mut rnew = Vec::new();
        for (i, sd) in side.iter_mut().enumerate() {
            if *sd != BOTH {
                continue;
            }
            let g = w.prims[i];
            let (l, r) = (self.region(g, &lcell), self.region(g, &rcell));
            *sd = match (l.is_empty(), r.is_empty()) {
                (false, false) => BOTH,
                (false, true) => LEFT_NEW,
                (true, false) => RIGHT_NEW,
                (true, true) => NEITHER,
            };
            if !l.is_empty() {
                lnew.push((i, l));
            }
            if !r.is_empty() {
                rnew.push((i, r));
            }
        }

        let mut lmap = vec![u32::MAX; n];
        let mut rmap = vec![u32::MAX; n];
        let mut lprims = Vec::with_capacity(n);
        let mut rprims = Vec::with_capacity(n);
        for (i, &sd) in side.iter().enumerate() {
            if matches!(sd, LEFT | LEFT_NEW | BOTH) {
                lmap[i] = lprims.len() as u32;
                lprims.push(w.prims[i]);
            }
            if matches!(sd, RIGHT | RIGHT_NEW | BOTH) {
                rmap[i] = rprims.len() as u32;
                rprims.push(w.prims[i]);
            }
        }

        let parallel = n >= PAR_AXES_MIN_PRIMS;
        let (side, lmap, rmap, lnew, rnew) = (&side, &lmap, &rmap, &lnew, &rnew);
        let events = w.events;
        let per = per_axis(parallel, |a| {
            let mut l = Vec::with_capacity(events[a].len());
            let mut r = Vec::with_capacity(events[a].len());
            for &e in &events[a] {
                let i = e.idx();
                match side[i] {
                    LEFT => l.push(Event { pos: e.pos, code: (e.code & !IDX_MASK) | lmap[i] }),
                    RIGHT => r.push(Event { pos: e.pos, code: (e.code & !IDX_MASK) | rmap[i] }),
                    _ => {}
                }
            }
            let fresh = |new: &[(usize, Aabb)], map: &[u32]| {
                let mut ev = Vec::with_capacity(2 * new.len());
                for &(i, b) in new {
                    push_events_axis(&mut ev, &b, a, map[i]);
                }
                ev.sort_unstable_by_key(|e| e.key());
                ev
            };
            (merge(l, &fresh(lnew, lmap)), merge(r, &fresh(rnew, rmap)))
        });
        let [(lx, rx), (ly, ry), (lz, rz)] = per;
        (
            Work { cell: lcell, prims: lprims, events: [lx, ly, lz] },
            Work { cell: rcell, prims: rprims, events: [rx, ry, rz] },
        )
    }
}

fn build_rec<P: Primitives>(ctx: &Ctx<'_, P>, w: Work, depth: u32, out: &mut Out) {
    let n = w.prims.len();
    let split = if n <= ctx.max_leaf_prims || depth >= ctx.max_depth { None } else { ctx.find_split(&w) };
    // Automatic termination: a leaf costs `intersection_cost · n`; split only if cheaper.
    let Some(split) = split.filter(|s| s.cost < ctx.intersection_cost * n as f32) else {
        out.nodes.push(Node::leaf(&w.prims, &mut out.ids));
        return;
    };
    let (left, right) = ctx.split(w, split);
    let at = out.nodes.len();
    out.nodes.push(Node::default());
    let above = if n >= PAR_MIN_PRIMS && depth < PAR_MAX_DEPTH {
        let (lo, ro) = rayon::join(
            || {
                let mut o = Out::default();
                build_rec(ctx, left, depth + 1, &mut o);
                o
            },
            || {
                let mut o = Out::default();
                build_rec(ctx, right, depth + 1, &mut o);
                o
            },
        );
        out.append(lo);
        let above = out.nodes.len();
        out.append(ro);
        above
    } else {
        build_rec(ctx, left, depth + 1, out);
        let above = out.nodes.len();
        build_rec(ctx, right, depth + 1, out);
        above
    };
    out.nodes[at] = Node::interior(split.axis, split.pos, (above - at) as u32);
}

fn push_events_axis(ev: &mut Vec<Event>, b: &Aabb, axis: usize, idx: u32) {
    if b.min[axis] == b.max[axis] {
        ev.push(Event::new(b.min[axis], PLANAR, idx));
    } else {
        ev.push(Event::new(b.min[axis], START, idx));
        ev.push(Event::new(b.max[axis], END, idx));
    }
}

/// Merges two lists sorted by `Event::key`.
fn merge(a: Vec<Event>, b: &[Event]) -> Vec<Event> {
    if b.is_empty() {
        return a;
    }
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        if a[i].key() <= b[j].key() {
            out.push(a[i]);
            i += 1;
        } else {
            out.push(b[j]);
            j += 1;
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

/// Runs `f` for the three axes, on the rayon pool when `parallel`.
fn per_axis<T: Send>(parallel: bool, f: impl Fn(usize) -> T + Sync) -> [T; 3] {
    if parallel {
        let (x, (y, z)) = rayon::join(|| f(0), || rayon::join(|| f(1), || f(2)));
        [x, y, z]
    } else {
        [f(0), f(1), f(2)]
    }
}
