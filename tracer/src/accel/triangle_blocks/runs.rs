//! Runs of consecutive triangles for the packet queries (`accel/ray_packets.rs`): a
//! packet none of whose searching rays can reach a run's box skips the run's triangles.
//!
//! Runs keep index order (a file's objects are usually consecutive, so a run is usually
//! one object), and a skipped run holds no triangle any lane could hit, so the answers
//! are still brute force's, bit for bit. Where to cut is planned once per scene by the
//! surface area heuristic over contiguous ranges, a small dynamic program: a run costs
//! [`BOX_COST`] for its box test plus its triangles times the chance a packet reaches the
//! box, or just its triangles untested.

use glam::Vec3;

use crate::geometry::Aabb;

/// A box test of eight rays, in triangle tests of eight rays (about 30 vector
/// operations against about 40).
const BOX_COST: f32 = 1.0;

/// How much likelier eight rays are to reach a box than one ray, whose chance is the
/// box's share of the scene's surface area (the eight are samples of one pixel: close
/// at first, scattered after a bounce).
const PACKET_REACH: f32 = 2.0;

/// Triangles `start..end`, with the bounds to test first (`None`: test them all).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Run {
    pub start: u32,
    pub end: u32,
    pub bounds: Option<Aabb>,
}

/// The cheapest cut of triangles `0..n` (corners `tri(i)`, in index order) into runs,
/// within a scene of `bounds`.
pub(crate) fn plan(n: usize, tri: impl Fn(usize) -> [Vec3; 3], bounds: &Aabb) -> Vec<Run> {
    let whole = bounds.surface_area();
    if n == 0 {
        return Vec::new();
    }
    if !(whole > 0.0) || !whole.is_finite() {
        return vec![Run { start: 0, end: n as u32, bounds: None }];
    }
    // cost[j]: the cheapest runs of triangles 0..j; cut[j]: where its last run starts
    // and whether that run is tested.
    let mut cost = vec![f32::INFINITY; n + 1];
    let mut cut = vec![(0usize, false); n + 1];
    cost[0] = 0.0;
    for j in 1..=n {
        let mut b = Aabb::EMPTY;
        for i in (0..j).rev() {
            b = tri(i).iter().fold(b, |b, &p| b.grow(p));
            let k = (j - i) as f32;
            let reach = (PACKET_REACH * b.surface_area() / whole).min(1.0);
            let tested = BOX_COST + k * reach;
            let (c, test) = if tested < k { (tested, true) } else { (k, false) };
            if cost[i] + c < cost[j] {
                cost[j] = cost[i] + c;
                cut[j] = (i, test);
            }
        }
    }
    let mut runs = Vec::new();
    let mut j = n;
    while j > 0 {
        let (i, test) = cut[j];
        let bounds = test.then(|| (i..j).flat_map(&tri).fold(Aabb::EMPTY, |b, p| b.grow(p)));
        runs.push(Run { start: i as u32, end: j as u32, bounds });
        j = i;
    }
    runs.reverse();
    // Untested neighbours are one run (fewer loop turns, the same tests).
    runs.dedup_by(|next, run| {
        let merge = run.bounds.is_none() && next.bounds.is_none();
        if merge {
            run.end = next.end;
        }
        merge
    });
    runs
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad(x: f32, y: f32, s: f32) -> [[Vec3; 3]; 2] {
        let p = |a: f32, b: f32| Vec3::new(x + a * s, y + b * s, 0.0);
        [[p(0.0, 0.0), p(1.0, 0.0), p(1.0, 1.0)], [p(0.0, 0.0), p(1.0, 1.0), p(0.0, 1.0)]]
    }

    /// Runs cover every triangle once, in order; small far-apart objects get boxes of
    /// their own, and an object as large as the scene is tested without one.
    #[test]
    fn runs_cover_in_order_and_box_small_objects() {
        let mut tris = Vec::new();
        tris.extend(quad(-10.0, -10.0, 20.0)); // the whole scene: no box pays
        for k in 0..4 {
            // four small clusters of five quads each
            for q in 0..5 {
                tris.extend(quad(-9.0 + 6.0 * k as f32 + 0.1 * q as f32, -9.0 + 6.0 * k as f32, 0.1));
            }
        }
        let bounds = tris.iter().flatten().fold(Aabb::EMPTY, |b, &p| b.grow(p));
        let bounds = bounds.union(Aabb::new(Vec3::splat(-10.0), Vec3::splat(10.0)));
        let runs = plan(tris.len(), |i| tris[i], &bounds);
        assert_eq!(runs.first().map(|r| r.start), Some(0));
        assert_eq!(runs.last().map(|r| r.end), Some(tris.len() as u32));
        assert!(runs.windows(2).all(|w| w[0].end == w[1].start && w[0].start < w[0].end));
        assert_eq!(runs[0], Run { start: 0, end: 2, bounds: None });
        let boxed: Vec<_> = runs.iter().filter(|r| r.bounds.is_some()).collect();
        assert_eq!(boxed.len(), 4, "{runs:?}");
        for r in boxed {
            assert_eq!(r.end - r.start, 10, "{runs:?}");
            let b = r.bounds.unwrap();
            assert!(tris[r.start as usize..r.end as usize].iter().flatten().all(|&p| b.grow(p) == b));
        }
        // Degenerate scenes: nothing, or bounds without area.
        assert!(plan(0, |i| tris[i], &bounds).is_empty());
        let flat = Aabb::new(Vec3::ZERO, Vec3::new(1.0, 0.0, 0.0));
        assert_eq!(plan(tris.len(), |i| tris[i], &flat), vec![Run { start: 0, end: tris.len() as u32, bounds: None }]);
    }
}
