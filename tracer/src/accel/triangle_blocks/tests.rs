//! Tests of `triangle_blocks.rs`.

use super::*;
use crate::accel::{brute_force_intersect, brute_force_occluded};
use crate::shapes::{Sphere, Tri, TriangleMesh};

pub(crate) struct Rng(pub(crate) u64);
impl Rng {
    pub(crate) fn f(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }
    pub(crate) fn v(&mut self) -> Vec3 {
        Vec3::new(self.f(), self.f(), self.f()) * 2.0 - 1.0
    }
}

/// Random triangles, a closed grid of quads sharing edges and vertices (rays through
/// them exercise the exact-zero path), duplicates, and a few spheres.
pub(crate) fn scene(r: &mut Rng, n: usize, spheres: usize) -> Geometry {
    scaled_scene(r, n, spheres, 1.0)
}

/// [`scene`] with every coordinate (and radius) multiplied by `scale`.
pub(crate) fn scaled_scene(r: &mut Rng, n: usize, spheres: usize, scale: f32) -> Geometry {
    let mut mesh = TriangleMesh::default();
    let none = [crate::shapes::NONE; 3];
    let tri = |mesh: &mut TriangleMesh, p: [Vec3; 3]| {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(p.map(|q| q * scale));
        mesh.tris.push(Tri { v: [base, base + 1, base + 2], n: none, uv: none, material: 0 });
    };
    for _ in 0..n {
        let c = r.v();
        tri(&mut mesh, [c, c + r.v() * 0.4, c + r.v() * 0.4]);
    }
    // A 4×4 grid of unit quads in the z = 0.25 plane, two triangles each.
    for i in 0..4 {
        for j in 0..4 {
            let p = |a: i32, b: i32| Vec3::new((i + a) as f32 * 0.5 - 1.0, (j + b) as f32 * 0.5 - 1.0, 0.25);
            tri(&mut mesh, [p(0, 0), p(1, 0), p(1, 1)]);
            tri(&mut mesh, [p(0, 0), p(1, 1), p(0, 1)]);
        }
    }
    let dup = mesh.corners(3);
    tri(&mut mesh, dup);
    // `spheres` of them (eleven: a full block of eight and a partial one).
    let spheres = (0..spheres)
        .map(|_| Sphere { center: r.v() * scale, radius: (0.05 + 0.2 * r.f()) * scale, material: 0 })
        .collect();
    Geometry::new(mesh, spheres)
}

#[test]
fn block_test_is_exactly_brute_force() {
    let mut r = Rng(3);
    let mut sphere_hits = 0;
    // 9 (plus the grid's 32 and one duplicate) without spheres: a pair whose second
    // block is nearly empty, and no primitives past the triangles (a lane kept
    // beyond them would index out of the set). 100: enough blocks to cull by box.
    for (n, spheres) in [(0, 11), (1, 11), (7, 11), (8, 11), (9, 11), (9, 0), (40, 11), (100, 11)] {
        let geo = scene(&mut r, n, spheres);
        let detected = PackedTriangles::for_small_scene(&geo).expect("small");
        // The instruction set found here, the x86-64 baseline, and AVX2 where the
        // found one is AVX-512.
        let baseline = PackedTriangles { simd: InstructionSet::Baseline, ..detected.clone() };
        #[cfg(target_arch = "x86_64")]
        let avx2 = PackedTriangles {
            simd: if detected.simd == InstructionSet::Avx512 { InstructionSet::Avx2 } else { detected.simd },
            ..detected.clone()
        };
        #[cfg(not(target_arch = "x86_64"))]
        let avx2 = detected.clone();
        let variants = [&detected, &baseline, &avx2];
        for (k, packed) in (0..12000).map(|k| (k / 3, variants[k % 3])) {
            let o = r.v() * 2.0;
            // Every fourth ray aims exactly at a grid vertex or edge point.
            let target = if k % 4 == 0 {
                Vec3::new((k / 4 % 9) as f32 * 0.25 - 1.0, (k / 36 % 9) as f32 * 0.25 - 1.0, 0.25)
            } else {
                r.v()
            };
            let ray = Ray::new(o, (target - o).normalize());
            let tmax = if k % 3 == 0 { f32::INFINITY } else { (target - o).length() * (0.5 + r.f()) };
            let expected = brute_force_intersect(&geo, &ray, tmax);
            sphere_hits += usize::from(expected.is_some_and(|h| h.prim as usize >= geo.triangle_count()));
            assert_eq!(packed.intersect(&geo, &ray, tmax), expected, "n {n} ray {k}");
            assert_eq!(packed.occluded(&geo, &ray, tmax), brute_force_occluded(&geo, &ray, tmax), "n {n} ray {k}");
            // tmax at and just around a hit's own distance: where `t·det` meets
            // `tmax·det` and the block test must keep exactly the lanes that can pass.
            if let Some(h) = expected {
                for tmax in [h.t, h.t.next_up(), h.t.next_down(), h.t * (1.0 + 4.0 * f32::EPSILON)] {
                    let bf = brute_force_intersect(&geo, &ray, tmax);
                    assert_eq!(packed.intersect(&geo, &ray, tmax), bf, "n {n} ray {k} tmax {tmax}");
                    let bo = brute_force_occluded(&geo, &ray, tmax);
                    assert_eq!(packed.occluded(&geo, &ray, tmax), bo, "n {n} ray {k} tmax {tmax}");
                }
            }
        }
    }
    assert!(sphere_hits > 700, "only {sphere_hits} sphere hits tested");
}

