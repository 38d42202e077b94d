//! A folder of prepared scenes kept between jobs: the second job of a scene (or a
//! restarted process) reads the built mesh and BVH back instead of parsing and
//! building again.
//!
//! An entry's name is the caller's key (over everything the loaded scene depends on:
//! the files' digests and the overrides, see `proto::domain::JobSpec::scene_key`) and
//! this process's executable (another build of the tracer may build differently). The
//! file itself is checked by [`super::read`] (length and SHA-256): a damaged entry is
//! removed and the scene built again. The folder is this user's alone (mode 0700, owned
//! by them), since whoever can write an entry chooses what is rendered; the least
//! recently used entries go once the folder holds more than its limit.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::{Duration, SystemTime};

use sha2::{Digest, Sha256};

use super::PreparedError;
use crate::scene::Scene;

/// The default limit on a folder of prepared scenes.
pub const DEFAULT_MAX_BYTES: u64 = 4 << 30;

/// A leftover temporary file older than this belongs to a process that died mid-write.
const STALE_PART: Duration = Duration::from_secs(3600);

#[derive(Debug)]
pub struct PreparedScenes {
    dir: PathBuf,
    build: [u8; 32],
    max_bytes: u64,
}

/// The folder for prepared scenes of this user's local renders: `$XDG_CACHE_HOME/tilefarm/prepared`, else `~/.cache/tilefarm/prepared`.
pub fn user_dir() -> Option<PathBuf> {
    let base = match std::env::var_os("XDG_CACHE_HOME").filter(|v| !v.is_empty()) {
        Some(x) => PathBuf::from(x),
        None => PathBuf::from(std::env::var_os("HOME").filter(|v| !v.is_empty())?).join(".cache"),
    };
    Some(base.join("tilefarm").join("prepared"))
}

/// SHA-256 of this process's executable, read once.
fn build_id() -> Result<[u8; 32], String> {
    static ID: OnceLock<Result<[u8; 32], String>> = OnceLock::new();
    let id = ID.get_or_init(|| {
        let exe = std::env::current_exe().map_err(|e| e.to_string())?;
        let mut file = fs::File::open(&exe).map_err(|e| format!("{}: {e}", exe.display()))?;
        let mut hash = Sha256::new();
        std::io::copy(&mut file, &mut hash).map_err(|e| format!("{}: {e}", exe.display()))?;
        Ok(hash.finalize().into())
    });
    id.clone().map_err(|e| format!("cannot identify this build: {e}"))
}

impl PreparedScenes {
    /// Opens `dir` (created private to this user), holding at most `max_bytes`. The
    /// error says why prepared scenes cannot be kept there.
    pub fn open(dir: &Path, max_bytes: u64) -> Result<Self, String> {
        create_private(dir)?;
        let scenes = Self { dir: dir.to_path_buf(), build: build_id()?, max_bytes };
        scenes.remove_stale_parts();
        Ok(scenes)
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Where the prepared scene of `key` is kept.
    fn entry(&self, key: &[u8; 32]) -> PathBuf {
        let mut h = Sha256::new();
        h.update(b"tilefarm prepared scene\n");
        h.update(self.build);
        h.update(key);
        self.dir.join(format!("{:x}.scene", h.finalize()))
    }

    /// The prepared scene of `key`, if one is kept and whole; a damaged entry is removed
    /// (and said so, naming `what`), so that the caller builds it again.
    pub fn get(&self, key: &[u8; 32], what: &str) -> Option<Scene> {
        let path = self.entry(key);
        match super::read(&path, self.max_bytes) {
            Ok(scene) => {
                // Most recently used: the last to go.
                let _ = fs::File::options().append(true).open(&path).and_then(|f| f.set_modified(SystemTime::now()));
                Some(scene)
            }
            Err(PreparedError::Io { .. }) if !path.exists() => None,
            Err(e) => {
                tracing::warn!("{what}: {e}; loading the scene again");
                let _ = fs::remove_file(&path);
                None
            }
        }
    }

    /// Waits until no other process is building `key`'s entry, then holds that right
    /// until the value returned is dropped: processes sharing the folder (`render`'s
    /// local workers) build a scene once, and the others read what it kept. The system
    /// lets go of the lock if the holder dies. `None` when no lock can be taken there
    /// (the caller builds anyway).
    pub fn building(&self, key: &[u8; 32]) -> Option<Building> {
        let path = self.entry(key).with_extension("lock");
        let file = fs::OpenOptions::new().create(true).truncate(false).write(true).open(path).ok()?;
        file.lock().ok()?;
        Some(Building { _file: file })
    }

    /// Keeps `scene` under `key` for the next load of the same scene, then trims the
    /// folder to its limit.
    pub fn put(&self, key: &[u8; 32], scene: &Scene, what: &str) {
        let path = self.entry(key);
        match super::write(scene, &path) {
            Ok(bytes) => tracing::debug!("{what}: prepared scene kept ({bytes} bytes)"),
            Err(e) => tracing::warn!("{what}: the prepared scene was not kept: {e}"),
        }
        self.trim();
    }

    /// Removes the least recently used entries until the folder is within its limit.
    fn trim(&self) {
        let Ok(dir) = fs::read_dir(&self.dir) else { return };
        let mut entries: Vec<(SystemTime, u64, PathBuf)> = dir
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().ends_with(".scene"))
            .filter_map(|e| {
                let m = e.metadata().ok()?;
                Some((m.modified().ok()?, m.len(), e.path()))
            })
            .collect();
        entries.sort();
        let mut total: u64 = entries.iter().map(|e| e.1).sum();
        for (_, len, path) in entries {
            if total <= self.max_bytes {
                break;
            }
            if fs::remove_file(&path).is_ok() {
                total -= len;
            }
        }
    }

