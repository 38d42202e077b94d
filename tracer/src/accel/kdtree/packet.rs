//! Eight rays through the tree together, for callers whose eight rays are coherent: a
//! tile's camera rays, shadow rays from them towards one light.
//!
//! The eight-path renderer (`integrator/eight_paths.rs`) does not use it: its lanes
//! refill one by one, so after the first round a packet mixes camera, bounce and shadow
//! rays from unrelated points, and the grouped walk cost more than it saved
//! (`bench/RESULTS.md`, "Packet queries through the kd-tree").
//!
//! The walk is the one-ray walk of `traverse.rs` with a lane mask: a treelet step
//! computes the grandchildren's intervals for all eight rays at once (one lane per ray),
//! the packet descends into the nearest child that any of its rays reaches, and the
//! others are pushed with the lanes that reach them. Leaves are tested ray by ray, by the
//! one-ray query's own leaf code. For coherent rays (a tile's camera rays, shadow rays
//! towards one light) most node steps then serve eight rays instead of one.
//!
//! Exactness. Each lane visits the same leaves in the same order as its one-ray walk,
//! so its leaf calls, and its answer, are that query's bit for bit: the rays walked
//! together have the same direction signs (lanes of another sign pattern walk apart),
//! so the children's front-to-back order is the same for all; a lane's intervals come
//! from the one-ray step's operations (`Stack::step`), are kept by the same test against
//! the lane's own reach, visited nearest first, and checked again when popped. A lane
//! that does not reach the packet's nearest child waits on the stack with its own
//! nearest, and its reach does not change meanwhile, as only its own leaves change it.

use super::KdTree;
use crate::accel::Primitives;
#[cfg(target_arch = "x86_64")]
use crate::accel::block_test::InstructionSet;
use crate::accel::ray_packets::{PacketHits, RayPacket};
use crate::simd::each;

impl KdTree {
    /// The nearest hits of the packet's active lanes: lane by lane exactly
    /// [`KdTree::intersect`] (and so brute force) of its ray and `tmax`.
    pub fn intersect8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> PacketHits {
        #[cfg(target_arch = "x86_64")]
        if matches!(self.simd, InstructionSet::Avx2 | InstructionSet::Avx512) {
            // SAFETY: `Avx2` and `Avx512` are only chosen when the CPU reports AVX2.
            return unsafe { self.intersect8_avx2(prims, rays) };
        }
        let mut out = PacketHits::none();
        for l in each(rays.active) {
            out.put(l, self.intersect(prims, &rays.ray(l), rays.tmax[l]));
        }
        out
    }

    /// Which active lanes hit anything: lane by lane exactly [`KdTree::occluded`].
    pub fn occluded8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if matches!(self.simd, InstructionSet::Avx2 | InstructionSet::Avx512) {
            // SAFETY: as in `intersect8`.
            return unsafe { self.occluded8_avx2(prims, rays) };
        }
        each(rays.active).fold(0, |m, l| m | (u32::from(self.occluded(prims, &rays.ray(l), rays.tmax[l])) << l))
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use core::arch::x86_64::*;
    use std::mem::MaybeUninit;

    use super::super::KdTree;
    use super::super::treelet::{EMPTY, LEAF, ONE, PATH, STACK, TREELET, Treelet, child_of_rank, prefetch_children};
    use crate::accel::exact::{Closest, any_leaf, gatherable};
    use crate::accel::ray_packets::{PACKET, PacketHits, RayPacket};
    use crate::accel::{Primitives, RayPrecomp};
    use crate::geometry::Ray;
    use crate::simd::each;

    /// The lanes' rays as the one-ray queries see them, clipped to the root cell.
    struct Lanes {
        ray: [Ray; PACKET],
        pre: [RayPrecomp; PACKET],
        tmax: [f32; PACKET],
        lo: [f32; PACKET],
        hi: [f32; PACKET],
        slack: [f32; PACKET],
        /// The lanes asked for whose ray meets the root cell.
        walking: u32,
    }

