//! Checkpoints: a job's spec, settings, units (which are done) and tile accumulations,
//! persisted so that a render survives its coordinator.
//!
//! One file, `<dir>/checkpoint.tfck`, written atomically (temp file, fsync, rename,
//! fsync of the folder): a crash at any moment leaves the old checkpoint or the new one,
//! never a torn one. The file ends with the SHA-256 of everything before it, so a
//! truncated or altered file is refused rather than used. The scene's files live beside
//! it in `<dir>/blobs/` (the content-addressed store), so `coordinator resume DIR`
//! needs nothing else. A plain file suffices here — there is one writer, and the whole
//! state is replaced at once — so an embedded database would add a dependency and a
//! format without adding a guarantee.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use proto::domain::{AssetRef, JobSpec};
use sha2::{Digest, Sha256};
use tracer::film::{Accumulation, SampleRange, Tile};

use super::job::{Job, Restored, UnitId, UnitRecord};

/// Version 3 records whether each tile keeps the AOV layers, and their sums; version 2
/// the job's owner after its name. Versions 1 (no owner) and 2 (no layers) are still read.
const MAGIC: &[u8; 16] = b"tilefarm-ckpt-3\n";
const MAGIC_2: &[u8; 16] = b"tilefarm-ckpt-2\n";
const MAGIC_1: &[u8; 16] = b"tilefarm-ckpt-1\n";
const FILE: &str = "checkpoint.tfck";
/// Beside a checkpoint: its job was cancelled, and must come back cancelled.
const CANCELLED: &str = "cancelled";
/// Beside a checkpoint: the done units each identity returned that no other identity
/// confirmed (JSON, identity name to unit ids), so that a ban after a restart still
/// throws them away. Written before the checkpoint, so it lists at least the
/// checkpoint's (a unit it lists that is confirmed by then is only rendered again).
const UNCONFIRMED: &str = "unconfirmed.json";
/// Largest unconfirmed-units file read back (a job has at most 4,194,304 units).
const MAX_UNCONFIRMED_BYTES: u64 = 64 << 20;

/// A job as persisted.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    pub spec: JobSpec,
    pub name: String,
    pub owner: Option<String>,
    pub job: Restored,
}

impl Snapshot {
    pub fn of(spec: &JobSpec, job: &Job) -> Self {
        Self {
            spec: spec.clone(),
            name: job.name.clone(),
            owner: job.owner.clone(),
            job: Restored {
                width: job.width,
                height: job.height,
                spp: job.spp,
                tile_size: job.tile_size,
                batch_spp: job.batch_spp,
                non_negative: job.non_negative,
                units: job.records(),
                tiles: job.tile_accumulations().to_vec(),
                rays: job.rays,
                nonfinite: job.nonfinite,
                cancelled: job.phase == crate::farm::job::JobPhase::Cancelled,
                unconfirmed: Vec::new(),
            },
        }
    }

    pub fn units_done(&self) -> usize {
        self.job.units.iter().filter(|u| u.done).count()
    }

    /// Samples of the finished units.
    pub fn samples_done(&self) -> u64 {
        let pixels = |t: u32| self.job.tiles.get(t as usize).map_or(0, |a| a.tile.pixel_count() as u64);
        self.job.units.iter().filter(|u| u.done).map(|u| pixels(u.tile_index) * u.samples.len() as u64).sum()
    }
}

pub fn path(dir: &Path) -> PathBuf {
    dir.join(FILE)
}

/// What identifies a scene and the settings that change its pixels (all but spp and the
/// unit size): a checkpoint only resumes a job with the same key.
pub fn scene_key(spec: &JobSpec) -> String {
    let mut h = Sha256::new();
    let mut file = |a: &AssetRef| {
        h.update(a.path.as_bytes());
        h.update([0]);
        h.update(a.sha256.as_bytes());
        h.update([0]);
    };
    file(&spec.scene);
    let mut assets: Vec<_> = spec.assets.iter().collect();
    assets.sort_by(|a, b| a.path.cmp(&b.path));
    for a in assets {
        file(a);
    }
    let o = &spec.overrides;
    let size = (o.width.unwrap_or(0), o.height.unwrap_or(0));
    h.update(format!("{}|{}|{:?}|{:?}|{}", size.0, size.1, o.max_depth, o.seed, spec.integrator.name()).as_bytes());
    // Added after the fields above, and only when set, so that checkpoints written
    // before the clamp existed keep their keys.
    if let Some(c) = o.clamp {
        h.update(format!("|clamp {:08x}", c.to_bits()).as_bytes());
    }
    // Layers change what a tile's accumulation holds, not its beauty bits; but a
    // checkpoint without them cannot continue a render that keeps them (nor back).
    if o.aovs {
        h.update(b"|aovs");
    }
    // Adaptive sampling's target decides which samples are taken; so does a map.
    if let Some(n) = o.noise {
        h.update(format!("|noise {:08x}", n.to_bits()).as_bytes());
    }
    if let Some(m) = &spec.spp_map {
        h.update(format!("|sppmap {}x{}/{}:", m.width, m.height, m.tile_size).as_bytes());
        m.tile_spp.iter().for_each(|n| h.update(n.to_le_bytes()));
    }
    hex::encode(h.finalize())
}