    fn remove_stale_parts(&self) {
        let Ok(dir) = fs::read_dir(&self.dir) else { return };
        for e in dir.flatten() {
            let stale =
                e.metadata().and_then(|m| m.modified()).is_ok_and(|t| t.elapsed().unwrap_or_default() > STALE_PART);
            let name = e.file_name().to_string_lossy().into_owned();
            if (name.ends_with(".part") || name.ends_with(".lock")) && stale {
                let _ = fs::remove_file(e.path());
            }
        }
    }
}

/// The right to build one entry ([`PreparedScenes::building`]), held until dropped.
#[derive(Debug)]
pub struct Building {
    _file: fs::File,
}

/// Creates `dir` readable and writable by this user alone, or checks that an existing
/// one is: another user who could write there could choose what this worker renders.
fn create_private(dir: &Path) -> Result<(), String> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::{DirBuilderExt, MetadataExt, PermissionsExt};
        if let Some(parent) = dir.parent() {
            fs::create_dir_all(parent).map_err(|e| format!("cannot create {}: {e}", parent.display()))?;
        }
        match fs::DirBuilder::new().mode(0o700).create(dir) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(format!("cannot create {}: {e}", dir.display())),
        }
        let m = fs::symlink_metadata(dir).map_err(|e| format!("cannot read {}: {e}", dir.display()))?;
        // SAFETY: geteuid has no preconditions and cannot fail.
        let me = unsafe { libc::geteuid() };
        if !m.is_dir() || m.uid() != me || m.permissions().mode() & 0o022 != 0 {
            return Err(format!(
                "{} is not a folder private to this user (owner and mode); prepared scenes are not kept",
                dir.display()
            ));
        }
    }
    #[cfg(not(unix))]
    fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("tilefarm-prepared-{name}-{}", std::process::id()))
    }

    /// One builder per key at a time; other keys do not wait.
    #[test]
    fn one_process_at_a_time_builds_an_entry() {
        let dir = temp("building");
        let p = std::sync::Arc::new(PreparedScenes::open(&dir, 1 << 30).unwrap());
        let first = p.building(&[7; 32]).expect("a lock in a private folder");
        assert!(p.building(&[8; 32]).is_some(), "another key is free");
        let (q, (tx, rx)) = (std::sync::Arc::clone(&p), std::sync::mpsc::channel());
        let waiter = std::thread::spawn(move || {
            let held = q.building(&[7; 32]);
            tx.send(held.is_some()).unwrap();
        });
        assert!(rx.recv_timeout(Duration::from_millis(300)).is_err(), "the second builder waits");
        drop(first);
        assert_eq!(rx.recv_timeout(Duration::from_secs(10)), Ok(true), "and goes on once the first is done");
        waiter.join().unwrap();
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn entries_follow_the_key() {
        let dir = temp("keys");
        let p = PreparedScenes::open(&dir, 1 << 30).unwrap();
        assert_ne!(p.entry(&[1; 32]), p.entry(&[2; 32]));
        assert_eq!(p.entry(&[1; 32]), p.entry(&[1; 32]));
        fs::remove_dir_all(&dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn a_folder_others_may_write_is_refused() {
        use std::os::unix::fs::PermissionsExt;
        let dir = temp("shared");
        fs::create_dir_all(&dir).unwrap();
        fs::set_permissions(&dir, fs::Permissions::from_mode(0o777)).unwrap();
        let e = PreparedScenes::open(&dir, 1 << 30).unwrap_err();
        assert!(e.contains("not a folder private to this user"), "{e}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_least_recently_used_go_first() {
        let dir = temp("trim");
        let p = PreparedScenes { max_bytes: 2500, ..PreparedScenes::open(&dir, 0).unwrap() };
        let now = SystemTime::now();
        for (i, age) in [(0, 30), (1, 10), (2, 20)] {
            let path = dir.join(format!("{i}.scene"));
            fs::write(&path, [0u8; 1000]).unwrap();
            let f = fs::File::options().append(true).open(&path).unwrap();
            f.set_modified(now - Duration::from_secs(age)).unwrap();
        }
        p.trim();
        let mut left: Vec<String> =
            fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        left.sort();
        assert_eq!(left, ["1.scene", "2.scene"]);
        fs::remove_dir_all(&dir).unwrap();
    }
}
