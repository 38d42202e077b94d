//! Image textures (`map_Kd`), decoded by the `image` crate and stored as linear RGB.

use glam::{Vec2, Vec3};

#[derive(Clone, Debug)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    /// Linear RGB, row 0 at the top of the image.
    pub texels: Vec<Vec3>,
}

impl Texture {
    /// Bilinear lookup with wrap-around. `uv` follows OBJ's convention: v = 0 is the
    /// bottom row of the image.
    pub fn sample(&self, uv: Vec2) -> Vec3 {
        let (w, h) = (self.width as i64, self.height as i64);
        if w == 0 || h == 0 {
            return Vec3::ZERO;
        }
        let x = uv.x * self.width as f32 - 0.5;
        let y = (1.0 - uv.y) * self.height as f32 - 0.5;
        if !x.is_finite() || !y.is_finite() {
            return self.texels[0];
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let texel = |ix: i64, iy: i64| self.texels[(iy.rem_euclid(h) * w + ix.rem_euclid(w)) as usize];
        let (ix, iy) = (x0 as i64, y0 as i64);
        let top = texel(ix, iy) * (1.0 - fx) + texel(ix + 1, iy) * fx;
        let bottom = texel(ix, iy + 1) * (1.0 - fx) + texel(ix + 1, iy + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}
