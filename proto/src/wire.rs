//! The one mapping between the wire types and the domain types, used by the coordinator
//! and the worker alike. Everything the network sends is checked here, once: a malformed
//! message becomes an error message naming what is wrong (a status for the sender, or a
//! unit dropped), never a panic deeper in; every domain value is encoded here too.

use std::sync::Arc;

use prost::Message;
use tracer::film::{Accumulation, SampleRange, Tile};
use tracer::integrator::Integrator;
use tracer::scene::Overrides;

pub use crate::domain::{AssetRef, JobSpec, ReceivedResult, SppMap, UnitKey, UnitResult, WorkUnit};

/// Largest tile side the worker accepts.
pub const MAX_TILE_SIDE: u32 = 4096;
/// Largest sample range the worker accepts in one unit.
pub const MAX_SAMPLES_PER_UNIT: u32 = 1 << 20;
/// Upper bound of a result's encoded size per pixel: three i128 sums (48 bytes) and one
/// packed varint count (≤ 5 bytes).
const RESULT_BYTES_PER_PIXEL: usize = 53;
/// Room for the result's other fields.
const RESULT_OVERHEAD_BYTES: usize = 4096;

impl From<&AssetRef> for crate::AssetRef {
    fn from(a: &AssetRef) -> Self {
        crate::AssetRef { path: a.path.clone(), sha256: a.sha256.clone(), size: a.size }
    }
}

impl From<&crate::AssetRef> for AssetRef {
    fn from(a: &crate::AssetRef) -> Self {
        AssetRef { path: a.path.clone(), sha256: a.sha256.clone(), size: a.size }
    }
}

/// The settings message of a job's overrides, integrator and unit shape.
pub fn settings_to_proto(j: &JobSpec) -> crate::RenderSettings {
    let o = &j.overrides;
    crate::RenderSettings {
        spp: o.spp.unwrap_or(0),
        width: o.width.unwrap_or(0),
        height: o.height.unwrap_or(0),
        max_depth: o.max_depth,
        seed: o.seed,
        clamp: o.clamp,
        aovs: o.aovs,
        noise: o.noise,
        time_budget_ms: o.time_budget.map(|d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX)),
        integrator: j.integrator.name().to_string(),
        tile_size: j.tile_size.unwrap_or(0),
        batch_spp: j.batch_spp.unwrap_or(0),
        spp_map: j.spp_map.as_ref().map(|m| crate::SppMap {
            width: m.width,
            height: m.height,
            tile_size: m.tile_size,
            tile_spp: m.tile_spp.clone(),
        }),
        up: match o.up {
            tracer::scene::UpAxis::Y => String::new(),
            tracer::scene::UpAxis::Z => "z".into(),
        },
    }
}

pub fn job_to_proto(j: &JobSpec) -> crate::JobSpec {
    crate::JobSpec {
        job_id: j.job_id.clone(),
        scene: Some((&j.scene).into()),
        assets: j.assets.iter().map(Into::into).collect(),
        settings: Some(settings_to_proto(j)),
        group: j.group.clone().unwrap_or_default(),
    }
}

/// A job as a user submits it (it has no id yet): the scene, its files and settings,
/// checked. Paths are the store's to check against its folder.
pub fn submission_from_proto(
    scene: Option<crate::AssetRef>,
    assets: Vec<crate::AssetRef>,
    settings: Option<&crate::RenderSettings>,
    group: String,
) -> Result<JobSpec, String> {
    let group = group_from_proto(group)?;
    let (overrides, integrator) = settings_from_proto(settings).map_err(|e| format!("settings: {e}"))?;
    let scene = asset_from_proto(scene, "scene file")?;
    let assets = assets.into_iter().map(|a| asset_from_proto(Some(a), "asset")).collect::<Result<Vec<_>, _>>()?;
    let nonzero = |v: u32| (v != 0).then_some(v);
    let (tile_size, batch_spp) = settings.map_or((None, None), |s| (nonzero(s.tile_size), nonzero(s.batch_spp)));
    let spp_map = match settings.and_then(|s| s.spp_map.as_ref()) {
        None => None,
        Some(m) => {
            let map = SppMap { width: m.width, height: m.height, tile_size: m.tile_size, tile_spp: m.tile_spp.clone() };
            map.check().map_err(|e| format!("settings: {e}"))?;
            Some(map)
        }
    };
    Ok(JobSpec { job_id: String::new(), scene, assets, overrides, integrator, tile_size, batch_spp, spp_map, group })
}

