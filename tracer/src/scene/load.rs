//! Assembling a [`Scene`] from a TOML scene file or a bare OBJ: loading meshes, placing
//! them, classifying materials, collecting lights and building the hierarchy (BVH).

use std::path::Path;

use glam::Vec3;

use super::builder::Builder;
pub(super) use super::builder::Depth;
use super::environment::Background;
use super::file::{LightDesc, SceneFile, SphereDesc, UpAxis};
use super::obj::{ObjModel, load_obj_as};
use super::{Geometry, Scene, Sphere};
use crate::accel::Primitives;
use crate::accel::bvh8::{Bvh8, Bvh8Params};
use crate::accel::instances::Instances;
use crate::accel::triangle_blocks::PackedTriangles;
use crate::camera::Camera;
use crate::light::{Light, LightSet};
use crate::material::{Material, MaterialDesc, Slot};
use crate::math;

pub use super::error::SceneError;

/// Render settings from the `[render]` table.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RenderSettings {
    pub spp: u32,
    /// Mitsuba 3 `path` semantics: path segments from the camera, -1 = unlimited.
    pub max_depth: i32,
    pub seed: u64,
    /// Firefly control: a path sample whose largest channel exceeds this is scaled down to
    /// it (biased, so off unless asked for; recorded in the EXR). Finite and positive.
    pub clamp: Option<f32>,
    /// Keep the AOV layers beside the beauty pass (see [`crate::film::layers`]): more
    /// memory per pixel, the same beauty bits.
    pub aovs: bool,
    /// Adaptive sampling's noise target: a tile stops once its pixels' relative standard
    /// error is at most this (the farm decides; see the coordinator's `job/adaptive.rs`).
    /// Needs the layers' squared sums, so it turns `aovs` on. Finite and positive.
    pub noise: Option<f32>,
}

/// A noise target is a finite number above zero.
pub fn check_noise(target: f32) -> Result<(), String> {
    if target.is_finite() && target > 0.0 {
        Ok(())
    } else {
        Err(format!("must be a finite number above 0 (a relative error, such as 0.01), not {target}"))
    }
}

/// A clamp limit is a finite number above zero (zero would blank the image).
pub fn check_clamp(limit: f32) -> Result<(), String> {
    if limit.is_finite() && limit > 0.0 { Ok(()) } else { Err(format!("must be a finite number above 0, not {limit}")) }
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self { spp: 64, max_depth: 8, seed: 0, clamp: None, aovs: false, noise: None }
    }
}

/// Loads a scene: a `.toml` scene file, or a bare `.obj` that is framed automatically.
pub fn load_scene(path: &Path) -> Result<Scene, SceneError> {
    load_scene_up(path, UpAxis::Y)
}

/// [`load_scene`], with the up axis of a bare `.obj` (a scene file sets each mesh's own).
pub fn load_scene_up(path: &Path, up: UpAxis) -> Result<Scene, SceneError> {
    load_scene_as(path, &path.display().to_string(), up)
}

/// [`load_scene_up`], naming the scene file `display` in errors and warnings and the
/// files it refers to relative to that name: a job's copy of a scene is reported as the
/// user's own files (`quad.mtl`), not as where the copy lies.
pub fn load_scene_as(path: &Path, display: &str, up: UpAxis) -> Result<Scene, SceneError> {
    let display = display.to_string();
    if scene_kind(path, &display)? == SceneKind::Obj {
        let model = load_obj_as(path, &display)?;
        return Ok(scene_from_bare_obj(model, up));
    }
    refuse_up_for_scene_file(&display, up)?;
    let text = read_scene_text(path, &display)?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    scene_from_toml(&text, &display, &base)
}

/// An up axis belongs to a bare `.obj`; a scene file sets each mesh's own.
pub(super) fn refuse_up_for_scene_file(display: &str, up: UpAxis) -> Result<(), SceneError> {
    if up == UpAxis::Y {
        return Ok(());
    }
    Err(SceneError::Invalid {
        path: display.to_string(),
        field: "up".into(),
        message: "an up axis is given for a bare .obj; in a scene file, set up = \"z\" in its [[mesh]] tables".into(),
    })
}

/// The two kinds of scene input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneKind {
    Toml,
    Obj,
}

