//! Scene input — the TOML scene file, OBJ/MTL meshes — and the assembled [`Scene`] with
//! its ray queries.

mod area_lights;
pub mod assets;
mod builder;
pub mod check;
mod environment;
mod error;
pub mod file;
pub mod files;
pub mod generate;
pub mod load;
mod materials;
pub use materials::MAX_MIX_DEPTH;
pub mod obj;
pub mod overrides;
pub mod placement;
pub mod prepared;
pub mod textures;
mod uv_frame;

pub use crate::shapes::{Geometry, GeometryBytes, NONE, PrimRef, Sphere, Tri, TriangleMesh};
pub use check::{SceneCheck, check_scene_as};
pub use file::UpAxis;
pub use load::{
    RenderSettings, SceneError, check_clamp, check_noise, load_scene, load_scene_as, load_scene_up,
    scene_from_bare_obj, scene_from_toml,
};
pub use overrides::Overrides;

use glam::{Vec2, Vec3};

use crate::accel::Hit;
use crate::accel::bvh8::Bvh8;
use crate::accel::instances::Instances;
use crate::accel::triangle_blocks::PackedTriangles;
use crate::camera::Camera;
use crate::geometry::Ray;
use crate::light::LightSet;
use crate::material::Material;
use crate::math;
use crate::simd::{F8, M8, U8, V3w, each};
use crate::texture::Texture;

/// Everything needed to render: immutable once built, shared by all render threads.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Scene {
    pub camera: Camera,
    pub settings: RenderSettings,
    pub geometry: Geometry,
    /// The hierarchy over `geometry` (its triangles stored in the hierarchy's leaf order).
    pub accel: Bvh8,
    /// Scenes of a few hundred triangles are traced by brute force in blocks instead of
    /// the hierarchy ([`PackedTriangles::for_small_scene`]); same answers, bit for bit.
    pub packed: Option<PackedTriangles>,
    /// Meshes placed more than once, stored once each (their triangles are numbered
    /// after `geometry`'s primitives). A scene with instances has no `packed`.
    pub instances: Option<Instances>,
    pub materials: Vec<Material>,
    /// The name of each material (from `newmtl`), for messages and tests.
    pub material_names: Vec<String>,
    pub textures: Vec<Texture>,
    pub lights: LightSet,
    /// Some material has `d < 1` (stochastic opacity): shadow rays must see through it.
    pub has_cutouts: bool,
    /// Bounding sphere of the geometry.
    pub center: Vec3,
    pub radius: f32,
    pub warnings: Vec<String>,
}

/// The local geometry at a ray hit.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceHit {
    pub p: Vec3,
    /// Geometric normal of the front face (counter-clockwise winding; outward on spheres).
    pub ng: Vec3,
    /// Shading normal, on the same side as `ng`.
    pub ns: Vec3,
    pub uv: Vec2,
    pub material: u32,
    pub prim: u32,
    pub t: f32,
}

impl Scene {
    /// What a scene read back from disk needs that serde does not give it: the large
    /// arrays' memory hints (see [`crate::memory::advise_huge_pages`]).
    pub(crate) fn after_read(&self) {
        self.geometry.advise_huge_pages();
        self.accel.advise_huge_pages();
        if let Some(inst) = &self.instances {
            inst.advise_huge_pages();
        }
    }

    /// The nearest hit with `0 < t < tmax`; a copy of an instanced mesh is taken over the
    /// scene's own primitives only when strictly nearer.
    #[inline]
    pub fn intersect(&self, ray: &Ray, tmax: f32) -> Option<Hit> {
        let own = match &self.packed {
            Some(p) => p.intersect(&self.geometry, ray, tmax),
            None => self.accel.intersect(&self.geometry, ray, tmax),
        };
        match &self.instances {
            None => own,
            Some(inst) => inst.intersect(ray, own.map_or(tmax, |h| h.t)).or(own),
        }
    }

    #[inline]
    pub fn occluded(&self, ray: &Ray, tmax: f32) -> bool {
        let own = match &self.packed {
            Some(p) => p.occluded(&self.geometry, ray, tmax),
            None => self.accel.occluded(&self.geometry, ray, tmax),
        };
        own || self.instances.as_ref().is_some_and(|inst| inst.occluded(ray, tmax))
    }

    /// The material of the primitive a hit names.
    #[inline]
    pub fn material_of(&self, prim: u32) -> u32 {
        match &self.instances {
            Some(inst) if inst.holds(prim) => {
                let (_, mesh, tri) = inst.resolve(prim);
                mesh.geometry.material(tri)
            }
            _ => match self.geometry.resolve(prim) {
                PrimRef::Triangle(i) => self.geometry.material(i),
                PrimRef::Sphere(i) => self.geometry.spheres[i].material,
            },
        }
    }

