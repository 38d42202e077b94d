//! The build: a binary tree by binned SAH over the primitives' centroids (in parallel
//! below the top, the same tree on any number of threads), then collapsed into wide
//! nodes by opening, while a node has room, the child of largest surface area.
//!
//! Boxes are the primitives' extents padded as the kd-tree pads them (the hit tests
//! decide on rounded coordinates and can report a hit a rounding error outside a
//! primitive), so the traversal's intervals contain every hit the brute-force loop finds.

use glam::Vec4;
use rayon::prelude::*;

use super::{Bvh8, Bvh8Params, Bvh8Stats, EMPTY, LEAF, MAX_LEAF, NODE, Node8, ONE, WIDTH, leaf_first};
use crate::accel::Primitives;
use crate::accel::block_test::InstructionSet;
use crate::accel::exact::pad_extent;
use crate::geometry::Aabb;

/// Bins per axis of the SAH sweep.
const BINS: usize = 16;
/// Subtrees of at least this many primitives build their halves in parallel.
const PARALLEL_MIN: usize = 4096;
/// Deepest binary level: deeper sets become one leaf, whatever their size (it keeps the
/// traversal's fixed stack sufficient). Reached only by pathological inputs.
pub(super) const MAX_BINARY_DEPTH: usize = 60;

/// A binary node: a leaf over `ids[start..start + len]`, or two children.
enum Binary {
    Leaf { b: Aabb, start: usize, len: usize },
    Inner { b: Aabb, kids: Box<[Binary; 2]> },
}

impl Binary {
    fn bounds(&self) -> Aabb {
        match self {
            Binary::Leaf { b, .. } | Binary::Inner { b, .. } => *b,
        }
    }
}

/// A box in SIMD lanes (x, y, z; the fourth lane is not a coordinate): the build's
/// passes over millions of primitives take two vector operations per union, not six.
#[derive(Clone, Copy)]
struct Box4 {
    lo: Vec4,
    hi: Vec4,
}

impl Box4 {
    const EMPTY: Box4 = Box4 { lo: Vec4::splat(f32::INFINITY), hi: Vec4::splat(f32::NEG_INFINITY) };

    #[inline(always)]
    fn union(self, o: Box4) -> Box4 {
        Box4 { lo: self.lo.min(o.lo), hi: self.hi.max(o.hi) }
    }

    #[inline(always)]
    fn grow(self, p: Vec4) -> Box4 {
        Box4 { lo: self.lo.min(p), hi: self.hi.max(p) }
    }

    fn aabb(self) -> Aabb {
        Aabb::new(self.lo.truncate(), self.hi.truncate())
    }
}

/// A primitive as the build moves it: its padded box, with its index in the low box's
/// fourth lane (see [`Ref::new`]). Partitioning these (rather than indices into a table
/// of boxes) keeps every pass sequential in memory; 32 bytes, two to a cache line.
#[derive(Clone, Copy)]
struct Ref {
    b: Box4,
}

/// Added to an index to make its lane's bits a float from 1.0 up (finite below 2^30
/// indices), so that no sum, half, min or max in that lane comes near a subnormal or a
/// NaN. Subnormals take the vector units' slow path, and on the Intel host measured so
/// did results at the smallest normal exponent: with the former bias, 2^24 (floats from
/// 2^-125, halves from 2^-126), the whole build ran as slowly as that path makes it, and
/// as fast as now once subnormals were flushed to zero (a test only; no flag was raised).
const ID_BIAS: u32 = 0x3f80_0000; // 1.0

impl Ref {
    fn new(b: Aabb, id: u32) -> Self {
        debug_assert!(id < 1 << 30);
        Ref { b: Box4 { lo: b.min.extend(f32::from_bits(id + ID_BIAS)), hi: b.max.extend(0.0) } }
    }

    fn id(&self) -> u32 {
        self.b.lo.w.to_bits() - ID_BIAS
    }

    /// The centroid (its fourth lane is not a coordinate).
    #[inline(always)]
    fn c(&self) -> Vec4 {
        (self.b.lo + self.b.hi) * 0.5
    }
}

/// Boxes and centroid bounds of a set of refs.
fn bounds_of(refs: &[Ref]) -> (Box4, Box4) {
    refs.iter().fold((Box4::EMPTY, Box4::EMPTY), |(b, cb), r| (b.union(r.b), cb.grow(r.c())))
}