/// What kind of scene `path` is, by its extension; a folder or another kind of file (a
/// PNG given by mistake) is "not a scene file", named as `display`.
pub fn scene_kind(path: &Path, display: &str) -> Result<SceneKind, SceneError> {
    let not = |what: &str| SceneError::Io {
        path: display.to_string(),
        message: format!("not a scene file ({what}): expected a .toml scene or an .obj model"),
    };
    if path.is_dir() {
        return Err(not("a folder"));
    }
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("toml") => Ok(SceneKind::Toml),
        Some("obj") => Ok(SceneKind::Obj),
        _ => Err(not("another kind of file")),
    }
}

/// A scene file's text; binary content is "not a scene file" rather than a UTF-8 error.
pub(crate) fn read_scene_text(path: &Path, display: &str) -> Result<String, SceneError> {
    let io = |message: String| SceneError::Io { path: display.to_string(), message };
    let bytes = super::files::read_bounded(path, super::files::MAX_SCENE_BYTES).map_err(|e| io(e.to_string()))?;
    String::from_utf8(bytes).map_err(|_| io("not a scene file: it is not text (a scene is a .toml file)".into()))
}

/// Parses and assembles a scene file's text; relative paths resolve against `base`.
pub fn scene_from_toml(text: &str, display_name: &str, base: &Path) -> Result<Scene, SceneError> {
    let file: SceneFile = toml::from_str(text)
        .map_err(|e| SceneError::Syntax { path: display_name.to_string(), message: e.to_string() })?;
    assemble(&file, text, display_name, base)
}

fn vec3(v: [f32; 3]) -> Vec3 {
    Vec3::from_array(v)
}

fn assemble(file: &SceneFile, text: &str, name: &str, base: &Path) -> Result<Scene, SceneError> {
    let Assembled { mut b, camera, settings, lights, background } =
        assemble_parts(file, text, name, base, Depth::Build)?;
    // The copies' triangles are numbered after the scene's own primitives.
    let instances = match std::mem::take(&mut b.copies) {
        copies if copies.is_empty() => None,
        copies => {
            let first = u32::try_from(b.mesh.tris.len() + b.spheres.len()).unwrap_or(u32::MAX);
            let mut meshes = std::mem::take(&mut b.instanced);
            if has_normal_maps(&b.materials) {
                meshes.iter_mut().for_each(|m| m.geometry.add_tangents());
            }
            let made = Instances::new(meshes, copies, first);
            Some(made.map_err(|e| invalid_in(text, name)("mesh".into(), e.to_string()))?)
        }
    };
    Ok(finish(b, camera, settings, lights, background, instances))
}

/// A scene file's parts before its geometry is built.
pub(super) struct Assembled {
    pub b: Builder,
    pub camera: Camera,
    pub settings: RenderSettings,
    pub lights: Vec<Light>,
    pub background: Background,
}

/// An error about `field` of the scene file `name`, at the field's line in `text`.
pub(super) fn invalid_in<'a>(text: &'a str, name: &'a str) -> impl Fn(String, String) -> SceneError + 'a {
    move |field: String, message: String| {
        let path = match super::file::line_of(text, &field) {
            Some(line) => format!("{name}:{line}"),
            None => name.to_string(),
        };
        SceneError::Invalid { path, field, message }
    }
}

