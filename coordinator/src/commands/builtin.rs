//! The built-in Cornell box, so `coordinator render` works with no scene at all. The
//! files are the bundled `scenes/cornell-box`, compiled in.

use std::path::{Path, PathBuf};

use anyhow::Context;

const FILES: [(&str, &str); 3] = [
    ("scene.toml", include_str!("../../../scenes/cornell-box/scene.toml")),
    ("cbox.obj", include_str!("../../../scenes/cornell-box/cbox.obj")),
    ("cbox.mtl", include_str!("../../../scenes/cornell-box/cbox.mtl")),
];

/// A temporary copy of the built-in scene on disk (the loader reads files, as it does
/// for every scene); removed when dropped.
pub struct BuiltinScene {
    dir: PathBuf,
}

impl BuiltinScene {
    pub fn write() -> anyhow::Result<Self> {
        let dir = std::env::temp_dir().join(format!("tilefarm-cornell-box-{}", std::process::id()));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        for (name, text) in FILES {
            let path = dir.join(name);
            std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
        }
        Ok(Self { dir })
    }

    pub fn path(&self) -> PathBuf {
        self.dir.join("scene.toml")
    }
}

impl Drop for BuiltinScene {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Loads `path`, or the built-in Cornell box when `None`.
pub fn load(path: Option<&Path>) -> anyhow::Result<tracer::scene::Scene> {
    match path {
        Some(p) => Ok(tracer::scene::load_scene(p)?),
        None => {
            let b = BuiltinScene::write()?;
            Ok(tracer::scene::load_scene(&b.path())?)
        }
    }
}
