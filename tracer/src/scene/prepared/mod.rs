//! A prepared scene on disk: everything [`load_scene`](super::load_scene) builds (the
//! merged mesh in the kd-tree's leaf order, the tree, materials, textures, lights), so
//! that loading the same scene again reads it back instead of parsing and building.
//!
//! The file is a header — a magic tag, the payload's length and its SHA-256 — followed
//! by the scene in serde's postcard form. Reading checks all three before decoding, so a
//! truncated or corrupted file is an error (the caller rebuilds), never a wrong scene.
//! [`PreparedScenes`] keeps such files in a folder, by key.

mod folder;

pub use folder::{Building, DEFAULT_MAX_BYTES, PreparedScenes, user_dir};

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::Path;

use sha2::{Digest, Sha256};

use super::Scene;

/// The format's tag; the last byte is its version.
const MAGIC: &[u8; 8] = b"TFPREP\0\x07";
const HEADER: usize = MAGIC.len() + 8 + 32;

#[derive(Debug, thiserror::Error)]
pub enum PreparedError {
    #[error("{path}: {message}")]
    Io { path: String, message: String },
    /// The file is not a whole prepared scene of this format: rebuild it.
    #[error("{path}: not a valid prepared scene ({message})")]
    Corrupt { path: String, message: String },
}

