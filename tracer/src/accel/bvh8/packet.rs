//! Eight rays through the hierarchy together, for callers whose rays are coherent: a
//! tile's camera rays, shadow rays from neighbouring points towards one light.
//!
//! Rays walked together share their direction signs and start and point close to one
//! another ([`coherent_groups`]; the others go one by one). Each node's eight boxes are
//! tested once for the whole packet, against its frustum: bounds on all the rays' plane
//! distances, from the extremes of their origins and reciprocal directions, in one
//! eight-lane test like one ray's. Only leaves are met ray by ray: a node's leaf children
//! are clipped against the eight rays at once (one lane per ray, the one-ray test's
//! operations), and a leaf is tested, with the one-ray leaf code and each ray's own
//! bound, for the rays that reach it, from one load of its triangles. Coherent rays
//! share most nodes and many leaves, so a node test or a leaf's load serves up to eight
//! rays instead of one.
//!
//! Exactness: each lane's answer is its one-ray query's (brute force's) bit for bit.
//! - The frustum keeps every child a ray of the packet keeps. With a common sign, a
//!   ray's plane distance `fl(fl(p - o) · i)` is monotone in `o` and in `i` (rounding is
//!   monotone), so over the packet it is at least the smaller of `fl(fl(p - o*) · i)` at
//!   the two extremes of `i`, `o*` being the extreme origin on the near side, and at
//!   most the larger on the far side. Widened by the largest slack, clipped to the lowest
//!   start and the highest end and held against the largest reach, the frustum's
//!   interval covers each ray's. Reciprocals are finite and non-zero and origins finite
//!   (lanes otherwise go alone), so no distance is NaN.
//! - So a ray meets every leaf its one-ray walk would: the leaf's own box test is the
//!   one-ray test with the ray's reach, and a leaf is dropped for a ray only when its
//!   start lies beyond the ray's current reach, as the one-ray walk drops it.
//! - The order of a ray's leaves does not matter: its closest-hit bookkeeping collects
//!   every hit within a margin of the nearest and replays them in index order
//!   (`accel/exact.rs`), and an any-hit query stops at any hit.

use super::Bvh8;
use crate::accel::Primitives;
#[cfg(target_arch = "x86_64")]
use crate::accel::block_test::InstructionSet;
use crate::accel::ray_packets::{PacketHits, RayPacket};
use crate::simd::each;

impl Bvh8 {
    /// The nearest hits of the packet's active lanes: lane by lane exactly
    /// [`Bvh8::intersect`] (and so brute force) of its ray and `tmax`.
    pub fn intersect8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> PacketHits {
        let mut out = PacketHits::none();
        let mut alone = rays.active;
        #[cfg(target_arch = "x86_64")]
        if matches!(self.simd, InstructionSet::Avx2 | InstructionSet::Avx512) {
            for group in coherent_groups(rays, &self.bounds) {
                // SAFETY: `Avx2` and `Avx512` are only chosen when the CPU reports AVX2.
                alone &= !group | unsafe { self.intersect8_avx2(prims, rays, group, &mut out) };
            }
        }
        for l in each(alone) {
            out.put(l, self.intersect(prims, &rays.ray(l), rays.tmax[l]));
        }
        out
    }

    /// Which active lanes hit anything: lane by lane exactly [`Bvh8::occluded`].
    pub fn occluded8<P: Primitives>(&self, prims: &P, rays: &RayPacket) -> u32 {
        let mut hit = 0;
        let mut alone = rays.active;
        #[cfg(target_arch = "x86_64")]
        if matches!(self.simd, InstructionSet::Avx2 | InstructionSet::Avx512) {
            for group in coherent_groups(rays, &self.bounds) {
                // SAFETY: as in `intersect8`.
                let (h, refused) = unsafe { self.occluded8_avx2(prims, rays, group) };
                hit |= h;
                alone &= !group | refused;
            }
        }
        for l in each(alone) {
            hit |= u32::from(self.occluded(prims, &rays.ray(l), rays.tmax[l])) << l;
        }
        hit
    }
}

