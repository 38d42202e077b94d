//! The traversal's node format: the binary tree cut into treelets of three levels, one
//! 64-byte cache line each, whose seven split planes are tested at once.
//!
//! Why. A binary kd-tree walk takes a node step per level, each a load, a plane
//! distance and a compare that the next step depends on, so on a large tree much of its
//! time goes to waiting for node loads; treelets take about a third of the steps
//! (`bench/RESULTS.md`). A treelet
//! holds a node, its two children and its four grandchildren in one line, so one load
//! serves three levels, and their seven plane distances, the eight grandchild intervals
//! and their front-to-back order are computed side by side in eight lanes (AVX2) with
//! no branch per level.
//!
//! Exactness. Each grandchild's interval is the one the binary walk would give it: the
//! parent interval clipped, level by level, by `fmin(tp + slack, hi)` on the near side
//! and `fmax(tp - slack, lo)` on the far side, in the same order and with the same NaN
//! rule (a ray in a plane keeps the whole interval on both sides); a grandchild is kept
//! when `lo <= min(hi, reach)`, which is the binary walk's test at each level combined.
//! A leaf of the binary tree above the third level is reached through placeholder
//! nodes whose plane lies at infinity, which send the whole interval to their below
//! child (on either side of the ray's direction) and nothing to the other.

use std::mem::MaybeUninit;

use super::{MAX_DEPTH, Node};

/// A child reference's kind, in its low two bits; the rest is an index.
pub(super) const TREELET: u32 = 0;
/// A leaf of several primitives: the index of its count in `leaves`, its ids following.
pub(super) const LEAF: u32 = 1;
/// A leaf of one primitive: the primitive's index.
pub(super) const ONE: u32 = 2;
/// Nothing (an empty leaf, or below a placeholder node): never visited.
pub(super) const EMPTY: u32 = 3;

/// Seven nodes in breadth-first order (node k's children are 2k+1 below and 2k+2 above;
/// the children of nodes 3..7 are `child[2(k-3)]` and `child[2(k-3)+1]`), their split
/// axes two bits each in `axes`, and the references of the eight grandchildren's
/// children. 64 bytes, one cache line; `axes` is read as the eighth lane of the splits,
/// whose result is never used.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(super) struct Treelet {
    pub(super) split: [f32; 7],
    pub(super) axes: u32,
    pub(super) child: [u32; 8],
}

/// The treelet form of a binary tree (depth-first nodes with the below child next and
/// leaves' ids at `data` in `ids`, as the build emits them): treelets in depth-first
/// order, the leaves of several primitives as `[count, ids..]` runs in `leaves` (in
/// depth-first order too), and the root's reference.
pub(super) fn to_treelets(nodes: &[Node], ids: &[u32]) -> (Vec<Treelet>, Vec<u32>, u32) {
    // Sized exactly: grown by doubling, the two arrays took half again as much memory.
    let leaf_words = nodes.iter().filter(|n| n.is_leaf() && n.prim_count() > 1).map(|n| 1 + n.prim_count()).sum();
    let interior = nodes.iter().filter(|n| !n.is_leaf()).count();
    let mut t = Convert { nodes, ids, treelets: Vec::with_capacity(interior), leaves: Vec::with_capacity(leaf_words) };
    let root = if nodes.is_empty() { EMPTY } else { t.reference(0) };
    t.treelets.shrink_to_fit();
    (t.treelets, t.leaves, root)
}

struct Convert<'a> {
    nodes: &'a [Node],
    ids: &'a [u32],
    treelets: Vec<Treelet>,
    leaves: Vec<u32>,
}

/// What a treelet slot holds while a treelet is filled.
#[derive(Clone, Copy)]
enum Slot {
    /// An interior binary node.
    Node(usize),
    /// A placeholder passing everything to its below child: this binary node (a leaf),
    /// or nothing.
    Pass(Option<usize>),
}

