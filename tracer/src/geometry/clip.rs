//! Bounds of a triangle clipped to a box, for the kd-tree's "perfect splits" (Havran;
//! Wald & Havran 2006): the part of a triangle that lies inside a kd-tree cell is
//! usually much smaller than the triangle's bounds ∩ the cell, and using it as the
//! primitive's extent in the child cells makes the SAH see the geometry as it is.

use glam::Vec3;

use super::Aabb;

/// Most vertices a triangle clipped by 6 planes can have: each plane adds at most one.
const MAX_VERTS: usize = 9;

/// Bounds of the part of triangle `p` that lies inside `clip`, by Sutherland–Hodgman
/// clipping against the box's 6 planes. Returns [`Aabb::EMPTY`] when nothing is left.
///
/// The result is always inside both the triangle's bounds and `clip`. Vertices created
/// on a clipping plane get that plane's coordinate exactly, so a triangle crossing a
/// plane yields bounds that end exactly on it; other coordinates of created vertices are
/// interpolated and carry rounding error, which callers that need conservative bounds
/// (the kd-tree) pad for.
pub fn clipped_triangle_bounds(p: [Vec3; 3], clip: &Aabb) -> Aabb {
    let tri_bounds = Aabb::from_points(&p);
    let inter = tri_bounds.intersection(*clip);
    if inter.is_empty() {
        return Aabb::EMPTY;
    }
    // Fully inside: nothing to clip (the common case deep in the tree).
    if tri_bounds.min.cmpge(clip.min).all() && tri_bounds.max.cmple(clip.max).all() {
        return tri_bounds;
    }

    // Ping-pong between two buffers (swapping them cost as much as a clip step).
    let mut bufs = [[Vec3::ZERO; MAX_VERTS]; 2];
    bufs[0][..3].copy_from_slice(&p);
    let (mut cur, mut n) = (0, 3);
    // One plane: clip if it cuts the triangle's bounds (otherwise it cannot remove
    // anything), then stop if nothing is left.
    macro_rules! plane {
        ($axis:literal, $above:literal, $cuts:expr, $value:expr) => {
            if $cuts {
                let [a, b] = &mut bufs;
                let (from, to) = if cur == 0 { (a, b) } else { (b, a) };
                n = clip_plane::<$axis, $above>(&from[..n], to, $value);
                cur ^= 1;
            }
            if n == 0 {
                return Aabb::EMPTY;
            }
        };
    }
    macro_rules! clip {
        ($axis:literal) => {
            plane!($axis, true, tri_bounds.min[$axis] < clip.min[$axis], clip.min[$axis]);
            plane!($axis, false, tri_bounds.max[$axis] > clip.max[$axis], clip.max[$axis]);
        };
    }
    clip!(0);
    clip!(1);
    clip!(2);
    // Interpolation may round a created vertex a hair outside the box or the triangle's
    // bounds; the intersection keeps the documented containment.
    Aabb::from_points(&bufs[cur][..n]).intersection(inter)
}

