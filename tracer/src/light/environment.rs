//! An environment map: radiance arriving from infinitely far away, by direction, from a
//! latitude-longitude (equirectangular) image, importance-sampled by solid angle.
//!
//! The orientation is Mitsuba 3's `envmap`, so that the same map lights both renderers
//! alike. In the map's frame (+Y up) a unit direction `d` has
//!
//! ```text
//! u = 1/2 − atan2(d.x, d.z) / 2π   (mod 1)      v = acos(d.y) / π
//! ```
//!
//! and the image is looked up bilinearly at column `u·W − 1/2` (wrapping around) and row
//! `v·(H − 1)`: row 0 is the zenith, the last row the nadir. The world reaches the map's
//! frame by a rotation ([`EnvironmentMap::new`]).
//!
//! Sampling: the cells between four neighbouring texel centres (W columns × H − 1 rows)
//! are chosen in proportion to the mean luminance of their corners (the integral of the
//! bilinear image over the cell) times the cell's solid angle; within a cell the
//! direction is uniform in solid angle (uniform in `u` and in `cos θ`). The pdf is then
//! constant over each cell: the cell's probability over its solid angle.

use std::f32::consts::PI;

use glam::{Mat3, Vec2, Vec3};

use super::distribution::Grid;
use crate::math;
use crate::sampling::sin_cos_turns;
use crate::texture::luminance;

/// Which world axis is the map's zenith.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Up {
    #[default]
    Y,
    /// A Z-up world (Blender's): a world direction `(x, y, z)` is looked up as the Y-up
    /// direction `(x, z, −y)`, the turn Blender's OBJ exporter makes for Y up.
    Z,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct EnvironmentMap {
    width: u32,
    height: u32,
    /// Linear RGB, row 0 at the zenith, times the map's strength.
    texels: Vec<Vec3>,
    /// World directions to the map's frame, and back.
    to_map: Mat3,
    to_world: Mat3,
    /// `cos θ` at each texel row's centre (θ = π·row / (H − 1)); the cells' edges.
    cos_rows: Vec<f32>,
    cells: Grid,
    /// The mean radiance over the sphere (for the power that light selection uses).
    mean: Vec3,
}

/// A direction drawn from an [`EnvironmentMap`]: in world space, its radiance, and its
/// solid-angle pdf.
#[derive(Clone, Copy, Debug)]
pub struct EnvironmentSample {
    pub wi: Vec3,
    pub radiance: Vec3,
    pub pdf: f32,
}

impl EnvironmentMap {
    /// The map of `texels` (`width × height`, linear RGB, row 0 at the top), scaled by
    /// `strength`, turned by `rotate_degrees` right-handed about the up axis `up`.
    pub fn new(width: u32, height: u32, texels: Vec<Vec3>, strength: f32, rotate_degrees: f32, up: Up) -> Self {
        assert!(width > 0 && height > 0 && texels.len() == width as usize * height as usize);
        let texels: Vec<Vec3> = texels.into_iter().map(|t| t * strength).collect();
        // The world's up axis onto +Y, then the rotation undone: R_y(−rotate) · C.
        let c = match up {
            Up::Y => Mat3::IDENTITY,
            Up::Z => Mat3::from_cols(Vec3::X, -Vec3::Z, Vec3::Y),
        };
        let (sin, cos) = math::sin_cos(-rotate_degrees.to_radians());
        let r = Mat3::from_cols(Vec3::new(cos, 0.0, -sin), Vec3::Y, Vec3::new(sin, 0.0, cos));
        let to_map = r * c;
        let rows = (height - 1).max(1);
        let cos_rows: Vec<f32> = (0..=rows).map(|i| math::cos(PI * i as f32 / rows as f32)).collect();
        let (w, h) = (width as usize, height as usize);
        let at = |row: u32, col: u32| texels[(row as usize).min(h - 1) * w + (col as usize) % w];
        // The corners' mean (the bilinear image's integral over the cell) and the cell's
        // solid angle, 2π/W · (cos θ₀ − cos θ₁).
        let corners = |r: u32, c: u32| (at(r, c) + at(r, c + 1) + at(r + 1, c) + at(r + 1, c + 1)) * 0.25;
        let solid = |r: u32| {
            2.0 * std::f64::consts::PI / w as f64
                * (f64::from(cos_rows[r as usize]) - f64::from(cos_rows[r as usize + 1]))
        };
        let cells = Grid::new(rows, width, |r, c| f64::from(luminance(corners(r, c))) * solid(r));
        let mut sum = [0.0f64; 3];
        for r in 0..rows {
            for c in 0..width {
                let v = corners(r, c);
                for (s, x) in sum.iter_mut().zip(v.to_array()) {
                    *s += f64::from(x) * solid(r);
                }
            }
        }
        let mean = Vec3::from_array(sum.map(|s| (s / (4.0 * std::f64::consts::PI)) as f32));
        Self { width, height, texels, to_map, to_world: to_map.transpose(), cos_rows, cells, mean }
    }

