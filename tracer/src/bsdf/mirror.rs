//! Perfect specular reflection tinted by `ks` (a delta lobe: eval and pdf are 0).

use super::{BsdfSample, reflect};
use glam::Vec3;

#[derive(Clone, Copy, Debug)]
pub struct SpecularReflection {
    pub ks: Vec3,
}

impl SpecularReflection {
    /// The mirror direction, chosen with probability 1: f |cos θi| / pdf = ks.
    #[inline]
    pub fn sample(&self, wo: Vec3) -> Option<BsdfSample> {
        if wo.z == 0.0 || !wo.is_finite() {
            return None;
        }
        Some(BsdfSample { wi: reflect(wo), weight: self.ks, pdf: 1.0, delta: true })
    }
}
