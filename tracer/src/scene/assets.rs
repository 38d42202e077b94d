//! Every file a scene consists of, for shipping it to machines without a shared
//! filesystem.

use std::path::{Path, PathBuf};

use super::SceneError;
use super::file::SceneFile;
use super::load::{SceneKind, read_scene_text, scene_kind};
use super::obj::obj_dependencies_where;

/// The scene file itself first, then every file it refers to (OBJ, MTL, textures),
/// each once. Files that do not exist are listed too: loading will report them.
pub fn scene_files(scene_path: &Path) -> Result<Vec<PathBuf>, SceneError> {
    files_where(scene_path, &|_| true)
}

/// Checks that a scene refers only to files inside `root` (a farm job's folder, which
/// holds just the job's uploaded files): an absolute path, a `..` past the folder or a
/// link out of it is an error naming the reference, and no file outside `root` is read
/// on the way. A scene loaded after this check reads nothing else.
pub fn check_within(scene_path: &Path, root: &Path) -> Result<(), SceneError> {
    let canonical = |p: &Path| {
        p.canonicalize().map_err(|e| SceneError::Io { path: p.display().to_string(), message: e.to_string() })
    };
    // From canonical paths on, every reference resolves to a plain absolute path, so a
    // lexical check (after `.` and `..`) is exact; links are followed where files exist.
    let (root, scene_path) = (canonical(root)?, canonical(scene_path)?);
    let inside = |p: &Path| is_within(p, &root);
    for f in files_where(&scene_path, &inside)? {
        if !inside(&f) {
            return Err(SceneError::Io {
                path: scene_path.strip_prefix(&root).unwrap_or(&scene_path).display().to_string(),
                message: format!(
                    "refers to {}, which is not one of the job's files (a farm's scene may only refer to files \
                     beside it, by relative paths)",
                    f.display()
                ),
            });
        }
    }
    Ok(())
}

/// `path` (absolute, built from canonical parts) lies in `root` (canonical): lexically,
/// after `.` and `..`, and — if it exists — also after following links.
fn is_within(path: &Path, root: &Path) -> bool {
    use std::path::Component;
    let mut lexical = PathBuf::new();
    for c in path.components() {
        match c {
            Component::ParentDir => {
                lexical.pop();
            }
            Component::CurDir => {}
            c => lexical.push(c),
        }
    }
    if !lexical.starts_with(root) {
        return false;
    }
    match path.canonicalize() {
        Ok(real) => real.starts_with(root),
        Err(_) => true, // missing: loading reports it, and nothing is read
    }
}

fn files_where(scene_path: &Path, readable: &dyn Fn(&Path) -> bool) -> Result<Vec<PathBuf>, SceneError> {
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
        files.extend(file.materials.values().flat_map(|m| m.textures()).map(|t| base.join(&t.file)));
        files.extend(file.background.map.iter().map(|m| base.join(m)));
        objs
    };
    for obj in objs.iter().filter(|o| o.is_file() && readable(o)) {
        files.extend(obj_dependencies_where(obj, readable)?);
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