    /// Surface data at a hit found by [`Scene::intersect`] for `ray`.
    // Inline: see the note on `Bsdf`'s methods (bsdf/mod.rs).
    #[inline(always)]
    pub fn interaction(&self, ray: &Ray, hit: &Hit) -> SurfaceHit {
        if let Some(inst) = &self.instances
            && inst.holds(hit.prim)
        {
            return instanced_interaction(inst, hit);
        }
        match self.geometry.resolve(hit.prim) {
            PrimRef::Triangle(i) => {
                let g = &self.geometry;
                let [p0, p1, p2] = *g.triangle(i);
                let b = Vec3::new(1.0 - hit.u - hit.v, hit.u, hit.v);
                // Interpolating the corners is more accurate than ray.at(t) far away.
                let p = b.x * p0 + b.y * p1 + b.z * p2;
                let ng = (p1 - p0).cross(p2 - p0).normalize_or_zero();
                let ns = if let Some([n0, n1, n2]) = g.shading_normals(i) {
                    let n = b.x * n0 + b.y * n1 + b.z * n2;
                    let n = n.normalize_or_zero();
                    if n == Vec3::ZERO || !n.is_finite() {
                        ng
                    } else if n.dot(ng) < 0.0 {
                        -n
                    } else {
                        n
                    }
                } else {
                    ng
                };
                let uv = g.uv(i, b);
                SurfaceHit { p, ng, ns, uv, material: g.material(i), prim: hit.prim, t: hit.t }
            }
            PrimRef::Sphere(i) => {
                let s = &self.geometry.spheres[i];
                let n = (ray.at(hit.t) - s.center).normalize_or_zero();
                let n = if n == Vec3::ZERO { Vec3::Z } else { n };
                // Re-project onto the surface to remove the error of ray.at(t).
                let p = s.center + s.radius * n;
                let uv = Vec2::new(
                    (math::atan2(n.z, n.x) / std::f32::consts::TAU).rem_euclid(1.0),
                    math::acos(n.y.clamp(-1.0, 1.0)) / std::f32::consts::PI,
                );
                SurfaceHit { p, ng: n, ns: n, uv, material: s.material, prim: hit.prim, t: hit.t }
            }
        }
    }

    /// [`Scene::interaction`]'s position, geometric and shading normals at eight hits,
    /// lane by lane with the same operations: the lanes of `tri` hit triangles, those of
    /// `sph` spheres; `prim`, `t`, `u`, `v` are the hits'. (Texture coordinates are not
    /// computed: the eight-path integrator takes lanes whose materials have no texture.)
    #[inline(always)]
    pub(crate) fn interaction_wide(
        &self,
        origin: V3w,
        dir: V3w,
        hit: (U8, F8, F8, F8),
        tri: M8,
        sph: M8,
    ) -> (V3w, V3w, V3w) {
        let (prim, t, u, v) = hit;
        let g = &self.geometry;
        let simd = origin.simd();
        let zero = simd.v3(Vec3::ZERO);
        let (mut p, mut ng, mut ns) = (zero, zero, zero);
        if tri.any() {
            let (mut p0, mut p1, mut p2) = (zero, zero, zero);
            let (mut n0, mut n1, mut n2, mut smooth) = (zero, zero, zero, simd.none());
            for l in each(tri.bits()) {
                let i = prim.0[l] as usize;
                let [a, b, c] = *g.triangle(i);
                p0.set(l, a);
                p1.set(l, b);
                p2.set(l, c);
                if let Some([a, b, c]) = g.shading_normals(i) {
                    n0.set(l, a);
                    n1.set(l, b);
                    n2.set(l, c);
                    smooth.0[l] = u32::MAX;
                }
            }
            let b = V3w::new(1.0 - u - v, u, v);
            let pt = b.x * p0 + b.y * p1 + b.z * p2;
            p = tri.select3(pt, p);
            let n_g = (p1 - p0).cross(p2 - p0).normalize_or_zero();
            ng = tri.select3(n_g, ng);
            let mut n_s = n_g;
            if smooth.any() {
                let n = (b.x * n0 + b.y * n1 + b.z * n2).normalize_or_zero();
                let degenerate = (n.x.eq(0.0) & n.y.eq(0.0) & n.z.eq(0.0)) | !n.is_finite();
                let n = n.dot(n_g).lt(0.0).select3(-n, n);
                n_s = (smooth & !degenerate).select3(n, n_g);
            }
            ns = tri.select3(n_s, ns);
        }
        if sph.any() {
            let (mut c, mut r) = (zero, simd.zero());
            for l in each(sph.bits()) {
                let s = &g.spheres[prim.0[l] as usize - g.triangle_count()];
                c.set(l, s.center);
                r.0[l] = s.radius;
            }
            let n = (origin + t * dir - c).normalize_or_zero();
            let n = (n.x.eq(0.0) & n.y.eq(0.0) & n.z.eq(0.0)).select3(simd.v3(Vec3::Z), n);
            p = sph.select3(c + r * n, p);
            ng = sph.select3(n, ng);
            ns = sph.select3(n, ns);
        }
        (p, ng, ns)
    }
}

