//! What to render: the job options `render` and `submit` share, and their parsers.

use std::path::PathBuf;

use clap::Args;
use proto::domain::JobSpec;
use tracer::integrator::Integrator;

use crate::farm::assets::AssetRef;

/// Options shared by `render` and `submit`: what to render.
#[derive(Args, Clone, Debug)]
pub struct JobArgs {
    /// Samples per pixel [default: the scene's [render] spp].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub spp: Option<u32>,
    /// Image width in pixels [default: the scene's; the height follows the aspect ratio
    /// unless --height is given too].
    #[arg(long, value_name = "PIXELS", value_parser = clap::value_parser!(u32).range(1..=65_536))]
    pub width: Option<u32>,
    /// Image height in pixels [default: the scene's].
    #[arg(long, value_name = "PIXELS", value_parser = clap::value_parser!(u32).range(1..=65_536))]
    pub height: Option<u32>,
    /// Override the scene's max_depth (path segments; -1 = unlimited).
    #[arg(long, value_name = "N", allow_hyphen_values = true)]
    pub max_depth: Option<i32>,
    /// Override the scene's seed.
    #[arg(long, value_name = "N")]
    pub seed: Option<u64>,
    /// Firefly control (biased, off by default): a sample whose brightest channel exceeds
    /// L is scaled down to L, keeping its colour. The EXR header records the limit
    /// (`tilefarm/clamp`). Overrides the scene's [render] clamp.
    #[arg(long, value_name = "L", value_parser = clamp_limit, allow_hyphen_values = true)]
    pub clamp: Option<f32>,
    /// Also write the AOV layers into the EXR, from the same samples: albedo.R/G/B,
    /// N.X/Y/Z (shading normal), Z (distance to the first hit) and variance.R/G/B (of
    /// each pixel's value), beside R/G/B/A and samples. Costs 176 bytes of memory a pixel.
    /// Also set by the scene's [render] aovs = true.
    #[arg(long)]
    pub aovs: bool,
    /// Render each tile to the samples per pixel a previous render's EXR reached (its
    /// `samples` channel): after --time-budget or --adaptive, the same bits again. The
    /// image is that render's size; --tile must be its tile size.
    #[arg(long, value_name = "FILE.exr", conflicts_with_all = ["adaptive", "noise", "spp"])]
    pub spp_map: Option<PathBuf>,
    /// Adaptive sampling: each tile renders batch after batch until its noise is at most
    /// --noise, or it reaches --spp. Decided from the merged image alone, so the result
    /// is the same bits for any number of workers; the EXR's `samples` channel shows
    /// where the samples went. Implies --aovs.
    #[arg(long)]
    pub adaptive: bool,
    /// Adaptive sampling's target: a tile's RMS relative error (per pixel, the root of
    /// its estimated relMSE); judged from 64 spp on (implies --adaptive) [default with
    /// --adaptive: 0.01].
    #[arg(long, value_name = "E", value_parser = noise_target)]
    pub noise: Option<f32>,
    /// Render for this long, in whole batches: no unit is leased once it has passed
    /// since the job started, the ones out finish, and the image holds what was done,
    /// every tile within one batch of the others (its `samples` channel shows the spp
    /// each reached). A duration such as 90s, 10m, 1h or 1h30m; --spp stays the most.
    #[arg(long, value_name = "DURATION", value_parser = duration, allow_hyphen_values = true)]
    pub time_budget: Option<std::time::Duration>,
    /// path (default: NEE + MIS); path-light or path-bsdf (one strategy only, to compare
    /// estimators); or an AOV: normals, albedo, depth.
    #[arg(long, default_value = "path")]
    pub integrator: Integrator,
    /// Tile size of a unit of work, in pixels.
    #[arg(long, value_name = "PIXELS", default_value_t = 64, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub tile: u32,
    /// Samples per pixel in one unit of work. Every tile gets its first batch before any
    /// tile gets its second, so a preview refines evenly.
    #[arg(long, value_name = "N", default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..))]
    pub batch_spp: u32,
    /// The up axis of a bare .obj model: y or z (many CAD and robotics models are Z-up). In
    /// a scene file, set `up = "z"` in a [[mesh]] table instead.
    #[arg(long, value_name = "AXIS", default_value = "y")]
    pub up: tracer::scene::UpAxis,
}

/// A duration as people write one (humantime's: 90s, 10m, 1h, 1h30m); a bare number
/// is seconds. Zero is refused: a budget of nothing renders nothing.
pub fn duration(s: &str) -> Result<std::time::Duration, String> {
    let d = match s.trim().parse::<u64>() {
        Ok(secs) => std::time::Duration::from_secs(secs),
        Err(_) => humantime::parse_duration(s.trim())
            .map_err(|e| format!("{s:?} is not a duration such as 90s, 10m, 1h or 1h30m ({e})"))?,
    };
    if d.is_zero() {
        return Err("a time budget must be longer than zero".into());
    }
    Ok(d)
}

/// `--noise`'s value: a finite number above zero.
fn noise_target(s: &str) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    tracer::scene::check_noise(v).map(|()| v)
}

/// `--clamp`'s value: a finite number above zero.
fn clamp_limit(s: &str) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|_| format!("{s:?} is not a number"))?;
    tracer::scene::check_clamp(v).map(|()| v)
}

impl JobArgs {
    /// The job these options ask for, of a scene and its files.
    pub fn spec(&self, scene: AssetRef, assets: Vec<AssetRef>) -> JobSpec {
        JobSpec {
            job_id: String::new(),
            scene,
            assets,
            overrides: tracer::scene::Overrides {
                spp: self.spp,
                width: self.width,
                height: self.height,
                max_depth: self.max_depth,
                seed: self.seed,
                clamp: self.clamp,
                // Adaptive sampling judges by the layers' squared sums: said on the wire
                // too, so that every worker keeps them.
                aovs: self.aovs || self.adaptive || self.noise.is_some(),
                noise: self.noise.or(self.adaptive.then_some(crate::farm::job::DEFAULT_NOISE)),
                time_budget: self.time_budget,
                up: self.up,
            },
            integrator: self.integrator,
            tile_size: Some(self.tile),
            batch_spp: Some(self.batch_spp),
            spp_map: None,
            group: None,
        }
    }

    /// [`JobArgs::spec`] with the `--spp-map` file read, if one was given.
    pub fn spec_with_map(&self, scene: AssetRef, assets: Vec<AssetRef>) -> anyhow::Result<JobSpec> {
        let mut spec = self.spec(scene, assets);
        if let Some(path) = &self.spp_map {
            let map = super::spp_map::read(path, self.tile)?;
            // The map's own size unless another is asked for (and then refused).
            if self.width.is_none() && self.height.is_none() {
                (spec.overrides.width, spec.overrides.height) = (Some(map.width), Some(map.height));
            }
            spec.spp_map = Some(map);
        }
        Ok(spec)
    }
}
