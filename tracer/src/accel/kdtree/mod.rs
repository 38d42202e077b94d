//! SAH kd-tree: build with perfect (clipped) splits, binned SAH for large nodes and
//! exact sweeps for small ones, into compact 8-byte nodes, in `build.rs`; the nodes cut
//! into cache-line treelets of three levels for traversal, in `treelet.rs`; a
//! stack-based front-to-back traversal in `traverse.rs` whose answers are bit-identical
//! to the brute-force loops (by the bookkeeping of `accel/exact.rs`). Leaves test their triangles eight at a time
//! (`accel/block_test.rs`).

mod build;
mod packet;
mod traverse;
mod treelet;

use self::treelet::{Treelet, to_treelets};
use super::block_test::InstructionSet;
use super::{Hit, Primitives, Ray};
use crate::geometry::Aabb;

/// Deepest tree the traversal stack supports.
const MAX_DEPTH: u32 = 60;

/// Build parameters.
///
/// Leaves test their triangles eight at a time (corners loaded by index,
/// `accel/block_test.rs`), which makes a primitive test cheap against a node step (a likely
/// cache miss), so big leaves and shallow trees win: the defaults are the best closest-
/// and any-hit throughput of incoherent rays on large meshes. The measurements behind
/// each default, with their commands, are in `bench/RESULTS.md` ("kd-tree build
/// parameters").
#[derive(Clone, Debug)]
pub struct BuildParams {
    /// SAH cost of visiting an interior node. Default 1.
    pub traversal_cost: f32,
    /// SAH cost of one primitive test; only its ratio to `traversal_cost` shapes the
    /// tree. Default 0.12: the best throughput on large meshes, and half the build time
    /// and tree size of 0.35.
    pub intersection_cost: f32,
    /// Fraction (0..1) by which the SAH discounts a split that cuts off empty space.
    /// Default 0.2; larger values cut thin empty slabs around every sphere, which costs
    /// sphere scenes much more than it gains on meshes.
    pub empty_bonus: f32,
    /// Deepest level; `None` is pbrt's `round(8 + 1.3 log2 N)` (34 for 1M primitives),
    /// deep enough that the SAH, not the limit, ends nearly every branch. Capped at 60
    /// (the traversal stack).
    pub max_depth: Option<u32>,
    /// Nodes with at most this many primitives become leaves without an SAH sweep.
    /// Default 1. With SAH termination the value barely matters (0, 1, 2 and 4 give the
    /// same tree at Ci/Ct 0.08): the SAH already stops before leaves get that small.
    pub max_leaf_prims: usize,
}

/// Scenes of at most this many primitives get [`BuildParams::for_scene`]'s deeper
/// trees.
pub const SMALL_SCENE_PRIMS: usize = 1024;

/// Cost ratio for sets where other primitives than triangles (spheres) are at least
/// [`OTHER_PRIMS_SHARE`] of all: their tests run one by one, not eight lanes at a
/// time, so smaller leaves pay.
pub const OTHER_PRIMS_INTERSECTION_COST: f32 = 0.35;
/// See [`OTHER_PRIMS_INTERSECTION_COST`]: one primitive in ten.
pub const OTHER_PRIMS_SHARE: f64 = 0.1;

impl BuildParams {
    /// The parameters for a scene of `triangles` triangles and `others` other
    /// primitives. The default cost ratio was tuned on large meshes, whose trees do not
    /// fit in cache, so each node step risks a miss. A small scene's tree and triangles
    /// stay in L1/L2, node steps are cheap, and a deeper tree with fewer primitive tests
    /// per leaf wins, up to [`SMALL_SCENE_PRIMS`] primitives. Sets of many spheres keep
    /// [`OTHER_PRIMS_INTERSECTION_COST`].
    pub fn for_scene(triangles: usize, others: usize) -> Self {
        let n = triangles + others;
        if n <= SMALL_SCENE_PRIMS {
            Self { intersection_cost: 2.0, ..Self::default() }
        } else if others as f64 >= OTHER_PRIMS_SHARE * n as f64 {
            Self { intersection_cost: OTHER_PRIMS_INTERSECTION_COST, ..Self::default() }
        } else {
            Self::default()
        }
    }
}