// ------------------------------------------------------------------ encoding

fn put_varint(out: &mut Vec<u8>, mut v: u128) {
    loop {
        let byte = (v & 0x7f) as u8;
        v >>= 7;
        if v == 0 {
            out.push(byte);
            return;
        }
        out.push(byte | 0x80);
    }
}

/// Sums are mostly small and positive: zigzag + LEB128 keeps a pixel near 20 bytes
/// instead of the 52 of the raw i128s.
fn put_i128(out: &mut Vec<u8>, v: i128) {
    put_varint(out, ((v << 1) ^ (v >> 127)) as u128);
}

fn put_bytes(out: &mut Vec<u8>, b: &[u8]) {
    put_varint(out, b.len() as u128);
    out.extend_from_slice(b);
}

/// The checkpoint file's bytes (see [`write`], which streams them to disk instead).
pub fn encode(s: &Snapshot) -> Vec<u8> {
    let mut out = Vec::new();
    encode_to(s, &mut out).expect("writing to memory");
    out
}

/// Writes the checkpoint to `out` a tile at a time, hashing on the way (the digest goes
/// last): no copy of the whole file is held. Returns the bytes written.
fn encode_to(s: &Snapshot, out: &mut impl Write) -> std::io::Result<u64> {
    let j = &s.job;
    let mut h = Sha256::new();
    let mut written = 0u64;
    let mut flush = |buf: &mut Vec<u8>, out: &mut dyn Write| -> std::io::Result<()> {
        h.update(&buf[..]);
        out.write_all(buf)?;
        written += buf.len() as u64;
        buf.clear();
        Ok(())
    };
    let mut buf = Vec::with_capacity(1 << 16);
    buf.extend_from_slice(MAGIC);
    put_bytes(&mut buf, &proto::wire::job_to_bytes(&s.spec));
    put_bytes(&mut buf, s.name.as_bytes());
    put_bytes(&mut buf, s.owner.as_deref().unwrap_or("").as_bytes());
    for v in [j.width, j.height, j.spp, j.tile_size, j.batch_spp, j.non_negative as u32] {
        put_varint(&mut buf, v as u128);
    }
    put_varint(&mut buf, j.rays as u128);
    put_varint(&mut buf, j.nonfinite as u128);
    put_varint(&mut buf, j.units.len() as u128);
    for u in &j.units {
        for v in [u.tile_index, u.samples.start, u.samples.end, u.done as u32] {
            put_varint(&mut buf, v as u128);
        }
        if buf.len() >= 1 << 16 {
            flush(&mut buf, out)?;
        }
    }
    put_varint(&mut buf, j.tiles.len() as u128);
    for t in &j.tiles {
        for v in [t.tile.x0, t.tile.y0, t.tile.width, t.tile.height] {
            put_varint(&mut buf, v as u128);
        }
        put_varint(&mut buf, t.nonfinite as u128);
        put_varint(&mut buf, u128::from(t.has_layers()));
        for (i, (c, s)) in t.counts.iter().zip(&t.sums).enumerate() {
            put_varint(&mut buf, *c as u128);
            for v in s.iter().chain(t.layers.get(i).into_iter().flatten()) {
                put_i128(&mut buf, *v);
            }
        }
        flush(&mut buf, out)?;
    }
    flush(&mut buf, out)?;
    let digest = h.finalize();
    out.write_all(&digest)?;
    Ok(written + digest.len() as u64)
}

struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn varint(&mut self) -> anyhow::Result<u128> {
        let mut v: u128 = 0;
        for shift in (0..128).step_by(7) {
            let Some(&byte) = self.b.get(self.pos) else { bail!("ends early") };
            self.pos += 1;
            v |= ((byte & 0x7f) as u128) << shift;
            if byte & 0x80 == 0 {
                return Ok(v);
            }
        }
        bail!("a number is too long")
    }

    fn u32(&mut self) -> anyhow::Result<u32> {
        u32::try_from(self.varint()?).context("a 32-bit field is out of range")
    }

    fn u64(&mut self) -> anyhow::Result<u64> {
        u64::try_from(self.varint()?).context("a 64-bit field is out of range")
    }

    fn i128(&mut self) -> anyhow::Result<i128> {
        let z = self.varint()?;
        Ok(((z >> 1) as i128) ^ -((z & 1) as i128))
    }

    fn bytes(&mut self) -> anyhow::Result<&[u8]> {
        let n = usize::try_from(self.varint()?)?;
        let end = self.pos.checked_add(n).filter(|&e| e <= self.b.len()).context("ends early")?;
        let s = &self.b[self.pos..end];
        self.pos = end;
        Ok(s)
    }
}

pub fn decode(bytes: &[u8]) -> anyhow::Result<Snapshot> {
    let version = match bytes.get(..MAGIC.len()) {
        Some(m) if m == MAGIC => 3,
        Some(m) if m == MAGIC_2 => 2,
        Some(m) if m == MAGIC_1 => 1,
        _ => 0,
    };
    if bytes.len() < MAGIC.len() + 32 || version == 0 {
        bail!("not a tilefarm checkpoint (or truncated)");
    }
    let (body, digest) = bytes.split_at(bytes.len() - 32);
    if Sha256::digest(body).as_slice() != digest {
        bail!("checksum mismatch: the file is truncated or corrupt");
    }
    let mut r = Reader { b: body, pos: MAGIC.len() };
    let spec = proto::wire::job_from_bytes(r.bytes()?).map_err(anyhow::Error::msg).context("job spec")?;
    let name = String::from_utf8(r.bytes()?.to_vec()).context("job name")?;
    let owner = if version >= 2 {
        Some(String::from_utf8(r.bytes()?.to_vec()).context("job owner")?).filter(|o| !o.is_empty())
    } else {
        None
    };
    let (width, height, spp, tile_size, batch_spp) = (r.u32()?, r.u32()?, r.u32()?, r.u32()?, r.u32()?);
    let non_negative = r.u32()? != 0;
    let (rays, nonfinite) = (r.u64()?, r.u64()?);
    let n = usize::try_from(r.varint()?)?;
    anyhow::ensure!(n <= body.len(), "unit count out of range");
    let mut units = Vec::with_capacity(n);
    for _ in 0..n {
        let (tile_index, start, end, done) = (r.u32()?, r.u32()?, r.u32()?, r.u32()?);
        units.push(UnitRecord { tile_index, samples: SampleRange::new(start, end), done: done != 0 });
    }
    let n = usize::try_from(r.varint()?)?;
    anyhow::ensure!(n <= body.len(), "tile count out of range");
    let mut tiles = Vec::with_capacity(n);
    for _ in 0..n {
        let tile = Tile::new(r.u32()?, r.u32()?, r.u32()?, r.u32()?);
        anyhow::ensure!(tile.pixel_count() <= body.len(), "tile size out of range");
        let nonfinite = r.u64()?;
        let layers = version >= 3 && r.u32()? != 0;
        let mut acc = Accumulation::with_layers(tile, layers);
        acc.nonfinite = nonfinite;
        for i in 0..tile.pixel_count() {
            acc.counts[i] = r.u32()?;
            acc.sums[i] = [r.i128()?, r.i128()?, r.i128()?];
            if let Some(l) = acc.layers.get_mut(i) {
                for v in l {
                    *v = r.i128()?;
                }
            }
        }
        tiles.push(std::sync::Arc::new(acc));
    }
    anyhow::ensure!(r.pos == body.len(), "trailing data");
    Ok(Snapshot {
        spec,
        name,
        owner,
        // A cancel is kept beside the checkpoint, by `serve` (see `mark_cancelled`).
        job: Restored {
            width,
            height,
            spp,
            tile_size,
            batch_spp,
            non_negative,
            units,
            tiles,
            rays,
            nonfinite,
            cancelled: false,
            unconfirmed: Vec::new(),
        },
    })
}

