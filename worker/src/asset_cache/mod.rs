//! Scene files by content digest, job folders, and the loaded scenes.
//!
//! ```text
//! <cache>/blobs/<sha256>           verified content, written once (temp file, fsync, rename)
//! <cache>/tmp/                     downloads in progress
//! <cache>/jobs/<job_id>/<path>     a job's files under their own names (hard links to blobs)
//! ```
//!
//! Several worker processes may share one cache folder (local workers do): every file
//! appears by an atomic rename, so they never see each other's partial files.

use std::collections::{HashMap, VecDeque};
use std::fs::{self, File};
use std::io::Write;
use std::path::{Component, Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow, bail, ensure};
use sha2::{Digest, Sha256};
use tracer::integrator::Integrator;
use tracer::scene::Scene;
use tracer::scene::prepared::PreparedScenes;

use crate::rpc::{self, Client, RpcFailure};
use proto::wire::{AssetRef, JobSpec};

/// The default cache folder: `tilefarm-worker-cache` in the system's temp folder.
pub fn default_cache_dir() -> PathBuf {
    std::env::temp_dir().join("tilefarm-worker-cache")
}

/// A unique suffix for temp files, across threads and processes.
fn temp_suffix() -> String {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    format!("{}.{}", std::process::id(), COUNTER.fetch_add(1, Ordering::Relaxed))
}

/// Checks a digest from the wire: 64 lowercase hex digits (it becomes a file name).
pub fn check_digest(sha256: &str) -> anyhow::Result<()> {
    ensure!(
        sha256.len() == 64 && sha256.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f')),
        "'{sha256}' is not a SHA-256 digest (64 lowercase hex digits)"
    );
    Ok(())
}

/// Checks a job id from the wire: it becomes one folder name.
pub fn check_job_id(job_id: &str) -> anyhow::Result<()> {
    ensure!(
        !job_id.is_empty()
            && job_id.len() <= 128
            && !job_id.starts_with('.')
            && job_id.bytes().all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.')),
        "job id '{job_id}' is not a safe folder name (1 to 128 of A-Z a-z 0-9 - _ ., not starting with '.')"
    );
    Ok(())
}

/// Turns an asset path from the wire into a relative path that stays inside the job
/// folder: no absolute paths, no `..`, no backslashes, no drive prefixes. `.` components
/// are dropped.
pub fn sanitize_asset_path(path: &str) -> anyhow::Result<PathBuf> {
    let bad = |why: &str| anyhow!("asset path '{path}' is refused: {why}");
    if path.is_empty() {
        return Err(bad("it is empty"));
    }
    if path.contains('\\') {
        return Err(bad("it contains a backslash (use '/')"));
    }
    if path.contains('\0') {
        return Err(bad("it contains a NUL character"));
    }
    if path.starts_with('/') || Path::new(path).is_absolute() {
        return Err(bad("it is absolute"));
    }
    let mut out = PathBuf::new();
    for c in Path::new(path).components() {
        match c {
            Component::Normal(part) => {
                // "C:" would be a drive prefix on Windows.
                if part.to_str().is_some_and(|s| s.contains(':')) {
                    return Err(bad("it contains a ':'"));
                }
                out.push(part);
            }
            Component::CurDir => {}
            Component::ParentDir => return Err(bad("it has a '..' component")),
            Component::RootDir | Component::Prefix(_) => return Err(bad("it is absolute")),
        }
    }
    if out.as_os_str().is_empty() {
        return Err(bad("it names no file"));
    }
    Ok(out)
}

/// The on-disk cache.
#[derive(Debug)]
pub struct AssetCache {
    root: PathBuf,
    /// A job's scene may refer only to the job's own files (see
    /// [`AssetCache::trust_scene_paths`]).
    confine: bool,
    /// Where scenes, once loaded, are kept prepared for the next job of the same scene.
    prepared: Option<Arc<PreparedScenes>>,
}

impl AssetCache {
    pub fn open(root: &Path) -> anyhow::Result<Self> {
        for sub in ["blobs", "jobs", "tmp"] {
            let dir = root.join(sub);
            fs::create_dir_all(&dir).with_context(|| format!("cannot create cache folder {}", dir.display()))?;
        }
        Ok(Self { root: root.to_path_buf(), confine: true, prepared: None })
    }

    /// Keeps loaded scenes prepared in `scenes`, and loads them from there.
    pub fn with_prepared(mut self, scenes: PreparedScenes) -> Self {
        self.prepared = Some(Arc::new(scenes));
        self
    }