/// Longest job group name, in characters.
pub const MAX_GROUP_CHARS: usize = 200;

/// A job group's name from the wire: empty for none; else at most [`MAX_GROUP_CHARS`]
/// printable characters.
pub fn group_from_proto(group: String) -> Result<Option<String>, String> {
    if group.is_empty() {
        return Ok(None);
    }
    if group.chars().count() > MAX_GROUP_CHARS || group.chars().any(char::is_control) || group.trim() != group {
        return Err(format!(
            "group: a name of 1 to {MAX_GROUP_CHARS} printable characters, without spaces at its ends, is needed"
        ));
    }
    Ok(Some(group))
}

/// A job spec as bytes (its wire encoding), for files that keep it, such as checkpoints.
pub fn job_to_bytes(j: &JobSpec) -> Vec<u8> {
    job_to_proto(j).encode_to_vec()
}

/// The inverse of [`job_to_bytes`], checked as a submission is.
pub fn job_from_bytes(bytes: &[u8]) -> Result<JobSpec, String> {
    let j = crate::JobSpec::decode(bytes).map_err(|e| e.to_string())?;
    let mut spec = submission_from_proto(j.scene, j.assets, j.settings.as_ref(), j.group)?;
    spec.job_id = j.job_id;
    Ok(spec)
}

fn asset_from_proto(a: Option<crate::AssetRef>, what: &str) -> Result<AssetRef, String> {
    let a = a.ok_or_else(|| format!("{what} is missing"))?;
    Ok(AssetRef { path: a.path, sha256: a.sha256, size: a.size })
}

/// The job-level settings the worker applies: the scene overrides and the integrator.
/// Zero (or absent) means "as in the scene"; tile size and batch size are the
/// coordinator's business.
pub fn settings_from_proto(s: Option<&crate::RenderSettings>) -> Result<(Overrides, Integrator), String> {
    let Some(s) = s else { return Ok((Overrides::default(), Integrator::Path)) };
    let nonzero = |v: u32| (v != 0).then_some(v);
    let overrides = Overrides {
        spp: nonzero(s.spp),
        width: nonzero(s.width),
        height: nonzero(s.height),
        max_depth: s.max_depth,
        seed: s.seed,
        clamp: s.clamp,
        aovs: s.aovs,
        noise: s.noise,
        time_budget: s.time_budget_ms.map(std::time::Duration::from_millis),
        up: if s.up.is_empty() { tracer::scene::UpAxis::Y } else { s.up.parse()? },
    };
    let integrator = if s.integrator.is_empty() {
        Integrator::Path
    } else {
        s.integrator.parse().map_err(|_| {
            format!("unknown integrator {} (expected one of: {})", quote(&s.integrator), Integrator::NAMES.join(", "))
        })?
    };
    Ok((overrides, integrator))
}

/// A job as a leased unit carries it: it must have its id.
pub fn job_from_proto(j: crate::JobSpec) -> Result<JobSpec, String> {
    if j.job_id.is_empty() {
        return Err("job id is empty".into());
    }
    let mut spec = submission_from_proto(j.scene, j.assets, j.settings.as_ref(), j.group)
        .map_err(|e| format!("job {}: {e}", j.job_id))?;
    spec.job_id = j.job_id;
    Ok(spec)
}

/// An upper bound of the encoded size of a result of `tile` (what batching counts),
/// with the AOV layers' sums (`layers`) or without.
pub fn result_bytes_bound(tile: Tile, layers: bool) -> usize {
    let per_pixel = RESULT_BYTES_PER_PIXEL + if layers { tracer::film::LAYER_BYTES } else { 0 };
    tile.pixel_count() * per_pixel + RESULT_OVERHEAD_BYTES
}

