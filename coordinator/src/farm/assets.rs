//! Content-addressed scene files. Every file of a job is stored once under its SHA-256,
//! and a job's folder is laid out from the store by the files' relative paths, so the
//! coordinator and every worker load byte-identical scenes without a shared filesystem.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Component, Path, PathBuf};

use anyhow::{Context, bail};
use sha2::{Digest, Sha256};

/// A file of a job: where it goes in the job folder, and what it contains (the wire's
/// one definition, shared with the worker).
pub use proto::wire::AssetRef;

pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

/// A relative path that stays inside the folder it is joined to: no root, no `..`, no
/// backslashes (which mean different things on different systems).
pub fn safe_relative_path(p: &str) -> anyhow::Result<PathBuf> {
    if p.is_empty() || p.contains('\\') {
        bail!("asset path '{p}' is empty or contains a backslash");
    }
    let path = Path::new(p);
    if !path.components().all(|c| matches!(c, Component::Normal(_))) {
        bail!("asset path '{p}' must be relative, without '..' or '.'");
    }
    Ok(path.to_path_buf())
}

/// The folder of the store where finished jobs' images are kept, as `<job id>.exr`.
pub const IMAGES: &str = "images";

/// The blob store: `<dir>/blobs/<sha256>`.
pub struct AssetStore {
    dir: PathBuf,
    sizes: HashMap<String, u64>,
    /// Uploads begun, for their temporary files' names.
    uploads: u64,
}

/// An upload on its way into the store: its bytes go to a temporary file as they arrive,
/// hashed on the way, so no upload is held in memory.
pub struct Upload {
    tmp: PathBuf,
    file: std::fs::File,
    hasher: Sha256,
    written: u64,
}

impl Upload {
    pub fn written(&self) -> u64 {
        self.written
    }

    pub fn write(&mut self, bytes: &[u8]) -> anyhow::Result<()> {
        self.file.write_all(bytes).with_context(|| format!("writing {}", self.tmp.display()))?;
        self.hasher.update(bytes);
        self.written += bytes.len() as u64;
        Ok(())
    }
}

impl Drop for Upload {
    /// An upload that did not finish leaves nothing behind.
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.tmp);
    }
}