    /// Lets scenes refer to files outside their job (absolute paths, `..` past the
    /// job's folder): for `render`'s own local workers, which read the user's scene where
    /// it lies, never for a farm's.
    pub fn trust_scene_paths(mut self) -> Self {
        self.confine = false;
        self
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn blob_path(&self, sha256: &str) -> PathBuf {
        self.root.join("blobs").join(sha256)
    }

    pub fn job_dir(&self, job_id: &str) -> anyhow::Result<PathBuf> {
        check_job_id(job_id)?;
        Ok(self.root.join("jobs").join(job_id))
    }

    /// Is this asset's content in the cache? (Blobs only appear after verification, so
    /// the size is checked as a guard against outside tampering, not re-hashed.)
    pub fn has_blob(&self, asset: &AssetRef) -> bool {
        check_digest(&asset.sha256).is_ok()
            && fs::metadata(self.blob_path(&asset.sha256)).is_ok_and(|m| m.is_file() && m.len() == asset.size)
    }

    /// Starts writing `asset`'s content; [`BlobWriter::finish`] verifies it.
    pub fn blob_writer(&self, asset: &AssetRef) -> anyhow::Result<BlobWriter> {
        check_digest(&asset.sha256).with_context(|| format!("asset '{}'", asset.path))?;
        let temp = self.root.join("tmp").join(format!("{}.{}.part", asset.sha256, temp_suffix()));
        let file = File::create(&temp).with_context(|| format!("cannot create {}", temp.display()))?;
        Ok(BlobWriter {
            file: Some(file),
            temp,
            dest: self.blob_path(&asset.sha256),
            asset: asset.clone(),
            hasher: Sha256::new(),
            written: 0,
        })
    }

    /// Lays the job's files out under `<cache>/jobs/<job_id>/` (hard links to the blobs,
    /// or copies) and returns the scene file's path there. All blobs must be present.
    pub fn lay_out_job(&self, job: &JobSpec) -> anyhow::Result<PathBuf> {
        let dir = self.job_dir(&job.job_id)?;
        let mut seen: HashMap<PathBuf, &str> = HashMap::new();
        let mut scene_path = None;
        for (i, asset) in std::iter::once(&job.scene).chain(&job.assets).enumerate() {
            let rel = sanitize_asset_path(&asset.path)?;
            check_digest(&asset.sha256).with_context(|| format!("asset '{}'", asset.path))?;
            if i == 0 {
                scene_path = Some(dir.join(&rel));
            }
            match seen.get(&rel) {
                Some(&sha) if sha == asset.sha256 => continue,
                Some(_) => bail!("asset path '{}' appears twice with different contents", asset.path),
                None => {
                    seen.insert(rel.clone(), &asset.sha256);
                }
            }
            let dest = dir.join(&rel);
            if fs::metadata(&dest).is_ok_and(|m| m.is_file() && m.len() == asset.size) && same_file(&dest, asset, self)
            {
                continue;
            }
            let parent = dest.parent().unwrap_or(&dir);
            fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
            let blob = self.blob_path(&asset.sha256);
            let name = rel.file_name().and_then(|n| n.to_str()).unwrap_or("asset");
            let temp = parent.join(format!(".{name}.{}.tmp", temp_suffix()));
            if fs::hard_link(&blob, &temp).is_err() {
                fs::copy(&blob, &temp)
                    .with_context(|| format!("cannot copy {} to {}", blob.display(), temp.display()))?;
            }
            if let Err(e) = fs::rename(&temp, &dest) {
                let _ = fs::remove_file(&temp);
                return Err(e).with_context(|| format!("cannot create {}", dest.display()));
            }
        }
        scene_path.ok_or_else(|| anyhow!("job has no scene file"))
    }
}

/// Is `dest` the cached blob itself (a hard link to it)? Copies are re-made, cheaply.
fn same_file(dest: &Path, asset: &AssetRef, cache: &AssetCache) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (fs::metadata(dest), fs::metadata(cache.blob_path(&asset.sha256))) {
            (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = (dest, asset, cache);
        false
    }
}

/// A download in progress: hashes as it writes, and publishes the blob only when the
/// size and digest match. Dropped unfinished, it removes its temp file.
pub struct BlobWriter {
    file: Option<File>,
    temp: PathBuf,
    dest: PathBuf,
    asset: AssetRef,
    hasher: Sha256,
    written: u64,
}

impl BlobWriter {
    pub fn write(&mut self, chunk: &[u8]) -> anyhow::Result<()> {
        let len = chunk.len() as u64;
        ensure!(
            self.written + len <= self.asset.size,
            "asset '{}' ({}): the coordinator sent more than the expected {} bytes",
            self.asset.path,
            self.asset.sha256,
            self.asset.size
        );
        let file = self.file.as_mut().ok_or_else(|| anyhow!("blob writer already finished"))?;
        file.write_all(chunk).with_context(|| format!("cannot write {}", self.temp.display()))?;
        self.hasher.update(chunk);
        self.written += len;
        Ok(())
    }