/// Writes the checkpoint atomically; returns its size.
pub fn write(dir: &Path, s: &Snapshot) -> anyhow::Result<u64> {
    write_unconfirmed(dir, &s.job.unconfirmed)?;
    let dest = path(dir);
    let tmp = dir.join(format!("{FILE}.tmp"));
    let f = std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    let mut out = std::io::BufWriter::with_capacity(1 << 20, f);
    let written = encode_to(s, &mut out).and_then(|n| {
        let f = out.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        Ok(n)
    });
    let size = match written {
        Ok(n) => n,
        Err(e) => {
            // Leave no partial file behind to fill the disk further.
            let _ = std::fs::remove_file(&tmp);
            return Err(e).with_context(|| format!("writing {}", dest.display()));
        }
    };
    std::fs::rename(&tmp, &dest).with_context(|| format!("replacing {}", dest.display()))?;
    // The rename itself must reach the disk before we count the checkpoint as written.
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(size)
}

/// Reads `<dir>/checkpoint.tfck` if there is one; a damaged one is an error.
/// Records beside the checkpoint in `dir` that its job was cancelled (durably: the file
/// and the folder are synced), so a restarted `serve` does not run it again.
pub fn mark_cancelled(dir: &Path) -> anyhow::Result<()> {
    let p = dir.join(CANCELLED);
    let f = std::fs::File::create(&p).with_context(|| format!("creating {}", p.display()))?;
    f.sync_all().with_context(|| format!("writing {}", p.display()))?;
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Writes the [`UNCONFIRMED`] file in `dir` (atomically), or removes it when `list` is empty.
fn write_unconfirmed(dir: &Path, list: &[(String, Vec<UnitId>)]) -> anyhow::Result<()> {
    let p = dir.join(UNCONFIRMED);
    if list.is_empty() {
        return match std::fs::remove_file(&p) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e).with_context(|| p.display().to_string()),
            _ => Ok(()),
        };
    }
    let map: std::collections::BTreeMap<&str, &Vec<UnitId>> = list.iter().map(|(n, u)| (n.as_str(), u)).collect();
    let tmp = dir.join(format!("{UNCONFIRMED}.tmp"));
    let text = serde_json::to_vec(&map).expect("unit ids serialise");
    let f = std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    std::io::Write::write_all(&mut &f, &text).and_then(|()| f.sync_all()).with_context(|| tmp.display().to_string())?;
    std::fs::rename(&tmp, &p).with_context(|| format!("replacing {}", p.display()))
}

/// Reads the [`UNCONFIRMED`] file in `dir` (none: nothing unconfirmed).
fn read_unconfirmed(dir: &Path) -> anyhow::Result<Vec<(String, Vec<UnitId>)>> {
    let p = dir.join(UNCONFIRMED);
    let size = match std::fs::metadata(&p) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        m => m.with_context(|| p.display().to_string())?.len(),
    };
    anyhow::ensure!(size <= MAX_UNCONFIRMED_BYTES, "{}: {size} bytes, more than it can hold", p.display());
    let text = std::fs::read(&p).with_context(|| p.display().to_string())?;
    let map: std::collections::BTreeMap<String, Vec<UnitId>> =
        serde_json::from_slice(&text).with_context(|| format!("{} refused", p.display()))?;
    Ok(map.into_iter().collect())
}

/// Reads the checkpoint in `dir`; `None` when there is none.
pub fn read(dir: &Path) -> anyhow::Result<Option<Snapshot>> {
    let p = path(dir);
    match std::fs::read(&p) {
        Ok(bytes) => {
            let mut snap = decode(&bytes).with_context(|| format!("checkpoint {} refused", p.display()))?;
            snap.job.cancelled = dir.join(CANCELLED).exists();
            snap.job.unconfirmed = read_unconfirmed(dir)?;
            Ok(Some(snap))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e).with_context(|| format!("reading {}", p.display())),
    }
}

/// Decides when to write: every `min_interval`, or, when writes are slow, ten times
/// the last write's duration (the disk busy with checkpoints at most a tenth of the
/// time). So a crash loses at most what was done in one such interval and one write:
/// the interval does not grow with the job, only with a slow disk, and `serve` logs
/// when it does. (It was 100 times the write: a 0.2 s write meant 20 s of work lost.)
pub struct Pacer {
    last: Instant,
    last_cost: Duration,
    min_interval: Duration,
}

