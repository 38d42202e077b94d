//! The files an OBJ depends on (its MTL libraries and their textures), found with the
//! loader's own parsing so that what a render farm ships is exactly what loading reads.

use std::path::{Path, PathBuf};

use super::ObjError;
use super::check::{BLOCK_BYTES, scan_blocks};
use super::mtl::{decode_utf8, parse_mtl_str, resolve_path};

/// The MTL files and textures (`map_Kd`, `map_Pr`, `norm`, ...) `obj_path` refers to, whether or not they exist
/// (a missing one is the loader's warning to give, not an error here). Errors are those
/// of a malformed OBJ or MTL.
pub fn obj_dependencies(obj_path: &Path) -> Result<Vec<PathBuf>, ObjError> {
    obj_dependencies_where(obj_path, &|_| true)
}

/// [`obj_dependencies`], reading only the MTL files `readable` allows (the others are
/// listed, not read).
pub fn obj_dependencies_where(obj_path: &Path, readable: &dyn Fn(&Path) -> bool) -> Result<Vec<PathBuf>, ObjError> {
    let display = obj_path.display().to_string();
    // Read in blocks, as a check reads it: only the `mtllib` statements are kept.
    let mut mtllibs = Vec::new();
    scan_blocks(obj_path, &display, BLOCK_BYTES, |mut c| {
        mtllibs.append(&mut c.mtllibs);
        c.error
    })?;
    let base = obj_path.parent().unwrap_or(Path::new(""));
    let mut out = Vec::new();
    for (_, arg) in &mtllibs {
        // The same rule as the loader: one name with spaces if that file exists, else several.
        let files: Vec<&str> =
            if resolve_path(base, arg).is_file() { vec![arg.as_str()] } else { arg.split_whitespace().collect() };
        for file in files {
            let path = resolve_path(base, file);
            out.push(path.clone());
            if !readable(&path) {
                continue;
            }
            let Ok(bytes) = crate::scene::files::read_bounded(&path, crate::scene::files::MAX_MTL_BYTES) else {
                continue;
            };
            let mtl_display = path.display().to_string();
            let mtl_text = decode_utf8(bytes, &mtl_display)?;
            let dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
            let mut warnings = Vec::new();
            for raw in parse_mtl_str(&mtl_text, &mtl_display, &dir, &mut warnings)? {
                if let Some(tex) = &raw.map_kd {
                    out.push(resolve_path(&raw.dir, tex));
                }
                for (_, arg) in &raw.maps {
                    out.push(resolve_path(&raw.dir, &arg.name));
                }
            }
        }
    }
    out.sort();
    out.dedup();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_mtl_and_textures_including_missing_ones() {
        let dir = std::env::temp_dir().join(format!("tilefarm-deps-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("tex")).unwrap();
        std::fs::write(dir.join("m.obj"), "mtllib a.mtl gone.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl x\nf 1 2 3\n")
            .unwrap();
        std::fs::write(dir.join("a.mtl"), "newmtl x\nKd 1 1 1\nmap_Kd -s 2 2 1 tex/wood.png\n").unwrap();
        let deps = obj_dependencies(&dir.join("m.obj")).unwrap();
        assert_eq!(deps, vec![dir.join("a.mtl"), dir.join("gone.mtl"), dir.join("tex/wood.png")]);
        std::fs::remove_dir_all(&dir).ok();
    }
}