impl Convert<'_> {
    /// The reference of binary node `i`, converting its subtree.
    fn reference(&mut self, i: usize) -> u32 {
        let n = self.nodes[i];
        if !n.is_leaf() {
            return self.treelet(i);
        }
        let prims = match n.prim_count() {
            0 => return EMPTY,
            // Fits beside the kind: the build takes fewer than 2^30 primitives.
            1 => return (n.data << 2) | ONE,
            c => &self.ids[n.data as usize..n.data as usize + c],
        };
        let at = self.leaves.len();
        assert!(at < 1 << 30, "kd-tree: too many leaf references");
        self.leaves.push(prims.len() as u32);
        self.leaves.extend_from_slice(prims);
        ((at as u32) << 2) | LEAF
    }

    /// Converts the subtree of interior node `root` into treelets; its index.
    fn treelet(&mut self, root: usize) -> u32 {
        let at = self.treelets.len();
        assert!(at < 1 << 30, "kd-tree: too many treelets");
        self.treelets.push(Treelet { split: [0.0; 7], axes: 0, child: [EMPTY; 8] });
        let mut slots = [Slot::Pass(None); 15];
        slots[0] = Slot::Node(root);
        let mut split = [f32::INFINITY; 7];
        let mut axes = 0;
        for k in 0..7 {
            let (below, above) = match slots[k] {
                Slot::Node(i) => {
                    let n = self.nodes[i];
                    split[k] = n.split();
                    axes |= (n.axis() as u32) << (2 * k);
                    let side = |j: usize| if self.nodes[j].is_leaf() { Slot::Pass(Some(j)) } else { Slot::Node(j) };
                    (side(i + 1), side(i + n.above()))
                }
                pass => (pass, Slot::Pass(None)),
            };
            slots[2 * k + 1] = below;
            slots[2 * k + 2] = above;
        }
        // Depth-first: each child's subtree is converted before the next child's.
        let mut child = [EMPTY; 8];
        for (c, r) in child.iter_mut().enumerate() {
            *r = match slots[7 + c] {
                Slot::Node(i) | Slot::Pass(Some(i)) => self.reference(i),
                Slot::Pass(None) => EMPTY,
            };
        }
        self.treelets[at] = Treelet { split, axes, child };
        ((at as u32) << 2) | TREELET
    }
}

/// The per-ray values the treelet step uses: origin, reciprocal direction and whether
/// the direction is negative, per axis; the slack by which intervals are widened.
pub(super) struct RayAxes {
    pub(super) o: [f32; 3],
    pub(super) inv: [f32; 3],
    pub(super) neg: [bool; 3],
    pub(super) slack: f32,
}

/// Room on the stack: at most seven entries stay behind per treelet level (of eight
/// children, the nearest is taken at once), a tree of depth `MAX_DEPTH` has at most
/// `MAX_DEPTH / 3 + 1` treelet levels, and a push writes eight lanes.
pub(super) const STACK: usize = 7 * (MAX_DEPTH as usize / 3 + 1) + 8;

/// The walk's stack, structure of arrays so that a treelet's children go on in three
/// vector stores. Uninitialised: an entry is read only below `sp`, where it was written.
pub(super) struct Stack {
    node: [MaybeUninit<u32>; STACK],
    lo: [MaybeUninit<f32>; STACK],
    hi: [MaybeUninit<f32>; STACK],
    sp: usize,
}

/// The path of grandchild `c` (0..8): its ancestor at level `l` is node `PATH[l][c]` and
/// it lies on that node's above side when bit `2 - l` of `c` is set.
pub(super) const PATH: [[usize; 8]; 3] = [[0; 8], [1, 1, 1, 1, 2, 2, 2, 2], [3, 3, 4, 4, 5, 5, 6, 6]];

/// `a.min(b)` for a non-NaN `b`, and `b` when `a` is NaN (as `minps`).
#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