/// Checks a tile from the wire: non-empty, at most [`MAX_TILE_SIDE`] on each side, no
/// coordinate overflow, and a result small enough for one message.
pub fn tile_from_proto(t: Option<&crate::Tile>) -> Result<Tile, String> {
    let t = t.ok_or("tile is missing")?;
    if t.width == 0 || t.height == 0 || t.width > MAX_TILE_SIDE || t.height > MAX_TILE_SIDE {
        return Err(format!("tile size {}×{} must be between 1 and {MAX_TILE_SIDE} on each side", t.width, t.height));
    }
    if t.x0.checked_add(t.width).is_none() || t.y0.checked_add(t.height).is_none() {
        return Err(format!("tile at ({}, {}) of {}×{} overflows", t.x0, t.y0, t.width, t.height));
    }
    let tile = Tile::new(t.x0, t.y0, t.width, t.height);
    // Without layers: a job with them is refused tiles too large for them when it starts.
    if result_bytes_bound(tile, false) > crate::MAX_MESSAGE_BYTES {
        return Err(format!("tile {}×{}: its result would exceed the message size limit", t.width, t.height));
    }
    Ok(tile)
}

pub fn samples_from_proto(start: u32, end: u32) -> Result<SampleRange, String> {
    if start >= end {
        return Err(format!("sample range [{start}, {end}) is empty"));
    }
    if end - start > MAX_SAMPLES_PER_UNIT {
        return Err(format!("sample range [{start}, {end}) is longer than {MAX_SAMPLES_PER_UNIT}"));
    }
    Ok(SampleRange::new(start, end))
}

/// Converts and checks a leased unit. The error names the unit when it can.
pub fn unit_from_proto(u: crate::Unit) -> Result<WorkUnit, String> {
    let job = u.job.ok_or_else(|| format!("unit {}: job spec is missing", u.unit_id))?;
    let job = job_from_proto(job).map_err(|e| format!("unit {}: {e}", u.unit_id))?;
    let key = UnitKey { job_id: job.job_id.clone(), unit_id: u.unit_id };
    let tile = tile_from_proto(u.tile.as_ref()).map_err(|e| format!("unit {key}: {e}"))?;
    let samples = samples_from_proto(u.sample_start, u.sample_end).map_err(|e| format!("unit {key}: {e}"))?;
    Ok(WorkUnit { key, job: Arc::new(job), tile, samples })
}

pub fn unit_key_to_proto(k: &UnitKey) -> crate::UnitKey {
    crate::UnitKey { job_id: k.job_id.clone(), unit_id: k.unit_id }
}

pub fn unit_key_from_proto(k: crate::UnitKey) -> UnitKey {
    UnitKey { job_id: k.job_id, unit_id: k.unit_id }
}

pub fn tile_to_proto(t: Tile) -> crate::Tile {
    crate::Tile { x0: t.x0, y0: t.y0, width: t.width, height: t.height }
}

/// The longest a unit may say it took to render (a week): more is a broken clock.
pub const MAX_RENDER_SECONDS: f64 = 7.0 * 86_400.0;

/// Converts and checks a unit result from a worker.
pub fn result_from_proto(r: crate::UnitResult) -> Result<ReceivedResult, String> {
    let key = UnitKey { job_id: r.job_id, unit_id: r.unit_id };
    let tile = tile_from_proto(r.tile.as_ref()).map_err(|e| format!("unit {key}: {e}"))?;
    let samples = samples_from_proto(r.sample_start, r.sample_end).map_err(|e| format!("unit {key}: {e}"))?;
    let sums = Accumulation::sums_from_bytes(&r.sums)
        .ok_or_else(|| format!("unit {key}: sums are not a whole number of pixels (48 bytes each)"))?;
    let layers = Accumulation::layers_from_bytes(&r.layers).ok_or_else(|| {
        format!("unit {key}: layers are not a whole number of pixels ({} bytes each)", tracer::film::LAYER_BYTES)
    })?;
    if !(r.render_seconds.is_finite() && (0.0..=MAX_RENDER_SECONDS).contains(&r.render_seconds)) {
        return Err(format!(
            "unit {key}: render_seconds must be between 0 and {MAX_RENDER_SECONDS}, got {}",
            r.render_seconds
        ));
    }
    let result = UnitResult {
        unit: key.unit_id,
        tile,
        samples,
        sums,
        counts: r.counts,
        layers,
        nonfinite: r.nonfinite,
        rays: r.rays,
        render_seconds: r.render_seconds,
    };
    Ok(ReceivedResult { worker_id: r.worker_id, job_id: key.job_id, result })
}

/// A leased unit as the wire message `Unit` carries it.
pub fn unit_to_proto(job: &JobSpec, unit_id: u64, tile: Tile, samples: SampleRange) -> crate::Unit {
    crate::Unit {
        job: Some(job_to_proto(job)),
        unit_id,
        tile: Some(tile_to_proto(tile)),
        sample_start: samples.start,
        sample_end: samples.end,
    }
}

