//! Shading normals from textures, as Blender's Normal Map (tangent space) and Bump nodes
//! define them in Cycles, and the correction Cycles applies to every perturbed normal so
//! that a specular reflection about it stays above the surface.

use glam::Vec3;

/// How strongly a material's normal and bump maps tilt its normal (Blender's inputs).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Bumps {
    /// The Normal Map node's Strength (MTL `norm -bm`).
    pub normal_strength: f32,
    /// The Bump node's Strength (MTL `bump -bm`) and Distance.
    pub bump_strength: f32,
    pub bump_distance: f32,
}

impl Default for Bumps {
    fn default() -> Self {
        Self { normal_strength: 1.0, bump_strength: 1.0, bump_distance: 1.0 }
    }
}

/// The surface at a point as the maps need it: its texture-coordinate derivatives, and
/// the MikkTSpace tangent where the mesh has one. All on the front face's side.
#[derive(Clone, Copy, Debug)]
pub struct UvFrame {
    /// ∂p/∂u and ∂p/∂v (zero where the texture coordinates are degenerate).
    pub dpdu: Vec3,
    pub dpdv: Vec3,
    /// The interpolated (unnormalized) tangent and the bitangent's sign, with the
    /// unnormalized interpolated normal they were made with: MikkTSpace's convention is
    /// to build the frame from these without normalizing first.
    pub tangent: Option<(Vec3, f32, Vec3)>,
}

/// A tangent-space normal map's texel `rgb` (non-colour data) applied to the frame, with
/// Blender's strength: x and y scaled, z blended towards 1. `None` without a tangent.
pub fn normal_map(rgb: Vec3, strength: f32, frame: &UvFrame) -> Option<Vec3> {
    let (t, sign, n) = frame.tangent?;
    let c = 2.0 * (rgb - Vec3::splat(0.5));
    let s = strength.max(0.0);
    let c = Vec3::new(c.x * strength, c.y * strength, 1.0 + (c.z - 1.0) * s.min(1.0));
    let b = sign * n.cross(t);
    let out = (c.x * t + c.y * b + c.z * n).normalize_or_zero();
    (out != Vec3::ZERO && out.is_finite()).then_some(out)
}

/// The Bump node: the normal `n` tilted by a height field with texture-space gradient
/// `(dh/du, dh/dv)`, scaled by `distance`, then blended with `n` by `strength`. A
/// negative strength is Blender's Invert: the height turned upside down.
///
/// Cycles differentiates the height over screen-space offsets dx, dy; the construction
/// `|det| n − distance · sign(det) · (h_x R_x + h_y R_y)` with `R_x = ∂p/∂y × n`,
/// `R_y = n × ∂p/∂x` is the same for any parametrization, so the texture's own (u, v)
/// serve as well and need no ray differentials.
pub fn bump(n: Vec3, grad: glam::Vec2, distance: f32, strength: f32, frame: &UvFrame) -> Vec3 {
    let (distance, strength) = if strength < 0.0 { (-distance, -strength) } else { (distance, strength) };
    let (rx, ry) = (frame.dpdv.cross(n), n.cross(frame.dpdu));
    let det = frame.dpdu.dot(rx);
    let surfgrad = grad.x * rx + grad.y * ry;
    let tilted = (det.abs() * n - distance * det.signum() * surfgrad).normalize_or_zero();
    if tilted == Vec3::ZERO || !tilted.is_finite() || det == 0.0 {
        return n;
    }
    (strength * tilted + (1.0 - strength) * n).normalize_or_zero()
}