/// Writes `scene` to `path`, streamed (no second copy of the scene in memory), through a
/// temporary file beside it that is renamed into place: a reader sees the old file, the
/// new one, or none, never half of one. Returns the file's size.
pub fn write(scene: &Scene, path: &Path) -> Result<u64, PreparedError> {
    let io = |e: std::io::Error| PreparedError::Io { path: path.display().to_string(), message: e.to_string() };
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let temp = path.with_file_name(format!(".{name}.{}.part", std::process::id()));
    let result = (|| {
        let mut file = BufWriter::with_capacity(1 << 20, File::create(&temp).map_err(io)?);
        file.write_all(&[0; HEADER]).map_err(io)?;
        let mut body = Hashing { inner: &mut file, hash: Sha256::new(), len: 0 };
        postcard::to_io(scene, &mut body)
            .map_err(|e| PreparedError::Io { path: path.display().to_string(), message: e.to_string() })?;
        let (len, digest) = (body.len, body.hash.finalize());
        let mut file = file.into_inner().map_err(|e| io(e.into_error()))?;
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        file.write_all(MAGIC).map_err(io)?;
        file.write_all(&len.to_le_bytes()).map_err(io)?;
        file.write_all(&digest).map_err(io)?;
        file.sync_all().map_err(io)?;
        std::fs::rename(&temp, path).map_err(io)?;
        Ok(HEADER as u64 + len)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    result
}

/// Reads a prepared scene, refusing a file larger than `max_bytes` before reading it.
pub fn read(path: &Path, max_bytes: u64) -> Result<Scene, PreparedError> {
    let shown = || path.display().to_string();
    let io = |e: std::io::Error| PreparedError::Io { path: shown(), message: e.to_string() };
    let corrupt = |message: String| PreparedError::Corrupt { path: shown(), message };
    let mut file = File::open(path).map_err(io)?;
    let size = file.metadata().map_err(io)?.len();
    if size > max_bytes {
        return Err(corrupt(format!("{size} bytes, more than the {max_bytes} allowed")));
    }
    let mut bytes = Vec::with_capacity(size as usize);
    file.read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() < HEADER || &bytes[..MAGIC.len()] != MAGIC {
        return Err(corrupt("no prepared-scene header of this version".into()));
    }
    let (head, body) = bytes.split_at(HEADER);
    let len = u64::from_le_bytes(head[8..16].try_into().expect("8 bytes"));
    if len != body.len() as u64 {
        return Err(corrupt(format!("{} bytes of scene where the header says {len}", body.len())));
    }
    if Sha256::digest(body).as_slice() != &head[16..HEADER] {
        return Err(corrupt("its content does not match its digest".into()));
    }
    let scene: Scene = postcard::from_bytes(body).map_err(|e| corrupt(e.to_string()))?;
    scene.after_read();
    Ok(scene)
}

/// A writer that hashes and counts what passes through it.
struct Hashing<W> {
    inner: W,
    hash: Sha256,
    len: u64,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash.update(&buf[..n]);
        self.len += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrator::Integrator;

    fn scene_path(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(name)
    }

    fn pixels(scene: &Scene) -> Vec<[u32; 3]> {
        let samples = crate::film::SampleRange::new(0, 4);
        let (image, _) = crate::render::render_image(scene, Integrator::Path, samples, 8, &|_| {});
        image.pixels.iter().map(|p| p.to_array().map(f32::to_bits)).collect()
    }

    /// A scene read back renders the same bits as the scene that was written, through
    /// the kd-tree (a large mesh) and through the packed brute force (a small one).
    #[test]
    fn a_prepared_scene_renders_the_same_bits() {
        let dir = std::env::temp_dir().join(format!("tilefarm-prepared-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let big = super::super::generate::displaced_sphere(30_000, 3);
        let grey = crate::material::MaterialDesc::default_grey("grey");
        let model = super::super::obj::ObjModel { mesh: big, materials: vec![grey], ..Default::default() };
        let mut tree_scene = super::super::scene_from_bare_obj(model, super::super::UpAxis::Y);
        tree_scene.camera =
            crate::camera::Camera::look_at(tree_scene.camera.position, tree_scene.center, glam::Vec3::Y, 40.0, 24, 16)
                .unwrap();
        assert!(tree_scene.packed.is_none(), "the first scene is traced through its tree");
        let mut cornell = crate::scene::load_scene(&scene_path("cornell-box/scene.toml")).unwrap();
        cornell.camera = crate::camera::Camera::look_at(
            cornell.camera.position,
            cornell.camera.position + cornell.camera.forward,
            cornell.camera.up,
            39.3,
            24,
            16,
        )
        .unwrap();
        assert!(cornell.packed.is_some(), "the second is traced by packed brute force");
        for (name, scene) in [("tree", tree_scene), ("cornell", cornell)] {
            let path = dir.join(name);
            let size = write(&scene, &path).unwrap();
            assert_eq!(size, std::fs::metadata(&path).unwrap().len());
            let back = read(&path, u64::MAX).unwrap();
            assert_eq!(pixels(&back), pixels(&scene), "{name}");
            assert_eq!(back.warnings, scene.warnings);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Every kind of damage is detected: a flipped byte anywhere, a cut, another
    /// format's file, a file over the limit.
    #[test]
    fn damage_is_detected() {
        let dir = std::env::temp_dir().join(format!("tilefarm-prepared-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let scene = crate::scene::load_scene(&scene_path("cornell-box/scene.toml")).unwrap();
        let path = dir.join("cornell");
        let size = write(&scene, &path).unwrap();
        let good = std::fs::read(&path).unwrap();
        let is_corrupt = |bytes: &[u8]| {
            std::fs::write(&path, bytes).unwrap();
            matches!(read(&path, u64::MAX), Err(PreparedError::Corrupt { .. }))
        };
        for at in [0, 9, 20, good.len() / 2, good.len() - 1] {
            let mut bad = good.clone();
            bad[at] ^= 0x10;
            assert!(is_corrupt(&bad), "a flipped byte at {at}");
        }
        assert!(is_corrupt(&good[..good.len() - 7]), "a cut file");
        assert!(is_corrupt(b"[camera]\nfov = 40\n"), "a scene file, not a prepared scene");
        std::fs::write(&path, &good).unwrap();
        assert!(matches!(read(&path, size - 1), Err(PreparedError::Corrupt { .. })), "over the limit");
        assert!(read(&path, size).is_ok());
        let missing = read(&dir.join("missing"), u64::MAX);
        assert!(matches!(missing, Err(PreparedError::Io { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