impl Pacer {
    pub fn new(min_interval: Duration) -> Self {
        Self { last: Instant::now(), last_cost: Duration::ZERO, min_interval }
    }

    pub fn due(&self) -> bool {
        self.last.elapsed() >= self.interval()
    }

    /// The time between two writes now.
    pub fn interval(&self) -> Duration {
        self.min_interval.max(self.last_cost * 10)
    }

    pub fn wrote(&mut self, cost: Duration) {
        self.last = Instant::now();
        self.last_cost = cost;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn snapshot() -> Snapshot {
        snapshot_with(false)
    }

    fn snapshot_with(layers: bool) -> Snapshot {
        let mut job = Job::loading("job-1".into(), "scene.toml".into());
        job.layers = layers;
        job.start(5, 3, 4, 2, 2, true);
        let far = Instant::now() + Duration::from_secs(60);
        for _ in 0..4 {
            let id = job.lease_next(1, Instant::now(), far, Duration::MAX).unwrap();
            let u = &job.units[id as usize];
            let n = u.tile.pixel_count();
            let r = crate::farm::job::UnitResult {
                unit: id,
                tile: u.tile,
                samples: u.samples,
                sums: (0..n).map(|i| [i as i128 * 1_000_000_007, 1 << 90, 0]).collect(),
                counts: vec![u.samples.len(); n],
                layers: if layers {
                    (0..n).map(|i| std::array::from_fn(|k| (i * 11 + k) as i128 * -3_000_000_019)).collect()
                } else {
                    Vec::new()
                },
                nonfinite: 1,
                rays: 77,
                render_seconds: 0.0,
            };
            job.apply(1, &r).unwrap();
        }
        let spec = JobSpec {
            job_id: "job-1".into(),
            scene: AssetRef { path: "scene.toml".into(), sha256: "ab".repeat(32), size: 10 },
            assets: vec![],
            overrides: tracer::scene::Overrides { spp: Some(4), ..Default::default() },
            integrator: Default::default(),
            tile_size: None,
            batch_spp: None,
            spp_map: None,
            group: Some("shot".into()),
        };
        Snapshot::of(&spec, &job)
    }

    #[test]
    fn round_trips_exactly() {
        let s = snapshot();
        assert_eq!(decode(&encode(&s)).unwrap(), s);
        assert_eq!(s.units_done(), 4);
        let layered = snapshot_with(true);
        assert!(layered.job.tiles.iter().all(|t| t.has_layers()));
        assert!(layered.job.tiles.iter().any(|t| t.layers.iter().flatten().any(|&v| v != 0)));
        assert_eq!(decode(&encode(&layered)).unwrap(), layered);
    }

    /// A version-2 file (before layers) still reads: the same bytes less the layers flag.
    /// A queued frame of a group, saved before it started: nothing rendered, its group
    /// kept, so that a restarted farm queues it again.
    #[test]
    fn a_queued_frame_round_trips() {
        let mut s = snapshot();
        let job = Job::loading("job-2".into(), "shot.0002".into());
        s = Snapshot::of(&s.spec, &job);
        assert_eq!((s.job.width, s.job.units.len(), s.job.tiles.len()), (0, 0, 0));
        let back = decode(&encode(&s)).unwrap();
        assert_eq!(back, s);
        assert_eq!(back.spec.group.as_deref(), Some("shot"));
    }

    #[test]
    fn version_two_checkpoints_still_read() {
        let s = snapshot();
        let mut buf = Vec::new();
        buf.extend_from_slice(MAGIC_2);
        let j = &s.job;
        put_bytes(&mut buf, &proto::wire::job_to_bytes(&s.spec));
        put_bytes(&mut buf, s.name.as_bytes());
        put_bytes(&mut buf, b"");
        for v in [j.width, j.height, j.spp, j.tile_size, j.batch_spp, j.non_negative as u32] {
            put_varint(&mut buf, v as u128);
        }
        put_varint(&mut buf, j.rays as u128);
        put_varint(&mut buf, j.nonfinite as u128);
        put_varint(&mut buf, j.units.len() as u128);
        for u in &j.units {
            for v in [u.tile_index, u.samples.start, u.samples.end, u.done as u32] {
                put_varint(&mut buf, v as u128);
            }
        }
        put_varint(&mut buf, j.tiles.len() as u128);
        for t in &j.tiles {
            for v in [t.tile.x0, t.tile.y0, t.tile.width, t.tile.height] {
                put_varint(&mut buf, v as u128);
            }
            put_varint(&mut buf, t.nonfinite as u128);
            for (c, s) in t.counts.iter().zip(&t.sums) {
                put_varint(&mut buf, *c as u128);
                s.iter().for_each(|v| put_i128(&mut buf, *v));
            }
        }
        let digest = Sha256::digest(&buf);
        buf.extend_from_slice(&digest);
        assert_eq!(decode(&buf).unwrap(), s);
    }

    #[test]
    fn truncation_and_flipped_bytes_are_refused() {
        let bytes = encode(&snapshot());
        for cut in [0, 10, bytes.len() / 2, bytes.len() - 1] {
            assert!(decode(&bytes[..cut]).is_err(), "truncated at {cut}");
        }
        for i in [0, 20, bytes.len() / 2, bytes.len() - 1] {
            let mut b = bytes.clone();
            b[i] ^= 0x01;
            assert!(decode(&b).is_err(), "flipped byte {i}");
        }
    }

    #[test]
    fn writes_atomically_and_reads_back() {
        let dir = std::env::temp_dir().join(format!("tilefarm-ckpt-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(read(&dir).unwrap().is_none());
        let mut s = snapshot();
        write(&dir, &s).unwrap();
        assert_eq!(read(&dir).unwrap().unwrap(), s);
        assert!(!dir.join("checkpoint.tfck.tmp").exists());
        // Who returned units unconfirmed comes back too, and goes when nothing is.
        s.job.unconfirmed = vec![("cert:0123".into(), vec![0, 2]), ("registration 4".into(), vec![1])];
        write(&dir, &s).unwrap();
        assert_eq!(read(&dir).unwrap().unwrap(), s);
        s.job.unconfirmed.clear();
        write(&dir, &s).unwrap();
        assert!(!dir.join(UNCONFIRMED).exists());
        std::fs::write(dir.join(UNCONFIRMED), "{\"x\": [\"a\"]}").unwrap();
        assert!(read(&dir).is_err(), "a damaged list is refused, not taken as nothing");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn scene_key_ignores_spp_but_not_the_scene_or_pixels() {
        let s = snapshot().spec;
        let mut more = s.clone();
        more.overrides.spp = Some(64);
        assert_eq!(scene_key(&s), scene_key(&more));
        let mut other = s.clone();
        other.scene.sha256 = "cd".repeat(32);
        assert_ne!(scene_key(&s), scene_key(&other));
        let mut wider = s.clone();
        wider.overrides.width = Some(99);
        assert_ne!(scene_key(&s), scene_key(&wider));
        // A clamp changes the image: its checkpoint is another render's.
        let mut clamped = s.clone();
        clamped.overrides.clamp = Some(4.0);
        assert_ne!(scene_key(&s), scene_key(&clamped));
        let mut layered = s.clone();
        layered.overrides.aovs = true;
        assert_ne!(scene_key(&s), scene_key(&layered), "a render with layers continues only one with layers");
        let mut adaptive = s.clone();
        adaptive.overrides.noise = Some(0.01);
        assert_ne!(scene_key(&s), scene_key(&adaptive));
        let map = |n: u32| proto::domain::SppMap { width: 8, height: 8, tile_size: 4, tile_spp: vec![n; 4] };
        let (mut mapped, mut other_map) = (s.clone(), s.clone());
        (mapped.spp_map, other_map.spp_map) = (Some(map(8)), Some(map(16)));
        assert_ne!(scene_key(&s), scene_key(&mapped));
        assert_ne!(scene_key(&mapped), scene_key(&other_map));
        let mut other_limit = s.clone();
        other_limit.overrides.clamp = Some(8.0);
        assert_ne!(scene_key(&clamped), scene_key(&other_limit));
    }

    #[test]
    fn the_pacer_writes_every_interval_unless_writes_take_over_a_tenth_of_it() {
        let mut p = Pacer::new(Duration::from_secs(5));
        assert!(!p.due());
        p.wrote(Duration::from_millis(200));
        assert_eq!(p.interval(), Duration::from_secs(5), "a 0.2 s write does not stretch 5 s");
        p.wrote(Duration::from_secs(2));
        assert_eq!(p.interval(), Duration::from_secs(20));
    }
}