/// A rendered unit as the wire message `SubmitResult` takes.
pub fn result_to_proto(
    worker_id: u64,
    key: &UnitKey,
    samples: SampleRange,
    acc: &Accumulation,
    rays: u64,
    render_seconds: f64,
) -> crate::UnitResult {
    crate::UnitResult {
        worker_id,
        job_id: key.job_id.clone(),
        unit_id: key.unit_id,
        tile: Some(tile_to_proto(acc.tile)),
        sample_start: samples.start,
        sample_end: samples.end,
        sums: acc.sums_to_bytes(),
        counts: acc.counts.clone(),
        layers: acc.layers_to_bytes(),
        nonfinite: acc.nonfinite,
        rays,
        render_seconds,
    }
}

/// A batch's outcomes: merged (true), a duplicate (false), or refused with why.
pub fn outcomes_from_proto(r: crate::SubmitResultsReply) -> Vec<Result<bool, String>> {
    let outcome = |o: crate::ResultOutcome| if o.refused.is_empty() { Ok(o.accepted) } else { Err(o.refused) };
    r.outcomes.into_iter().map(outcome).collect()
}

pub fn outcome_to_proto(o: Result<bool, String>) -> crate::ResultOutcome {
    match o {
        Ok(accepted) => crate::ResultOutcome { accepted, refused: String::new() },
        Err(refused) => crate::ResultOutcome { accepted: false, refused },
    }
}

/// Most characters of an error message sent to a client: messages quote what the client
/// sent, and an echo must not be as large as the input.
pub const MAX_ERROR_CHARS: usize = 1024;

/// At most the first 64 characters of something a client sent, escaped, for quoting
/// in an error message.
pub fn quote(input: &str) -> String {
    const MAX: usize = 64;
    let head: String = input.chars().take(MAX).collect();
    if head.len() < input.len() {
        format!("'{}…'", head.escape_debug())
    } else {
        format!("'{}'", head.escape_debug())
    }
}

