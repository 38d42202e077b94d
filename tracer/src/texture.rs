//! Image textures, decoded by the `image` crate and stored as linear RGB, with what
//! places them on a surface: MTL's texture options (`-s`, `-o`, `-clamp`), and Blender's
//! Mapping node (scale, rotation, offset) and Image Texture interpolation.

use glam::{Vec2, Vec3};

/// How texture coordinates map onto an image: `R(uv · scale) + offset` (MTL's `-s` and
/// `-o`; Blender's Mapping node of type Point, R the rotation by `rotation` (cos, sin)
/// counter-clockwise), then wrapped around, or with `clamp` (MTL's `-clamp on`) held to
/// the edge; looked up bilinearly, or the closest texel with `closest`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TexMap {
    pub scale: Vec2,
    pub offset: Vec2,
    pub rotation: Vec2,
    pub clamp: bool,
    pub closest: bool,
}

impl Default for TexMap {
    fn default() -> Self {
        Self { scale: Vec2::ONE, offset: Vec2::ZERO, rotation: Vec2::X, clamp: false, closest: false }
    }
}

impl TexMap {
    /// Texture coordinates after scale, rotation and offset.
    #[inline]
    pub fn apply(&self, uv: Vec2) -> Vec2 {
        let s = uv * self.scale;
        let (c, n) = (self.rotation.x, self.rotation.y);
        Vec2::new(c * s.x - n * s.y, n * s.x + c * s.y) + self.offset
    }
}

/// The luminance of linear Rec. 709 RGB: how a colour feeds a scalar input (Blender's
/// implicit colour-to-float conversion).
#[inline]
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    /// Linear RGB, row 0 at the top of the image.
    pub texels: Vec<Vec3>,
    pub map: TexMap,
}

impl Texture {
    /// Where mapped coordinates `uv` fall in the image, in texels (x to the right, y down
    /// from the top row; texel centres at integers), or None if not finite.
    #[inline]
    fn texel_position(&self, uv: Vec2) -> Option<(f32, f32)> {
        let x = uv.x * self.width as f32 - 0.5;
        let y = (1.0 - uv.y) * self.height as f32 - 0.5;
        (x.is_finite() && y.is_finite()).then_some((x, y))
    }

    /// Texel (ix, iy), the image repeating or, with `clamp`, its edge extending.
    #[inline]
    fn texel(&self, ix: i64, iy: i64) -> Vec3 {
        let (w, h) = (self.width as i64, self.height as i64);
        let wrap = |i: i64, n: i64| if self.map.clamp { i.clamp(0, n - 1) } else { i.rem_euclid(n) };
        self.texels[(wrap(iy, h) * w + wrap(ix, w)) as usize]
    }