impl AssetStore {
    pub fn open(dir: &Path) -> anyhow::Result<Self> {
        let blobs = dir.join("blobs");
        std::fs::create_dir_all(&blobs).with_context(|| format!("creating {}", blobs.display()))?;
        let mut sizes = HashMap::new();
        for e in std::fs::read_dir(&blobs)?.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.ends_with(".upload") {
                // An upload cut off by a crash.
                let _ = std::fs::remove_file(e.path());
                continue;
            }
            if name.len() == 64
                && let Ok(m) = e.metadata()
            {
                sizes.insert(name, m.len());
            }
        }
        Ok(Self { dir: dir.to_path_buf(), sizes, uploads: 0 })
    }

    /// Bytes of all stored blobs.
    pub fn stored_bytes(&self) -> u64 {
        self.sizes.values().sum()
    }

    /// Starts an upload (write its bytes, then [`AssetStore::finish_upload`]).
    pub fn begin_upload(&mut self) -> anyhow::Result<Upload> {
        self.uploads += 1;
        let tmp = self.dir.join("blobs").join(format!("{}-{}.upload", std::process::id(), self.uploads));
        let file = std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
        Ok(Upload { tmp, file, hasher: Sha256::new(), written: 0 })
    }

    /// Makes an upload a blob (durably: fsync, rename) and returns its digest and size.
    pub fn finish_upload(&mut self, mut up: Upload) -> anyhow::Result<(String, u64)> {
        let sha = hex::encode(std::mem::take(&mut up.hasher).finalize());
        let size = up.written;
        if !self.contains(&sha) {
            up.file.sync_all().with_context(|| format!("writing {}", up.tmp.display()))?;
            std::fs::rename(&up.tmp, self.blob_path(&sha)).with_context(|| format!("storing {}", up.tmp.display()))?;
            self.sizes.insert(sha.clone(), size);
        }
        Ok((sha, size))
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Where the finished image of `job` is kept, if `job` is a job id (never a path of
    /// the caller's choosing).
    pub fn stored_image(&self, job: &str) -> Option<PathBuf> {
        let n = job.strip_prefix("job-")?;
        let valid = !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit());
        valid.then(|| self.dir.join(IMAGES).join(format!("{job}.exr")))
    }

    /// The folder of finished jobs' images and their sidecars (`farm::stored`).
    pub fn images(&self) -> PathBuf {
        self.dir.join(IMAGES)
    }

    pub fn blob_path(&self, sha256: &str) -> PathBuf {
        self.dir.join("blobs").join(sha256)
    }

    pub fn contains(&self, sha256: &str) -> bool {
        self.sizes.contains_key(sha256)
    }

    /// The size of a stored blob, if it is stored.
    pub fn size_of(&self, sha256: &str) -> Option<u64> {
        self.sizes.get(sha256).copied()
    }

    /// Stores `bytes` (atomically: temp file, fsync, rename) and returns its digest.
    pub fn put(&mut self, bytes: &[u8]) -> anyhow::Result<(String, u64)> {
        let sha = sha256_hex(bytes);
        if !self.contains(&sha) {
            let path = self.blob_path(&sha);
            let tmp = path.with_extension(format!("tmp{}", std::process::id()));
            let mut f = std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
            f.write_all(bytes)?;
            f.sync_all()?;
            std::fs::rename(&tmp, &path)?;
            self.sizes.insert(sha.clone(), bytes.len() as u64);
        }
        Ok((sha, bytes.len() as u64))
    }

    /// Stores the file at `path` as [`AssetStore::put`] stores bytes, read in pieces
    /// (a scene's OBJ may be gigabytes) through an upload.
    pub fn put_file(&mut self, path: &Path) -> anyhow::Result<(String, u64)> {
        let mut file = std::fs::File::open(path).with_context(|| format!("reading {}", path.display()))?;
        let mut up = self.begin_upload()?;
        let mut buf = vec![0u8; 1 << 20];
        loop {
            let n = std::io::Read::read(&mut file, &mut buf).with_context(|| format!("reading {}", path.display()))?;
            if n == 0 {
                break;
            }
            up.write(&buf[..n])?;
        }
        self.finish_upload(up)
    }

    /// Lays out a job's files under `job_dir` by their relative paths and returns the
    /// scene file's path there.
    pub fn materialize(&self, job_dir: &Path, scene: &AssetRef, assets: &[AssetRef]) -> anyhow::Result<PathBuf> {
        // Start from an empty folder: a stale file of an earlier job with the same id
        // (a restarted coordinator) must never be loaded in place of this job's.
        if job_dir.exists() {
            std::fs::remove_dir_all(job_dir).with_context(|| format!("clearing {}", job_dir.display()))?;
        }
        for a in std::iter::once(scene).chain(assets) {
            let rel = safe_relative_path(&a.path)?;
            if !self.contains(&a.sha256) {
                bail!("asset {} ({}) was never uploaded", a.path, a.sha256);
            }
            let dest = job_dir.join(&rel);
            if let Some(parent) = dest.parent() {
                std::fs::create_dir_all(parent)?;
            }
            if std::fs::hard_link(self.blob_path(&a.sha256), &dest).is_err() {
                std::fs::copy(self.blob_path(&a.sha256), &dest)
                    .with_context(|| format!("placing {} in {}", a.path, job_dir.display()))?;
            }
        }
        Ok(job_dir.join(safe_relative_path(&scene.path)?))
    }
}

/// The files of a scene on this machine, relative to their deepest common folder:
/// `(scene, other files, files referred to but missing)`. What a farm receives of them:
/// their paths below that folder, with the folders above the scene's named `up1`,
/// `up2`, … (a `..` reference resolves the same, and the farm's job folder does not
/// mirror the submitter's folders).
pub struct LocalScene {
    pub root: PathBuf,
    pub scene: PathBuf,
    pub files: Vec<PathBuf>,
    pub missing: Vec<PathBuf>,
}