/// `a.max(b)` for a non-NaN `b`, and `b` when `a` is NaN (as `maxps`).
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// The grandchild visited `k`-th (front to back) when the nodes whose bits are set in
/// `neg` have a negative direction along their axis: at each level the near side comes
/// first.
#[inline(always)]
pub(super) const fn child_of_rank(k: usize, neg: usize) -> usize {
    let hi = (k >> 2) ^ (neg & 1);
    let mid = ((k >> 1) & 1) ^ ((neg >> (1 + hi)) & 1);
    let lo = (k & 1) ^ ((neg >> (3 + 2 * hi + mid)) & 1);
    (hi << 2) | (mid << 1) | lo
}

impl Stack {
    #[inline(always)]
    pub(super) fn new() -> Self {
        Self {
            node: [const { MaybeUninit::uninit() }; STACK],
            lo: [const { MaybeUninit::uninit() }; STACK],
            hi: [const { MaybeUninit::uninit() }; STACK],
            sp: 0,
        }
    }

    #[inline(always)]
    pub(super) fn push(&mut self, node: u32, lo: f32, hi: f32) {
        self.node[self.sp] = MaybeUninit::new(node);
        self.lo[self.sp] = MaybeUninit::new(lo);
        self.hi[self.sp] = MaybeUninit::new(hi);
        self.sp += 1;
    }

    /// The top entry, removed: (reference, lo, hi).
    #[inline(always)]
    pub(super) fn pop(&mut self) -> Option<(u32, f32, f32)> {
        if self.sp == 0 {
            return None;
        }
        self.sp -= 1;
        let i = self.sp;
        // SAFETY: entries below `sp` were all written (`sp` only grows past written
        // entries).
        Some(unsafe { (self.node[i].assume_init(), self.lo[i].assume_init(), self.hi[i].assume_init()) })
    }

    /// The children of `t` that the interval `[lo, hi]` reaches and that start no later
    /// than `reach`: the nearest is returned as (reference, lo, hi), the others pushed
    /// farthest first. One lane at a time: the reference for [`step_avx2`].
    #[inline(always)]
    pub(super) fn step(&mut self, t: &Treelet, r: &RayAxes, lo: f32, hi: f32, reach: f32) -> Option<(u32, f32, f32)> {
        let mut tp = [0.0f32; 7];
        let mut neg = [false; 7];
        for k in 0..7 {
            let a = ((t.axes >> (2 * k)) & 3) as usize;
            tp[k] = (t.split[k] - r.o[a]) * r.inv[a];
            neg[k] = r.neg[a];
        }
        let signs = (0..7).fold(0, |m, k| m | (usize::from(neg[k]) << k));
        let before = self.sp;
        for rank in (0..8).rev() {
            let c = child_of_rank(rank, signs);
            let (mut clo, mut chi) = (lo, hi);
            for (l, path) in PATH.iter().enumerate() {
                let k = path[c];
                let above = (c >> (2 - l)) & 1 == 1;
                if above != neg[k] {
                    clo = fmax(tp[k] - r.slack, clo);
                } else {
                    chi = fmin(tp[k] + r.slack, chi);
                }
            }
            if t.child[c] & 3 != EMPTY && clo <= fmin(chi, reach) {
                self.push(t.child[c], clo, chi);
            }
        }
        if self.sp > before { self.pop() } else { None }
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) use avx2::{RayLanes, prefetch_children, step_avx2};

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use core::arch::x86_64::*;

    use super::{EMPTY, RayAxes, STACK, Stack, Treelet};

    /// [`RayAxes`] in registers, each axis broadcast to eight lanes.
    #[derive(Clone, Copy)]
    pub(in crate::accel::kdtree) struct RayLanes {
        o: [__m256; 3],
        inv: [__m256; 3],
        /// Lanes 0..3: all ones where the direction is negative along that axis.
        neg: __m256i,
        slack: __m256,
    }

