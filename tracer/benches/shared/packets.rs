//! Packets of eight rays for the packet-query benches (`kdtree.rs`, `bvh8.rs`): a
//! camera's rays in 4×2-pixel packets, the shadow rays from their hits towards a point
//! light, and any rays eight by eight.

use glam::Vec3;
use tracer::accel::ray_packets::{PacketHits, RayPacket};
use tracer::geometry::{Aabb, Ray};

/// A pinhole camera's rays in packets of 4×2 pixels, closest hit: `side`² pixels from 1.5
/// diagonals away from the box's center, through a square grid covering it.
pub fn camera_packets(b: Aabb, side: usize) -> Vec<RayPacket> {
    let (c, size) = (b.center(), b.diagonal().length());
    let eye = c + Vec3::new(0.3, 0.4, 3.0).normalize() * (1.5 * size);
    let fwd = (c - eye).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    let mut out = Vec::new();
    for by in (0..side).step_by(2) {
        for bx in (0..side).step_by(4) {
            let mut p = RayPacket::default();
            for l in 0..8 {
                let (px, py) = (bx + l % 4, by + l / 4);
                let (x, y) = (px as f32 / side as f32 - 0.5, py as f32 / side as f32 - 0.5);
                let d = (fwd + (right * x + up * y) * 0.7).normalize();
                p.set(l, &Ray::new(eye, d), f32::INFINITY);
            }
            out.push(p);
        }
    }
    out
}

/// The shadow rays of `camera`'s hits (`hits` answers a packet) towards a point light
/// above and beside the camera, packet by packet (lanes that missed stay inactive),
/// nudged off the surface.
pub fn shadow_packets(b: Aabb, camera: &[RayPacket], hits: impl Fn(&RayPacket) -> PacketHits) -> Vec<RayPacket> {
    let light = b.center() + Vec3::new(-1.0, 2.0, 1.5).normalize() * b.diagonal().length();
    let eps = 1e-4 * b.diagonal().length();
    camera
        .iter()
        .map(|p| {
            let hits = hits(p);
            let mut s = RayPacket::default();
            for l in 0..8 {
                if let Some(h) = hits.get(l) {
                    let ray = p.ray(l);
                    let x = ray.origin + ray.dir * h.t;
                    let to = light - x;
                    let d = to.normalize();
                    s.set(l, &Ray::new(x + d * eps, d), to.length() - 2.0 * eps);
                }
            }
            s
        })
        .collect()
}

/// `rays` eight by eight, in order.
pub fn packets_of(rays: &[(Ray, f32)]) -> Vec<RayPacket> {
    rays.chunks(8)
        .map(|c| {
            let mut p = RayPacket::default();
            for (l, (r, len)) in c.iter().enumerate() {
                p.set(l, r, *len);
            }
            p
        })
        .collect()
}
