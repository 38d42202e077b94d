//! Image textures (`map_Kd`), decoded by the `image` crate and stored as linear RGB, with
//! the MTL texture options that place them (`-s`, `-o`, `-clamp`).

use glam::{Vec2, Vec3};

/// How texture coordinates map onto an image: `uv · scale + offset` (MTL's `-s` and
/// `-o`), then wrapped around, or with `clamp` (MTL's `-clamp on`) held to the edge.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TexMap {
    pub scale: Vec2,
    pub offset: Vec2,
    pub clamp: bool,
}

impl Default for TexMap {
    fn default() -> Self {
        Self { scale: Vec2::ONE, offset: Vec2::ZERO, clamp: false }
    }
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
    /// Bilinear lookup. `uv` follows OBJ's convention: v = 0 is the bottom row of the
    /// image; outside [0, 1] the image repeats, or with `clamp` its edge texels extend.
    pub fn sample(&self, uv: Vec2) -> Vec3 {
        let (w, h) = (self.width as i64, self.height as i64);
        if w == 0 || h == 0 {
            return Vec3::ZERO;
        }
        let mut uv = uv * self.map.scale + self.map.offset;
        if self.map.clamp {
            uv = uv.clamp(Vec2::ZERO, Vec2::ONE);
        }
        let x = uv.x * self.width as f32 - 0.5;
        let y = (1.0 - uv.y) * self.height as f32 - 0.5;
        if !x.is_finite() || !y.is_finite() {
            return self.texels[0];
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let clamp = self.map.clamp;
        let wrap = |i: i64, n: i64| if clamp { i.clamp(0, n - 1) } else { i.rem_euclid(n) };
        let texel = |ix: i64, iy: i64| self.texels[(wrap(iy, h) * w + wrap(ix, w)) as usize];
        let (ix, iy) = (x0 as i64, y0 as i64);
        let top = texel(ix, iy) * (1.0 - fx) + texel(ix + 1, iy) * fx;
        let bottom = texel(ix, iy + 1) * (1.0 - fx) + texel(ix + 1, iy + 1) * fx;
        top * (1.0 - fy) + bottom * fy
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
