//! Procedural test geometry for benchmarks and tests.

use std::collections::HashMap;

use glam::Vec3;

use super::{NONE, Tri, TriangleMesh};

/// A unit geodesic sphere (icosahedron with each face split into `f²` triangles)
/// displaced along its normals by deterministic value noise, with about
/// `target_triangles` triangles (`20 f²`, `f = round(sqrt(target / 20))`, at least 20).
/// All triangles use material 0 and have no normals or texture coordinates.
///
/// Vertices shared by neighbouring faces are computed from the same integer weights, so
/// they come out bit-identical and the mesh is closed (indexed once each).
pub fn displaced_sphere(target_triangles: usize, seed: u64) -> TriangleMesh {
    let f = ((target_triangles as f64 / 20.0).sqrt().round() as usize).max(1);
    let (ico_v, ico_f) = icosahedron();
    let noise = Noise { seed };
    let mut mesh = TriangleMesh::default();
    let mut index: HashMap<[u32; 3], u32> = HashMap::with_capacity(10 * f * f + 2);
    let mut grid = vec![0u32; (f + 1) * (f + 2) / 2];
    let at = |i: usize, j: usize| i * (2 * f + 3 - i) / 2 + j; // row i has f + 1 - i entries
    mesh.tris.reserve(20 * f * f);
    for face in ico_f {
        let [a, b, c] = face.map(|k| ico_v[k]);
        for i in 0..=f {
            for j in 0..=f - i {
                let k = f - i - j;
                // Products of exact integers by the same corner, summed in an order-free
                // way (one addition with a possible zero term), give identical points on
                // the shared edges of neighbouring faces.
                let p = a * (k as f32 / f as f32) + b * (i as f32 / f as f32) + c * (j as f32 / f as f32);
                let n = p.normalize();
                let q = n * (1.0 + 0.12 * noise.fbm(n * 3.0));
                let key = q.to_array().map(f32::to_bits);
                let next = mesh.positions.len() as u32;
                let id = *index.entry(key).or_insert(next);
                if id == next {
                    mesh.positions.push(q);
                }
                grid[at(i, j)] = id;
            }
        }
        for i in 0..f {
            for j in 0..f - i {
                let tri = |v: [u32; 3]| Tri { v, n: [NONE; 3], uv: [NONE; 3], material: 0 };
                mesh.tris.push(tri([grid[at(i, j)], grid[at(i + 1, j)], grid[at(i, j + 1)]]));
                if i + j + 1 < f {
                    mesh.tris.push(tri([grid[at(i + 1, j)], grid[at(i + 1, j + 1)], grid[at(i, j + 1)]]));
                }
            }
        }
    }
    mesh
}

fn icosahedron() -> ([Vec3; 12], [[usize; 3]; 20]) {
    let t = (1.0 + 5.0f32.sqrt()) / 2.0;
    let v = [
        Vec3::new(-1.0, t, 0.0),
        Vec3::new(1.0, t, 0.0),
        Vec3::new(-1.0, -t, 0.0),
        Vec3::new(1.0, -t, 0.0),
        Vec3::new(0.0, -1.0, t),
        Vec3::new(0.0, 1.0, t),
        Vec3::new(0.0, -1.0, -t),
        Vec3::new(0.0, 1.0, -t),
        Vec3::new(t, 0.0, -1.0),
        Vec3::new(t, 0.0, 1.0),
        Vec3::new(-t, 0.0, -1.0),
        Vec3::new(-t, 0.0, 1.0),
    ]
    .map(Vec3::normalize);
    let f = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    (v, f)
}

/// Seeded 3D value noise (smoothstep-interpolated lattice values), summed in octaves.
struct Noise {
    seed: u64,
}

impl Noise {
    fn lattice(&self, x: i32, y: i32, z: i32) -> f32 {
        let mut h = self.seed ^ 0x9E37_79B9_7F4A_7C15;
        for c in [x, y, z] {
            h = splitmix(h ^ (c as u32 as u64));
        }
        (h >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
    }

    fn value(&self, p: Vec3) -> f32 {
        let b = p.floor();
        let f = p - b;
        let s = f * f * (Vec3::splat(3.0) - 2.0 * f);
        let (x, y, z) = (b.x as i32, b.y as i32, b.z as i32);
        let mut acc = 0.0;
        for corner in 0..8 {
            let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
            let w = (if dx == 1 { s.x } else { 1.0 - s.x })
                * (if dy == 1 { s.y } else { 1.0 - s.y })
                * (if dz == 1 { s.z } else { 1.0 - s.z });
            acc += w * self.lattice(x + dx, y + dy, z + dz);
        }
        acc
    }

    fn fbm(&self, p: Vec3) -> f32 {
        let mut sum = 0.0;
        let mut amp = 0.5;
        let mut q = p;
        for _ in 0..4 {
            sum += amp * self.value(q);
            amp *= 0.5;
            q *= 2.03;
        }
        sum
    }
}

fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn displaced_sphere_has_requested_size_and_is_closed() {
        let m = displaced_sphere(5000, 7);
        let f = 16; // round(sqrt(250))
        assert_eq!(m.tris.len(), 20 * f * f);
        // Closed genus-0 mesh: V - E + F = 2 with E = 3F/2.
        assert_eq!(m.positions.len() as i64 - (3 * m.tris.len() / 2) as i64 + m.tris.len() as i64, 2);
        assert!(m.tris.iter().all(|t| t.material == 0 && t.n == [NONE; 3] && t.uv == [NONE; 3]));
        assert!(m.positions.iter().all(|p| (0.7..1.3).contains(&p.length())));
        let again = displaced_sphere(5000, 7);
        assert_eq!(again.positions, m.positions);
        assert_ne!(displaced_sphere(5000, 8).positions, m.positions);
    }
}
