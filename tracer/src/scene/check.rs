//! Checking a scene without building it: what a farm's coordinator needs before it
//! hands out the scene's work — the errors and warnings a load would give, the camera
//! (auto-framed for a bare OBJ) and the render settings — while its OBJ files are read
//! in blocks and no mesh, tree or texture is kept ([`super::obj::check_obj_as`]). The
//! workers load the scene themselves, at the same time.

use std::path::Path;

use super::load::{Assembled, Depth, RenderSettings, SceneError, assemble_parts, bare_obj_view, invalid_in};
use super::load::{SceneKind, scene_kind};
use super::{Overrides, UpAxis};
use crate::accel::instances::InstanceError;
use crate::camera::Camera;
use crate::geometry::Aabb;

/// What checking a scene finds: what [`load_scene_as`](super::load_scene_as) would give
/// but the geometry.
#[derive(Clone, Debug)]
pub struct SceneCheck {
    pub camera: Camera,
    pub settings: RenderSettings,
    /// The load's warnings, in its order.
    pub warnings: Vec<String>,
    /// Triangles the scene holds, counting each placed copy.
    pub triangles: u64,
}

impl SceneCheck {
    /// [`Overrides::apply`], on the checked camera and settings.
    pub fn apply(&mut self, overrides: &Overrides) -> Result<(), String> {
        overrides.apply_to(&mut self.camera, &mut self.settings)
    }
}

/// Checks the scene at `path` (named `display`, as [`load_scene_as`](super::load_scene_as)
/// names it): the same errors as loading it, and on success what [`SceneCheck`] holds.
pub fn check_scene_as(path: &Path, display: &str, up: UpAxis) -> Result<SceneCheck, SceneError> {
    if scene_kind(path, display)? == SceneKind::Obj {
        let checked = super::obj::check_obj_as(path, display)?;
        let any_emitter = checked.model.materials.iter().any(|m| m.ke.max_element() > 0.0);
        // As the loader places it: `linear * p + translate`, translate zero.
        let linear = up.to_y_up();
        let placed = checked.used_positions.iter().map(|&p| linear * p + glam::Vec3::ZERO);
        let bounds = placed.fold(Aabb::EMPTY, Aabb::grow);
        let (camera, _, _) = bare_obj_view(bounds, any_emitter);
        let warnings = checked.model.warnings;
        return Ok(SceneCheck {
            camera,
            settings: RenderSettings::default(),
            warnings,
            triangles: checked.triangles as u64,
        });
    }
    super::load::refuse_up_for_scene_file(display, up)?;
    let text = super::load::read_scene_text(path, display)?;
    let base = path.parent().unwrap_or(Path::new("."));
    let file: super::file::SceneFile =
        toml::from_str(&text).map_err(|e| SceneError::Syntax { path: display.to_string(), message: e.to_string() })?;
    let Assembled { b, camera, settings, .. } = assemble_parts(&file, &text, display, base, Depth::Check)?;
    // As `Instances::new` counts: the copies' triangles are numbered after the scene's
    // own primitives, within 32 bits.
    let own = (b.flat_triangles + b.spheres.len() as u64).min(u64::from(u32::MAX));
    if !b.copies.is_empty() && own + b.copy_triangles > u64::from(u32::MAX) {
        return Err(invalid_in(&text, display)("mesh".into(), InstanceError::TooManyTriangles.to_string()));
    }
    let triangles = b.flat_triangles + b.copy_triangles;
    Ok(SceneCheck { camera, settings, warnings: b.warnings, triangles })
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::scene::load_scene_as;

    fn scenes() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes")
    }

    /// A check gives the load's error, or its camera, settings, warnings and triangles.
    fn check_matches_load(path: &Path, up: UpAxis) {
        let what = format!("{} ({up:?})", path.display());
        match (load_scene_as(path, "s", up), check_scene_as(path, "s", up)) {
            (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "{what}"),
            (Ok(s), Ok(c)) => {
                assert_eq!(s.camera, c.camera, "{what}");
                assert_eq!(s.settings, c.settings, "{what}");
                assert_eq!(s.warnings, c.warnings, "{what}");
                if s.instances.is_none() {
                    assert_eq!(s.geometry.triangle_count() as u64, c.triangles, "{what}");
                }
            }
            (a, b) => panic!("{what}: load {:?}, check {:?}", a.map(|s| s.warnings), b.map(|c| c.warnings)),
        }
    }

    /// Every bundled scene, and each of its OBJ files framed on its own (both up axes).
    #[test]
    fn a_check_finds_what_a_load_finds_on_the_bundled_scenes() {
        let mut checked = 0;
        for dir in std::fs::read_dir(scenes()).unwrap() {
            for f in std::fs::read_dir(dir.unwrap().path()).into_iter().flatten() {
                let p = f.unwrap().path();
                match p.extension().and_then(|e| e.to_str()) {
                    Some("toml") => check_matches_load(&p, UpAxis::Y),
                    Some("obj") => [UpAxis::Y, UpAxis::Z].into_iter().for_each(|up| check_matches_load(&p, up)),
                    _ => continue,
                }
                checked += 1;
            }
        }
        assert!(checked >= 10, "{checked} files");
    }

    /// Copies, emitters placed twice, and bad fields: the same warnings and errors.
    #[test]
    fn a_check_finds_what_a_load_finds_on_placed_copies_and_bad_fields() {
        let dir = std::env::temp_dir().join(format!("tilefarm-scene-check-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for f in ["cube.obj", "cube.mtl", "cbox.obj", "cbox.mtl"] {
            let from = if f.starts_with("cube") { "cube" } else { "cornell-box" };
            std::fs::copy(scenes().join(from).join(f), dir.join(f)).unwrap();
        }
        let camera = "[camera]\nposition = [0, 1, -6]\nlook_at = [0, 0, 0]\nfov = 40\nwidth = 32\nheight = 24\n";
        let cases = [
            "[[mesh]]\nobj = \"cube.obj\"\ninstance = [{ translate = [1, 0, 0] }, { rotate_y = 30 }]\n\
             [[mesh]]\nobj = \"cube.obj\"\nscale = 2\n",
            "[[mesh]]\nobj = \"cbox.obj\"\n[[mesh]]\nobj = \"cbox.obj\"\ntranslate = [0, 3, 0]\n",
            "[[mesh]]\nobj = \"cube.obj\"\ninstance = [{ scale = [1, 0, 1] }]\n",
            "[[mesh]]\nobj = \"missing.obj\"\n",
            "[render]\nspp = 0\n",
        ];
        for (i, body) in cases.iter().enumerate() {
            let p = dir.join(format!("s{i}.toml"));
            std::fs::write(&p, format!("{camera}{body}")).unwrap();
            check_matches_load(&p, UpAxis::Y);
        }
        let copies = check_scene_as(&dir.join("s0.toml"), "s", UpAxis::Y).unwrap();
        let one = crate::scene::load_scene(&dir.join("cube.obj")).unwrap().geometry.triangle_count() as u64;
        assert_eq!(copies.triangles, 3 * one, "two copies and one more table");
        let emitters = check_scene_as(&dir.join("s1.toml"), "s", UpAxis::Y).unwrap();
        assert!(emitters.warnings.iter().any(|w| w.contains("emits light")), "{:?}", emitters.warnings);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