    /// The mean radiance over all directions.
    pub fn mean(&self) -> Vec3 {
        self.mean
    }

    /// Heap bytes held (texels and the sampling distribution).
    pub fn bytes(&self) -> usize {
        12 * self.texels.len() + 4 * self.cos_rows.len() + self.cells.bytes()
    }

    fn rows(&self) -> u32 {
        (self.height - 1).max(1)
    }

    /// `(u, v)` of a direction in the map's frame (unit or not).
    #[inline]
    fn uv(d: Vec3) -> Option<Vec2> {
        let d = d.normalize_or_zero();
        if d == Vec3::ZERO {
            return None;
        }
        let u = 0.5 - math::atan2(d.x, d.z) * (0.5 / PI);
        let u = if u < 0.0 {
            u + 1.0
        } else if u >= 1.0 {
            u - 1.0
        } else {
            u
        };
        Some(Vec2::new(u, math::acos(d.y.clamp(-1.0, 1.0)) / PI))
    }

    #[inline]
    fn texel(&self, row: i64, col: i64) -> Vec3 {
        let (w, h) = (self.width as i64, self.height as i64);
        self.texels[(row.clamp(0, h - 1) * w + col.rem_euclid(w)) as usize]
    }

    /// Radiance arriving from direction `dir` (world space, towards the environment).
    #[inline]
    pub fn eval(&self, dir: Vec3) -> Vec3 {
        let Some(uv) = Self::uv(self.to_map * dir) else {
            return Vec3::ZERO;
        };
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * (self.height - 1) as f32;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (c, r) = (x0 as i64, y0 as i64);
        let top = self.texel(r, c) * (1.0 - fx) + self.texel(r, c + 1) * fx;
        let bottom = self.texel(r + 1, c) * (1.0 - fx) + self.texel(r + 1, c + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// The solid angle of the cells of row `row`.
    #[inline]
    fn cell_solid_angle(&self, row: u32) -> f32 {
        2.0 * PI / self.width as f32 * (self.cos_rows[row as usize] - self.cos_rows[row as usize + 1])
    }

    /// The cell (row, column) that direction `d` (map frame) lies in.
    #[inline]
    fn cell_of(&self, uv: Vec2) -> (u32, u32) {
        let row = ((uv.y * self.rows() as f32) as u32).min(self.rows() - 1);
        let x = (uv.x * self.width as f32 - 0.5).floor() as i64;
        (row, x.rem_euclid(i64::from(self.width)) as u32)
    }

    /// The solid-angle pdf with which [`EnvironmentMap::sample`] produces `dir` (world).
    #[inline]
    pub fn pdf(&self, dir: Vec3) -> f32 {
        let Some(uv) = Self::uv(self.to_map * dir) else {
            return 0.0;
        };
        let (row, col) = self.cell_of(uv);
        let omega = self.cell_solid_angle(row);
        if omega > 0.0 { self.cells.pmf(row, col) / omega } else { 0.0 }
    }

    /// A direction in proportion to the map's luminance over solid angle.
    #[inline]
    pub fn sample(&self, u: Vec2) -> Option<EnvironmentSample> {
        let s = self.cells.sample(u)?;
        let omega = self.cell_solid_angle(s.row);
        if !(omega > 0.0) {
            return None;
        }
        let (c0, c1) = (self.cos_rows[s.row as usize], self.cos_rows[s.row as usize + 1]);
        let cos_theta = (c0 + s.offset.y * (c1 - c0)).clamp(-1.0, 1.0);
        let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
        let u_map = (s.col as f32 + 0.5 + s.offset.x) / self.width as f32;
        // u = 1/2 − φ/2π: φ in turns is 1/2 − u.
        let (sin_phi, cos_phi) = sin_cos_turns(0.5 - u_map);
        let local = Vec3::new(sin_theta * sin_phi, cos_theta, sin_theta * cos_phi);
        let wi = self.to_world * local;
        Some(EnvironmentSample { wi, radiance: self.eval(wi), pdf: s.pmf / omega })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::disallowed_methods)] // values checked, not platform-free bits
    use super::*;

    /// A `w × h` map, black but for texel (`row`, `col`) of radiance `bright`.
    fn spot(w: u32, h: u32, row: u32, col: u32, bright: f32) -> Vec<Vec3> {
        let mut t = vec![Vec3::ZERO; (w * h) as usize];
        t[(row * w + col) as usize] = Vec3::splat(bright);
        t
    }

    /// The direction (map frame) of texel (`row`, `col`)'s centre, by the formula.
    fn texel_direction(w: u32, h: u32, row: u32, col: u32) -> Vec3 {
        let u = (col as f32 + 0.5) / w as f32;
        let theta = PI * row as f32 / (h - 1) as f32;
        let phi = PI - 2.0 * PI * u;
        Vec3::new(theta.sin() * phi.sin(), theta.cos(), theta.sin() * phi.cos())
    }

    #[test]
    fn a_texel_is_seen_where_the_formula_puts_it() {
        let (w, h) = (32, 17);
        let map = EnvironmentMap::new(w, h, spot(w, h, 5, 7, 10.0), 2.0, 0.0, Up::Y);
        let d = texel_direction(w, h, 5, 7);
        assert!((map.eval(d) - Vec3::splat(20.0)).abs().max_element() < 1e-3, "{}", map.eval(d));
        assert_eq!(map.eval(-d), Vec3::ZERO);
        // Mitsuba's axes: u = 1/4 is +X, u = 1/2 is +Z, and row 0 is +Y.
        assert!((texel_direction(4, 3, 1, 0) - Vec3::new(0.5f32.sqrt(), 0.0, -(0.5f32.sqrt()))).length() < 1e-6);
        let up = EnvironmentMap::new(1, 2, vec![Vec3::ONE, Vec3::ZERO], 1.0, 0.0, Up::Y);
        assert_eq!((up.eval(Vec3::Y), up.eval(-Vec3::Y)), (Vec3::ONE, Vec3::ZERO));
    }

    #[test]
    fn rotation_turns_the_map_right_handed_about_the_up_axis() {
        let (w, h) = (64, 33);
        let d = texel_direction(w, h, 10, 20);
        for (up, axis) in [(Up::Y, Vec3::Y), (Up::Z, Vec3::Z)] {
            // Where the texel is seen in the world unrotated (for z up: (x, y, z)_map is
            // the world's (x, −z, y)).
            let world = match up {
                Up::Y => d,
                Up::Z => Vec3::new(d.x, -d.z, d.y),
            };
            let plain = EnvironmentMap::new(w, h, spot(w, h, 10, 20, 1.0), 1.0, 0.0, up);
            assert!((plain.eval(world).x - 1.0).abs() < 1e-3, "{up:?}");
            let turned = EnvironmentMap::new(w, h, spot(w, h, 10, 20, 1.0), 1.0, 90.0, up);
            let moved = Mat3::from_axis_angle(axis, 90f32.to_radians()) * world;
            assert!((turned.eval(moved).x - 1.0).abs() < 1e-3, "{up:?}: {}", turned.eval(moved));
            assert!(turned.eval(world).x < 1e-3);
        }
        // Z up: the map's zenith is +Z.
        let z = EnvironmentMap::new(1, 2, vec![Vec3::ONE, Vec3::ZERO], 1.0, 0.0, Up::Z);
        assert_eq!((z.eval(Vec3::Z), z.eval(-Vec3::Z)), (Vec3::ONE, Vec3::ZERO));
    }

    fn gradient_with_sun(w: u32, h: u32) -> Vec<Vec3> {
        let mut t: Vec<Vec3> = (0..h)
            .flat_map(|r| (0..w).map(move |c| Vec3::new(0.2 + r as f32 / h as f32, 0.5, 0.1 + (c % 3) as f32 * 0.2)))
            .collect();
        t[(4 * w + 9) as usize] = Vec3::splat(500.0);
        t
    }

    #[test]
    fn the_pdf_integrates_to_one_and_matches_the_samples() {
        let (w, h) = (24, 13);
        let map = EnvironmentMap::new(w, h, gradient_with_sun(w, h), 1.0, 25.0, Up::Y);
        // Integral of the pdf over the sphere by a fine (u, cos θ) grid.
        let n = 600;
        let mut total = 0.0f64;
        for i in 0..n {
            for j in 0..n {
                let cos_t = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let phi = 2.0 * PI * (j as f32 + 0.5) / n as f32;
                let s = (1.0 - cos_t * cos_t).sqrt();
                total += f64::from(map.pdf(Vec3::new(s * phi.cos(), cos_t, s * phi.sin())));
            }
        }
        total *= 4.0 * std::f64::consts::PI / (n * n) as f64;
        assert!((total - 1.0).abs() < 5e-3, "∫ pdf = {total}");
        for k in 0..2000 {
            // Off the cells' edges, where rounding may give the neighbour's pdf.
            let u = Vec2::new((k as f32 * 0.618_034 + 0.123).fract(), (k as f32 + 0.5) / 2000.0);
            let s = map.sample(u).unwrap();
            assert!((s.wi.length() - 1.0).abs() < 1e-5);
            let p = map.pdf(s.wi);
            assert!((p - s.pdf).abs() <= 1e-4 * s.pdf, "sample {k}: pdf {} against {p}", s.pdf);
            assert_eq!(s.radiance, map.eval(s.wi));
        }
    }

    #[test]
    fn importance_sampling_estimates_the_irradiance_of_the_map() {
        // E = ∫ L(ω) max(0, ω·n) dω for an upward normal, by quadrature and by the map's
        // own samples (the sun dominates: a wrong pdf shows at once).
        let (w, h) = (24, 13);
        let map = EnvironmentMap::new(w, h, gradient_with_sun(w, h), 1.0, 0.0, Up::Y);
        let n = 1200;
        let mut quad = 0.0f64;
        for i in 0..n {
            for j in 0..n {
                let cos_t = (i as f32 + 0.5) / n as f32;
                let phi = 2.0 * PI * (j as f32 + 0.5) / n as f32;
                let s = (1.0 - cos_t * cos_t).sqrt();
                quad += f64::from(map.eval(Vec3::new(s * phi.cos(), cos_t, s * phi.sin())).x * cos_t);
            }
        }
        quad *= 2.0 * std::f64::consts::PI / (n * n) as f64;
        let m = 1 << 16;
        let mut est = 0.0f64;
        for k in 0..m {
            let mut sampler = crate::sampler::Sampler::new(3, 0, 0, k);
            let s = map.sample(sampler.next_2d()).unwrap();
            est += f64::from(s.radiance.x * s.wi.y.max(0.0) / s.pdf);
        }
        est /= f64::from(m);
        assert!((est / quad - 1.0).abs() < 2e-3, "sampled {est} against quadrature {quad}");
    }

    #[test]
    fn the_mean_is_the_average_over_the_sphere() {
        let map = EnvironmentMap::new(8, 5, vec![Vec3::new(1.0, 2.0, 3.0); 40], 0.5, 0.0, Up::Y);
        assert!((map.mean() - Vec3::new(0.5, 1.0, 1.5)).abs().max_element() < 1e-5, "{}", map.mean());
        // A constant map is sampled uniformly: pdf 1/4π everywhere.
        let p = map.pdf(Vec3::new(0.3, -0.2, 0.9));
        assert!((p - 0.25 / PI).abs() < 1e-4 / PI, "{p}");
    }
}