    impl Lanes {
        #[inline(always)]
        fn new(tree: &KdTree, rays: &RayPacket, lanes: u32) -> Self {
            let ray: [Ray; PACKET] = core::array::from_fn(|l| rays.ray(l));
            let pre = core::array::from_fn(|l| RayPrecomp::new(&ray[l]));
            let mut s = Lanes {
                ray,
                pre,
                tmax: rays.tmax,
                lo: [0.0; PACKET],
                hi: [0.0; PACKET],
                slack: [0.0; PACKET],
                walking: 0,
            };
            for l in each(lanes) {
                if let Some(set) = tree.setup(&s.ray[l], s.pre[l].inv_dir, s.tmax[l]) {
                    (s.lo[l], s.hi[l], s.slack[l]) = (set.lo, set.hi, set.slack);
                    s.walking |= 1 << l;
                }
            }
            s
        }
    }

    /// The packet walk's stack: per entry a child reference, its lanes and their
    /// intervals. Uninitialised: an entry is read only below `sp`, where it was written.
    struct Stack8 {
        node: [MaybeUninit<u32>; STACK],
        mask: [MaybeUninit<u32>; STACK],
        lo: [MaybeUninit<__m256>; STACK],
        hi: [MaybeUninit<__m256>; STACK],
        sp: usize,
    }

    impl Stack8 {
        #[inline(always)]
        fn new() -> Self {
            Self {
                node: [const { MaybeUninit::uninit() }; STACK],
                mask: [const { MaybeUninit::uninit() }; STACK],
                lo: [const { MaybeUninit::uninit() }; STACK],
                hi: [const { MaybeUninit::uninit() }; STACK],
                sp: 0,
            }
        }

        #[inline(always)]
        fn push(&mut self, node: u32, mask: u32, lo: __m256, hi: __m256) {
            // At most seven entries stay behind per treelet level, as on the one-ray
            // stack, which is sized for that.
            let i = self.sp;
            self.node[i] = MaybeUninit::new(node);
            self.mask[i] = MaybeUninit::new(mask);
            self.lo[i] = MaybeUninit::new(lo);
            self.hi[i] = MaybeUninit::new(hi);
            self.sp += 1;
        }

        #[inline(always)]
        fn pop(&mut self) -> Option<(u32, u32, __m256, __m256)> {
            if self.sp == 0 {
                return None;
            }
            self.sp -= 1;
            let i = self.sp;
            // SAFETY: entries below `sp` were all written.
            Some(unsafe {
                (
                    self.node[i].assume_init(),
                    self.mask[i].assume_init(),
                    self.lo[i].assume_init(),
                    self.hi[i].assume_init(),
                )
            })
        }
    }

    /// The rays of one walk in registers: lanes' origins, reciprocal directions and
    /// slacks, and the sign pattern they share.
    struct Walk {
        o: [__m256; 3],
        inv: [__m256; 3],
        slack: __m256,
        signs: u32,
    }

    /// Fewest rays of one sign pattern that walk together.
    const MIN_GROUP: u32 = 4;

    /// A ray's direction signs, bit `a` for axis `a` (by the sign bit, as the one-ray
    /// walk's).
    #[inline(always)]
    fn signs(ray: &Ray) -> u32 {
        let d = ray.dir;
        u32::from(d.x.is_sign_negative())
            | u32::from(d.y.is_sign_negative()) << 1
            | u32::from(d.z.is_sign_negative()) << 2
    }

    /// The active lanes that walk together: those whose sign pattern at least
    /// [`MIN_GROUP`] lanes share. The others take the one-ray query, for which the
    /// packet walk's bookkeeping would not pay (incoherent rays: four of eight share
    /// their signs in few packets).
    #[inline(always)]
    fn together(rays: &RayPacket) -> u32 {
        let active = rays.active & ((1 << PACKET) - 1);
        let mut count = [0u32; 8];
        let sig: [u32; PACKET] = core::array::from_fn(|l| {
            u32::from(rays.dir[0][l].is_sign_negative())
                | u32::from(rays.dir[1][l].is_sign_negative()) << 1
                | u32::from(rays.dir[2][l].is_sign_negative()) << 2
        });
        for l in each(active) {
            count[sig[l] as usize] += 1;
        }
        each(active).filter(|&l| count[sig[l] as usize] >= MIN_GROUP).fold(0, |m, l| m | 1 << l)
    }