impl Default for BuildParams {
    fn default() -> Self {
        Self { traversal_cost: 1.0, intersection_cost: 0.12, empty_bonus: 0.2, max_depth: None, max_leaf_prims: 1 }
    }
}

/// Shape and size of a built tree.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KdTreeStats {
    /// Nodes of the binary tree, leaves included.
    pub nodes: usize,
    /// The 64-byte treelets the traversal reads them from.
    pub treelets: usize,
    pub leaves: usize,
    pub empty_leaves: usize,
    /// Deepest leaf (the root is at depth 0).
    pub max_depth: usize,
    /// The depth limit the build used.
    pub depth_limit: usize,
    /// Sum over leaves of their primitive counts.
    pub prim_refs: usize,
    /// Largest leaf.
    pub max_leaf_prims: usize,
    /// Memory of the treelets and the leaves' primitive indices.
    pub bytes: usize,
}

/// A node in 8 bytes (pbrt's layout), as the build emits them. `flags` low 2 bits: split
/// axis, or 3 for a leaf; upper 30 bits: the above child's offset from this node
/// (interior; the below child is the next node), or the primitive count (leaf). `data`:
/// the split position's bits (interior), the primitive itself (leaf of one), or the
/// offset of the leaf's indices in the build's index array. A built [`KdTree`] holds
/// them as treelets (`treelet.rs`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Node {
    data: u32,
    flags: u32,
}

const LEAF: u32 = 3;

impl Node {
    fn interior(axis: usize, split: f32, above: u32) -> Self {
        assert!(above < 1 << 30, "kd-tree: too many nodes");
        Self { data: split.to_bits(), flags: axis as u32 | (above << 2) }
    }

    fn leaf(prims: &[u32], ids: &mut Vec<u32>) -> Self {
        assert!(prims.len() < 1 << 30);
        let flags = LEAF | ((prims.len() as u32) << 2);
        match prims {
            [] => Self { data: 0, flags },
            [one] => Self { data: *one, flags },
            _ => {
                let data = ids.len() as u32;
                ids.extend_from_slice(prims);
                Self { data, flags }
            }
        }
    }

    /// The node with its index offset moved by `base` (leaves of several primitives).
    fn shifted(self, base: u32) -> Self {
        if self.is_leaf() && self.prim_count() > 1 { Self { data: self.data + base, flags: self.flags } } else { self }
    }

    #[inline(always)]
    fn is_leaf(self) -> bool {
        self.flags & 3 == LEAF
    }
    #[inline(always)]
    fn axis(self) -> usize {
        (self.flags & 3) as usize
    }
    #[inline(always)]
    fn split(self) -> f32 {
        f32::from_bits(self.data)
    }
    #[inline(always)]
    fn above(self) -> usize {
        (self.flags >> 2) as usize
    }
    #[inline(always)]
    fn prim_count(self) -> usize {
        (self.flags >> 2) as usize
    }
}

/// The kd-tree over a [`Primitives`] set. It stores primitive indices only: queries take
/// the same set again.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct KdTree {
    /// The nodes, three levels to a treelet, in depth-first order.
    treelets: Vec<Treelet>,
    /// Each leaf of several primitives as its count and its indices, in depth-first
    /// order.
    leaves: Vec<u32>,
    /// The root's reference (`treelet.rs`): a treelet, a leaf, or nothing.
    root: u32,
    bounds: Aabb,
    /// Root cell (the primitives' padded extents): what traversal clips rays to.
    cell: Aabb,
    stats: KdTreeStats,
    /// The instruction set of the treelet step and of the leaves' eight-lane triangle
    /// test: this machine's, also for a tree read back from disk.
    #[serde(skip, default = "InstructionSet::detect")]
    simd: InstructionSet,
}

impl super::LeafOrdered for KdTree {
    fn for_each_leaf(&self, f: &mut dyn FnMut(&[u32])) {
        let mut stack = vec![self.root];
        while let Some(r) = stack.pop() {
            let at = (r >> 2) as usize;
            match r & 3 {
                treelet::TREELET => stack.extend(self.treelets[at].child.iter().rev()),
                treelet::LEAF => f(&self.leaves[at + 1..at + 1 + self.leaves[at] as usize]),
                treelet::ONE => f(&[r >> 2]),
                _ => {}
            }
        }
    }