/// [`Scene::interaction`] on a copy of an instanced mesh: the triangle's corners and
/// shading normals moved to the world, then the same steps as on the scene's own
/// triangles (the face normal keeps the mesh's front side when the copy is mirrored).
#[inline(never)]
fn instanced_interaction(instances: &Instances, hit: &Hit) -> SurfaceHit {
    let (inst, mesh, i) = instances.resolve(hit.prim);
    let g = &mesh.geometry;
    let [p0, p1, p2] = g.triangle(i).map(|p| if inst.identity { p } else { inst.to_world.transform_point3(p) });
    let b = Vec3::new(1.0 - hit.u - hit.v, hit.u, hit.v);
    let p = b.x * p0 + b.y * p1 + b.z * p2;
    let ng = (p1 - p0).cross(p2 - p0).normalize_or_zero();
    let ng = if inst.mirrored { -ng } else { ng };
    let ns = match g.shading_normals(i) {
        Some([n0, n1, n2]) => {
            let n = b.x * n0 + b.y * n1 + b.z * n2;
            let n = if inst.identity { n } else { inst.normal_to_world * n };
            let n = n.normalize_or_zero();
            if n == Vec3::ZERO || !n.is_finite() {
                ng
            } else if n.dot(ng) < 0.0 {
                -n
            } else {
                n
            }
        }
        None => ng,
    };
    SurfaceHit { p, ng, ns, uv: g.uv(i, b), material: g.material(i), prim: hit.prim, t: hit.t }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The wide interaction gives [`Scene::interaction`]'s bits, on flat and smooth
    /// triangles (with shading normals facing away from the face, and cancelling to zero
    /// on an edge) and on spheres.
    #[test]
    fn interaction_wide_is_the_interaction() {
        let simd = crate::simd::tests::require_avx2();
        let dir = std::env::temp_dir().join(format!("tilefarm-interaction-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("t.obj"),
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvn 0 0 1\nvn 0 0 -1\nvn 0.3 0.2 -1\nvn 1 1 1\n\
             f 1 2 3\nf 1//1 2//2 3//1\nf 1//3 2//4 4//3\n",
        )
        .unwrap();
        let text = "[camera]\nposition = [0, 0, 10]\nlook_at = [0, 0, 0]\nfov = 40\nwidth = 8\nheight = 8\n\
                    [[mesh]]\nobj = \"t.obj\"\n[[sphere]]\ncenter = [2, 0, 0]\nradius = 0.5\nkd = [0.5, 0.5, 0.5]\n";
        let scene = crate::scene::scene_from_toml(text, "interaction.toml", &dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let ntri = scene.geometry.triangle_count() as u32;
        assert_eq!(ntri, 3);
        // (prim, u, v): u = 0.5, v = 0 puts the second triangle's normals at zero; at
        // u = 0.8 they face away from the face normal, as do the third's.
        let hits = [(0, 0.2, 0.3), (1, 0.5, 0.0), (1, 0.8, 0.0), (2, 0.1, 0.7), (3, 0.0, 0.0), (2, 0.5, 0.5)];
        let mut origin = simd.v3(Vec3::ZERO);
        let mut dirw = simd.v3(Vec3::ZERO);
        let (mut prim, mut t, mut u, mut v) = (simd.splat_u(0), simd.zero(), simd.zero(), simd.zero());
        let (mut tri, mut sph) = (simd.none(), simd.none());
        let mut want = Vec::new();
        for (l, &(p, hu, hv)) in hits.iter().enumerate() {
            let o = Vec3::new(0.3 + l as f32 * 0.1, -0.2, 5.0);
            let d = Vec3::new(0.05 * l as f32, 0.02, -1.0).normalize();
            let hit = Hit { t: 4.0 + 0.1 * l as f32, prim: p, u: hu, v: hv };
            let si = scene.interaction(&Ray::new(o, d), &hit);
            want.push((si.p, si.ng, si.ns));
            origin.set(l, o);
            dirw.set(l, d);
            (prim.0[l], t.0[l], u.0[l], v.0[l]) = (p, hit.t, hu, hv);
            if p < ntri {
                tri.0[l] = u32::MAX;
            } else {
                sph.0[l] = u32::MAX;
            }
        }
        assert_eq!(want[1].2, want[1].1, "the cancelling normals fall back to the face normal");
        assert_ne!(want[3].2, want[3].1);
        let (p, ng, ns) = scene.interaction_wide(origin, dirw, (prim, t, u, v), tri, sph);
        let bits = |v: Vec3| v.to_array().map(f32::to_bits);
        for (l, w) in want.iter().enumerate() {
            assert_eq!(
                [bits(p.get(l)), bits(ng.get(l)), bits(ns.get(l))],
                [bits(w.0), bits(w.1), bits(w.2)],
                "hit {l}"
            );
        }
    }
}
