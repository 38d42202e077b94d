//! The kd-tree's front-to-back walk (pbrt-style, fixed-size stack), whose leaves run the
//! exact bookkeeping of `accel/exact.rs`: its answers are bit-identical to
//! [`brute_force_intersect`] / [`brute_force_occluded`].
//!
//! [`brute_force_intersect`]: crate::accel::brute_force_intersect
//! [`brute_force_occluded`]: crate::accel::brute_force_occluded

use glam::Vec3;

use super::KdTree;
use super::treelet::{EMPTY, LEAF, ONE, RayAxes, Stack, TREELET, Treelet};
#[cfg(target_arch = "x86_64")]
use super::treelet::{RayLanes, step_avx2};
use crate::accel::exact::{Closest, Setup, any_leaf, clip_to_cell, gatherable};
use crate::accel::{Hit, Primitives, RayPrecomp, prefetch};
use crate::geometry::Ray;

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