/// Cycles' `ensure_valid_specular_reflection`: if the mirror reflection of `wo` about
/// `n` dips below the surface `ng` (both on `wo`'s side), `n` is turned towards `ng`
/// just enough that the reflection leaves at a height of min(0.9 · wo·ng, 0.01).
pub fn ensure_valid_specular_reflection(ng: Vec3, wo: Vec3, n: Vec3) -> Vec3 {
    let r = 2.0 * n.dot(wo) * n - wo;
    let iz = wo.dot(ng);
    let threshold = (0.9 * iz).min(0.01);
    if ng.dot(r) >= threshold {
        return n;
    }
    // Ng is the z axis; x is n's part orthogonal to it.
    let x = (n - n.dot(ng) * ng).try_normalize().unwrap_or(n);
    let ix = wo.dot(x);
    let a = ix * ix + iz * iz;
    let b = 2.0 * (a + iz * threshold);
    let c = (threshold + iz) * (threshold + iz);
    let root = (b * b - 4.0 * a * c).max(0.0).sqrt();
    let nz2 = if ix < 0.0 { 0.25 * (b + root) / a } else { 0.25 * (b - root) / a };
    let nx = (1.0 - nz2).max(0.0).sqrt();
    let nz = nz2.max(0.0).sqrt();
    (nx * x + nz * ng).normalize_or_zero()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;

    fn flat() -> UvFrame {
        UvFrame { dpdu: Vec3::X, dpdv: Vec3::Y, tangent: Some((Vec3::X, 1.0, Vec3::Z)) }
    }

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).length() < 1e-5
    }

    #[test]
    fn a_flat_normal_map_texel_keeps_the_normal() {
        let n = normal_map(Vec3::new(0.5, 0.5, 1.0), 1.0, &flat()).unwrap();
        assert!(close(n, Vec3::Z), "{n}");
    }

    #[test]
    fn normal_map_axes_follow_the_tangent_and_the_bitangent_sign() {
        // A texel leaning towards +x (red) tilts towards the tangent.
        let rgb = Vec3::new(0.5 + 0.5 * 0.6, 0.5, 0.5 + 0.5 * 0.8);
        assert!(close(normal_map(rgb, 1.0, &flat()).unwrap(), Vec3::new(0.6, 0.0, 0.8)));
        // Green tilts towards the bitangent, n × t = +y, or −y with sign −1.
        let g = Vec3::new(0.5, 0.5 + 0.5 * 0.6, 0.5 + 0.5 * 0.8);
        assert!(close(normal_map(g, 1.0, &flat()).unwrap(), Vec3::new(0.0, 0.6, 0.8)));
        let mirrored = UvFrame { tangent: Some((Vec3::X, -1.0, Vec3::Z)), ..flat() };
        assert!(close(normal_map(g, 1.0, &mirrored).unwrap(), Vec3::new(0.0, -0.6, 0.8)));
        // Strength 0 is the unperturbed normal; no tangent, no normal map.
        assert!(close(normal_map(rgb, 0.0, &flat()).unwrap(), Vec3::Z));
        assert_eq!(normal_map(rgb, 1.0, &UvFrame { tangent: None, ..flat() }), None);
    }

    #[test]
    fn bump_tilts_against_the_slope_and_scales_with_distance() {
        let f = flat();
        // Height rising along +u: the normal leans towards −x, as tan θ = slope · distance.
        let n = bump(Vec3::Z, Vec2::new(0.5, 0.0), 1.0, 1.0, &f);
        assert!(close(n, Vec3::new(-0.5, 0.0, 1.0).normalize()), "{n}");
        let n2 = bump(Vec3::Z, Vec2::new(0.5, 0.0), 2.0, 1.0, &f);
        assert!(close(n2, Vec3::new(-1.0, 0.0, 1.0).normalize()), "{n2}");
        // The same surface parametrized at twice the scale (u' = u/2) gives the same normal.
        let stretched = UvFrame { dpdu: 2.0 * Vec3::X, ..f };
        assert!(close(bump(Vec3::Z, Vec2::new(1.0, 0.0), 1.0, 1.0, &stretched), n));
        // Mirrored texture coordinates (∂p/∂v = −y) keep the geometric meaning.
        let mirrored = UvFrame { dpdv: -Vec3::Y, ..f };
        let up = bump(Vec3::Z, Vec2::new(0.0, 0.5), 1.0, 1.0, &mirrored);
        assert!(close(up, Vec3::new(0.0, 0.5, 1.0).normalize()), "{up}");
        // A negative strength inverts the height.
        let inverted = bump(Vec3::Z, Vec2::new(0.5, 0.0), 1.0, -1.0, &f);
        assert!(close(inverted, Vec3::new(0.5, 0.0, 1.0).normalize()), "{inverted}");
        // Strength 0 and a flat height leave the normal alone.
        assert!(close(bump(Vec3::Z, Vec2::new(0.5, 0.0), 1.0, 0.0, &f), Vec3::Z));
        assert!(close(bump(Vec3::Z, Vec2::ZERO, 1.0, 1.0, &f), Vec3::Z));
    }

    #[test]
    fn a_reflection_below_the_surface_is_lifted_to_the_threshold() {
        let ng = Vec3::Z;
        let wo = Vec3::new(0.8, 0.0, 0.6);
        // A normal tilted far away from wo reflects it below the surface.
        let n = Vec3::new(-0.7, 0.0, 0.714_142_8).normalize();
        assert!((2.0 * n.dot(wo) * n - wo).z < 0.0);
        let fixed = ensure_valid_specular_reflection(ng, wo, n);
        let r = 2.0 * fixed.dot(wo) * fixed - wo;
        assert!((r.z - 0.01).abs() < 1e-4, "reflection height {}", r.z);
        assert!((fixed.length() - 1.0).abs() < 1e-5);
        // A normal whose reflection is fine is kept.
        let ok = Vec3::new(0.1, 0.0, 1.0).normalize();
        assert_eq!(ensure_valid_specular_reflection(ng, wo, ok), ok);
    }
}