pub(super) fn build<P: Primitives>(prims: &P, params: &Bvh8Params) -> Bvh8 {
    let n = prims.len();
    assert!(n < 1 << 30, "bvh: at most 2^30 primitives");
    let raw: Vec<Aabb> = (0..n as u32).into_par_iter().map(|i| prims.bounds(i)).collect();
    let valid = |b: &Aabb| !b.is_empty() && b.min.is_finite() && b.max.is_finite();
    let scene = raw.iter().filter(|b| valid(b)).fold(Aabb::EMPTY, |a, b| a.union(*b));
    let magnitude = scene.min.abs().max(scene.max.abs()).max_element();
    let mut refs: Vec<Ref> = raw
        .par_iter()
        .enumerate()
        .filter(|(_, b)| valid(b))
        .map(|(i, b)| Ref::new(pad_extent(*b, magnitude), i as u32))
        .collect();
    drop(raw);
    // Min and max are exact, so the reduction's grouping does not change the result.
    let (b, cb) = refs
        .par_chunks(1 << 16)
        .map(bounds_of)
        .reduce(|| (Box4::EMPTY, Box4::EMPTY), |(b0, c0), (b1, c1)| (b0.union(b1), c0.union(c1)));
    let root = (!refs.is_empty()).then(|| split(params, &mut refs, Span { start: 0, depth: 0, b, cb }));
    let ids: Vec<u32> = refs.iter().map(Ref::id).collect();
    drop(refs);
    let mut out = Collapse { ids: &ids, nodes: Vec::new(), leaves: Vec::new(), leaf_count: 0, filled: 0, depth: 0 };
    let root_ref = match &root {
        Some(r) => out.reference(r, 0),
        None => EMPTY,
    };
    let cell = root.as_ref().map_or(Aabb::EMPTY, Binary::bounds);
    let scene = if root.is_some() { scene } else { Aabb::EMPTY };
    let (nodes, leaves) = (out.nodes, out.leaves);
    let stats = Bvh8Stats {
        nodes: nodes.len(),
        leaves: out.leaf_count,
        mean_children: out.filled as f64 / nodes.len().max(1) as f64,
        mean_leaf_prims: ids.len() as f64 / out.leaf_count.max(1) as f64,
        max_depth: out.depth,
        bytes: nodes.len() * size_of::<Node8>() + leaves.len() * size_of::<u32>(),
    };
    Bvh8 { nodes, leaves, root: root_ref, bounds: scene, cell, stats, simd: InstructionSet::detect() }
}

/// Where a set of refs sits: its offset in the whole array, its binary depth, and its
/// boxes' and centroids' bounds (found by the parent's partition).
struct Span {
    start: usize,
    depth: usize,
    b: Box4,
    cb: Box4,
}

/// Splits `refs` by the best binned SAH plane, or makes a leaf when that is cheaper
/// (and the leaf fits one eight-lane pass).
fn split(params: &Bvh8Params, refs: &mut [Ref], at: Span) -> Binary {
    let n = refs.len();
    let (b, cb) = (at.b.aabb(), at.cb.aabb());
    let leaf = Binary::Leaf { b, start: at.start, len: n };
    if n == 1 || at.depth >= MAX_BINARY_DEPTH {
        return leaf;
    }
    let (ct, ci) = (params.traversal_cost, params.intersection_cost);
    let area = b.surface_area();
    let binner = Binner::new(&cb);
    let best = best_split(refs, &cb, &binner);
    let (left, sides) = match best {
        Some((axis, bin, cost)) => {
            let split_cost = ct + ci * cost / area;
            if n <= MAX_LEAF && ci * n as f32 <= split_cost {
                return leaf;
            }
            partition(refs, |c| binner.bin_on(axis, c) <= bin)
        }
        // All centroids in one point: halve by index until leaves fit.
        None if n <= MAX_LEAF => return leaf,
        None => (n / 2, [bounds_of(&refs[..n / 2]), bounds_of(&refs[n / 2..])]),
    };
    let (l, r) = refs.split_at_mut(left);
    let [(lb, lcb), (rb, rcb)] = sides;
    let ls = Span { start: at.start, depth: at.depth + 1, b: lb, cb: lcb };
    let rs = Span { start: at.start + left, depth: at.depth + 1, b: rb, cb: rcb };
    let (l, r) = if n >= PARALLEL_MIN {
        rayon::join(|| split(params, l, ls), || split(params, r, rs))
    } else {
        (split(params, l, ls), split(params, r, rs))
    };
    Binary::Inner { b, kids: Box::new([l, r]) }
}

