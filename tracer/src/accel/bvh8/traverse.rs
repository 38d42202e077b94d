//! Front-to-back traversal: each node's eight boxes are clipped against the ray at
//! once (eight lanes in AVX2, a loop otherwise), the children met are visited nearest
//! first, and a child is skipped once its interval starts beyond the current bound.
//!
//! Exactness, as in the kd-tree (`accel/exact.rs`): every interval is widened by
//! the slack (which covers the rounding of the plane distances and of the hit
//! distances) and a child is dropped only when its widened interval is empty or starts
//! beyond `bound + slack`; boxes are padded like the kd-tree's primitive extents. A
//! plane distance that is NaN (the ray lies in the slab's face plane, `0 · inf`) leaves
//! the interval as it is, on both sides. The leaves then run the shared closest- and
//! any-hit bookkeeping, which makes the answer brute force's.

use std::mem::MaybeUninit;

use glam::Vec3;

use super::build::MAX_BINARY_DEPTH;
use super::{Bvh8, EMPTY, LEAF, NODE, Node8, ONE, WIDTH};
use crate::accel::exact::{Closest, Setup, any_leaf, clip_to_cell, gatherable};
use crate::accel::prefetch;
use crate::accel::{Hit, Primitives, RayPrecomp};
use crate::geometry::Ray;

/// Stack entries: at most seven per wide level stay behind (the nearest child is taken
/// at once), and a wide level spans at least one binary level.
pub(super) const STACK: usize = (WIDTH - 1) * (MAX_BINARY_DEPTH + 1) + WIDTH;

/// Per-ray values of the box test: the origin, the reciprocal direction, and for each
/// axis the offsets (in floats, within a [`Node8`]'s bounds) of the near and far planes.
struct RayBoxes {
    o: [f32; 3],
    inv: [f32; 3],
    near: [usize; 3],
    far: [usize; 3],
    slack: f32,
}

impl RayBoxes {
    fn new(ray: &Ray, inv: Vec3, slack: f32) -> Self {
        // By the sign bit, so that -0 and +0 agree with the sign of `inv`.
        let neg = ray.dir.to_array().map(|x| x.is_sign_negative());
        let (lo, hi) = (|a: usize| a * WIDTH, |a: usize| 3 * WIDTH + a * WIDTH);
        Self {
            o: ray.origin.to_array(),
            inv: inv.to_array(),
            near: [0, 1, 2].map(|a| if neg[a] { hi(a) } else { lo(a) }),
            far: [0, 1, 2].map(|a| if neg[a] { lo(a) } else { hi(a) }),
            slack,
        }
    }
}

/// `a.max(b)` for a non-NaN `b`, and `b` when `a` is NaN (as `maxps`).
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// `a.min(b)` for a non-NaN `b`, and `b` when `a` is NaN (as `minps`).
#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

/// The node's bounds as one array: `lo` then `hi`, axis by axis, eight lanes each.
#[inline(always)]
pub(super) fn planes(n: &Node8) -> &[f32; 6 * WIDTH] {
    // SAFETY: `Node8` is `repr(C)` with `lo` and `hi` first, 48 contiguous f32s.
    unsafe { &*(n as *const Node8).cast::<[f32; 6 * WIDTH]>() }
}