// Long on purpose: One scene assembled in order (camera, materials, meshes, spheres, lights), each step short and commented; the order is the file's.
pub(super) fn assemble_parts(
    file: &SceneFile,
    text: &str,
    name: &str,
    base: &Path,
    depth: Depth,
) -> Result<Assembled, SceneError> {
    // Errors name the file and the field's line, as TOML's own errors do.
    let invalid = invalid_in(text, name);
    let finite3 = |field: String, v: [f32; 3]| {
        if v.iter().all(|x| x.is_finite()) { Ok(vec3(v)) } else { Err(invalid(field, "must be finite".into())) }
    };
    let non_negative3 = |field: String, v: [f32; 3]| {
        if v.iter().all(|x| x.is_finite() && *x >= 0.0) {
            Ok(vec3(v))
        } else {
            Err(invalid(field, "must be finite and ≥ 0".into()))
        }
    };

    // Camera.
    let c = &file.camera;
    let camera = Camera::look_at(
        finite3("camera.position".into(), c.position)?,
        finite3("camera.look_at".into(), c.look_at)?,
        finite3("camera.up".into(), c.up)?,
        c.fov,
        c.width,
        c.height,
    )
    .map_err(|e| invalid(e.field().into(), e.to_string()))?;
    let camera = if c.aperture != 0.0 || c.focus_distance.is_some() {
        let focus = c.focus_distance.unwrap_or_else(|| (vec3(c.look_at) - vec3(c.position)).length());
        camera.with_lens(c.aperture, focus).map_err(|e| invalid(e.field().into(), e.to_string()))?
    } else {
        camera
    };

    // Render settings.
    let r = &file.render;
    if r.spp == 0 {
        return Err(invalid("render.spp".into(), "must be at least 1".into()));
    }
    if r.max_depth == 0 || r.max_depth < -1 {
        return Err(invalid("render.max_depth".into(), "must be -1 (unlimited) or ≥ 1".into()));
    }
    if let Some(c) = r.clamp {
        check_clamp(c).map_err(|e| invalid("render.clamp".into(), e))?;
    }
    if let Some(n) = r.noise {
        check_noise(n).map_err(|e| invalid("render.noise".into(), e))?;
    }
    let settings = RenderSettings {
        spp: r.spp,
        max_depth: r.max_depth,
        seed: r.seed,
        clamp: r.clamp,
        aovs: r.aovs || r.noise.is_some(),
        noise: r.noise,
    };

    // Meshes, each OBJ read once (see `place_meshes`).
    let mut b = Builder::default();
    // The material table first: meshes and spheres use its materials by name.
    super::materials::add_table(&mut b, &file.materials, base, &invalid)?;
    super::placement::place_meshes(&mut b, &file.mesh, name, base, depth, &invalid)?;
    // Spheres, each with its inline material.
    for (i, s) in file.sphere.iter().enumerate() {
        let field = |k: &str| format!("sphere[{i}].{k}");
        let center = finite3(field("center"), s.center)?;
        if !(s.radius > 0.0 && s.radius.is_finite()) {
            return Err(invalid(field("radius"), format!("must be > 0, got {}", s.radius)));
        }
        let material = match &s.material {
            Some(m) => {
                if sphere_has_keys(s) {
                    return Err(invalid(
                        field("material"),
                        "a sphere takes `material` or inline keys, not both".into(),
                    ));
                }
                b.named(m)
                    .ok_or_else(|| invalid(field("material"), format!("'{m}' is not in the [materials] table")))?
            }
            None => {
                let desc = sphere_material(s, &field, &invalid)?;
                b.materials.push(Material::from_desc(&desc));
                b.material_names.push(format!("sphere[{i}]"));
                b.materials.len() as u32 - 1
            }
        };
        b.spheres.push(Sphere { center, radius: s.radius, material });
    }

    // Point, spot and directional lights.
    let mut lights = Vec::new();
    for (i, l) in file.light.iter().enumerate() {
        let field = |k: &str| format!("light[{i}].{k}");
        let unit = |k: &str, v: [f32; 3]| {
            let d = finite3(field(k), v)?.normalize_or_zero();
            if d == Vec3::ZERO { Err(invalid(field(k), "must not be zero".into())) } else { Ok(d) }
        };
        let hard = match *l {
            LightDesc::Area(ref a) => {
                lights.extend(super::area_lights::area_light(a, &mut b, &field, &invalid)?);
                continue;
            }
            LightDesc::Point { position, intensity, .. } => Light::Point {
                position: finite3(field("position"), position)?,
                intensity: non_negative3(field("intensity"), intensity)?,
            },
            LightDesc::Spot { position, direction, intensity, cone_angle, falloff_start, .. } => {
                if !(cone_angle > 0.0 && cone_angle <= 180.0) {
                    return Err(invalid(field("cone_angle"), format!("must be in (0, 180] degrees, got {cone_angle}")));
                }
                let start = falloff_start.unwrap_or(cone_angle);
                if !(start >= 0.0 && start <= cone_angle) {
                    return Err(invalid(field("falloff_start"), format!("must be in [0, cone_angle], got {start}")));
                }
                Light::Spot {
                    position: finite3(field("position"), position)?,
                    direction: unit("direction", direction)?,
                    intensity: non_negative3(field("intensity"), intensity)?,
                    cos_total: math::cos(cone_angle.to_radians()),
                    cos_falloff_start: math::cos(start.to_radians()),
                }
            }
            LightDesc::Directional { direction, irradiance, .. } => Light::Directional {
                direction: unit("direction", direction)?,
                irradiance: non_negative3(field("irradiance"), irradiance)?,
            },
        };
        lights.push(super::area_lights::soften(hard, l, &field, &invalid)?);
    }
    let background = super::environment::background(&file.background, base, &invalid)?;
    if let Some(w) = &file.background.warning {
        b.warnings.push(format!("{name}: {w}"));
    }
    Ok(Assembled { b, camera, settings, lights, background })
}