    /// Bilinear lookup. `uv` follows OBJ's convention: v = 0 is the bottom row of the
    /// image; outside [0, 1] the image repeats, or with `clamp` its edge texels extend.
    pub fn sample(&self, uv: Vec2) -> Vec3 {
        let (w, h) = (self.width as i64, self.height as i64);
        if w == 0 || h == 0 {
            return Vec3::ZERO;
        }
        let mut uv = self.map.apply(uv);
        if self.map.clamp {
            uv = uv.clamp(Vec2::ZERO, Vec2::ONE);
        }
        let Some((x, y)) = self.texel_position(uv) else {
            return self.texels[0];
        };
        let texel = |ix: i64, iy: i64| self.texel(ix, iy);
        if self.map.closest {
            // The texel the point lies in (x + 0.5 is the position in texels).
            return texel((x + 0.5).floor() as i64, (y + 0.5).floor() as i64);
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (ix, iy) = (x0 as i64, y0 as i64);
        let top = texel(ix, iy) * (1.0 - fx) + texel(ix + 1, iy) * fx;
        let bottom = texel(ix, iy + 1) * (1.0 - fx) + texel(ix + 1, iy + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// The gradient of the luminance over `uv` (a height map's slope, for bump mapping):
    /// the derivative of the bilinear interpolation itself, constant within a cell of four
    /// texels (as Cycles' tiny finite differences see it); zero with `closest`.
    pub fn luminance_gradient(&self, uv: Vec2) -> Vec2 {
        let (w, h) = (self.width as i64, self.height as i64);
        if w == 0 || h == 0 || self.map.closest {
            return Vec2::ZERO;
        }
        let mapped = self.map.apply(uv);
        if self.map.clamp && (mapped.cmplt(Vec2::ZERO).any() || mapped.cmpgt(Vec2::ONE).any()) {
            return Vec2::ZERO;
        }
        let Some((x, y)) = self.texel_position(mapped) else {
            return Vec2::ZERO;
        };
        let l = |ix: i64, iy: i64| luminance(self.texel(ix, iy));
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (ix, iy) = (x0 as i64, y0 as i64);
        let (t00, t10, t01, t11) = (l(ix, iy), l(ix + 1, iy), l(ix, iy + 1), l(ix + 1, iy + 1));
        let d_dx = (1.0 - fy) * (t10 - t00) + fy * (t11 - t01);
        let d_dy = (1.0 - fx) * (t01 - t00) + fx * (t11 - t10);
        // Over the mapped coordinates (y runs down the image), then back through the
        // mapping's linear part R·S (transposed).
        let g = Vec2::new(d_dx * self.width as f32, -d_dy * self.height as f32);
        let (c, s) = (self.map.rotation.x, self.map.rotation.y);
        let (sx, sy) = (self.map.scale.x, self.map.scale.y);
        let grad = Vec2::new(sx * (c * g.x + s * g.y), sy * (-s * g.x + c * g.y));
        if grad.is_finite() { grad } else { Vec2::ZERO }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2×1 image: red on the left, green on the right.
    fn red_green(map: TexMap) -> Texture {
        Texture { width: 2, height: 1, texels: vec![Vec3::X, Vec3::Y], map }
    }

    #[test]
    fn scale_and_offset_move_the_image() {
        let plain = red_green(TexMap::default());
        assert_eq!(plain.sample(Vec2::new(0.25, 0.5)), Vec3::X);
        assert_eq!(plain.sample(Vec2::new(1.25, 0.5)), Vec3::X, "repeats");
        let offset = red_green(TexMap { offset: Vec2::new(0.5, 0.0), ..Default::default() });
        assert_eq!(offset.sample(Vec2::new(0.25, 0.5)), Vec3::Y);
        let scaled = red_green(TexMap { scale: Vec2::new(2.0, 1.0), ..Default::default() });
        assert_eq!(scaled.sample(Vec2::new(0.125, 0.5)), Vec3::X);
        assert_eq!(scaled.sample(Vec2::new(0.375, 0.5)), Vec3::Y);
    }

    #[test]
    fn rotation_turns_the_coordinates_counter_clockwise_after_scaling() {
        let quarter = TexMap { scale: Vec2::new(2.0, 1.0), rotation: Vec2::new(0.0, 1.0), ..Default::default() };
        let p = quarter.apply(Vec2::new(0.25, 0.1));
        assert!((p - Vec2::new(-0.1, 0.5)).length() < 1e-6, "{p}");
    }

    #[test]
    fn the_luminance_gradient_is_the_slope_of_a_ramp() {
        // A horizontal ramp 0, 1/8, ..., 7/8 over 8 texels: slope 1 per unit of u (inside
        // the image; the wrap at the edges is a jump).
        let texels = (0..8).map(|i| Vec3::splat(i as f32 / 8.0)).collect();
        let ramp = Texture { width: 8, height: 1, texels, map: TexMap::default() };
        let g = ramp.luminance_gradient(Vec2::new(0.5, 0.5));
        assert!((g - Vec2::new(1.0, 0.0)).length() < 1e-4, "{g}");
        let scaled = Texture { map: TexMap { scale: Vec2::splat(2.0), ..Default::default() }, ..ramp.clone() };
        let g2 = scaled.luminance_gradient(Vec2::new(0.25, 0.5));
        assert!((g2 - Vec2::new(2.0, 0.0)).length() < 1e-3, "chain rule through the mapping: {g2}");
        // A quarter turn: the ramp now rises along v (mapped x = −v·… after rotation).
        let turned = Texture { map: TexMap { rotation: Vec2::new(0.0, 1.0), ..Default::default() }, ..ramp.clone() };
        let uv = Vec2::new(0.5, -0.5);
        let g3 = turned.luminance_gradient(uv);
        let d = 1e-3;
        let fd = Vec2::new(
            luminance(turned.sample(uv + Vec2::new(d, 0.0))) - luminance(turned.sample(uv - Vec2::new(d, 0.0))),
            luminance(turned.sample(uv + Vec2::new(0.0, d))) - luminance(turned.sample(uv - Vec2::new(0.0, d))),
        ) / (2.0 * d);
        assert!((g3 - fd).length() < 1e-2, "{g3} against finite differences {fd}");
    }

    #[test]
    fn closest_takes_one_texel_without_blending() {
        let linear = red_green(TexMap::default());
        let closest = red_green(TexMap { closest: true, ..Default::default() });
        // Near the middle of the image bilinear blends; the closest texel does not.
        assert_eq!(closest.sample(Vec2::new(0.45, 0.5)), Vec3::X);
        assert_eq!(closest.sample(Vec2::new(0.55, 0.5)), Vec3::Y);
        assert!(linear.sample(Vec2::new(0.45, 0.5)).y > 0.3);
    }

    #[test]
    fn clamp_holds_the_edge_instead_of_repeating() {
        let wrapped = red_green(TexMap::default());
        let clamped = red_green(TexMap { clamp: true, ..Default::default() });
        // Just past the right edge: wrapping blends back towards red, clamping stays green.
        assert_eq!(clamped.sample(Vec2::new(1.2, 0.5)), Vec3::Y);
        assert_eq!(clamped.sample(Vec2::new(-3.0, 0.5)), Vec3::X);
        assert!(wrapped.sample(Vec2::new(1.2, 0.5)).x > 0.8);
        assert_eq!(clamped.sample(Vec2::new(0.999, 0.5)), Vec3::Y);
        assert_ne!(wrapped.sample(Vec2::new(0.999, 0.5)), Vec3::Y);
    }
}