    /// Verifies size and digest, syncs, and renames the blob into place.
    pub fn finish(mut self) -> anyhow::Result<PathBuf> {
        let a = self.asset.clone();
        ensure!(
            self.written == a.size,
            "asset '{}' ({}): received {} bytes, expected {}",
            a.path,
            a.sha256,
            self.written,
            a.size
        );
        let digest = hex::encode(std::mem::take(&mut self.hasher).finalize());
        ensure!(digest == a.sha256, "asset '{}': content digest is {digest}, expected {} (refused)", a.path, a.sha256);
        let file = self.file.take().ok_or_else(|| anyhow!("blob writer already finished"))?;
        file.sync_all().with_context(|| format!("cannot sync {}", self.temp.display()))?;
        drop(file);
        fs::rename(&self.temp, &self.dest).with_context(|| format!("cannot create {}", self.dest.display()))?;
        if let Some(dir) = self.dest.parent().and_then(|d| File::open(d).ok()) {
            let _ = dir.sync_all();
        }
        Ok(self.dest.clone())
    }
}

impl Drop for BlobWriter {
    fn drop(&mut self) {
        // After a successful finish the temp file has been renamed away; otherwise this
        // removes a partial or refused download.
        let _ = fs::remove_file(&self.temp);
    }
}

/// Downloads one asset into the cache, verifying it.
pub async fn fetch_blob(client: &mut Client, cache: &AssetCache, asset: &AssetRef) -> Result<(), FetchError> {
    const CHUNK_WAIT: Duration = Duration::from_secs(30);
    let mut writer = cache.blob_writer(asset).map_err(FetchError::Fatal)?;
    let request = proto::AssetRequest { sha256: asset.sha256.clone() };
    let mut stream = rpc::call(CHUNK_WAIT, client.fetch_asset(request)).await.map_err(FetchError::Rpc)?;
    loop {
        let next = tokio::time::timeout(CHUNK_WAIT, stream.message()).await;
        match next {
            Ok(Ok(Some(chunk))) => writer.write(&chunk.data).map_err(FetchError::Fatal)?,
            Ok(Ok(None)) => break,
            Ok(Err(status)) => return Err(FetchError::Rpc(rpc::classify(status))),
            Err(_) => return Err(FetchError::Rpc(RpcFailure::Transport(format!("no data within {CHUNK_WAIT:?}")))),
        }
    }
    tokio::task::spawn_blocking(move || writer.finish())
        .await
        .map_err(|e| FetchError::Fatal(anyhow!("blob writer task failed: {e}")))?
        .map_err(FetchError::Fatal)?;
    Ok(())
}

#[derive(Debug)]
pub enum FetchError {
    Rpc(RpcFailure),
    Fatal(anyhow::Error),
}

/// A job's scene, loaded and with the job's overrides applied.
pub struct LoadedJob {
    /// The spec it was loaded from. Lookups compare the whole spec, not only the job id:
    /// a restarted coordinator may reuse an id for a different scene.
    pub spec: JobSpec,
    /// Shared: an in-process executor uses the coordinator's own copy.
    pub scene: Arc<Scene>,
    pub integrator: Integrator,
    /// Read back from the prepared scenes rather than loaded from its files.
    pub prepared: bool,
}

/// Makes a job's scene available: fetches missing blobs, lays out the job folder, loads
/// the scene (in a blocking thread) and applies the overrides. The error names the job
/// and the file concerned.
pub async fn prepare_job(
    mut client: Client,
    cache: Arc<AssetCache>,
    job: Arc<JobSpec>,
    max_backoff: Duration,
) -> anyhow::Result<LoadedJob> {
    let start = Instant::now();
    check_job_id(&job.job_id)?;
    for asset in std::iter::once(&job.scene).chain(&job.assets) {
        sanitize_asset_path(&asset.path)?;
        check_digest(&asset.sha256).with_context(|| format!("asset '{}'", asset.path))?;
    }
    // A scene prepared before needs none of its files: nothing to download.
    let (c, j) = (Arc::clone(&cache), Arc::clone(&job));
    let prepared = tokio::task::spawn_blocking(move || read_prepared(&c, &j))
        .await
        .map_err(|e| anyhow!("scene loading thread failed: {e}"))?;
    if let Some(loaded) = prepared {
        tracing::info!("job {}: scene '{}' read prepared in {:.2?}", job.job_id, job.scene.path, start.elapsed());
        return Ok(loaded);
    }
    let mut fetched = 0usize;
    let mut done = std::collections::HashSet::new();
    for asset in std::iter::once(&job.scene).chain(&job.assets) {
        if !done.insert(asset.sha256.clone()) || cache.has_blob(asset) {
            continue;
        }
        // A few tries on transport trouble; a wrong digest or a refusal is final.
        let mut backoff = crate::machine::backoff::Backoff::new(max_backoff);
        let mut attempt = 0;
        loop {
            attempt += 1;
            match fetch_blob(&mut client, &cache, asset).await {
                Ok(()) => break,
                Err(FetchError::Rpc(RpcFailure::Transport(m))) if attempt < 4 => {
                    let d = backoff.next_delay();
                    tracing::warn!("fetching asset '{}' failed ({m}); retrying in {d:?}", asset.path);
                    tokio::time::sleep(d).await;
                }
                Err(FetchError::Rpc(f)) => bail!("cannot fetch asset '{}' ({}): {f}", asset.path, asset.sha256),
                Err(FetchError::Fatal(e)) => return Err(e),
            }
        }
        fetched += 1;
    }
    let blocking_job = job.clone();
    let loaded = tokio::task::spawn_blocking(move || load_from_files(&cache, &blocking_job))
        .await
        .map_err(|e| anyhow!("scene loading thread failed: {e}"))??;
    tracing::info!(
        "job {}: scene '{}' ready ({}×{}, {} file(s), {fetched} downloaded) in {:.2?}",
        job.job_id,
        job.scene.path,
        loaded.scene.camera.width,
        loaded.scene.camera.height,
        1 + job.assets.len(),
        start.elapsed()
    );
    // The coordinator reports a job's scene warnings, once; every worker would repeat them.
    for w in &loaded.scene.warnings {
        tracing::debug!("job {}: {w}", job.job_id);
    }
    Ok(loaded)
}

/// The job's scene as prepared by an earlier load of the same files, if one is kept.
/// Blocking.
pub fn read_prepared(cache: &AssetCache, job: &JobSpec) -> Option<LoadedJob> {
    let what = format!("job {}", job.job_id);
    let scene = cache.prepared.as_ref()?.get(&job.scene_key(cache.confine), &what)?;
    Some(LoadedJob { spec: job.clone(), scene: Arc::new(scene), integrator: job.integrator, prepared: true })
}

/// Loads a job's scene from its files (all cached), laid out in the job's folder, with
/// the job's overrides applied, and keeps it prepared. Blocking.
fn load_from_files(cache: &AssetCache, job: &JobSpec) -> anyhow::Result<LoadedJob> {
    let scene_path = cache.lay_out_job(job)?;
    if cache.confine {
        tracer::scene::assets::check_within(&scene_path, &cache.job_dir(&job.job_id)?)
            .map_err(|e| anyhow!("job {}: {e}", job.job_id))?;
    }
    let loaded = |scene, prepared| LoadedJob { spec: job.clone(), scene, integrator: job.integrator, prepared };
    let (key, what) = (job.scene_key(cache.confine), format!("job {}", job.job_id));
    // Workers sharing the folder build a scene once: while one builds, the others wait,
    // then read what it kept.
    let building = cache.prepared.as_ref().and_then(|p| p.building(&key));
    if let Some(scene) = building.as_ref().and_then(|_| cache.prepared.as_ref()?.get(&key, &what)) {
        return Ok(loaded(Arc::new(scene), true));
    }
    let mut scene =
        tracer::scene::load_scene_as(&scene_path, &job.scene.path, job.overrides.up).map_err(|e| anyhow!("{e}"))?;
    job.overrides.apply(&mut scene).map_err(|e| anyhow!("{}: settings: {e}", job.scene.path))?;
    let scene = Arc::new(scene);
    if let Some(p) = &cache.prepared {
        // Kept in the background: rendering need not wait for the disk. The others wait
        // until it is kept.
        let (p, scene) = (Arc::clone(p), Arc::clone(&scene));
        std::thread::spawn(move || {
            p.put(&key, &scene, &what);
            drop(building);
        });
    }
    Ok(loaded(scene, false))
}

/// The most recently used loaded scenes, by job spec.
pub struct SceneCache {
    capacity: usize,
    entries: VecDeque<Arc<LoadedJob>>,
}

impl SceneCache {
    pub fn new(capacity: usize) -> Self {
        Self { capacity: capacity.max(1), entries: VecDeque::new() }
    }

    pub fn get(&mut self, job: &JobSpec) -> Option<Arc<LoadedJob>> {
        let i = self.entries.iter().position(|j| j.spec == *job)?;
        let job = self.entries.remove(i)?;
        self.entries.push_front(job.clone());
        Some(job)
    }

    pub fn insert(&mut self, job: Arc<LoadedJob>) {
        self.entries.retain(|j| j.spec != job.spec);
        self.entries.push_front(job);
        self.entries.truncate(self.capacity);
    }
}

#[cfg(test)]
mod tests;