/// Largest spread of a group's origins, per axis, as a fraction of the hierarchy's
/// diagonal: the frustum of rays from far-apart points holds most of the scene, and
/// such rays are faster one by one (incoherent rays in packets took 50 to 100 times as
/// long before this check, `bench/RESULTS.md`).
const ORIGIN_SPREAD: f32 = 0.05;

/// Smallest cosine between a group's directions and its first ray's (about 5.7°).
const DIRECTION_COS: f32 = 0.995;

/// The active lanes that can walk together: groups of at least two rays with the same
/// direction signs, origins within [`ORIGIN_SPREAD`] and directions within the angle of
/// [`DIRECTION_COS`] of the group's first ray, direction components that are normal
/// numbers (so their reciprocals are finite and non-zero) and finite origins.
#[cfg(target_arch = "x86_64")]
pub(super) fn coherent_groups(rays: &RayPacket, bounds: &crate::geometry::Aabb) -> impl Iterator<Item = u32> {
    use glam::Vec3;
    let mut by_sign = [0u32; 8];
    for l in each(rays.active) {
        let ok = (0..3).all(|a| rays.dir[a][l].is_normal() && rays.origin[a][l].is_finite());
        if ok {
            let key = (0..3).fold(0, |k, a| k | (usize::from(rays.dir[a][l] < 0.0) << a));
            by_sign[key] |= 1 << l;
        }
    }
    let reach = ORIGIN_SPREAD * bounds.diagonal().length();
    let at = |l: usize| {
        let o = Vec3::new(rays.origin[0][l], rays.origin[1][l], rays.origin[2][l]);
        let d = Vec3::new(rays.dir[0][l], rays.dir[1][l], rays.dir[2][l]);
        (o, d)
    };
    by_sign.into_iter().filter(|m| m.count_ones() >= 2).filter_map(move |m| {
        let (o0, d0) = at(m.trailing_zeros() as usize);
        let near: u32 = each(m)
            .filter(|&l| {
                let (o, d) = at(l);
                // cos² ≥ DIRECTION_COS², without a square root (the dot product is
                // positive: the signs agree).
                let dot = d.dot(d0);
                let close = dot * dot >= DIRECTION_COS * DIRECTION_COS * d.length_squared() * d0.length_squared();
                (o - o0).abs().max_element() <= reach && close
            })
            .fold(0, |g, l| g | (1 << l));
        (near.count_ones() >= 2).then_some(near)
    })
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use core::arch::x86_64::*;
    use core::mem::MaybeUninit;

    use super::super::traverse::{STACK, by_distance, planes};
    use super::super::{Bvh8, EMPTY, LEAF, NODE, Node8, ONE, WIDTH};
    use crate::accel::block_test::{Gathered, LANES, gather_avx2};
    use crate::accel::exact::{Closest, any_leaf, any_leaf_gathered, clip_to_cell, gatherable, gathers};
    use crate::accel::ray_packets::{PACKET, PacketHits, RayPacket};
    use crate::accel::{Primitives, RayPrecomp};
    use crate::geometry::Ray;
    use crate::simd::each;

    /// The packet's bounds for the node test (children in lanes): per axis the plane
    /// offsets within a node (as the one-ray `RayBoxes`), the origin extremes for the
    /// near and far planes, the reciprocals' extremes; the largest slack, the lowest
    /// start, the highest end.
    struct Frustum {
        near: [usize; 3],
        far: [usize; 3],
        o_near: [f32; 3],
        o_far: [f32; 3],
        inv_lo: [f32; 3],
        inv_hi: [f32; 3],
        slack: f32,
        lo: f32,
        hi: f32,
    }

    /// The rays' values for the leaf test (rays in lanes), as each one-ray query has them.
    #[repr(C, align(32))]
    struct RayLanes {
        o: [[f32; PACKET]; 3],
        inv: [[f32; PACKET]; 3],
        slack: [f32; PACKET],
        lo: [f32; PACKET],
        hi: [f32; PACKET],
        /// The bound each ray's leaves have set, widened by its slack.
        reach: [f32; PACKET],
    }

    /// Each lane's ray and its precomputed values, as its one-ray query has them.
    struct Query {
        ray: [Ray; PACKET],
        pre: [RayPrecomp; PACKET],
    }

    impl Query {
        #[inline(always)]
        fn new(rays: &RayPacket) -> Self {
            let ray: [Ray; PACKET] = core::array::from_fn(|l| rays.ray(l));
            let pre = core::array::from_fn(|l| RayPrecomp::new(&ray[l]));
            Query { ray, pre }
        }
    }

    /// The group's walk state.
    struct Rays {
        lanes: RayLanes,
        frustum: Frustum,
        /// The signs of the group's directions.
        neg: [bool; 3],
        /// The rays still walking.
        walking: u32,
        /// The rays that met the hierarchy's cell (the others have no hit).
        started: u32,
        /// The group's rays left to the one-ray query (a slack too large to bound).
        refused: u32,
    }

    impl Rays {
        #[inline(always)]
        fn new(b: &Bvh8, rays: &RayPacket, group: u32, q: &Query) -> Self {
            let (ray, pre) = (&q.ray, &q.pre);
            let mut lanes = RayLanes {
                o: [[0.0; PACKET]; 3],
                inv: [[1.0; PACKET]; 3],
                slack: [0.0; PACKET],
                lo: [0.0; PACKET],
                hi: [0.0; PACKET],
                reach: [f32::NEG_INFINITY; PACKET],
            };
            let (mut walking, mut refused) = (0, 0);
            // An empty hierarchy: no lane walks, none has a hit.
            let group = if b.root & 3 == EMPTY { 0 } else { group };
            for l in each(group) {
                let Some(s) = clip_to_cell(&b.cell, &ray[l], pre[l].inv_dir, rays.tmax[l]) else { continue };
                if !s.slack.is_finite() {
                    refused |= 1 << l;
                    continue;
                }
                let reach = rays.tmax[l] + s.slack;
                if !(s.lo <= reach) {
                    continue;
                }
                for a in 0..3 {
                    lanes.o[a][l] = ray[l].origin[a];
                    lanes.inv[a][l] = pre[l].inv_dir[a];
                }
                (lanes.slack[l], lanes.lo[l], lanes.hi[l], lanes.reach[l]) = (s.slack, s.lo, s.hi, reach);
                walking |= 1 << l;
            }
            let lead = (group.trailing_zeros() as usize).min(PACKET - 1);
            // By the sign bit, as `RayBoxes`: the group shares it.
            let neg = ray[lead].dir.to_array().map(|x| x.is_sign_negative());
            let frustum = Frustum::of(&lanes, walking, neg);
            Rays { lanes, neg, frustum, walking, started: walking, refused }
        }

        /// The largest reach of the rays still walking.
        #[inline(always)]
        fn reach(&self) -> f32 {
            each(self.walking).map(|l| self.lanes.reach[l]).fold(f32::NEG_INFINITY, |m, x| if x > m { x } else { m })
        }
    }

    impl Frustum {
        /// The frustum of the rays `walking`, whose directions have the signs `neg`.
        #[inline(always)]
        fn of(r: &RayLanes, walking: u32, neg: [bool; 3]) -> Self {
            let (lo, hi) = (|a: usize| a * WIDTH, |a: usize| 3 * WIDTH + a * WIDTH);
            let ext = |v: &[f32; PACKET], max: bool| {
                each(walking).map(|l| v[l]).reduce(|a, b| if max { a.max(b) } else { a.min(b) }).unwrap_or(0.0)
            };
            Frustum {
                near: [0, 1, 2].map(|a| if neg[a] { hi(a) } else { lo(a) }),
                far: [0, 1, 2].map(|a| if neg[a] { lo(a) } else { hi(a) }),
                // Positive direction: the near distance `(lo - o) · i` is least at the
                // largest origin, the far one `(hi - o) · i` largest at the smallest;
                // negative: the other way round.
                o_near: [0, 1, 2].map(|a| ext(&r.o[a], !neg[a])),
                o_far: [0, 1, 2].map(|a| ext(&r.o[a], neg[a])),
                inv_lo: [0, 1, 2].map(|a| ext(&r.inv[a], false)),
                inv_hi: [0, 1, 2].map(|a| ext(&r.inv[a], true)),
                slack: ext(&r.slack, true),
                lo: ext(&r.lo, false),
                hi: ext(&r.hi, true),
            }
        }
    }

    /// The children of `n` whose frustum interval is non-empty and starts at most at
    /// `reach`, as a bit mask, and each child's interval start.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn frustum_boxes(n: &Node8, f: &Frustum, reach: f32, near: &mut [f32; WIDTH]) -> u32 {
        let p = planes(n).as_ptr();
        // SAFETY: the offsets are multiples of eight below 48, so each load reads eight
        // floats of the node, 32-byte aligned (the node is 64-byte aligned).
        let ld = |at: usize| unsafe { _mm256_load_ps(p.add(at)) };
        let s = |x: f32| _mm256_set1_ps(x);
        let mut tn = s(f32::NEG_INFINITY);
        let mut tf = s(f32::INFINITY);
        for a in 0..3 {
            let (i0, i1) = (s(f.inv_lo[a]), s(f.inv_hi[a]));
            let dn = _mm256_sub_ps(ld(f.near[a]), s(f.o_near[a]));
            tn = _mm256_max_ps(_mm256_min_ps(_mm256_mul_ps(dn, i0), _mm256_mul_ps(dn, i1)), tn);
            let df = _mm256_sub_ps(ld(f.far[a]), s(f.o_far[a]));
            tf = _mm256_min_ps(_mm256_max_ps(_mm256_mul_ps(df, i0), _mm256_mul_ps(df, i1)), tf);
        }
        let tn = _mm256_max_ps(_mm256_sub_ps(tn, s(f.slack)), s(f.lo));
        let tf = _mm256_min_ps(_mm256_add_ps(tf, s(f.slack)), s(f.hi));
        let keep = _mm256_and_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(tn, tf), _mm256_cmp_ps::<_CMP_LE_OQ>(tn, s(reach)));
        // SAFETY: `near` is eight floats.
        unsafe { _mm256_storeu_ps(near.as_mut_ptr(), tn) };
        _mm256_movemask_ps(keep) as u32
    }

    /// Child `j` of `n` against each ray (rays in lanes), by the one-ray box test's
    /// operations in its order (`traverse.rs`, `boxes_scalar`): the rays that reach it,
    /// and each ray's interval start.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn rays_box(n: &Node8, j: usize, f: &Frustum, r: &RayLanes, starts: &mut [f32; PACKET]) -> u32 {
        let p = planes(n);
        // SAFETY: the rows of `RayLanes` are eight floats, 32-byte aligned.
        let ld = |v: &[f32; PACKET]| unsafe { _mm256_load_ps(v.as_ptr()) };
        let s = |x: f32| _mm256_set1_ps(x);
        let mut tn = s(f32::NEG_INFINITY);
        let mut tf = s(f32::INFINITY);
        for a in 0..3 {
            let (o, inv) = (ld(&r.o[a]), ld(&r.inv[a]));
            tn = _mm256_max_ps(_mm256_mul_ps(_mm256_sub_ps(s(p[f.near[a] + j]), o), inv), tn);
            tf = _mm256_min_ps(_mm256_mul_ps(_mm256_sub_ps(s(p[f.far[a] + j]), o), inv), tf);
        }
        let tn = _mm256_max_ps(_mm256_sub_ps(tn, ld(&r.slack)), ld(&r.lo));
        let tf = _mm256_min_ps(_mm256_add_ps(tf, ld(&r.slack)), ld(&r.hi));
        let keep = _mm256_and_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(tn, tf), _mm256_cmp_ps::<_CMP_LE_OQ>(tn, ld(&r.reach)));
        // SAFETY: `starts` is eight floats.
        unsafe { _mm256_storeu_ps(starts.as_mut_ptr(), tn) };
        _mm256_movemask_ps(keep) as u32
    }

    /// The walk's stack: per entry a child reference and its frustum start; for a leaf
    /// also the rays that reach it and their starts (uninitialised for nodes).
    struct Stack {
        node: [MaybeUninit<u32>; STACK],
        near: [MaybeUninit<f32>; STACK],
        lanes: [MaybeUninit<u32>; STACK],
        starts: [MaybeUninit<[f32; PACKET]>; STACK],
        sp: usize,
    }

    /// A child to visit: a node with its frustum start, or a leaf with the rays that
    /// reach it and their starts.
    #[derive(Clone, Copy)]
    enum Visit {
        Node(u32, f32),
        Leaf(u32, u32, [f32; PACKET]),
    }

    impl Stack {
        #[inline(always)]
        fn new() -> Self {
            Self {
                node: [const { MaybeUninit::uninit() }; STACK],
                near: [const { MaybeUninit::uninit() }; STACK],
                lanes: [const { MaybeUninit::uninit() }; STACK],
                starts: [const { MaybeUninit::uninit() }; STACK],
                sp: 0,
            }
        }

        #[inline(always)]
        fn push(&mut self, v: Visit) {
            match v {
                Visit::Node(node, near) => {
                    self.node[self.sp] = MaybeUninit::new(node);
                    self.near[self.sp] = MaybeUninit::new(near);
                }
                Visit::Leaf(leaf, lanes, starts) => {
                    self.node[self.sp] = MaybeUninit::new(leaf);
                    self.lanes[self.sp] = MaybeUninit::new(lanes);
                    self.starts[self.sp] = MaybeUninit::new(starts);
                }
            }
            self.sp += 1;
        }

        #[inline(always)]
        fn pop(&mut self) -> Option<Visit> {
            if self.sp == 0 {
                return None;
            }
            self.sp -= 1;
            // SAFETY: entries below `sp` were written by `push`: `node` always, `near` for
            // node references, `lanes` and `starts` for the others.
            Some(unsafe {
                let node = self.node[self.sp].assume_init();
                if node & 3 == NODE {
                    Visit::Node(node, self.near[self.sp].assume_init())
                } else {
                    Visit::Leaf(node, self.lanes[self.sp].assume_init(), self.starts[self.sp].assume_init())
                }
            })
        }
    }

    impl Bvh8 {
        /// Answers the lanes of `group` into `out`; returns those it leaves to the
        /// one-ray query.
        ///
        /// # Safety
        /// AVX2.
        #[target_feature(enable = "avx2")]
        pub(super) unsafe fn intersect8_avx2<P: Primitives>(
            &self,
            prims: &P,
            rays: &RayPacket,
            group: u32,
            out: &mut PacketHits,
        ) -> u32 {
            let q = Query::new(rays);
            let (ray, pre) = (&q.ray, &q.pre);
            let mut r = Rays::new(self, rays, group, &q);
            // Only the lanes that walk need one (each is some 450 bytes).
            let mut c: [Option<Closest>; PACKET] = [const { None }; PACKET];
            for l in each(r.started) {
                c[l] = Some(Closest::new(rays.tmax[l], r.lanes.slack[l]));
            }
            let corners = gatherable(prims);
            self.walk8(prims, corners, &mut r, |l, ids, g| match (&mut c[l], g) {
                // SAFETY: AVX2 (this function's feature).
                (Some(c), Some(g)) => unsafe { c.leaf_gathered(prims, g, ids, &ray[l], &pre[l]) },
                (Some(c), None) => c.leaf::<P, true>(prims, corners, ids, &ray[l], &pre[l]),
                (None, _) => f32::NAN,
            });
            for (l, c) in c.iter_mut().enumerate() {
                if let Some(c) = c {
                    out.put(l, c.finish(prims, &ray[l], &pre[l], rays.tmax[l]));
                }
            }
            r.refused
        }

        /// The lanes of `group` that hit anything, and those left to the one-ray query.
        ///
        /// # Safety
        /// AVX2.
        #[target_feature(enable = "avx2")]
        pub(super) unsafe fn occluded8_avx2<P: Primitives>(
            &self,
            prims: &P,
            rays: &RayPacket,
            group: u32,
        ) -> (u32, u32) {
            let q = Query::new(rays);
            let (ray, pre) = (&q.ray, &q.pre);
            let mut r = Rays::new(self, rays, group, &q);
            let corners = gatherable(prims);
            let mut hit = [false; PACKET];
            self.walk8(prims, corners, &mut r, |l, ids, g| match g {
                // SAFETY: AVX2 (this function's feature).
                Some(g) => unsafe { any_leaf_gathered(prims, g, ids, &ray[l], &pre[l], rays.tmax[l], &mut hit[l]) },
                None => any_leaf::<P, true>(prims, corners, ids, &ray[l], &pre[l], rays.tmax[l], &mut hit[l]),
            });
            ((0..PACKET).filter(|&l| hit[l]).fold(0, |m, l| m | (1 << l)), r.refused)
        }

        /// The packet walk: `leaf(lane, ids, loaded)` tests a leaf for one ray and returns
        /// its new bound, or NaN when the ray is done. A leaf that several rays test is
        /// loaded once (`loaded`) when the one-ray leaf code would load it eight at a time.
        #[target_feature(enable = "avx2")]
        #[inline]
        fn walk8<P: Primitives>(
            &self,
            prims: &P,
            corners: &[[glam::Vec3; 3]],
            r: &mut Rays,
            mut leaf: impl FnMut(usize, &[u32], Option<&Gathered>) -> f32,
        ) {
            if r.walking == 0 {
                return;
            }
            let mut st = Stack::new();
            let mut reach = r.reach();
            let mut at = match self.root & 3 {
                NODE => Visit::Node(self.root, r.frustum.lo),
                _ => Visit::Leaf(self.root, r.walking, r.lanes.lo),
            };
            'walk: loop {
                match at {
                    Visit::Node(node, _) => {
                        let n = &self.nodes[(node >> 2) as usize];
                        let mut near = [0.0f32; WIDTH];
                        let mask = frustum_boxes(n, &r.frustum, reach, &mut near);
                        if mask != 0 {
                            self.prefetch_children(prims, n, mask);
                            let (order, len) = by_distance(mask, &near);
                            let mut next = None;
                            for &j in &order[..len] {
                                let c = n.child[j];
                                let v = match c & 3 {
                                    NODE => Visit::Node(c, near[j]),
                                    EMPTY => continue,
                                    _ => {
                                        let mut starts = [0.0f32; PACKET];
                                        let lanes = rays_box(n, j, &r.frustum, &r.lanes, &mut starts) & r.walking;
                                        if lanes == 0 {
                                            continue;
                                        }
                                        Visit::Leaf(c, lanes, starts)
                                    }
                                };
                                if let Some(farther) = next.replace(v) {
                                    st.push(farther);
                                }
                            }
                            if let Some(v) = next {
                                at = v;
                                continue 'walk;
                            }
                        }
                    }
                    Visit::Leaf(c, lanes, starts) => {
                        let i = (c >> 2) as usize;
                        let one = [c >> 2];
                        let ids: &[u32] = match c & 3 {
                            LEAF => &self.leaves[i + 1..i + 1 + self.leaves[i] as usize],
                            ONE => &one,
                            _ => &[],
                        };
                        let walking = r.walking;
                        let live = each(lanes & walking)
                            .filter(|&l| starts[l] <= r.lanes.reach[l])
                            .fold(0u32, |m, l| m | (1 << l));
                        let shared = live.count_ones() >= 2 && ids.len() <= LANES && gathers(corners, ids);
                        let loaded = if shared { Some(gather_avx2(corners, ids)) } else { None };
                        for l in each(live) {
                            // Rays earlier in this loop do not change this one's reach.
                            let bound = leaf(l, ids, loaded.as_ref());
                            if bound.is_nan() {
                                r.walking &= !(1 << l);
                            } else {
                                r.lanes.reach[l] = bound + r.lanes.slack[l];
                            }
                        }
                        if r.walking == 0 {
                            return;
                        }
                        if r.walking != walking {
                            // Rays done: the frustum of those left is narrower.
                            r.frustum = Frustum::of(&r.lanes, r.walking, r.neg);
                        }
                        reach = r.reach();
                    }
                }
                loop {
                    match st.pop() {
                        None => return,
                        Some(Visit::Node(node, near)) if near <= reach => {
                            at = Visit::Node(node, near);
                            continue 'walk;
                        }
                        Some(Visit::Leaf(c, lanes, starts)) => {
                            let live = each(lanes & r.walking)
                                .filter(|&l| starts[l] <= r.lanes.reach[l])
                                .fold(0, |m, l| m | (1 << l));
                            if live != 0 {
                                at = Visit::Leaf(c, live, starts);
                                continue 'walk;
                            }
                        }
                        Some(Visit::Node(..)) => {}
                    }
                }
            }
        }
    }
}