impl LocalScene {
    /// Collects the scene at `scene_path` and every file it refers to. A file reached
    /// through a symbolic link that leads outside the scene's folder is an error naming
    /// it: `submit` sends nothing but the scene's own files (a link to a private key
    /// would otherwise land in the farm's store, where every worker can fetch it).
    pub fn collect(scene_path: &Path) -> anyhow::Result<Self> {
        // Named as the user gave it: a folder or a PNG is "not a scene file".
        tracer::scene::load::scene_kind(scene_path, &scene_path.display().to_string())?;
        let given_dir = scene_path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let dir = std::fs::canonicalize(given_dir).with_context(|| format!("{}", given_dir.display()))?;
        let scene = std::fs::canonicalize(scene_path).with_context(|| format!("{}", scene_path.display()))?;
        let outside = |f: &Path, c: &Path| {
            anyhow::anyhow!(
                "{}: a symbolic link that leads outside the scene's folder ({}), to {}; submit sends only the \
                 scene's own files: copy it into the folder",
                f.display(),
                dir.display(),
                c.display()
            )
        };
        if scene.parent() != Some(dir.as_path()) {
            return Err(outside(scene_path, &scene));
        }
        let listed = tracer::scene::assets::scene_files(scene_path)?;
        let (mut files, mut missing) = (Vec::new(), Vec::new());
        for f in listed.into_iter().skip(1) {
            match std::fs::canonicalize(&f) {
                Ok(c) if c.is_file() => {
                    // Where the path leads without following links: a difference is a link.
                    let plain = lexical(&dir.join(f.strip_prefix(given_dir).unwrap_or(&f)));
                    if plain != c && !c.starts_with(&dir) {
                        return Err(outside(&f, &c));
                    }
                    // Under the name the scene uses (a link inside the folder is read
                    // through), so that the farm finds it by that name.
                    files.push(plain)
                }
                _ => missing.push(f),
            }
        }
        let mut root = dir;
        for f in &files {
            while !f.starts_with(&root) {
                root = root.parent().map(Path::to_path_buf).unwrap_or_default();
            }
        }
        Ok(Self { root, scene, files, missing })
    }

    /// The path of `file` as the farm receives it: relative to the root, with `/`
    /// separators, the folders above the scene's renamed `up1`, `up2`, ….
    pub fn relative(&self, file: &Path) -> String {
        let rel = file.strip_prefix(&self.root).unwrap_or(file);
        let chain: Vec<_> = self
            .scene
            .parent()
            .and_then(|d| d.strip_prefix(&self.root).ok())
            .map_or_else(Vec::new, |d| d.components().collect());
        let mut same = true;
        let parts = rel.components().enumerate().map(|(i, c)| {
            same &= chain.get(i) == Some(&c);
            if same { format!("up{}", chain.len() - i) } else { c.as_os_str().to_string_lossy().into_owned() }
        });
        parts.collect::<Vec<_>>().join("/")
    }
}

