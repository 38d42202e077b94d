//! Cycles' shadowing of diffuse lobes whose normal a normal or bump map tilted (Chiang,
//! Li and Burley 2019, "Taming the Shadow Terminator"). A BSDF-level term: it multiplies
//! a diffuse or sheen lobe's value, not its pdf.

use glam::Vec3;

/// Cycles' shadowing of a diffuse lobe whose normal `bumped` a map tilted away from the
/// surface's own shading normal `smooth` (Chiang, Li and Burley 2019, "Taming the Shadow
/// Terminator"): light `wi` that the tilted normal faces but the surface barely does
/// is faded out smoothly instead of lighting the terminator. Multiplies the BSDF, not
/// its pdf.
pub fn bump_shadowing(smooth: Vec3, bumped: Vec3, wi: Vec3) -> f32 {
    let cos_ni = bumped.dot(wi);
    let ng = if cos_ni < 0.0 { -smooth } else { smooth };
    let denom = cos_ni * ng.dot(bumped);
    let g = if denom != 0.0 { ng.dot(wi) / denom } else { 0.0 };
    if g >= 1.0 {
        return 1.0;
    }
    if !(g >= 0.0) {
        return 0.0;
    }
    let g2 = g * g;
    -g2 * g + g2 + g
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bump_shadowing_fades_light_the_surface_itself_barely_faces() {
        let smooth = Vec3::Z;
        let bumped = Vec3::new(0.5, 0.0, 0.866_025_4);
        // Light the surface faces at least as much as the tilted normal does: untouched.
        assert_eq!(bump_shadowing(smooth, bumped, Vec3::Z), 1.0);
        // Grazing light from the side the normal leans to: faded, and 0 below the surface.
        let grazing = Vec3::new(0.99, 0.0, 0.141).normalize();
        let g = grazing.z / (bumped.dot(grazing) * bumped.z);
        let s = bump_shadowing(smooth, bumped, grazing);
        assert!((s - (-g * g * g + g * g + g)).abs() < 1e-6 && s > 0.0 && s < 1.0, "{s}");
        assert_eq!(bump_shadowing(smooth, bumped, Vec3::new(1.0, 0.0, -0.05).normalize()), 0.0);
        // No tilt, no shadowing.
        assert_eq!(bump_shadowing(smooth, smooth, grazing), 1.0);
    }
}