    fn remap(&mut self, new_index: &[u32]) {
        let rename = |r: &mut u32| {
            if *r & 3 == treelet::ONE {
                *r = (new_index[(*r >> 2) as usize] << 2) | treelet::ONE;
            }
        };
        rename(&mut self.root);
        for t in &mut self.treelets {
            t.child.iter_mut().for_each(rename);
        }
        super::remap_leaf_lists(&mut self.leaves, new_index);
    }
}

impl KdTree {
    pub fn build<P: Primitives>(prims: &P, params: &BuildParams) -> KdTree {
        let b = build::build(prims, params);
        let (treelets, leaves, root) = to_treelets(&b.out.nodes, &b.out.ids);
        let stats = KdTreeStats {
            treelets: treelets.len(),
            bytes: treelets.len() * size_of::<Treelet>() + leaves.len() * size_of::<u32>(),
            ..binary_stats(&b.out.nodes, b.max_depth as usize)
        };
        let tree =
            KdTree { treelets, leaves, root, bounds: b.bounds, cell: b.cell, stats, simd: InstructionSet::detect() };
        tree.advise_huge_pages();
        tree
    }

    /// The nodes and leaves on huge pages where the kernel allows (a tree's first steps
    /// touch pages far apart).
    pub(crate) fn advise_huge_pages(&self) {
        crate::accel::advise_huge_pages(&self.treelets);
        crate::accel::advise_huge_pages(&self.leaves);
    }

    /// Union of the primitives' bounds (empty for an empty set).
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    pub fn stats(&self) -> KdTreeStats {
        self.stats.clone()
    }

    /// A hash of the treelets and leaves: equal fingerprints mean the same tree, for
    /// checking that a build change left the tree alone.
    pub fn fingerprint(&self) -> u64 {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        for t in &self.treelets {
            (t.split.map(f32::to_bits), t.axes, t.child).hash(&mut h);
        }
        (&self.leaves, self.root).hash(&mut h);
        h.finish()
    }

    /// Bytes allocated for the treelets and the leaves (their capacity).
    pub fn heap_bytes(&self) -> usize {
        self.treelets.capacity() * size_of::<Treelet>() + self.leaves.capacity() * size_of::<u32>()
    }

    /// Nearest hit with `0 < t < tmax`: exactly what [`super::brute_force_intersect`]
    /// returns.
    pub fn intersect<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        match self.simd {
            InstructionSet::Baseline => self.intersect_impl::<P, false>(prims, ray, tmax),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Avx2` and `Avx512` are only chosen when the CPU reports AVX2. (The
            // leaves stay at eight lanes with AVX-512: sixteen were no faster.)
            InstructionSet::Avx2 | InstructionSet::Avx512 => unsafe { self.intersect_avx2(prims, ray, tmax) },
        }
    }

    /// Whether anything is hit with `0 < t < tmax`: exactly
    /// [`super::brute_force_occluded`], stopping at the first hit found.
    pub fn occluded<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        match self.simd {
            InstructionSet::Baseline => self.occluded_impl::<P, false>(prims, ray, tmax),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `intersect`.
            InstructionSet::Avx2 | InstructionSet::Avx512 => unsafe { self.occluded_avx2(prims, ray, tmax) },
        }
    }
}

/// The shape of the binary tree the build emitted (depth-first, below child next).
fn binary_stats(nodes: &[Node], depth_limit: usize) -> KdTreeStats {
    let mut s = KdTreeStats { depth_limit, ..Default::default() };
    let mut stack = if nodes.is_empty() { vec![] } else { vec![(0usize, 0usize)] };
    while let Some((i, d)) = stack.pop() {
        let n = nodes[i];
        s.nodes += 1;
        s.max_depth = s.max_depth.max(d);
        if n.is_leaf() {
            s.leaves += 1;
            s.empty_leaves += usize::from(n.prim_count() == 0);
            s.prim_refs += n.prim_count();
            s.max_leaf_prims = s.max_leaf_prims.max(n.prim_count());
        } else {
            stack.push((i + 1, d + 1));
            stack.push((i + n.above(), d + 1));
        }
    }
    s
}

#[cfg(test)]
pub(in crate::accel) mod tests;