/// `path` with `.` and `..` resolved as text, links not followed.
fn lexical(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uploads_become_blobs_by_their_digest_and_unfinished_ones_leave_nothing() {
        let dir = std::env::temp_dir().join(format!("tilefarm-upload-{}", std::process::id()));
        let mut store = AssetStore::open(&dir).unwrap();
        let mut up = store.begin_upload().unwrap();
        up.write(b"hello ").unwrap();
        up.write(b"farm").unwrap();
        assert_eq!(up.written(), 10);
        let (sha, size) = store.finish_upload(up).unwrap();
        assert_eq!((sha.as_str(), size), (sha256_hex(b"hello farm").as_str(), 10));
        assert_eq!(std::fs::read(store.blob_path(&sha)).unwrap(), b"hello farm");
        assert_eq!(store.stored_bytes(), 10);
        let mut cut = store.begin_upload().unwrap();
        cut.write(b"half").unwrap();
        drop(cut);
        let names: Vec<String> = std::fs::read_dir(dir.join("blobs"))
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into())
            .collect();
        assert_eq!(names, [sha]);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn unsafe_paths_are_refused() {
        for bad in ["", "/etc/passwd", "../x.obj", "a/../../x", "a\\b.obj", "./a.obj"] {
            assert!(safe_relative_path(bad).is_err(), "{bad}");
        }
        assert_eq!(safe_relative_path("meshes/a.obj").unwrap(), PathBuf::from("meshes/a.obj"));
    }

    #[test]
    fn store_dedups_and_materializes_jobs() {
        let dir = std::env::temp_dir().join(format!("tilefarm-store-test-{}", std::process::id()));
        let mut store = AssetStore::open(&dir).unwrap();
        let (a, _) = store.put(b"scene").unwrap();
        let (a2, _) = store.put(b"scene").unwrap();
        assert_eq!(a, a2);
        let (b, size) = store.put(b"mesh data").unwrap();
        let scene = AssetRef { path: "s/scene.toml".into(), sha256: a, size: 5 };
        let mesh = AssetRef { path: "m/mesh.obj".into(), sha256: b, size };
        let p = store.materialize(&dir.join("job"), &scene, std::slice::from_ref(&mesh)).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"scene");
        assert_eq!(std::fs::read(dir.join("job/m/mesh.obj")).unwrap(), b"mesh data");
        let bogus = AssetRef { path: "x".into(), sha256: "0".repeat(64), size: 1 };
        assert!(store.materialize(&dir.join("job2"), &bogus, &[]).is_err());
        // Reopening finds what was stored.
        assert!(AssetStore::open(&dir).unwrap().contains(&mesh.sha256));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn bundled_scene_collects_relative_to_its_folder() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cup/scene.toml");
        let s = LocalScene::collect(&p).unwrap();
        assert!(s.missing.is_empty());
        assert_eq!(s.relative(&s.scene), "scene.toml");
        let mut rel: Vec<String> = s.files.iter().map(|f| s.relative(f)).collect();
        rel.sort();
        assert_eq!(rel, ["cup.mtl", "cup.obj", "table.obj"]);
    }

    /// A scene folder in a temporary folder, with a file outside it.
    fn scene_with(tag: &str, mesh_ref: &str) -> (PathBuf, PathBuf) {
        let top = std::env::temp_dir().join(format!("tilefarm-collect-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&top);
        let dir = top.join("alice/shots/a");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::create_dir_all(top.join("alice/assets")).unwrap();
        std::fs::write(top.join("alice/assets/m.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        let scene = dir.join("scene.toml");
        let text = format!("[camera]\nposition = [0, 0, -5]\nlook_at = [0, 0, 0]\n[[mesh]]\nobj = \"{mesh_ref}\"\n");
        std::fs::write(&scene, text).unwrap();
        (top, scene)
    }

    #[test]
    fn links_out_of_the_scene_folder_are_refused_and_paths_above_it_are_not_sent() {
        // A plain `..` reference: sent, with the folders above the scene renamed.
        let (top, scene) = scene_with("up", "../../assets/m.obj");
        let s = LocalScene::collect(&scene).unwrap();
        assert_eq!(s.relative(&s.scene), "up2/up1/scene.toml");
        assert_eq!(s.files.iter().map(|f| s.relative(f)).collect::<Vec<_>>(), ["assets/m.obj"]);
        std::fs::remove_dir_all(&top).ok();
        // A link beside the scene that leads out of its folder: an error naming it.
        let (top, scene) = scene_with("link", "m.obj");
        std::os::unix::fs::symlink(top.join("alice/assets/m.obj"), scene.with_file_name("m.obj")).unwrap();
        let e = LocalScene::collect(&scene).err().expect("refused").to_string();
        assert!(e.contains("m.obj: a symbolic link that leads outside the scene's folder"), "{e}");
        // A link that stays inside is followed, and sent under the name the scene uses.
        std::fs::remove_file(scene.with_file_name("m.obj")).unwrap();
        std::fs::copy(top.join("alice/assets/m.obj"), scene.with_file_name("real.obj")).unwrap();
        std::os::unix::fs::symlink("real.obj", scene.with_file_name("m.obj")).unwrap();
        let s = LocalScene::collect(&scene).unwrap();
        assert_eq!(s.files.iter().map(|f| s.relative(f)).collect::<Vec<_>>(), ["m.obj"]);
        std::fs::remove_dir_all(&top).ok();
    }

    #[test]
    fn stored_images_are_named_by_job_ids_only() {
        let dir = std::env::temp_dir().join(format!("tilefarm-images-{}", std::process::id()));
        let store = AssetStore::open(&dir).unwrap();
        assert_eq!(store.stored_image("job-12"), Some(dir.join("images/job-12.exr")));
        for bad in ["../job-1", "job-", "job-1/../../etc", "job-1.exr", "x"] {
            assert_eq!(store.stored_image(bad), None, "{bad}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
