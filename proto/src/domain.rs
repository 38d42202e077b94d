//! The domain types that the coordinator and the worker share, apart from their wire
//! form: what a job is, which unit is which, and a unit's result as received. Plain
//! data over the tracer's types; [`crate::wire`] maps them to and from the messages.

use std::sync::Arc;

use tracer::film::{SampleRange, Tile};
use tracer::integrator::Integrator;
use tracer::scene::Overrides;

/// A unit's identity: the coordinator's (job id, unit id).
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct UnitKey {
    pub job_id: String,
    pub unit_id: u64,
}

impl std::fmt::Display for UnitKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.job_id, self.unit_id)
    }
}

/// A file of a job: its path relative to the job folder (not yet sanitised: the asset
/// cache does that, with the error naming the path) and its content digest.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AssetRef {
    pub path: String,
    pub sha256: String,
    pub size: u64,
}

/// A job: what a worker needs to load its scene, and how the coordinator cuts it.
#[derive(Clone, Debug, PartialEq)]
pub struct JobSpec {
    pub job_id: String,
    pub scene: AssetRef,
    pub assets: Vec<AssetRef>,
    pub overrides: Overrides,
    pub integrator: Integrator,
    /// The unit shape the job asks for: tile side and samples per unit (`None`: the
    /// farm's default). The coordinator's business; workers ignore them.
    pub tile_size: Option<u32>,
    pub batch_spp: Option<u32>,
    /// `--spp-map`: each tile's samples per pixel, instead of the same spp for all.
    pub spp_map: Option<SppMap>,
    /// The job group (an animation) this job is a frame of: the coordinator starts and
    /// renders a group's frames in submission order. Workers ignore it.
    pub group: Option<String>,
}

/// Samples per pixel for each tile of a `width`×`height` image cut into tiles of side
/// `tile_size`, in the tiles' grid order (row by row): the map a previous render reached
/// (after `--time-budget` or `--adaptive`), to render the same pixels again.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SppMap {
    pub width: u32,
    pub height: u32,
    pub tile_size: u32,
    pub tile_spp: Vec<u32>,
}

impl SppMap {
    /// The tiles of a `width`×`height` image with side `tile`, row by row.
    pub fn tile_count(width: u32, height: u32, tile: u32) -> usize {
        let tile = tile.max(1);
        width.div_ceil(tile) as usize * height.div_ceil(tile) as usize
    }

    /// Whether the map's size and tile count agree (what the wire must check before
    /// trusting it); the message says what does not.
    pub fn check(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 || self.width > 65536 || self.height > 65536 || self.tile_size == 0 {
            return Err(format!("an spp map of {}×{} in tiles of {}", self.width, self.height, self.tile_size));
        }
        let n = Self::tile_count(self.width, self.height, self.tile_size);
        if self.tile_spp.len() != n {
            return Err(format!("an spp map with {} tiles where its size has {n}", self.tile_spp.len()));
        }
        Ok(())
    }

    /// The most samples per pixel of any tile.
    pub fn most(&self) -> u32 {
        self.tile_spp.iter().copied().max().unwrap_or(0)
    }
}

impl JobSpec {
    /// A key over everything a loaded scene depends on besides the tracer itself: the
    /// overrides, the paths and digests of the scene's files (not the job's id: the
    /// same scene in another job is the same scene), and whether it was `confined` to
    /// them (a scene loaded with its paths trusted never stands in for a checked one).
    /// See [`tracer::scene::prepared::PreparedScenes`].
    pub fn scene_key(&self, confined: bool) -> [u8; 32] {
        use sha2::{Digest, Sha256};
        let mut h = Sha256::new();
        h.update(if confined { "confined\n" } else { "trusted paths\n" });
        h.update(format!("{:?}\n", self.overrides).as_bytes());
        for a in std::iter::once(&self.scene).chain(&self.assets) {
            h.update(format!("{}\n{}\n{}\n", a.path.len(), a.path, a.sha256).as_bytes());
        }
        h.finalize().into()
    }
}

/// One leased unit of work.
#[derive(Clone, Debug)]
pub struct WorkUnit {
    pub key: UnitKey,
    pub job: Arc<JobSpec>,
    pub tile: Tile,
    pub samples: SampleRange,
}

/// The contents of one unit's result: per-pixel fixed-point sums and sample counts.
#[derive(Clone, Debug)]
pub struct UnitResult {
    pub unit: u64,
    pub tile: Tile,
    pub samples: SampleRange,
    pub sums: Vec<[i128; 3]>,
    pub counts: Vec<u32>,
    /// The AOV layers' sums per pixel (empty unless the job keeps layers).
    pub layers: Vec<tracer::film::LayerSums>,
    pub nonfinite: u64,
    pub rays: u64,
    /// Seconds its worker spent rendering it (0 when unknown): not part of the image.
    pub render_seconds: f64,
}

/// A unit result as received: checked for shape (a valid tile and sample range, whole
/// pixels of sums); whether it fits its unit is the job's to check.
#[derive(Clone, Debug)]
pub struct ReceivedResult {
    pub worker_id: u64,
    pub job_id: String,
    pub result: UnitResult,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn job(digest: char) -> JobSpec {
        let asset = |path: &str| AssetRef { path: path.into(), sha256: digest.to_string().repeat(64), size: 1 };
        JobSpec {
            job_id: "j".into(),
            scene: asset("scene.toml"),
            assets: vec![asset("a.obj")],
            overrides: Default::default(),
            integrator: Integrator::Path,
            tile_size: None,
            batch_spp: None,
            spp_map: None,
            group: None,
        }
    }

    #[test]
    fn scene_keys_follow_the_files_and_the_overrides() {
        let a = job('a');
        assert_ne!(a.scene_key(true), job('b').scene_key(true), "another file's content");
        let mut renamed = job('a');
        renamed.assets[0].path = "b.obj".into();
        assert_ne!(a.scene_key(true), renamed.scene_key(true), "another file's name");
        let mut wider = job('a');
        wider.overrides.width = Some(64);
        assert_ne!(a.scene_key(true), wider.scene_key(true), "other overrides");
        let mut elsewhere = job('a');
        (elsewhere.job_id, elsewhere.tile_size) = ("k".into(), Some(32));
        assert_eq!(a.scene_key(true), elsewhere.scene_key(true), "the same scene in another job, cut otherwise");
        assert_ne!(a.scene_key(true), a.scene_key(false), "loaded with its paths trusted");
    }
}
