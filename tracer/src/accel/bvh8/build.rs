//! The build: a binary tree by binned SAH over the primitives' centroids (in parallel
//! below the top, the same tree on any number of threads), then collapsed into wide
//! nodes by opening, while a node has room, the child of largest surface area.
//!
//! Boxes are the primitives' extents padded as the kd-tree pads them (the hit tests
//! decide on rounded coordinates and can report a hit a rounding error outside a
//! primitive), so the traversal's intervals contain every hit the brute-force loop finds.

use glam::Vec3;
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

/// A primitive as the build moves it: padded box, centroid, index. Partitioning these
/// (rather than indices into a table of boxes) keeps every pass sequential in memory.
#[derive(Clone, Copy)]
struct Ref {
    b: Aabb,
    c: Vec3,
    id: u32,
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
        .map(|(i, b)| {
            let p = pad_extent(*b, magnitude);
            Ref { b: p, c: (p.min + p.max) * 0.5, id: i as u32 }
        })
        .collect();
    drop(raw);
    let root = (!refs.is_empty()).then(|| split(params, &mut refs, 0, 0));
    let ids: Vec<u32> = refs.iter().map(|r| r.id).collect();
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

/// Splits `refs` (at `start` in the whole array) by the best binned SAH plane, or makes
/// a leaf when that is cheaper (and the leaf fits one eight-lane pass).
fn split(params: &Bvh8Params, refs: &mut [Ref], start: usize, depth: usize) -> Binary {
    let n = refs.len();
    let (b, cb) = refs.iter().fold((Aabb::EMPTY, Aabb::EMPTY), |(b, cb), r| (b.union(r.b), cb.grow(r.c)));
    let leaf = Binary::Leaf { b, start, len: n };
    if n == 1 || depth >= MAX_BINARY_DEPTH {
        return leaf;
    }
    let (ct, ci) = (params.traversal_cost, params.intersection_cost);
    let area = b.surface_area();
    let binner = Binner::new(&cb);
    let best = best_split(refs, &cb, &binner);
    let left = match best {
        Some((axis, bin, cost)) => {
            let split_cost = ct + ci * cost / area;
            if n <= MAX_LEAF && ci * n as f32 <= split_cost {
                return leaf;
            }
            partition(refs, |r| binner.bin(axis, r.c) <= bin)
        }
        // All centroids in one point: halve by index until leaves fit.
        None if n <= MAX_LEAF => return leaf,
        None => n / 2,
    };
    let (l, r) = refs.split_at_mut(left);
    let (l, r) = if n >= PARALLEL_MIN {
        rayon::join(|| split(params, l, start, depth + 1), || split(params, r, start + left, depth + 1))
    } else {
        (split(params, l, start, depth + 1), split(params, r, start + left, depth + 1))
    };
    Binary::Inner { b, kids: Box::new([l, r]) }
}

/// The bins of a node's centroid bounds: the same function in the sweep and the
/// partition, so the sides have the sweep's counts.
struct Binner {
    min: [f32; 3],
    scale: [f32; 3],
}

impl Binner {
    fn new(cb: &Aabb) -> Self {
        Self {
            min: cb.min.to_array(),
            scale: [0, 1, 2].map(|a| BINS as f32 * (1.0 - 1.0 / 65536.0) / (cb.max[a] - cb.min[a])),
        }
    }

    /// Bin of centroid `c` along `axis`.
    #[inline(always)]
    fn bin(&self, axis: usize, c: Vec3) -> usize {
        // `as` saturates (and maps NaN to 0); the `min` keeps the last bin.
        (((c[axis] - self.min[axis]) * self.scale[axis]) as usize).min(BINS - 1)
    }
}

/// The cheapest plane between bins: `(axis, last bin on the left, A_l n_l + A_r n_r)`,
/// the first of equals (axes in order); `None` when the centroids do not spread on any
/// axis. One pass over the refs bins all three axes.
fn best_split(refs: &[Ref], cb: &Aabb, binner: &Binner) -> Option<(usize, usize, f32)> {
    let mut count = [[0u32; BINS]; 3];
    let mut bounds = [[Aabb::EMPTY; BINS]; 3];
    for r in refs {
        for axis in 0..3 {
            let k = binner.bin(axis, r.c);
            count[axis][k] += 1;
            bounds[axis][k] = bounds[axis][k].union(r.b);
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
        let (mut rb, mut rn) = (Aabb::EMPTY, 0u32);
        for k in (1..BINS).rev() {
            rb = rb.union(bounds[k]);
            rn += count[k];
            right[k] = if rn == 0 { f32::INFINITY } else { rb.surface_area() * rn as f32 };
        }
        let (mut lb, mut ln) = (Aabb::EMPTY, 0u32);
        for k in 0..BINS - 1 {
            lb = lb.union(bounds[k]);
            ln += count[k];
            if ln == 0 || right[k + 1].is_infinite() {
                continue;
            }
            let cost = lb.surface_area() * ln as f32 + right[k + 1];
            if best.is_none_or(|b| cost < b.2) {
                best = Some((axis, k, cost));
            }
        }
    }
    best
}

/// Moves the refs for which `left` holds to the front (stable for neither side); how
/// many.
fn partition(refs: &mut [Ref], left: impl Fn(&Ref) -> bool) -> usize {
    let (mut i, mut j) = (0, refs.len());
    while i < j {
        if left(&refs[i]) {
            i += 1;
        } else {
            j -= 1;
            refs.swap(i, j);
        }
    }
    i
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