/// The bins of a node's centroid bounds: the same function in the sweep and the
/// partition, so the sides have the sweep's counts.
struct Binner {
    min: Vec4,
    scale: Vec4,
}

impl Binner {
    fn new(cb: &Aabb) -> Self {
        // A flat axis gets scale 0 (every centroid in bin 0; the sweep skips it), and a
        // scale that would overflow (a subnormal extent) is capped at the largest float,
        // so no bin is computed from a NaN or an infinity.
        let scale = [0, 1, 2].map(|a| {
            let extent = cb.max[a] - cb.min[a];
            let s = BINS as f32 * (1.0 - 1.0 / 65536.0) / extent;
            if extent > 0.0 { s.min(f32::MAX) } else { 0.0 }
        });
        Self { min: cb.min.extend(0.0), scale: Vec4::new(scale[0], scale[1], scale[2], 0.0) }
    }

    /// Bins of centroid `c` along the three axes.
    #[inline(always)]
    fn bin(&self, c: Vec4) -> [usize; 3] {
        // Clamped in floats, so the conversions are exact truncations.
        let f = ((c - self.min) * self.scale).clamp(Vec4::ZERO, Vec4::splat((BINS - 1) as f32));
        [f.x as usize, f.y as usize, f.z as usize]
    }

    /// Bin of centroid `c` along `axis`: `bin(c)[axis]`, by the same operations.
    #[inline(always)]
    fn bin_on(&self, axis: usize, c: Vec4) -> usize {
        ((c[axis] - self.min[axis]) * self.scale[axis]).clamp(0.0, (BINS - 1) as f32) as usize
    }
}

/// The cheapest plane between bins: `(axis, last bin on the left, A_l n_l + A_r n_r)`,
/// the first of equals (axes in order); `None` when the centroids do not spread on any
/// axis. One pass over the refs bins all three axes.
fn best_split(refs: &[Ref], cb: &Aabb, binner: &Binner) -> Option<(usize, usize, f32)> {
    let mut count = [[0u32; BINS]; 3];
    let mut bounds = [[Box4::EMPTY; BINS]; 3];
    for r in refs {
        let k = binner.bin(r.c());
        for axis in 0..3 {
            count[axis][k[axis]] += 1;
            bounds[axis][k[axis]] = bounds[axis][k[axis]].union(r.b);
        }
    }
    let mut best: Option<(usize, usize, f32)> = None;
    for axis in 0..3 {
        if !(cb.max[axis] > cb.min[axis]) {
            continue;
        }
        let (count, bounds) = (&count[axis], &bounds[axis]);
        // Right sides' costs, from the last bin down.
        let mut right = [0.0f32; BINS];
        let (mut rb, mut rn) = (Box4::EMPTY, 0u32);
        for k in (1..BINS).rev() {
            rb = rb.union(bounds[k]);
            rn += count[k];
            right[k] = if rn == 0 { f32::INFINITY } else { rb.aabb().surface_area() * rn as f32 };
        }
        let (mut lb, mut ln) = (Box4::EMPTY, 0u32);
        for k in 0..BINS - 1 {
            lb = lb.union(bounds[k]);
            ln += count[k];
            if ln == 0 || right[k + 1].is_infinite() {
                continue;
            }
            let cost = lb.aabb().surface_area() * ln as f32 + right[k + 1];
            if best.is_none_or(|b| cost < b.2) {
                best = Some((axis, k, cost));
            }
        }
    }
    best
}

/// Moves the refs whose centroids `left` takes to the front (stable for neither side);
/// how many, and each side's boxes' and centroids' bounds (each ref is looked at once).
fn partition(refs: &mut [Ref], left: impl Fn(Vec4) -> bool) -> (usize, [(Box4, Box4); 2]) {
    let (mut i, mut j) = (0, refs.len());
    let (mut lb, mut lc, mut rb, mut rc) = (Box4::EMPTY, Box4::EMPTY, Box4::EMPTY, Box4::EMPTY);
    while i < j {
        let r = refs[i];
        let c = r.c();
        if left(c) {
            lb = lb.union(r.b);
            lc = lc.grow(c);
            i += 1;
        } else {
            rb = rb.union(r.b);
            rc = rc.grow(c);
            j -= 1;
            refs.swap(i, j);
        }
    }
    (i, [(lb, lc), (rb, rc)])
}

