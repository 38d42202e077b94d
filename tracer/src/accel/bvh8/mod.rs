//! An eight-wide bounding volume hierarchy, as Embree's BVH8 and Mitsuba's wavefront
//! traverse: a binned-SAH binary tree (`build.rs`) collapsed into nodes of up to eight
//! children whose boxes are tested together (`traverse.rs`). Each primitive is listed
//! once (no split references, unlike the kd-tree's 1.9 per triangle), and leaves hold at
//! most eight primitives, one pass of the eight-lane triangle test.
//!
//! Answers are bit-identical to [`brute_force_intersect`] / [`brute_force_occluded`],
//! by the bookkeeping the kd-tree uses too (`accel/exact.rs`): hits within a margin of
//! the nearest are collected and replayed in index order, boxes are padded as the
//! kd-tree pads primitive extents, and ray intervals are widened by the same slack.
//!
//! It traces each scene's own primitives (`Scene::accel`): against the kd-tree it is
//! 1.25-1.5x as fast on single rays (`BVH8=TRIANGLES cargo bench -p tracer --bench
//! bvh8`, `bench/RESULTS.md`), and instanced meshes too (each mesh's own and the top
//! level over the copies). The kd-tree stays for comparison.
//!
//! Coherent rays can also go eight at a time (`packet.rs`): one frustum test per node
//! for the whole packet, each ray on its own only at the leaves.
//!
//! [`brute_force_intersect`]: crate::accel::brute_force_intersect
//! [`brute_force_occluded`]: crate::accel::brute_force_occluded

mod build;
mod packet;
#[cfg(test)]
mod tests;
mod traverse;

use super::block_test::InstructionSet;
use super::{Hit, Primitives, Ray};
use crate::geometry::Aabb;

/// A child reference's kind, in its low two bits (as the kd-tree's treelets): a node.
const NODE: u32 = 0;
/// A leaf of several primitives: the index of its count in `leaves`, its ids following.
const LEAF: u32 = 1;
/// A leaf of one primitive: the primitive's index.
const ONE: u32 = 2;
/// Nothing.
const EMPTY: u32 = 3;

/// Children per node.
pub const WIDTH: usize = 8;

/// Most primitives in a leaf: one eight-lane pass.
pub const MAX_LEAF: usize = 8;

/// Build parameters: the SAH's costs, as ratios to one another.
#[derive(Clone, Debug)]
pub struct Bvh8Params {
    /// Cost of visiting a binary node (a wide node costs about as much: its eight box
    /// tests run side by side). Default 1.
    pub traversal_cost: f32,
    /// Cost of one primitive test. Default 0.25: leaves test eight triangles at a
    /// time, so full leaves pay (`bench/RESULTS.md`).
    pub intersection_cost: f32,
}

impl Default for Bvh8Params {
    fn default() -> Self {
        Self { traversal_cost: 1.0, intersection_cost: 0.25 }
    }
}

/// Up to eight children's boxes, structure of arrays (one vector per bound and axis),
/// and their references. Empty slots have inverted boxes (min +inf, max -inf), which no
/// ray interval meets.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
struct Node8 {
    lo: [[f32; WIDTH]; 3],
    hi: [[f32; WIDTH]; 3],
    child: [u32; WIDTH],
    /// For a leaf child, its lowest primitive index (prefetched with the node's other
    /// children: with the primitives stored in leaf order, its primitives follow it);
    /// 0 otherwise. Fills the node's fourth cache line.
    first: [u32; WIDTH],
}

impl Node8 {
    const EMPTY: Node8 = Node8 {
        lo: [[f32::INFINITY; WIDTH]; 3],
        hi: [[f32::NEG_INFINITY; WIDTH]; 3],
        child: [EMPTY; WIDTH],
        first: [0; WIDTH],
    };
}

/// The lowest primitive of leaf reference `r` (0 for other references), given the
/// leaves' lists (sorted).
fn leaf_first(leaves: &[u32], r: u32) -> u32 {
    match r & 3 {
        LEAF => leaves[(r >> 2) as usize + 1],
        ONE => r >> 2,
        _ => 0,
    }
}