fn sphere_material(
    s: &SphereDesc,
    field: &dyn Fn(&str) -> String,
    invalid: &dyn Fn(String, String) -> SceneError,
) -> Result<MaterialDesc, SceneError> {
    let colour = |k: &str, v: Option<[f32; 3]>| -> Result<Vec3, SceneError> {
        match v {
            None => Ok(Vec3::ZERO),
            Some(v) if v.iter().all(|x| x.is_finite() && *x >= 0.0) => Ok(vec3(v)),
            Some(_) => Err(invalid(field(k), "must be finite and ≥ 0".into())),
        }
    };
    let scalar = |k: &str, v: Option<f32>, default: f32, ok: &dyn Fn(f32) -> bool| match v {
        None => Ok(default),
        Some(x) if x.is_finite() && ok(x) => Ok(x),
        Some(x) => Err(invalid(field(k), format!("out of range: {x}"))),
    };
    if !sphere_has_keys(s) {
        return Ok(MaterialDesc::default_grey("sphere"));
    }
    let mut desc = MaterialDesc {
        name: "sphere".into(),
        kd: colour("kd", s.kd)?,
        ks: colour("ks", s.ks)?,
        ke: colour("ke", s.ke)?,
        tf: if s.tf.is_some() { colour("tf", s.tf)? } else { Vec3::ONE },
        ns: scalar("ns", s.ns, 0.0, &|x| x >= 0.0)?,
        ni: scalar("ni", s.ni, 1.0, &|x| x > 0.0)?,
        d: scalar("d", s.d, 1.0, &|x| (0.0..=1.0).contains(&x))?,
        illum: s.illum,
        ..MaterialDesc::default()
    };
    let keys = [("pr", s.pr), ("pm", s.pm), ("ps", s.ps), ("pc", s.pc), ("pcr", s.pcr)];
    let mut pbr = crate::scene::obj::PbrKeys::default();
    for (k, v) in keys {
        if let Some(x) = v {
            pbr.set(k, scalar(k, Some(x), 0.0, &|x| (0.0..=1.0).contains(&x))?);
        }
    }
    if pbr.principled() {
        desc.pbr = Some(pbr.pbr_desc(&desc, s.ni));
    }
    Ok(desc)
}

/// Whether a sphere has inline material keys.
fn sphere_has_keys(s: &SphereDesc) -> bool {
    s.kd.is_some()
        || s.ks.is_some()
        || s.ns.is_some()
        || s.ke.is_some()
        || s.ni.is_some()
        || s.d.is_some()
        || s.tf.is_some()
        || s.illum.is_some()
        || [s.pr, s.pm, s.ps, s.pc, s.pcr].iter().any(Option::is_some)
}

/// Whether some material has a tangent-space normal map or anisotropy (its triangles
/// then need MikkTSpace tangents, 48 bytes each).
fn has_normal_maps(materials: &[Material]) -> bool {
    materials.iter().any(|m| m.maps.get(Slot::Normal).is_some() || m.anisotropy.amount > 0.0)
}