    impl RayLanes {
        /// # Safety
        /// The CPU must have AVX2.
        #[inline(always)]
        pub(in crate::accel::kdtree) unsafe fn new(r: &RayAxes) -> Self {
            let neg = r.neg.map(|n| -(n as i32));
            // SAFETY: AVX2 (the caller's promise).
            unsafe {
                Self {
                    o: [_mm256_set1_ps(r.o[0]), _mm256_set1_ps(r.o[1]), _mm256_set1_ps(r.o[2])],
                    inv: [_mm256_set1_ps(r.inv[0]), _mm256_set1_ps(r.inv[1]), _mm256_set1_ps(r.inv[2])],
                    neg: _mm256_setr_epi32(neg[0], neg[1], neg[2], 0, 0, 0, 0, 0),
                    slack: _mm256_set1_ps(r.slack),
                }
            }
        }
    }

    /// Indices into an eight-lane table, packed four bits each: for each mask of eight
    /// lanes, its set lanes in ascending order (a compress, which AVX2 lacks).
    const COMPRESS: [u32; 256] = {
        let mut t = [0u32; 256];
        let mut m = 0;
        while m < 256 {
            let (mut packed, mut n, mut lane) = (0u32, 0, 0);
            while lane < 8 {
                if m & (1 << lane) != 0 {
                    packed |= (lane as u32) << (4 * n);
                    n += 1;
                }
                lane += 1;
            }
            t[m] = packed;
            m += 1;
        }
        t
    };

    /// For each pattern of the seven nodes' direction signs (bit k: node k's is
    /// negative), the children by rank from the farthest, four bits each: lane j of the
    /// step's `order` is the child of rank 7 - j ([`super::child_of_rank`]). A table
    /// load instead of fourteen vector operations: `KDTREE_AB` medians of 200 slice
    /// pairs, closest / any hit, 1.02 / 1.02 on the 10k mesh, 1.01 / 1.02 on 4k, 1.03 /
    /// 1.00 on 1M.
    const ORDER: [u32; 128] = {
        let mut t = [0u32; 128];
        let mut m = 0;
        while m < 128 {
            let mut j = 0;
            while j < 8 {
                t[m] |= (super::child_of_rank(7 - j, m) as u32) << (4 * j);
                j += 1;
            }
            m += 1;
        }
        t
    };

    /// Set lanes of each mask (`count_ones` without assuming POPCNT).
    const COUNT: [u8; 256] = {
        let mut t = [0u8; 256];
        let mut m = 0;
        while m < 256 {
            t[m] = (m as u32).count_ones() as u8;
            m += 1;
        }
        t
    };

    #[inline(always)]
    fn v(x: [i32; 8]) -> __m256i {
        // SAFETY: 32 bytes of plain integers, read unaligned.
        unsafe { _mm256_loadu_si256(x.as_ptr().cast()) }
    }

    #[repr(C, align(32))]
    struct Lanes<T>([T; 8]);

    /// Starts loading the lines of the children `child` of a treelet (see
    /// `KdTree::prefetch_children`): treelets at `tb`, leaves at `lb`, other kinds `tb`.
    /// The addresses are made in 64-bit lanes, four at a time: against the scalar loop,
    /// `KDTREE_AB` medians of 200 slice pairs, closest / any hit, 10k mesh 1.13 / 1.15,
    /// 1M mesh 1.11 / 1.11.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[inline(always)]
    pub(in crate::accel::kdtree) unsafe fn prefetch_children(child: __m256i, tb: usize, lb: usize) {
        // SAFETY: AVX2 (the caller's promise); a prefetch is a hint, it never faults,
        // whatever the address.
        unsafe {
            let kind = _mm256_and_si256(child, _mm256_set1_epi32(3));
            let is_t = _mm256_cmpeq_epi32(kind, _mm256_set1_epi32(super::TREELET as i32));
            let is_l = _mm256_cmpeq_epi32(kind, _mm256_set1_epi32(super::LEAF as i32));
            // Byte offsets' shifts: 64-byte treelets from the index `c >> 2`, 4-byte words.
            let index = _mm256_and_si256(_mm256_srli_epi32::<2>(child), _mm256_or_si256(is_t, is_l));
            let shift = _mm256_or_si256(
                _mm256_and_si256(is_t, _mm256_set1_epi32(6)),
                _mm256_and_si256(is_l, _mm256_set1_epi32(2)),
            );
            for half in 0..2 {
                let (i, sh, l) = if half == 0 {
                    (_mm256_castsi256_si128(index), _mm256_castsi256_si128(shift), _mm256_castsi256_si128(is_l))
                } else {
                    (
                        _mm256_extracti128_si256::<1>(index),
                        _mm256_extracti128_si256::<1>(shift),
                        _mm256_extracti128_si256::<1>(is_l),
                    )
                };
                let off = _mm256_sllv_epi64(_mm256_cvtepu32_epi64(i), _mm256_cvtepu32_epi64(sh));
                let base = _mm256_blendv_epi8(
                    _mm256_set1_epi64x(tb as i64),
                    _mm256_set1_epi64x(lb as i64),
                    _mm256_cvtepi32_epi64(l),
                );
                let a = _mm256_add_epi64(base, off);
                let lo = _mm256_castsi256_si128(a);
                let hi = _mm256_extracti128_si256::<1>(a);
                for p in [
                    _mm_cvtsi128_si64(lo),
                    _mm_extract_epi64::<1>(lo),
                    _mm_cvtsi128_si64(hi),
                    _mm_extract_epi64::<1>(hi),
                ] {
                    _mm_prefetch::<_MM_HINT_T0>(p as usize as *const i8);
                }
            }
        }
    }

