//! Every file a scene consists of, for shipping it to machines without a shared
//! filesystem.

use std::path::{Path, PathBuf};

use super::SceneError;
use super::file::SceneFile;
use super::load::{SceneKind, read_scene_text, scene_kind};
use super::obj::obj_dependencies;

/// The scene file itself first, then every file it refers to (OBJ, MTL, textures),
/// each once. Files that do not exist are listed too: loading will report them.
pub fn scene_files(scene_path: &Path) -> Result<Vec<PathBuf>, SceneError> {
    let mut files = vec![scene_path.to_path_buf()];
    let display = scene_path.display().to_string();
    let objs = if scene_kind(scene_path, &display)? == SceneKind::Obj {
        vec![scene_path.to_path_buf()]
    } else {
        let text = read_scene_text(scene_path, &display)?;
        let file: SceneFile =
            toml::from_str(&text).map_err(|e| SceneError::Syntax { path: display, message: e.to_string() })?;
        let base = scene_path.parent().unwrap_or(Path::new(""));
        let objs: Vec<PathBuf> = file.mesh.iter().map(|m| base.join(&m.obj)).collect();
        files.extend(objs.iter().cloned());
        objs
    };
    for obj in objs.iter().filter(|o| o.is_file()) {
        files.extend(obj_dependencies(obj)?);
    }
    let mut seen = std::collections::HashSet::new();
    files.retain(|f| seen.insert(f.clone()));
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bundled_cornell_box_consists_of_three_files() {
        let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box/scene.toml");
        let files = scene_files(&scene).unwrap();
        let names: Vec<String> = files.iter().map(|f| f.file_name().unwrap().to_string_lossy().into_owned()).collect();
        assert_eq!(names, ["scene.toml", "cbox.obj", "cbox.mtl"]);
    }
}