    /// Lanes where `a <= b` (ordered).
    #[inline(always)]
    fn le(a: __m256, b: __m256) -> u32 {
        // SAFETY: the callers run only on the AVX2 paths.
        unsafe { _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(a, b)) as u32 }
    }

    #[inline(always)]
    fn load(a: &[f32; PACKET]) -> __m256 {
        // SAFETY: eight floats, read unaligned; AVX2 as in `le`.
        unsafe { _mm256_loadu_ps(a.as_ptr()) }
    }

    impl KdTree {
        #[target_feature(enable = "avx2")]
        pub(super) unsafe fn intersect8_avx2<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> PacketHits {
            let together = together(rays);
            let mut out = PacketHits::none();
            for l in each(rays.active & !together) {
                out.put(l, self.intersect_impl::<P, true>(prims, &rays.ray(l), rays.tmax[l]));
            }
            if together == 0 {
                return out;
            }
            let lanes = Lanes::new(self, rays, together);
            let corners = gatherable(prims);
            let mut q: [Closest; PACKET] = core::array::from_fn(|l| Closest::new(lanes.tmax[l], lanes.slack[l]));
            self.walk_groups(&lanes, |l, ids| q[l].leaf::<P, true>(prims, corners, ids, &lanes.ray[l], &lanes.pre[l]));
            for l in each(lanes.walking) {
                out.put(l, q[l].finish(prims, &lanes.ray[l], &lanes.pre[l], lanes.tmax[l]));
            }
            out
        }

        #[target_feature(enable = "avx2")]
        pub(super) unsafe fn occluded8_avx2<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> u32 {
            let together = together(rays);
            let mut hit = [false; PACKET];
            for l in each(rays.active & !together) {
                hit[l] = self.occluded_impl::<P, true>(prims, &rays.ray(l), rays.tmax[l]);
            }
            if together != 0 {
                let lanes = Lanes::new(self, rays, together);
                let corners = gatherable(prims);
                self.walk_groups(&lanes, |l, ids| {
                    any_leaf::<P, true>(prims, corners, ids, &lanes.ray[l], &lanes.pre[l], lanes.tmax[l], &mut hit[l])
                });
            }
            (0..PACKET).fold(0, |m, l| m | (u32::from(hit[l]) << l))
        }

        /// Walks the lanes in groups of one sign pattern, each group together.
        #[inline(always)]
        fn walk_groups(&self, lanes: &Lanes, mut leaf: impl FnMut(usize, &[u32]) -> f32) {
            let mut todo = lanes.walking;
            while todo != 0 {
                let pattern = signs(&lanes.ray[todo.trailing_zeros() as usize]);
                let group = each(todo).filter(|&l| signs(&lanes.ray[l]) == pattern).fold(0, |m, l| m | 1 << l);
                todo &= !group;
                // SAFETY: this module runs only on the AVX2 paths.
                unsafe { self.walk8(lanes, group, pattern, &mut leaf) };
            }
        }

        /// The one-ray walk (`KdTree::walk`) for the lanes `group`, which share the
        /// direction signs `signs`: `leaf(l, ids)` for each leaf lane `l` reaches, in
        /// the order its own walk would, returning its new bound or NaN to stop.
        ///
        /// # Safety
        /// The CPU must have AVX2.
        #[inline(always)]
        unsafe fn walk8(&self, lanes: &Lanes, group: u32, signs: u32, leaf: &mut impl FnMut(usize, &[u32]) -> f32) {
            let w = Walk {
                o: [0, 1, 2].map(|a| load(&core::array::from_fn(|l| lanes.ray[l].origin[a]))),
                inv: [0, 1, 2].map(|a| load(&core::array::from_fn(|l| lanes.pre[l].inv_dir[a]))),
                slack: load(&lanes.slack),
                signs,
            };
            // Each lane's reach: its bound plus its slack (the bound starts at `tmax`).
            let mut reach: [f32; PACKET] = core::array::from_fn(|l| lanes.tmax[l] + lanes.slack[l]);
            let (mut lo, mut hi) = (load(&lanes.lo), load(&lanes.hi));
            let mut m = group & le(lo, load(&reach));
            if m == 0 {
                return;
            }
            let mut st = Stack8::new();
            let bases = (self.treelets.as_ptr() as usize, self.leaves.as_ptr() as usize);
            let mut r = self.root;
            loop {
                let at = (r >> 2) as usize;
                let next = match r & 3 {
                    // SAFETY: AVX2 (the caller's promise).
                    TREELET => unsafe { step8(&mut st, &self.treelets[at], &w, m, lo, hi, load(&reach), bases) },
                    kind => {
                        let one = [r >> 2];
                        let ids: &[u32] = match kind {
                            LEAF => &self.leaves[at + 1..at + 1 + self.leaves[at] as usize],
                            ONE => &one,
                            _ => &[],
                        };
                        if !ids.is_empty() {
                            for l in each(m) {
                                // NaN (stop) stays NaN: the lane reaches nothing more.
                                reach[l] = leaf(l, ids) + lanes.slack[l];
                            }
                        }
                        None
                    }
                };
                match next {
                    Some(n) => (r, m, lo, hi) = n,
                    None => loop {
                        let Some((node, mask, elo, ehi)) = st.pop() else { return };
                        let keep = mask & le(elo, load(&reach));
                        if keep != 0 {
                            (r, m, lo, hi) = (node, keep, elo, ehi);
                            break;
                        }
                    },
                }
            }
        }
    }

    /// [`super::super::treelet::Stack::step`] for the lanes `m`, one lane per ray: the
    /// children each lane reaches (by the one-ray step's operations, against its own
    /// `reach`) are pushed farthest first with their lanes, and the nearest is taken.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    unsafe fn step8(
        st: &mut Stack8,
        t: &Treelet,
        w: &Walk,
        m: u32,
        lo: __m256,
        hi: __m256,
        reach: __m256,
        (tb, lb): (usize, usize),
    ) -> Option<(u32, u32, __m256, __m256)> {
        // SAFETY: AVX2 (the caller's promise); the treelet's children are its last 32
        // bytes, 32-byte aligned.
        unsafe {
            prefetch_children(_mm256_load_si256(t.child.as_ptr().cast()), tb, lb);
            let mut tp_lo = [_mm256_setzero_ps(); 7];
            let mut tp_hi = [_mm256_setzero_ps(); 7];
            let mut neg = 0usize;
            for k in 0..7 {
                let a = ((t.axes >> (2 * k)) & 3) as usize;
                let tp = _mm256_mul_ps(_mm256_sub_ps(_mm256_set1_ps(t.split[k]), w.o[a]), w.inv[a]);
                tp_lo[k] = _mm256_sub_ps(tp, w.slack);
                tp_hi[k] = _mm256_add_ps(tp, w.slack);
                neg |= (((w.signs >> a) & 1) as usize) << k;
            }
            let before = st.sp;
            for rank in (0..8).rev() {
                let c = child_of_rank(rank, neg);
                if t.child[c] & 3 == EMPTY {
                    continue;
                }
                let (mut clo, mut chi) = (lo, hi);
                for (l, path) in PATH.iter().enumerate() {
                    let k = path[c];
                    let above = (c >> (2 - l)) & 1 == 1;
                    // `maxps` / `minps` return their second operand for a NaN distance
                    // (a ray in the plane), as the one-ray step's `fmax` / `fmin`.
                    if above != ((neg >> k) & 1 == 1) {
                        clo = _mm256_max_ps(tp_lo[k], clo);
                    } else {
                        chi = _mm256_min_ps(tp_hi[k], chi);
                    }
                }
                let keep = m & le(clo, _mm256_min_ps(chi, reach));
                if keep != 0 {
                    st.push(t.child[c], keep, clo, chi);
                }
            }
            if st.sp > before { st.pop() } else { None }
        }
    }
}