/// The AVX2 block test, and the AVX-512 test of two blocks, give the portable one's
/// masks and, for every lane that finishes from them, the same values, bit for bit.
#[cfg(target_arch = "x86_64")]
#[test]
fn avx2_block_test_matches_the_portable_one() {
    crate::simd::tests::require_avx2();
    let mut r = Rng(9);
    let geo = scene(&mut r, 40, 11);
    let packed = PackedTriangles::for_small_scene(&geo).expect("small");
    let (mut compared, mut wide_compared, mut sphere_kept) = (0, 0, 0);
    for k in 0..4000 {
        let o = r.v() * 2.0;
        let ray = Ray::new(o, (r.v() - o).normalize());
        let pre = RayPrecomp::new(&ray);
        let tmax = if k % 2 == 0 { f32::INFINITY } else { 3.0 * r.f() };
        for b in &packed.blocks {
            let (mut a, mut c) = (Lanes::default(), Lanes::default());
            let portable = block_test_lanes(b, &pre.shear, tmax, &mut a);
            // SAFETY: AVX2 was detected above.
            let avx2 = unsafe { block_test_avx2(b, &pre.shear, tmax, &mut c) };
            assert_eq!(portable, avx2, "ray {k}");
            let mut finishing = portable.0 & !portable.1;
            while finishing != 0 {
                let l = finishing.trailing_zeros() as usize;
                finishing &= finishing - 1;
                let bits = |x: &Lanes| [x.v[l], x.w[l], x.det[l], x.t_scaled[l]].map(f32::to_bits);
                assert_eq!(bits(&a), bits(&c), "ray {k} lane {l}");
                compared += 1;
            }
        }
        // Pairs of blocks in sixteen lanes: each half is its block's eight.
        if std::is_x86_feature_detected!("avx512f") {
            for pair in packed.blocks.windows(2) {
                let (mut a, mut b, mut w) = (Lanes::default(), Lanes::default(), Lanes::default());
                let (ka, za) = block_test_lanes(&pair[0], &pre.shear, tmax, &mut a);
                let (kb, zb) = block_test_lanes(&pair[1], &pre.shear, tmax, &mut b);
                // SAFETY: AVX2 and AVX-512F were detected above.
                let wide = unsafe { pair_test_avx512(&pair[0], &pair[1], &pre.shear, tmax, &mut w) };
                assert_eq!(wide, (ka | kb << LANES, za | zb << LANES), "ray {k}");
                let mut finishing = wide.0 & !wide.1;
                while finishing != 0 {
                    let l = finishing.trailing_zeros() as usize;
                    finishing &= finishing - 1;
                    let (x, m) = if l < LANES { (&a, l) } else { (&b, l - LANES) };
                    let bits = |x: &Lanes, l: usize| [x.v[l], x.w[l], x.det[l], x.t_scaled[l]].map(f32::to_bits);
                    assert_eq!(bits(&w, l), bits(x, m), "ray {k} lane {l}");
                    wide_compared += 1;
                }
            }
        }
        let a = ray.dir.length_squared();
        for b in &packed.sphere_blocks {
            let portable = sphere_candidates(b, &ray, a);
            // SAFETY: AVX2 was detected above.
            assert_eq!(portable, unsafe { sphere_candidates_avx2(b, &ray, a) }, "ray {k}");
            sphere_kept += portable.count_ones();
        }
    }
    assert!(compared > 1000, "only {compared} kept lanes compared");
    assert!(wide_compared > 1000 || !std::is_x86_feature_detected!("avx512f"), "{wide_compared} wide lanes");
    // Spheres kept and dropped both (two blocks of eight lanes per ray).
    assert!(sphere_kept > 300 && sphere_kept < 4000 * 16 - 1000, "{sphere_kept} sphere lanes kept");
}

#[test]
fn finds_hits_and_misses() {
    let mut r = Rng(5);
    let geo = scene(&mut r, 0, 11);
    let packed = PackedTriangles::for_small_scene(&geo).expect("small");
    // Straight down onto the grid (spheres are somewhere in [-1, 1]³: aim between).
    let ray = Ray::new(Vec3::new(-0.9, -0.9, 5.0), -Vec3::Z);
    let h = packed.intersect(&geo, &ray, f32::INFINITY).expect("the grid is hit");
    assert!((h.t - 4.75).abs() < 1e-5 || h.prim as usize >= geo.triangle_count(), "{h:?}");
    let away = Ray::new(Vec3::new(0.0, 0.0, 5.0), Vec3::Z);
    assert!(packed.intersect(&geo, &away, f32::INFINITY).is_none());
    assert!(!packed.occluded(&geo, &away, f32::INFINITY));
}