/// One Sutherland–Hodgman step: keeps the part of `poly` with `v[AXIS] >= value`
/// (`KEEP_ABOVE`) or `v[AXIS] <= value`. Returns the vertex count written to `out`.
#[inline(always)]
fn clip_plane<const AXIS: usize, const KEEP_ABOVE: bool>(
    poly: &[Vec3],
    out: &mut [Vec3; MAX_VERTS],
    value: f32,
) -> usize {
    let coord = |v: Vec3| v.to_array()[AXIS];
    let inside = |v: Vec3| if KEEP_ABOVE { coord(v) >= value } else { coord(v) <= value };
    let mut m = 0;
    let Some(&last) = poly.last() else { return 0 };
    let mut prev = last;
    let mut prev_in = inside(prev);
    for &cur in poly {
        let cur_in = inside(cur);
        if cur_in != prev_in {
            // Interpolate from the inside vertex so that the same edge gives the same
            // point whichever way it is walked.
            let (a, b) = if prev_in { (prev, cur) } else { (cur, prev) };
            let t = (value - coord(a)) / (coord(b) - coord(a));
            let mut x = a + (b - a) * t;
            x[AXIS] = value;
            if m < MAX_VERTS {
                out[m] = x;
                m += 1;
            }
        }
        if cur_in && m < MAX_VERTS {
            out[m] = cur;
            m += 1;
        }
        prev = cur;
        prev_in = cur_in;
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Proptest settings for CI: a fixed seed, so a run is repeatable (a new failure is
    /// hunted with `PROPTEST_RNG_SEED=<n>`, which this leaves in charge).
    fn pinned(cases: u32) -> ProptestConfig {
        let mut c = ProptestConfig { cases, failure_persistence: None, ..ProptestConfig::default() };
        if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
            c.rng_seed = proptest::test_runner::RngSeed::Fixed(0x7469_6c65_6661_726d);
        }
        c
    }

    fn bx(min: [f32; 3], max: [f32; 3]) -> Aabb {
        Aabb::new(Vec3::from(min), Vec3::from(max))
    }

    #[test]
    fn known_cases_are_exact() {
        let tri = [Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::new(0.0, 2.0, 0.0)];
        // Cutting off the corner at x = 1: the rest spans y in [0, 1].
        let b = clipped_triangle_bounds(tri, &bx([1.0, -1.0, -1.0], [3.0, 3.0, 1.0]));
        assert_eq!(b, bx([1.0, 0.0, 0.0], [2.0, 1.0, 0.0]));
        // The diagonal band x + y in the box [0.5, 1.5]²: the hypotenuse limits it.
        let b = clipped_triangle_bounds(tri, &bx([0.5, 0.5, -1.0], [1.5, 1.5, 1.0]));
        assert_eq!(b, bx([0.5, 0.5, 0.0], [1.5, 1.5, 0.0]));
        // A box the triangle's bounds overlap but the triangle misses.
        let b = clipped_triangle_bounds(tri, &bx([1.5, 1.5, -1.0], [3.0, 3.0, 1.0]));
        assert!(b.is_empty());
        // Entirely inside: unchanged.
        let b = clipped_triangle_bounds(tri, &bx([-1.0, -1.0, -1.0], [3.0, 3.0, 1.0]));
        assert_eq!(b, Aabb::from_points(&tri));
        // Disjoint.
        assert!(clipped_triangle_bounds(tri, &bx([5.0, 5.0, 5.0], [6.0, 6.0, 6.0])).is_empty());
        // A slanted triangle through a slab: z is cut to [0.25, 0.75] and so are x, y.
        let tri = [Vec3::ZERO, Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 1.0)];
        let b = clipped_triangle_bounds(tri, &bx([-5.0, -5.0, 0.25], [5.0, 5.0, 0.75]));
        assert_eq!(b, bx([0.0, 0.0, 0.25], [0.75, 0.75, 0.75]));
        // Touching the box only along a face: a flat (but non-empty) result.
        let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let b = clipped_triangle_bounds(tri, &bx([-1.0, -1.0, 0.0], [1.0, 1.0, 1.0]));
        assert_eq!(b, Aabb::from_points(&tri));
    }

    fn v3() -> impl Strategy<Value = Vec3> {
        (-4.0f32..4.0, -4.0f32..4.0, -4.0f32..4.0).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    proptest! {
        #![proptest_config(pinned(2000))]
        #[test]
        fn clipped_bounds_are_inside_both_and_cover_the_clipped_part(
            a in v3(), b in v3(), c in v3(), lo in v3(), ext in v3(),
            samples in prop::collection::vec((0.0f32..1.0, 0.0f32..1.0), 32),
        ) {
            let tri = [a, b, c];
            let clip = Aabb::new(lo, lo + ext.abs());
            let r = clipped_triangle_bounds(tri, &clip);
            let tb = Aabb::from_points(&tri);
            if !r.is_empty() {
                prop_assert!(r.min.cmpge(tb.min).all() && r.max.cmple(tb.max).all());
                prop_assert!(r.min.cmpge(clip.min).all() && r.max.cmple(clip.max).all());
            }
            // Every sampled point of the triangle inside the box lies in the result.
            let tol = 1e-4;
            for (s, t) in samples {
                let (s, t) = if s + t > 1.0 { (1.0 - s, 1.0 - t) } else { (s, t) };
                let q = a + (b - a) * s + (c - a) * t;
                if q.cmpge(clip.min).all() && q.cmple(clip.max).all() {
                    prop_assert!(!r.is_empty());
                    prop_assert!(q.cmpge(r.min - tol).all() && q.cmple(r.max + tol).all());
                }
            }
        }
    }
}
