//! Eight paths in flight: the path integrator for scenes traced by brute force
//! ([`PackedTriangles`]), with the ray queries of eight paths answered together by the
//! packet queries of `accel/packet.rs`.
//!
//! Each lane holds one sample's [`PathState`]. A round traces the closest hits of all
//! lanes' segments at once, lets each path [`scatter`](PathState::scatter) at its hit
//! (the same code as the one-path [`li`](super::path::li)), traces the shadow rays of
//! all lanes' light samples at once, and adds their contributions. A path that ends
//! leaves its radiance in the film and its lane takes the tile's next sample. Every
//! sample runs exactly the scalar integrator's operations and the packet queries give
//! exactly the one-ray queries' answers, so each sample's radiance is the same bits as
//! with [`li`](super::path::li), and the film's fixed-point sums do not depend on the
//! order in which samples end.

use glam::{Vec2, Vec3};

use super::RayCount;
use super::path::{Options, PathState, ShadowQuery, transmittance};
use crate::accel::packed::PackedTriangles;
use crate::accel::packet::{PACKET, RayPacket};
use crate::film::{Accumulation, SampleRange, Tile};
use crate::geometry::Ray;
use crate::sampler::Sampler;
use crate::sampling::select;
use crate::scene::Scene;

/// One lane's sample: its path, its random numbers and its pixel (index within the
/// tile).
#[derive(Clone)]
struct Lane {
    path: PathState,
    sampler: Sampler,
    pixel: usize,
}

/// Every sample of every pixel of `tile` with the path integrator, eight at a time.
/// Inlined into the render loop's instruction-set variants (`render.rs`), like [`li`].
/// Only where `packed.packets()` (the packet queries panic elsewhere).
///
/// [`li`]: super::path::li
#[inline(always)]
pub(crate) fn render_unit(
    scene: &Scene,
    packed: &PackedTriangles,
    opt: &Options,
    tile: Tile,
    samples: SampleRange,
) -> (Accumulation, RayCount) {
    let mut acc = Accumulation::new(tile);
    let mut count = RayCount::default();
    let cam = &scene.camera;
    let seed = scene.settings.seed;
    let per_pixel = u64::from(samples.len());
    let total = tile.pixel_count() as u64 * per_pixel;
    let mut next = 0u64;
    // Lanes are arrays with a mask of the live ones, not options: which lanes hold a
    // path, have a shadow ray or end is random, and branches on it mispredict.
    let idle =
        Lane { path: PathState::new(Ray::new(Vec3::ZERO, Vec3::Z)), sampler: Sampler::new(0, 0, 0, 0), pixel: 0 };
    let mut lanes: [Lane; PACKET] = std::array::from_fn(|_| idle.clone());
    let mut live = 0u32;
    let mut queries: [Option<ShadowQuery>; PACKET] = [None; PACKET];
    loop {
        // Idle lanes take the next samples, pixel by pixel.
        let mut idle = !live & ((1 << PACKET) - 1);
        while idle != 0 && next < total {
            let l = idle.trailing_zeros() as usize;
            idle &= idle - 1;
            let (pixel, s) = ((next / per_pixel) as u32, (next % per_pixel) as u32);
            next += 1;
            let (x, y) = (tile.x0 + pixel % tile.width, tile.y0 + pixel / tile.width);
            let mut sampler = Sampler::new(seed, x, y, samples.start + s);
            // Box filter: uniform positions within the pixel (as `render.rs`'s loop).
            let film = Vec2::new(x as f32, y as f32) + sampler.next_2d();
            let lens = if cam.has_lens() { sampler.next_2d() } else { Vec2::ZERO };
            let ray = cam.generate_ray(film, lens);
            lanes[l] = Lane { path: PathState::new(ray), sampler, pixel: pixel as usize };
            live |= 1 << l;
        }
        if live == 0 {
            return (acc, count);
        }

        // Idle lanes hold an old ray, which is harmless; the mask leaves them out.
        let mut rays = RayPacket::default();
        for (l, lane) in lanes.iter().enumerate() {
            rays.set(l, &lane.path.ray, f32::INFINITY);
        }
        rays.active = live;
        count.rays += u64::from(live.count_ones());
        let hits = packed.intersect8(&scene.geometry, &rays);

        let mut shadow = RayPacket::default();
        let mut ended = 0u32;
        for (l, lane) in lanes.iter_mut().enumerate() {
            if live & (1 << l) == 0 {
                continue;
            }
            let (query, go_on) = lane.path.scatter(scene, hits.get(l), &mut lane.sampler, opt);
            ended |= u32::from(!go_on) << l;
            if let Some(q) = query {
                match q.ray {
                    // Stochastic opacity needs a walk through the surfaces: one lane alone.
                    Some((ray, tmax)) if !scene.has_cutouts => {
                        shadow.set(l, &ray, tmax);
                        queries[l] = Some(q);
                    }
                    _ => lane.path.add_light(&q, transmittance(scene, &q, &mut count)),
                }
            }
        }

        if shadow.active != 0 {
            count.rays += u64::from(shadow.active.count_ones());
            let blocked = packed.occluded8(&scene.geometry, &shadow);
            let mut waiting = shadow.active;
            while waiting != 0 {
                let l = waiting.trailing_zeros() as usize;
                waiting &= waiting - 1;
                if let Some(q) = queries[l].take() {
                    lanes[l].path.add_light(&q, select(blocked & (1 << l) != 0, 0.0, 1.0));
                }
            }
        }

        live &= !ended;
        while ended != 0 {
            let l = ended.trailing_zeros() as usize;
            ended &= ended - 1;
            acc.add_sample(lanes[l].pixel, lanes[l].path.radiance());
        }
    }
}
