//! Command-line and job overrides of a scene's own camera and render settings, applied
//! identically by every process that renders the scene.

use super::{RenderSettings, Scene};
use crate::camera::Camera;

#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Overrides {
    pub spp: Option<u32>,
    /// Width alone keeps the aspect ratio; so does height alone.
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub max_depth: Option<i32>,
    pub seed: Option<u64>,
    /// `--clamp`: see [`RenderSettings::clamp`].
    pub clamp: Option<f32>,
    /// `--aovs`: keep the AOV layers even where the scene does not ask for them.
    pub aovs: bool,
    /// `--adaptive` / `--noise`: see [`RenderSettings::noise`].
    pub noise: Option<f32>,
    /// `--time-budget`: the farm stops leasing units once this long has passed since
    /// the job started, finishes the ones out, and ends the job with what it has.
    /// Scheduling only: not a scene setting, and no sample changes.
    pub time_budget: Option<std::time::Duration>,
    /// The up axis of a bare `.obj` (used when loading: [`super::load_scene_up`]).
    pub up: super::UpAxis,
}

impl Overrides {
    pub fn apply(&self, scene: &mut Scene) -> Result<(), String> {
        self.apply_to(&mut scene.camera, &mut scene.settings)
    }

    /// [`Overrides::apply`] to a camera and settings.
    pub fn apply_to(&self, cam: &mut Camera, settings: &mut RenderSettings) -> Result<(), String> {
        let aspect = cam.width as f64 / cam.height as f64;
        let (w, h) = match (self.width, self.height) {
            (Some(w), Some(h)) => (w, h),
            (Some(w), None) => (w, ((w as f64 / aspect).round() as u32).max(1)),
            (None, Some(h)) => (((h as f64 * aspect).round() as u32).max(1), h),
            (None, None) => (cam.width, cam.height),
        };
        if w == 0 || h == 0 || w > 65536 || h > 65536 {
            return Err(format!("image size {w}×{h} must be between 1 and 65536 on each side"));
        }
        (cam.width, cam.height) = (w, h);
        if let Some(spp) = self.spp {
            if spp == 0 {
                return Err("spp must be at least 1".into());
            }
            settings.spp = spp;
        }
        if let Some(d) = self.max_depth {
            if d != -1 && d < 1 {
                return Err("max_depth must be -1 (unlimited) or ≥ 1".into());
            }
            settings.max_depth = d;
        }
        if let Some(s) = self.seed {
            settings.seed = s;
        }
        if let Some(c) = self.clamp {
            super::load::check_clamp(c).map_err(|e| format!("clamp {e}"))?;
            settings.clamp = Some(c);
        }
        settings.aovs |= self.aovs;
        if let Some(n) = self.noise {
            super::load::check_noise(n).map_err(|e| format!("noise {e}"))?;
            settings.noise = Some(n);
        }
        // Adaptive sampling judges tiles by the layers' squared sums.
        settings.aovs |= settings.noise.is_some();
        Ok(())
    }
}
