use glam::{Affine3A, Mat3, Quat, Vec3};

use super::*;
use crate::accel::{brute_force_intersect, brute_force_occluded, incoherent_rays};
use crate::scene::generate::displaced_sphere;
use crate::shapes::Geometry;

fn mesh(triangles: usize, seed: u64) -> InstancedMesh {
    InstancedMesh::new(Geometry::new(displaced_sphere(triangles, seed), Vec::new()))
}

/// Copies of two meshes: the identity, a move, a turn with a non-uniform scale, a mirror
/// and a shear, some overlapping.
fn transforms() -> Vec<(u32, Affine3A)> {
    let shear = Mat3::from_cols(Vec3::new(1.0, 0.3, 0.0), Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.2, 0.0, 0.8));
    vec![
        (0, Affine3A::IDENTITY),
        (0, Affine3A::from_translation(Vec3::new(2.5, 0.0, 0.0))),
        (
            1,
            Affine3A::from_scale_rotation_translation(
                Vec3::new(0.5, 1.5, 1.0),
                Quat::from_mat3(&crate::scene::placement::about_axis(Vec3::Y, 40.0)),
                Vec3::Y * 2.2,
            ),
        ),
        (
            0,
            Affine3A::from_scale_rotation_translation(
                Vec3::new(-1.0, 1.0, 1.0),
                Quat::IDENTITY,
                Vec3::new(-2.5, 0.5, 0.0),
            ),
        ),
        (1, Affine3A::from_mat3_translation(shear, Vec3::new(0.5, -2.0, 0.3))),
        (0, Affine3A::from_translation(Vec3::new(0.4, 0.3, 0.2))),
    ]
}

fn scene_copies(first: u32) -> Instances {
    let meshes = vec![mesh(3000, 1), mesh(800, 2)];
    let list = transforms().into_iter().map(|(m, a)| place(m, a).unwrap()).collect();
    Instances::new(meshes, list, first).unwrap()
}

/// The two-level query is exact against brute force over the copies (the top tree's
/// guarantee, with each copy answering through its own tree), and any-hit agrees.
#[test]
fn the_top_tree_answers_as_brute_force_over_the_copies() {
    let inst = scene_copies(10);
    let rays = incoherent_rays(inst.bounds(), 3000, 7);
    let mut hits = 0;
    for (ray, len) in &rays {
        for tmax in [f32::INFINITY, *len] {
            let got = inst.intersect(ray, tmax);
            assert_eq!(got, brute_force_intersect(&inst.set, ray, tmax));
            assert_eq!(inst.occluded(ray, tmax), got.is_some());
            assert_eq!(brute_force_occluded(&inst.set, ray, tmax), got.is_some());
            hits += usize::from(got.is_some());
        }
    }
    assert!(hits > 2000, "the rays must hit the copies to test anything: {hits}");
}

/// A copy under the identity is the mesh, bit for bit: same distance, barycentrics and
/// triangle (numbered after `first`).
#[test]
fn an_identity_copy_is_the_mesh_itself() {
    let m = mesh(3000, 1);
    let own = m.geometry.clone();
    let own_tree = Bvh8::build(&own, &Bvh8Params::default());
    let inst = Instances::new(vec![m], vec![place(0, Affine3A::IDENTITY).unwrap()], 100).unwrap();
    assert!(inst.set.list[0].identity);
    for (ray, _) in incoherent_rays(inst.bounds(), 2000, 3) {
        let want = own_tree.intersect(&own, &ray, f32::INFINITY);
        let got = inst.intersect(&ray, f32::INFINITY);
        assert_eq!(got.map(|h| (h.t, h.u, h.v, h.prim - 100)), want.map(|h| (h.t, h.u, h.v, h.prim)));
    }
}

/// Against the same copies flattened into world-space triangles (the loader's other
/// route): the same triangles are hit at the same distances, up to the rounding of
/// moving the ray instead of the triangles. Rays may disagree only where they graze an
/// edge; the bound is a few per thousand.
#[test]
fn copies_agree_with_the_flattened_triangles() {
    let inst = scene_copies(0);
    let mut flat = crate::shapes::TriangleMesh::default();
    for c in &inst.set.list {
        let g = &inst.set.meshes[c.mesh as usize].geometry;
        for i in 0..g.triangle_count() {
            let base = flat.positions.len() as u32;
            flat.positions.extend(g.triangle(i).map(|p| c.to_world.transform_point3(p)));
            let mut v = [base, base + 1, base + 2];
            if c.mirrored {
                v.swap(1, 2);
            }
            flat.tris.push(crate::shapes::Tri {
                v,
                n: [crate::shapes::NONE; 3],
                uv: [crate::shapes::NONE; 3],
                material: 0,
            });
        }
    }
    let flat = Geometry::new(flat, Vec::new());
    assert_eq!(flat.triangle_count() as u64, inst.triangles_seen());
    let tree = Bvh8::build(&flat, &Bvh8Params::default());
    let rays = incoherent_rays(inst.bounds(), 4000, 11);
    let mut differ = 0;
    for (ray, _) in &rays {
        let (a, b) = (inst.intersect(ray, f32::INFINITY), tree.intersect(&flat, ray, f32::INFINITY));
        match (a, b) {
            (Some(a), Some(b)) if a.prim == b.prim => {
                assert!((a.t - b.t).abs() <= 1e-4 * a.t.max(1.0), "{} vs {}", a.t, b.t);
                assert!((a.u - b.u).abs() < 1e-3 && (a.v - b.v).abs() < 1e-3 || inst.resolve(a.prim).0.mirrored);
            }
            (None, None) => {}
            _ => differ += 1,
        }
    }
    assert!(differ * 1000 <= 3 * rays.len(), "{differ} of {} rays disagree", rays.len());
}

#[test]
fn triangles_are_numbered_after_the_scenes_own() {
    let inst = scene_copies(50);
    let n0 = inst.set.meshes[0].geometry.triangle_count() as u32;
    let n1 = inst.set.meshes[1].geometry.triangle_count() as u32;
    assert_eq!(inst.triangles_seen(), u64::from(4 * n0 + 2 * n1));
    assert!(!inst.holds(49) && inst.holds(50) && !inst.holds(50 + 4 * n0 + 2 * n1));
    let (c, _, tri) = inst.resolve(50 + n0 + 5);
    assert_eq!((c.first, tri), (50 + n0, 5));
    let (c, m, tri) = inst.resolve(50 + 2 * n0 + n1 - 1);
    assert_eq!((c.mesh, tri), (1, n1 as usize - 1));
    assert_eq!(m.geometry.triangle_count() as u32, n1);
}

#[test]
fn bad_copies_are_errors() {
    let flat = Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0));
    assert_eq!(place(0, flat).unwrap_err(), InstanceError::Singular);
    let list = vec![place(0, Affine3A::IDENTITY).unwrap(); 3];
    let err = Instances::new(vec![mesh(2000, 1)], list, u32::MAX - 4000).err();
    assert_eq!(err, Some(InstanceError::TooManyTriangles));
}