/// Shape and size of a built hierarchy.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Bvh8Stats {
    pub nodes: usize,
    pub leaves: usize,
    /// Mean filled child slots per node.
    pub mean_children: f64,
    /// Mean primitives per leaf.
    pub mean_leaf_prims: f64,
    /// Deepest wide node (the root is at depth 0).
    pub max_depth: usize,
    /// Memory of the nodes and the leaves' primitive indices.
    pub bytes: usize,
}

/// The hierarchy over a [`Primitives`] set. It stores primitive indices only: queries
/// take the same set again.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Bvh8 {
    nodes: Vec<Node8>,
    /// Each leaf of several primitives as its count and its indices, in depth-first order.
    leaves: Vec<u32>,
    root: u32,
    /// Union of the primitives' bounds (empty for an empty set), as the kd-tree's.
    bounds: Aabb,
    /// The valid primitives' padded boxes: what traversal clips rays to.
    cell: Aabb,
    stats: Bvh8Stats,
    /// The instruction set of the box tests and the leaves' triangle test: this
    /// machine's, also for a hierarchy read back from disk.
    #[serde(skip, default = "InstructionSet::detect")]
    simd: InstructionSet,
}

impl super::LeafOrdered for Bvh8 {
    fn for_each_leaf(&self, f: &mut dyn FnMut(&[u32])) {
        let mut stack = vec![self.root];
        while let Some(r) = stack.pop() {
            let at = (r >> 2) as usize;
            match r & 3 {
                NODE => stack.extend(self.nodes[at].child.iter().rev()),
                LEAF => f(&self.leaves[at + 1..at + 1 + self.leaves[at] as usize]),
                ONE => f(&[r >> 2]),
                _ => {}
            }
        }
    }

    fn remap(&mut self, new_index: &[u32]) {
        let rename = |r: &mut u32| {
            if *r & 3 == ONE {
                *r = (new_index[(*r >> 2) as usize] << 2) | ONE;
            }
        };
        rename(&mut self.root);
        super::remap_leaf_lists(&mut self.leaves, new_index);
        for n in &mut self.nodes {
            n.child.iter_mut().for_each(rename);
            for j in 0..WIDTH {
                n.first[j] = leaf_first(&self.leaves, n.child[j]);
            }
        }
    }
}

impl Bvh8 {
    pub fn build<P: Primitives>(prims: &P, params: &Bvh8Params) -> Bvh8 {
        build::build(prims, params)
    }

    pub fn stats(&self) -> Bvh8Stats {
        self.stats.clone()
    }

    /// Union of the primitives' bounds (empty for an empty set).
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Heap memory held.
    pub fn heap_bytes(&self) -> usize {
        self.nodes.capacity() * size_of::<Node8>() + self.leaves.capacity() * size_of::<u32>()
    }

    /// See [`crate::memory::advise_huge_pages`].
    pub(crate) fn advise_huge_pages(&self) {
        crate::accel::advise_huge_pages(&self.nodes);
        crate::accel::advise_huge_pages(&self.leaves);
    }

    /// The instruction set the queries use, for reports.
    pub fn instruction_set(&self) -> &'static str {
        self.simd.name()
    }

    /// Nearest hit with `0 < t < tmax`: exactly [`super::brute_force_intersect`].
    pub fn intersect<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> Option<Hit> {
        match self.simd {
            InstructionSet::Baseline => self.intersect_impl::<P, false>(prims, ray, tmax),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Avx2` and `Avx512` are only chosen when the CPU reports AVX2.
            InstructionSet::Avx2 | InstructionSet::Avx512 => unsafe { self.intersect_avx2(prims, ray, tmax) },
        }
    }

    /// Whether anything is hit with `0 < t < tmax`: exactly
    /// [`super::brute_force_occluded`].
    pub fn occluded<P: Primitives>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        match self.simd {
            InstructionSet::Baseline => self.occluded_impl::<P, false>(prims, ray, tmax),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `intersect`.
            InstructionSet::Avx2 | InstructionSet::Avx512 => unsafe { self.occluded_avx2(prims, ray, tmax) },
        }
    }
}