/// Collects area lights and builds the hierarchy.
// Long on purpose: The scene's last steps in order (store, accelerator, lights, checks), sharing its parts.
fn finish(
    b: Builder,
    camera: Camera,
    settings: RenderSettings,
    mut lights: Vec<Light>,
    background: Background,
    instances: Option<Instances>,
) -> Scene {
    let Background { radiance: background, map } = background;
    let Builder { mesh, spheres, materials, material_names, textures, warnings, .. } = b;
    // From here on the scene keeps only the compact runtime form of the mesh.
    let t = std::time::Instant::now();
    let mut geometry = Geometry::new(mesh, spheres);
    if has_normal_maps(&materials) {
        geometry.add_tangents();
    }
    let mut accel = Bvh8::build(&geometry, &Bvh8Params::default());
    tracing::debug!("BVH of {} primitives built in {:.2?}", geometry.len(), t.elapsed());
    // The eight-ray packets trace the scene's own primitives only.
    let packed = if instances.is_some() { None } else { PackedTriangles::for_small_scene(&geometry) };
    // When the hierarchy traces the scene, the triangles are stored in its leaf order from
    // here on, for memory locality (`order[new] = old`). Small scenes, traced by packed
    // brute force in index order, keep the file's order.
    let order: Vec<u32> = match packed {
        None => geometry.store_in_leaf_order(&mut accel),
        Some(_) => (0..geometry.triangle_count() as u32).collect(),
    };
    let mut new_index = vec![0u32; order.len()];
    for (new, &old) in order.iter().enumerate() {
        new_index[old as usize] = new as u32;
    }
    let bounds = accel.bounds().union(instances.as_ref().map_or(crate::geometry::Aabb::EMPTY, |i| i.bounds()));
    let (center, radius) = if bounds.is_empty() {
        (Vec3::ZERO, 1.0)
    } else {
        (bounds.center(), (0.5 * bounds.diagonal().length()).max(1e-3))
    };

    // Emissive triangles in the order the files list them (the light list's order shapes
    // light sampling, so it does not follow the storage order), by their new indices.
    for &i in &new_index {
        let i = i as usize;
        let m = &materials[geometry.material(i) as usize];
        // A textured emitter is found by its surfaces' BSDF samples only: a light's
        // radiance is one value over its triangle.
        if !m.is_emissive() || m.maps.get(Slot::Emission).is_some() {
            continue;
        }
        let [p0, p1, p2] = *geometry.triangle(i);
        let (e1, e2) = (p1 - p0, p2 - p0);
        let c = e1.cross(e2);
        let area = 0.5 * c.length();
        if area > 0.0 && area.is_finite() {
            lights.push(Light::Triangle {
                prim: i as u32,
                p0,
                e1,
                e2,
                normal: c.normalize(),
                area,
                radiance: m.emission,
            });
        }
    }
    let ntri = geometry.triangle_count();
    for (i, s) in geometry.spheres.iter().enumerate() {
        let m = &materials[s.material as usize];
        if m.is_emissive() && m.maps.get(Slot::Emission).is_none() {
            lights.push(Light::Sphere {
                prim: (ntri + i) as u32,
                center: s.center,
                radius: s.radius,
                radiance: m.emission,
            });
        }
    }
    if background.max_element() > 0.0 {
        lights.push(Light::Environment { radiance: background });
    }
    // A map lights the scene through one environment light of unit scale (the map holds
    // its strength); an all-black map is no light.
    let map = map.filter(|m| m.mean().max_element() > 0.0);
    if map.is_some() {
        lights.push(Light::Environment { radiance: Vec3::ONE });
    }
    let lights = LightSet::with_environment_map(lights, map, geometry.len(), radius);
    let has_cutouts = materials.iter().any(|m| m.has_cutout());
    if materials.iter().any(|m| matches!(m.bsdf, crate::bsdf::Bsdf::Principled(_))) {
        crate::bsdf::energy::prepare();
    }
    Scene {
        camera,
        settings,
        packed,
        instances,
        geometry,
        accel,
        materials,
        material_names,
        textures,
        lights,
        has_cutouts,
        center,
        radius,
        warnings,
    }
}

/// A bare OBJ: the camera frames its bounding box (OBJ files come at any scale) and, if
/// nothing emits, a default light (a key "sun" plus a dim sky) makes the model visible.
pub fn scene_from_bare_obj(model: ObjModel, up: UpAxis) -> Scene {
    let any_emitter = model.materials.iter().any(|m| m.ke.max_element() > 0.0);
    let mut b = Builder::default();
    b.add_model(model, up.to_y_up(), Vec3::ZERO);
    let (camera, lights, background) =
        bare_obj_view(crate::geometry::Aabb::from_points(&b.mesh.positions), any_emitter);
    let background = Background { radiance: background, map: None };
    finish(b, camera, RenderSettings::default(), lights, background, None)
}