/// The children of `n` whose widened interval within `[lo, hi]` is non-empty and starts
/// at most at `reach`, as a bit mask, and each child's interval start.
#[inline(always)]
fn boxes_scalar(n: &Node8, r: &RayBoxes, lo: f32, hi: f32, reach: f32, near: &mut [f32; WIDTH]) -> u32 {
    let p = planes(n);
    let mut mask = 0;
    for j in 0..WIDTH {
        let (mut tn, mut tf) = (f32::NEG_INFINITY, f32::INFINITY);
        for a in 0..3 {
            tn = fmax((p[r.near[a] + j] - r.o[a]) * r.inv[a], tn);
            tf = fmin((p[r.far[a] + j] - r.o[a]) * r.inv[a], tf);
        }
        let tn = fmax(tn - r.slack, lo);
        let tf = fmin(tf + r.slack, hi);
        near[j] = tn;
        if tn <= tf && tn <= reach {
            mask |= 1 << j;
        }
    }
    mask
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use core::arch::x86_64::*;

    use super::{Node8, RayBoxes, WIDTH, planes};

    /// The per-ray vectors of [`boxes`].
    pub(super) struct Lanes {
        o: [__m256; 3],
        inv: [__m256; 3],
        slack: __m256,
    }

    impl Lanes {
        #[target_feature(enable = "avx2")]
        #[inline]
        pub(super) fn new(r: &RayBoxes) -> Self {
            Self {
                o: r.o.map(|x| _mm256_set1_ps(x)),
                inv: r.inv.map(|x| _mm256_set1_ps(x)),
                slack: _mm256_set1_ps(r.slack),
            }
        }
    }

    /// [`super::boxes_scalar`] in eight lanes, the same operations in the same order.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) fn boxes(
        n: &Node8,
        r: &RayBoxes,
        v: &Lanes,
        lo: f32,
        hi: f32,
        reach: f32,
        near: &mut [f32; WIDTH],
    ) -> u32 {
        let p = planes(n).as_ptr();
        // SAFETY: the offsets are multiples of eight below 48, so each load reads eight
        // floats of the node, 32-byte aligned (the node is 64-byte aligned).
        let ld = |at: usize| unsafe { _mm256_load_ps(p.add(at)) };
        let mut tn = _mm256_set1_ps(f32::NEG_INFINITY);
        let mut tf = _mm256_set1_ps(f32::INFINITY);
        for a in 0..3 {
            // `maxps(x, acc)` returns `acc` when `x` is NaN, as `fmax` does.
            tn = _mm256_max_ps(_mm256_mul_ps(_mm256_sub_ps(ld(r.near[a]), v.o[a]), v.inv[a]), tn);
            tf = _mm256_min_ps(_mm256_mul_ps(_mm256_sub_ps(ld(r.far[a]), v.o[a]), v.inv[a]), tf);
        }
        let tn = _mm256_max_ps(_mm256_sub_ps(tn, v.slack), _mm256_set1_ps(lo));
        let tf = _mm256_min_ps(_mm256_add_ps(tf, v.slack), _mm256_set1_ps(hi));
        let keep =
            _mm256_and_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(tn, tf), _mm256_cmp_ps::<_CMP_LE_OQ>(tn, _mm256_set1_ps(reach)));
        // SAFETY: `near` is eight floats.
        unsafe { _mm256_storeu_ps(near.as_mut_ptr(), tn) };
        _mm256_movemask_ps(keep) as u32
    }
}

/// The slots in `mask` by interval start, nearest last (ties by slot), and how many:
/// an insertion sort, as there are at most eight.
#[inline(always)]
pub(super) fn by_distance(mask: u32, near: &[f32; WIDTH]) -> ([usize; WIDTH], usize) {
    let mut k = [0usize; WIDTH];
    let mut len = 0;
    let mut m = mask;
    while m != 0 {
        let j = m.trailing_zeros() as usize;
        m &= m - 1;
        let mut p = len;
        while p > 0 && near[k[p - 1]] < near[j] {
            k[p] = k[p - 1];
            p -= 1;
        }
        k[p] = j;
        len += 1;
    }
    (k, len)
}

/// The walk's stack of (reference, interval start), uninitialised above `sp`.
struct Stack {
    node: [MaybeUninit<u32>; STACK],
    near: [MaybeUninit<f32>; STACK],
    sp: usize,
}

impl Stack {
    #[inline(always)]
    fn new() -> Self {
        Self { node: [const { MaybeUninit::uninit() }; STACK], near: [const { MaybeUninit::uninit() }; STACK], sp: 0 }
    }

    #[inline(always)]
    fn push(&mut self, node: u32, near: f32) {
        self.node[self.sp] = MaybeUninit::new(node);
        self.near[self.sp] = MaybeUninit::new(near);
        self.sp += 1;
    }

    #[inline(always)]
    fn pop(&mut self) -> Option<(u32, f32)> {
        if self.sp == 0 {
            return None;
        }
        self.sp -= 1;
        // SAFETY: entries below `sp` were written by `push`.
        Some(unsafe { (self.node[self.sp].assume_init(), self.near[self.sp].assume_init()) })
    }
}