/// The binary tree's collapse into wide nodes, depth first.
struct Collapse<'a> {
    ids: &'a [u32],
    nodes: Vec<Node8>,
    leaves: Vec<u32>,
    leaf_count: usize,
    filled: usize,
    depth: usize,
}

impl Collapse<'_> {
    /// The reference of binary node `b`, converting its subtree.
    fn reference(&mut self, b: &Binary, depth: usize) -> u32 {
        let (start, len) = match b {
            Binary::Inner { .. } => return self.node(b, depth),
            Binary::Leaf { start, len, .. } => (*start, *len),
        };
        self.leaf_count += 1;
        let prims = &self.ids[start..start + len];
        match prims {
            [] => EMPTY,
            // Fits beside the kind: fewer than 2^30 primitives.
            [one] => (one << 2) | ONE,
            _ => {
                let at = self.leaves.len();
                assert!(at < 1 << 30, "bvh: too many leaf references");
                self.leaves.push(prims.len() as u32);
                let from = self.leaves.len();
                self.leaves.extend_from_slice(prims);
                self.leaves[from..].sort_unstable();
                ((at as u32) << 2) | LEAF
            }
        }
    }

    /// A wide node over interior binary node `b`: its children, opened largest first
    /// while there is room.
    fn node(&mut self, b: &Binary, depth: usize) -> u32 {
        self.depth = self.depth.max(depth);
        let Binary::Inner { kids, .. } = b else { unreachable!("node() takes interior nodes") };
        let mut open: Vec<&Binary> = vec![&kids[0], &kids[1]];
        while open.len() < WIDTH {
            let widest = open
                .iter()
                .enumerate()
                .filter(|(_, k)| matches!(k, Binary::Inner { .. }))
                .max_by(|(_, a), (_, b)| a.bounds().surface_area().total_cmp(&b.bounds().surface_area()))
                .map(|(j, _)| j);
            let Some(j) = widest else { break };
            let Binary::Inner { kids, .. } = open[j] else { unreachable!() };
            open[j] = &kids[0];
            open.insert(j + 1, &kids[1]);
        }
        let at = self.nodes.len();
        assert!(at < 1 << 30, "bvh: too many nodes");
        self.nodes.push(Node8::EMPTY);
        self.filled += open.len();
        let mut node = Node8::EMPTY;
        for (j, k) in open.iter().enumerate() {
            let kb = k.bounds();
            for a in 0..3 {
                node.lo[a][j] = kb.min[a];
                node.hi[a][j] = kb.max[a];
            }
            node.child[j] = self.reference(k, depth + 1);
            node.first[j] = leaf_first(&self.leaves, node.child[j]);
        }
        self.nodes[at] = node;
        ((at as u32) << 2) | NODE
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn a_refs_index_lane_round_trips_and_stays_far_from_subnormals() {
        let b = Aabb::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(1.0, 0.5, 3.0));
        for id in [0, 1, 12_345, (1 << 23) - 1, 1 << 23, (1 << 30) - 1] {
            let r = Ref::new(b, id);
            assert_eq!(r.id(), id);
            // The sums and halves of the build's passes: far from subnormal, and finite.
            assert!(r.b.lo.w >= 1.0 && r.c().w >= 0.5 && r.c().w.is_finite(), "id {id}");
            assert_eq!(r.c().truncate(), b.center());
        }
    }

    #[test]
    fn one_axis_bins_are_the_three_axis_bins() {
        let cb = Aabb::new(Vec3::new(-2.0, 5.0, 1.0), Vec3::new(3.0, 5.0, 1.0 + 1e-6));
        let binner = Binner::new(&cb);
        for i in 0..=100 {
            let t = i as f32 / 100.0;
            let c = (cb.min + (cb.max - cb.min) * t).extend(7.0);
            let k = binner.bin(c);
            assert_eq!(k, [0, 1, 2].map(|a| binner.bin_on(a, c)));
            // y is flat: one bin; the ends of x are the first and last bins.
            assert_eq!(k[1], 0);
            assert!(k.iter().all(|&k| k < BINS));
        }
        assert_eq!(binner.bin(cb.min.extend(0.0))[0], 0);
        assert_eq!(binner.bin(cb.max.extend(0.0))[0], BINS - 1);
    }
}