/// A bare OBJ's camera, framing its placed bounds, and its lights and background.
pub(super) fn bare_obj_view(bounds: crate::geometry::Aabb, any_emitter: bool) -> (Camera, Vec<Light>, Vec3) {
    let (center, radius) = if bounds.is_empty() {
        (Vec3::ZERO, 1.0)
    } else {
        (bounds.center(), (0.5 * bounds.diagonal().length()).max(1e-6))
    };
    let fov = 40.0f32;
    // Far enough that the bounding sphere fits the vertical field of view.
    let dist = radius / math::sin(0.5 * fov.to_radians()) * 1.05;
    let dir = Vec3::new(0.35, 0.35, 1.0).normalize();
    let camera = Camera::look_at(center + dir * dist, center, Vec3::Y, fov, 640, 480)
        .expect("auto-framed camera is well formed");
    let (lights, background) = if any_emitter {
        (vec![], Vec3::ZERO)
    } else {
        (
            vec![Light::Directional {
                direction: Vec3::new(-0.4, -1.0, -0.6).normalize(),
                irradiance: Vec3::splat(2.5),
            }],
            Vec3::splat(0.25),
        )
    };
    (camera, lights, background)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::MaterialDesc;
    use crate::scene::generate::displaced_sphere;

    /// The loader stores triangles in the hierarchy's leaf order: hits, materials and area
    /// lights must all speak of the same (permuted) triangles, and the lights keep the
    /// file's order.
    #[test]
    fn leaf_order_storage_keeps_lights_and_materials_consistent() {
        let mut mesh = displaced_sphere(20_000, 2);
        for (i, t) in mesh.tris.iter_mut().enumerate() {
            t.material = u32::from(i % 7 == 0);
        }
        let file_order: Vec<[Vec3; 3]> = (0..mesh.tris.len()).map(|i| mesh.corners(i)).collect();
        let emissive = MaterialDesc { name: "lamp".into(), ke: Vec3::ONE, ..MaterialDesc::default() };
        let model =
            ObjModel { mesh, materials: vec![MaterialDesc::default_grey("grey"), emissive], ..ObjModel::default() };
        let s = scene_from_bare_obj(model, UpAxis::Y);
        let g = &s.geometry;
        assert!(s.packed.is_none(), "the test is about the hierarchy's path");
        // The permutation moved triangles (else the test proves nothing).
        assert!((0..g.triangle_count()).any(|i| *g.triangle(i) != file_order[i]));
        let mut seen = Vec::new();
        for (li, l) in s.lights.lights.iter().enumerate() {
            if let Light::Triangle { prim, p0, e1, e2, .. } = *l {
                let i = prim as usize;
                let c = *g.triangle(i);
                assert_eq!((p0, e1, e2), (c[0], c[1] - c[0], c[2] - c[0]));
                assert_eq!(g.material(i), 1);
                assert_eq!(s.lights.light_of_prim(prim), Some(li));
                seen.push(c);
            }
        }
        let expect: Vec<[Vec3; 3]> = file_order.iter().step_by(7).copied().collect();
        assert_eq!(seen, expect, "area lights in the file's order");
        // A hit reports the material and corners of the triangle it names.
        for (k, c) in expect.iter().enumerate().step_by(97) {
            let target = (c[0] + c[1] + c[2]) / 3.0;
            let origin = target * 3.0 + Vec3::new(0.01, 0.02, 0.03) * k as f32;
            let ray = crate::geometry::Ray::new(origin, (target - origin).normalize());
            let hit = s.intersect(&ray, f32::INFINITY).expect("aimed at the mesh");
            let si = s.interaction(&ray, &hit);
            let i = hit.prim as usize;
            assert_eq!(si.material, g.material(i));
            assert_eq!(s.lights.light_of_prim(hit.prim).is_some(), si.material == 1);
        }
    }

    /// `scale`, then `rotate_y` (degrees, counter-clockwise seen from +y, as glam's
    /// `Mat3::from_rotation_y`), then `translate`.
    #[test]
    fn mesh_transform_scales_rotates_then_translates() {
        let dir = std::env::temp_dir().join(format!("tilefarm-transform-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("tri.obj"), "v 1 0 0\nv 0 0 1\nv 0 1 0\nf 1 2 3\n").unwrap();
        let text = "[camera]\nposition = [0, 0, 10]\nlook_at = [0, 0, 0]\nfov = 40\nwidth = 8\nheight = 8\n\
                    [[mesh]]\nobj = \"tri.obj\"\nscale = 2\nrotate_y = 90\ntranslate = [1, 2, 3]\n";
        let scene = scene_from_toml(text, "transform.toml", &dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let got = *scene.geometry.triangle(0);
        // x -> -z, z -> x (a quarter turn about +y), after doubling; then moved.
        let want = [Vec3::new(1.0, 2.0, 1.0), Vec3::new(3.0, 2.0, 3.0), Vec3::new(1.0, 4.0, 3.0)];
        for (g, w) in got.iter().zip(want) {
            assert!((*g - w).abs().max_element() < 1e-6, "{got:?} vs {want:?}");
        }
    }
}