impl Bvh8 {
    /// Walks the hierarchy front to back, calling `leaf` with each leaf's primitives;
    /// `leaf` returns the new bound (children starting beyond `bound + slack` are
    /// skipped) or NaN to stop. `AVX2`: test the boxes in eight lanes.
    #[inline(always)]
    fn walk<P: Primitives, const AVX2: bool>(
        &self,
        prims: &P,
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
        let r = RayBoxes::new(ray, inv, slack);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `AVX2` is set only on the paths `InstructionSet::Avx2` selects.
        let lanes = AVX2.then(|| unsafe { avx2::Lanes::new(&r) });
        let mut st = Stack::new();
        let mut near = [0.0f32; WIDTH];
        let mut at = self.root;
        'walk: loop {
            let i = (at >> 2) as usize;
            match at & 3 {
                NODE => {
                    let n = &self.nodes[i];
                    let mask = match &lanes {
                        #[cfg(target_arch = "x86_64")]
                        // SAFETY: `lanes` exists only on the AVX2 paths.
                        Some(v) => unsafe { avx2::boxes(n, &r, v, s.lo, s.hi, reach, &mut near) },
                        _ => boxes_scalar(n, &r, s.lo, s.hi, reach, &mut near),
                    };
                    if mask != 0 {
                        self.prefetch_children(prims, n, mask);
                        at = self.order(n, mask, &near, &mut st);
                        continue 'walk;
                    }
                }
                LEAF | ONE => {
                    let one = [at >> 2];
                    let ids: &[u32] =
                        if at & 3 == LEAF { &self.leaves[i + 1..i + 1 + self.leaves[i] as usize] } else { &one };
                    bound = leaf(ids);
                    if bound.is_nan() {
                        return;
                    }
                    reach = bound + slack;
                }
                _ => debug_assert_eq!(at & 3, EMPTY),
            }
            loop {
                let Some((next, tn)) = st.pop() else { return };
                if tn <= reach {
                    at = next;
                    continue 'walk;
                }
            }
        }
    }

    /// Starts loading the children in `mask`: their node's four lines, or a leaf's
    /// list. The nearest is needed at once, and waiting for its lines one node after
    /// another would be most of a walk's time.
    #[inline(always)]
    pub(super) fn prefetch_children<P: Primitives>(&self, prims: &P, n: &Node8, mask: u32) {
        let mut m = mask;
        while m != 0 {
            let j = m.trailing_zeros() as usize;
            let c = n.child[j];
            m &= m - 1;
            let i = (c >> 2) as usize;
            match c & 3 {
                NODE => {
                    let p = self.nodes.as_ptr().wrapping_add(i).cast::<u8>();
                    for k in 0..size_of::<Node8>() / 64 {
                        prefetch(p.wrapping_add(64 * k));
                    }
                }
                LEAF => {
                    prefetch(self.leaves.as_ptr().wrapping_add(i));
                    let f = n.first[j];
                    for k in [0, 2, 4, 6] {
                        prims.prefetch(f.wrapping_add(k));
                    }
                }
                ONE => prims.prefetch(c >> 2),
                _ => {}
            }
        }
    }

    /// Pushes the children in `mask` but the nearest, farthest first, and returns the
    /// nearest (ties by slot).
    #[inline(always)]
    fn order(&self, n: &Node8, mask: u32, near: &[f32; WIDTH], st: &mut Stack) -> u32 {
        let first = mask.trailing_zeros() as usize;
        let rest = mask & (mask - 1);
        if rest == 0 {
            return n.child[first];
        }
        let second = rest.trailing_zeros() as usize;
        if rest & (rest - 1) == 0 {
            let (a, b) = if near[second] < near[first] { (second, first) } else { (first, second) };
            st.push(n.child[b], near[b]);
            return n.child[a];
        }
        // Three or more.
        let (k, len) = by_distance(mask, near);
        for &j in &k[..len - 1] {
            st.push(n.child[j], near[j]);
        }
        n.child[k[len - 1]]
    }

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
        if self.root & 3 == EMPTY {
            return None;
        }
        let pre = RayPrecomp::new(ray);
        let s = clip_to_cell(&self.cell, ray, pre.inv_dir, tmax)?;
        let mut c = Closest::new(tmax, s.slack);
        let corners = gatherable(prims);
        self.walk::<P, AVX2>(prims, ray, pre.inv_dir, &s, tmax, |ids| {
            c.leaf::<P, AVX2>(prims, corners, ids, ray, &pre)
        });
        c.finish(prims, ray, &pre, tmax)
    }

    #[inline(always)]
    pub(super) fn occluded_impl<P: Primitives, const AVX2: bool>(&self, prims: &P, ray: &Ray, tmax: f32) -> bool {
        if self.root & 3 == EMPTY {
            return false;
        }
        let pre = RayPrecomp::new(ray);
        let Some(s) = clip_to_cell(&self.cell, ray, pre.inv_dir, tmax) else { return false };
        let corners = gatherable(prims);
        let mut hit = false;
        self.walk::<P, AVX2>(prims, ray, pre.inv_dir, &s, tmax, |ids| {
            any_leaf::<P, AVX2>(prims, corners, ids, ray, &pre, tmax, &mut hit)
        });
        hit
    }
}