/// An error message as a client may receive it: at most [`MAX_ERROR_CHARS`] characters.
pub fn bounded(message: String) -> String {
    if message.chars().count() <= MAX_ERROR_CHARS {
        return message;
    }
    let mut m: String = message.chars().take(MAX_ERROR_CHARS).collect();
    m.push('…');
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(tile: Option<crate::Tile>, start: u32, end: u32) -> crate::Unit {
        crate::Unit {
            job: Some(crate::JobSpec {
                job_id: "j1".into(),
                scene: Some(crate::AssetRef { path: "scene.toml".into(), sha256: "ab".repeat(32), size: 10 }),
                assets: vec![],
                settings: Some(crate::RenderSettings {
                    spp: 16,
                    width: 0,
                    height: 120,
                    max_depth: Some(4),
                    seed: None,
                    integrator: "normals".into(),
                    tile_size: 32,
                    batch_spp: 4,
                    up: "z".into(),
                    clamp: Some(0.5),
                    aovs: true,
                    noise: Some(0.02),
                    time_budget_ms: Some(90_000),
                    spp_map: Some(crate::SppMap {
                        width: 64,
                        height: 40,
                        tile_size: 32,
                        tile_spp: vec![8, 16, 24, 32],
                    }),
                }),
                group: "shot".into(),
            }),
            unit_id: 7,
            tile,
            sample_start: start,
            sample_end: end,
        }
    }

    #[test]
    fn a_good_unit_converts() {
        let u = unit_from_proto(unit(Some(crate::Tile { x0: 32, y0: 64, width: 32, height: 16 }), 4, 8)).unwrap();
        assert_eq!(u.key, UnitKey { job_id: "j1".into(), unit_id: 7 });
        assert_eq!(u.tile, Tile::new(32, 64, 32, 16));
        assert_eq!(u.samples, SampleRange::new(4, 8));
        assert_eq!(u.job.integrator, Integrator::Normals);
        assert_eq!(
            u.job.overrides,
            Overrides {
                spp: Some(16),
                width: None,
                height: Some(120),
                max_depth: Some(4),
                seed: None,
                up: tracer::scene::UpAxis::Z,
                clamp: Some(0.5),
                aovs: true,
                noise: Some(0.02),
                time_budget: Some(std::time::Duration::from_secs(90)),
            }
        );
    }

    #[test]
    fn malformed_units_are_errors_not_panics() {
        let t = |x0, y0, width, height| Some(crate::Tile { x0, y0, width, height });
        for (tile, s, e) in [
            (None, 0, 1),
            (t(0, 0, 0, 8), 0, 1),
            (t(0, 0, 8, 0), 0, 1),
            (t(0, 0, 5000, 8), 0, 1),
            (t(0, 0, 4096, 4096), 0, 1), // result too large for one message
            (t(u32::MAX, 0, 8, 8), 0, 1),
            (t(0, u32::MAX - 2, 8, 8), 0, 1),
            (t(0, 0, 8, 8), 5, 5),
            (t(0, 0, 8, 8), 9, 3),
            (t(0, 0, 8, 8), 0, (1 << 20) + 1),
        ] {
            assert!(unit_from_proto(unit(tile, s, e)).is_err(), "{tile:?} [{s}, {e})");
        }
        let mut u = unit(t(0, 0, 8, 8), 0, 1);
        u.job.as_mut().unwrap().settings.as_mut().unwrap().integrator = "bogus".into();
        assert!(unit_from_proto(u).unwrap_err().contains("bogus"));
        let mut u = unit(t(0, 0, 8, 8), 0, 1);
        u.job = None;
        assert!(unit_from_proto(u).is_err());
        let mut u = unit(t(0, 0, 8, 8), 0, 1);
        u.job.as_mut().unwrap().scene = None;
        assert!(unit_from_proto(u).is_err());
    }

    /// A job survives its trip through bytes (a checkpoint) and the wire unchanged.
    #[test]
    fn a_job_spec_round_trips() {
        let job = job_from_proto(unit(None, 0, 1).job.unwrap()).unwrap();
        assert_eq!((job.tile_size, job.batch_spp), (Some(32), Some(4)));
        assert_eq!(job_from_bytes(&job_to_bytes(&job)).unwrap(), job);
        assert_eq!(job_from_proto(job_to_proto(&job)).unwrap(), job);
        assert_eq!(job.spp_map.as_ref().map(|m| (m.width, m.height, m.tile_spp.len())), Some((64, 40, 4)));
        assert_eq!(job.group.as_deref(), Some("shot"));
        let plain = JobSpec {
            tile_size: None,
            batch_spp: None,
            overrides: Overrides::default(),
            spp_map: None,
            group: None,
            ..job
        };
        assert_eq!(job_from_bytes(&job_to_bytes(&plain)).unwrap(), plain);
        assert!(job_from_bytes(b"\xff\xff").is_err());
    }

    /// A group's name is bounded and printable.
    #[test]
    fn a_bad_group_name_is_refused() {
        for bad in [" shot".to_string(), "a\nb".into(), "x".repeat(MAX_GROUP_CHARS + 1)] {
            let mut j = unit(None, 0, 1).job.unwrap();
            j.group = bad.clone();
            assert!(job_from_proto(j).unwrap_err().contains("group"), "{bad:?}");
        }
    }

    /// A map whose tiles do not fit its size is refused before it is used.
    #[test]
    fn a_malformed_spp_map_is_refused() {
        for (w, h, tile, n) in [(64, 40, 32, 3), (64, 40, 32, 5), (0, 40, 32, 0), (64, 40, 0, 4), (70000, 1, 70000, 1)]
        {
            let mut u = unit(None, 0, 1).job.unwrap();
            u.settings.as_mut().unwrap().spp_map =
                Some(crate::SppMap { width: w, height: h, tile_size: tile, tile_spp: vec![1; n] });
            let err = job_from_proto(u).unwrap_err();
            assert!(err.contains("spp map"), "{w}×{h}/{tile} with {n}: {err}");
        }
    }

    #[test]
    fn empty_settings_mean_the_scene_as_is() {
        let (o, i) = settings_from_proto(Some(&crate::RenderSettings::default())).unwrap();
        assert_eq!(o, Overrides::default());
        assert_eq!(i, Integrator::Path);
        assert_eq!(settings_from_proto(None).unwrap(), (Overrides::default(), Integrator::Path));
    }

    #[test]
    fn a_result_converts_to_the_wire_message() {
        let tile = Tile::new(8, 16, 2, 1);
        let mut acc = Accumulation::new(tile);
        acc.add_sample(0, glam::Vec3::new(1.0, 0.5, 0.25));
        acc.add_sample(1, glam::Vec3::new(f32::NAN, 0.0, 0.0));
        acc.add_sample(1, glam::Vec3::new(2.0, 2.0, 2.0));
        let key = UnitKey { job_id: "job-9".into(), unit_id: 42 };
        let m = result_to_proto(3, &key, SampleRange::new(10, 12), &acc, 1234, 0.5);
        assert_eq!(m.worker_id, 3);
        assert_eq!(m.job_id, "job-9");
        assert_eq!(m.unit_id, 42);
        assert_eq!(m.tile, Some(crate::Tile { x0: 8, y0: 16, width: 2, height: 1 }));
        assert_eq!((m.sample_start, m.sample_end), (10, 12));
        assert_eq!(m.sums.len(), 2 * 48);
        assert_eq!(Accumulation::sums_from_bytes(&m.sums).unwrap(), acc.sums);
        assert_eq!(m.counts, vec![1, 2]);
        assert_eq!(m.nonfinite, 1);
        assert_eq!(m.rays, 1234);
        assert_eq!(m.render_seconds, 0.5);
        // Radiance 1.0 is 2^32 in fixed point, little-endian.
        assert_eq!(i128::from_le_bytes(m.sums[0..16].try_into().unwrap()), 1i128 << 32);
        assert!(m.layers.is_empty(), "no layers unless the job keeps them");

        // With layers: they travel, and come back as they were.
        let mut layered = Accumulation::with_layers(tile, true);
        let hit = tracer::film::FirstHit { albedo: glam::Vec3::ONE, normal: glam::Vec3::Y, depth: Some(3.5) };
        layered.add_sample_at(0, glam::Vec3::new(1.0, 0.5, 0.25), &hit);
        layered.add_sample_at(1, glam::Vec3::splat(2.0), &tracer::film::FirstHit::default());
        let m = result_to_proto(3, &key, SampleRange::new(10, 11), &layered, 1, 0.5);
        assert_eq!(m.layers.len(), 2 * tracer::film::LAYER_BYTES);
        let back = result_from_proto(m).unwrap().result;
        assert_eq!(back.layers, layered.layers);
    }

    /// What a worker sends is checked once, here, for the coordinator too: a bad tile, an
    /// empty sample range or sums that are not whole pixels name the unit.
    #[test]
    fn results_from_the_wire_are_checked_for_shape() {
        let acc = Accumulation::new(Tile::new(0, 0, 2, 1));
        let good =
            result_to_proto(9, &UnitKey { job_id: "job-1".into(), unit_id: 3 }, SampleRange::new(0, 4), &acc, 5, 0.25);
        let r = result_from_proto(good.clone()).unwrap();
        assert_eq!(
            (r.worker_id, r.result.unit, r.result.tile, r.result.samples, r.result.sums.len()),
            (9, 3, acc.tile, SampleRange::new(0, 4), 2)
        );
        let bad = [
            crate::UnitResult { tile: None, ..good.clone() },
            crate::UnitResult { tile: Some(crate::Tile { x0: u32::MAX, y0: 0, width: 2, height: 1 }), ..good.clone() },
            crate::UnitResult { sample_start: 4, sample_end: 4, ..good.clone() },
            crate::UnitResult { sums: vec![0; 47], ..good.clone() },
            crate::UnitResult { layers: vec![0; tracer::film::LAYER_BYTES + 1], ..good.clone() },
            crate::UnitResult { render_seconds: -1.0, ..good.clone() },
            crate::UnitResult { render_seconds: f64::NAN, ..good.clone() },
            crate::UnitResult { render_seconds: 1e300, ..good.clone() },
        ];
        for b in bad {
            let e = result_from_proto(b).unwrap_err();
            assert!(e.starts_with("unit job-1/3: "), "{e}");
        }
    }

    #[test]
    fn echoes_of_input_are_bounded() {
        let huge = "x".repeat(10 << 20);
        let settings = crate::RenderSettings { integrator: huge.clone(), ..Default::default() };
        let e = settings_from_proto(Some(&settings)).unwrap_err();
        assert!(
            e.len() < 300 && e.contains("unknown integrator 'xxx") && e.contains("…'"),
            "{}",
            &e[..e.len().min(300)]
        );
        assert_eq!(quote("path"), "'path'");
        assert_eq!(bounded(huge).chars().count(), MAX_ERROR_CHARS + 1);
    }
}