    /// [`Stack::step`] in eight lanes: the same nearest child, and the same entries
    /// pushed in the same order. It also starts loading the children's lines, treelets
    /// at `tb` and leaves at `lb` (the arrays' addresses).
    ///
    /// The work is ordered for latency, the chain from the treelet's load to the next
    /// one being what a walk waits for: the plane distance is computed for all three
    /// axes and the node's picked by blends (the axis masks come from a load in
    /// parallel), each level's near / far choice is made from the axes alone, and the
    /// intervals are reduced with `min`/`max`, which are exact, so their order does not
    /// matter once a NaN distance (a ray in the plane) is made to leave the interval
    /// alone, as in the binary walk.
    ///
    /// Not a `target_feature` function, which would not inline into the walk in every
    /// caller (it did not in the renderer's); `#[inline(always)]` puts its intrinsics in
    /// the AVX2 query, where they inline.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[inline(always)]
    pub(in crate::accel::kdtree) unsafe fn step_avx2(
        st: &mut Stack,
        t: &Treelet,
        r: &RayLanes,
        lo: f32,
        hi: f32,
        reach: f32,
        (tb, lb): (usize, usize),
    ) -> Option<(u32, f32, f32)> {
        // SAFETY: AVX2 (the caller's promise); the loads and stores are in bounds, as
        // commented at each.
        unsafe {
            // `Treelet` is 64-byte aligned; its first 32 bytes are the splits and `axes`,
            // its last the children.
            let p = (t as *const Treelet).cast::<__m256>();
            let (split, child) = (_mm256_load_ps(p.cast()), _mm256_load_si256(p.add(1).cast()));
            prefetch_children(child, tb, lb);
            let axes = _mm256_and_si256(
                _mm256_srlv_epi32(_mm256_set1_epi32(t.axes as i32), v([0, 2, 4, 6, 8, 10, 12, 14])),
                _mm256_set1_epi32(3),
            );
            let is_y = _mm256_castsi256_ps(_mm256_cmpeq_epi32(axes, _mm256_set1_epi32(1)));
            let is_z = _mm256_castsi256_ps(_mm256_cmpeq_epi32(axes, _mm256_set1_epi32(2)));
            let along = |a: usize| _mm256_mul_ps(_mm256_sub_ps(split, r.o[a]), r.inv[a]);
            let tp = _mm256_blendv_ps(_mm256_blendv_ps(along(0), along(1), is_y), along(2), is_z);
            let tp_hi = _mm256_add_ps(tp, r.slack);
            let tp_lo = _mm256_sub_ps(tp, r.slack);
            let neg = _mm256_permutevar8x32_epi32(r.neg, axes);
            let inf = _mm256_set1_ps(f32::INFINITY);
            let ninf = _mm256_set1_ps(f32::NEG_INFINITY);
            let (mut clo, mut chi) = (_mm256_set1_ps(lo), _mm256_set1_ps(hi));
            let mut chr = _mm256_set1_ps(if hi < reach { hi } else { reach });
            let levels = [
                (v([0; 8]), v([0, 0, 0, 0, -1, -1, -1, -1])),
                (v([1, 1, 1, 1, 2, 2, 2, 2]), v([0, 0, -1, -1, 0, 0, -1, -1])),
                (v([3, 3, 4, 4, 5, 5, 6, 6]), v([0, -1, 0, -1, 0, -1, 0, -1])),
            ];
            for (path, above) in levels {
                let far = _mm256_castsi256_ps(_mm256_xor_si256(_mm256_permutevar8x32_epi32(neg, path), above));
                // A far side leaves `hi` alone, a near side `lo`; `minps` / `maxps` return
                // their second operand for NaN (as `fmin` / `fmax`), which never is NaN.
                let h = _mm256_blendv_ps(_mm256_permutevar8x32_ps(tp_hi, path), inf, far);
                let l = _mm256_blendv_ps(ninf, _mm256_permutevar8x32_ps(tp_lo, path), far);
                chi = _mm256_min_ps(h, chi);
                chr = _mm256_min_ps(h, chr);
                clo = _mm256_max_ps(l, clo);
            }
            let empty =
                _mm256_cmpeq_epi32(_mm256_and_si256(child, _mm256_set1_epi32(3)), _mm256_set1_epi32(EMPTY as i32));
            let keep = _mm256_andnot_si256(empty, _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LE_OQ>(clo, chr)));
            // Lane j of `order`: the child of rank 7 - j, from the table by the seven
            // nodes' direction signs.
            let signs = (_mm256_movemask_ps(_mm256_castsi256_ps(neg)) & 0x7f) as usize;
            let order = _mm256_and_si256(
                _mm256_srlv_epi32(_mm256_set1_epi32(ORDER[signs] as i32), v([0, 4, 8, 12, 16, 20, 24, 28])),
                _mm256_set1_epi32(15),
            );
            let mask = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_permutevar8x32_epi32(keep, order))) as usize;
            if mask == 0 {
                return None;
            }
            // The nearest: the highest lane of `order` kept.
            let top = 31 - (mask as u32).leading_zeros() as usize;
            let rest = mask ^ (1 << top);
            let mut ord = Lanes([0u32; 8]);
            let (mut los, mut his) = (Lanes([0f32; 8]), Lanes([0f32; 8]));
            // Aligned 32-byte arrays.
            _mm256_store_si256(ord.0.as_mut_ptr().cast(), order);
            _mm256_store_ps(los.0.as_mut_ptr(), clo);
            _mm256_store_ps(his.0.as_mut_ptr(), chi);
            let c = ord.0[top] as usize & 7;
            let nearest = (t.child[c], los.0[c], his.0[c]);
            if rest != 0 {
                let packed = _mm256_set1_epi32(COMPRESS[rest] as i32);
                let pick = _mm256_and_si256(
                    _mm256_srlv_epi32(packed, v([0, 4, 8, 12, 16, 20, 24, 28])),
                    _mm256_set1_epi32(15),
                );
                let idx = _mm256_permutevar8x32_epi32(order, pick);
                let sp = st.sp;
                assert!(sp + 8 <= STACK);
                // `sp + 8 <= STACK` (checked): eight lanes fit in each array.
                _mm256_storeu_si256(st.node.as_mut_ptr().add(sp).cast(), _mm256_permutevar8x32_epi32(child, idx));
                _mm256_storeu_ps(st.lo.as_mut_ptr().add(sp).cast(), _mm256_permutevar8x32_ps(clo, idx));
                _mm256_storeu_ps(st.hi.as_mut_ptr().add(sp).cast(), _mm256_permutevar8x32_ps(chi, idx));
                st.sp = sp + COUNT[rest] as usize;
            }
            Some(nearest)
        }
    }
}

#[cfg(test)]
mod tests;
