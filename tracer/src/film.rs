//! The film: per-pixel radiance sums and sample counts that merge *exactly*.
//!
//! Floating-point addition is not associative, so summing the same samples in a
//! different grouping (one worker or four, batches in any order) would change the last
//! bits. Each sample is therefore converted to fixed point (2^-32 resolution, i128
//! accumulators) before it is added: integer addition is associative, so the film of
//! samples [0,a) merged with that of [a,b) is bit-identical to the film of [0,b).

pub mod layers;

use glam::Vec3;
pub use layers::{FirstHit, LayerSums, PixelLayers};

/// Fixed-point scale: radiance 1.0 is 2^32. Resolution 2.3e-10; the i128 range
/// (±1.7e38 / 2^32 ≈ 4e28) cannot overflow from finite f32 samples within a pixel.
pub(crate) const FIXED_ONE: f64 = 4294967296.0;

/// A rectangle of pixels: `x0..x0+width`, `y0..y0+height`, row 0 at the top.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Tile {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
}

impl Tile {
    pub fn new(x0: u32, y0: u32, width: u32, height: u32) -> Self {
        Self { x0, y0, width, height }
    }

    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Splits a `width × height` image into tiles of at most `size × size`, row-major.
    pub fn grid(width: u32, height: u32, size: u32) -> Vec<Tile> {
        let size = size.max(1);
        let mut tiles = Vec::new();
        for y0 in (0..height).step_by(size as usize) {
            for x0 in (0..width).step_by(size as usize) {
                tiles.push(Tile::new(x0, y0, size.min(width - x0), size.min(height - y0)));
            }
        }
        tiles
    }
}

/// A half-open range of sample indices `[start, end)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SampleRange {
    pub start: u32,
    pub end: u32,
}

impl SampleRange {
    pub fn new(start: u32, end: u32) -> Self {
        Self { start, end }
    }

    pub fn len(&self) -> u32 {
        self.end.saturating_sub(self.start)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Bytes of one pixel's layer sums on the wire.
pub const LAYER_BYTES: usize = layers::CHANNELS * 16;

/// Converts one channel of one sample to fixed point. Exact and deterministic: the f32
/// widens to f64 exactly, the multiplication by 2^32 is exact, and `round` is exact.
///
/// Values below 2^63 in magnitude (radiance below 2^31) convert through `i64`: one
/// instruction, where the direct conversion to `i128` is a library call. Both give the
/// same integer.
#[inline]
fn to_fixed(v: f32) -> i128 {
    let x = (v as f64 * FIXED_ONE).round();
    if x.abs() < 9.0e18 { x as i64 as i128 } else { x as i128 }
}

/// Per-pixel sums for one tile. Non-finite samples are counted (and contribute zero)
/// rather than poisoning the pixel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Accumulation {
    pub tile: Tile,
    /// Fixed-point RGB sums, row-major within the tile.
    pub sums: Vec<[i128; 3]>,
    pub counts: Vec<u32>,
    /// Samples that were NaN or infinite and were replaced by zero.
    pub nonfinite: u64,
    /// The AOV layers' sums per pixel ([`layers`]), row-major; empty unless the render
    /// keeps layers.
    pub layers: Vec<LayerSums>,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum MergeError {
    #[error("tile mismatch: {0:?} vs {1:?}")]
    TileMismatch(Tile, Tile),
    #[error("malformed accumulation: {0} sums and {1} counts for {2} pixels")]
    Malformed(usize, usize, usize),
    #[error("malformed accumulation: {0} pixels of layers for {1} pixels")]
    Layers(usize, usize),
    #[error("sample count overflow")]
    Overflow,
}

impl Accumulation {
    pub fn new(tile: Tile) -> Self {
        let n = tile.pixel_count();
        Self { tile, sums: vec![[0; 3]; n], counts: vec![0; n], nonfinite: 0, layers: Vec::new() }
    }

    /// An empty accumulation that also keeps the AOV layers (`with_layers`) or not.
    pub fn with_layers(tile: Tile, with_layers: bool) -> Self {
        let mut a = Self::new(tile);
        if with_layers {
            a.layers = vec![[0; layers::CHANNELS]; tile.pixel_count()];
        }
        a
    }

    /// Whether this accumulation keeps the AOV layers.
    pub fn has_layers(&self) -> bool {
        !self.layers.is_empty()
    }

    /// Adds one sample to pixel `i` (index within the tile).
    #[inline]
    pub fn add_sample(&mut self, i: usize, radiance: Vec3) {
        self.add_beauty(i, radiance);
    }

    /// [`Accumulation::add_sample`], with the sample's first hit for the layers (ignored
    /// unless the accumulation keeps layers).
    #[inline(always)]
    pub fn add_sample_at(&mut self, i: usize, radiance: Vec3, first: &FirstHit) {
        let v = self.add_beauty(i, radiance);
        if let Some(s) = self.layers.get_mut(i) {
            layers::add(s, v, first);
        }
    }

    /// Adds the beauty pass's part of a sample; returns the radiance as added (zero for a
    /// non-finite sample).
    #[inline]
    fn add_beauty(&mut self, i: usize, radiance: Vec3) -> Vec3 {
        let v = if radiance.is_finite() {
            radiance
        } else {
            self.nonfinite += 1;
            Vec3::ZERO
        };
        let s = &mut self.sums[i];
        s[0] += to_fixed(v.x);
        s[1] += to_fixed(v.y);
        s[2] += to_fixed(v.z);
        self.counts[i] += 1;
        v
    }

    fn check(&self) -> Result<(), MergeError> {
        let n = self.tile.pixel_count();
        if self.sums.len() != n || self.counts.len() != n {
            return Err(MergeError::Malformed(self.sums.len(), self.counts.len(), n));
        }
        if !self.layers.is_empty() && self.layers.len() != n {
            return Err(MergeError::Layers(self.layers.len(), n));
        }
        Ok(())
    }

    /// Adds another accumulation of the same tile (exact, order-independent).
    pub fn merge(&mut self, other: &Accumulation) -> Result<(), MergeError> {
        if self.tile != other.tile {
            return Err(MergeError::TileMismatch(self.tile, other.tile));
        }
        self.check()?;
        other.check()?;
        if self.layers.len() != other.layers.len() {
            return Err(MergeError::Layers(other.layers.len(), self.layers.len()));
        }
        for (c, o) in self.counts.iter().zip(&other.counts) {
            c.checked_add(*o).ok_or(MergeError::Overflow)?;
        }
        for (s, o) in self.sums.iter_mut().zip(&other.sums) {
            for k in 0..3 {
                s[k] += o[k];
            }
        }
        for (c, o) in self.counts.iter_mut().zip(&other.counts) {
            *c += o;
        }
        for (s, o) in self.layers.iter_mut().zip(&other.layers) {
            layers::merge(s, o);
        }
        self.nonfinite += other.nonfinite;
        Ok(())
    }

    /// The layer sums as bytes: per pixel [`layers::CHANNELS`] little-endian i128 (the
    /// wire format); empty without layers.
    pub fn layers_to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.layers.len() * LAYER_BYTES);
        for s in &self.layers {
            for v in s {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    }

    /// Inverse of [`Accumulation::layers_to_bytes`]; `None` unless the length is a whole
    /// number of pixels.
    pub fn layers_from_bytes(bytes: &[u8]) -> Option<Vec<LayerSums>> {
        if !bytes.len().is_multiple_of(LAYER_BYTES) {
            return None;
        }
        let read = |c: &[u8]| i128::from_le_bytes(c.try_into().expect("16-byte chunk"));
        Some(bytes.chunks_exact(LAYER_BYTES).map(|p| std::array::from_fn(|k| read(&p[16 * k..16 * k + 16]))).collect())
    }

    /// The layers of pixel `i`, if this accumulation keeps them.
    pub fn layers_at(&self, i: usize) -> Option<PixelLayers> {
        self.layers.get(i).map(|s| PixelLayers::of(self.counts[i], &self.sums[i], s))
    }

    /// The sums as bytes: per pixel three little-endian i128 (the wire format).
    pub fn sums_to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.sums.len() * 48);
        for s in &self.sums {
            for v in s {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    }

    /// Inverse of [`Accumulation::sums_to_bytes`]; `None` unless the length is a whole
    /// number of pixels.
    pub fn sums_from_bytes(bytes: &[u8]) -> Option<Vec<[i128; 3]>> {
        if !bytes.len().is_multiple_of(48) {
            return None;
        }
        let read = |c: &[u8]| i128::from_le_bytes(c.try_into().expect("16-byte chunk"));
        Some(bytes.chunks_exact(48).map(|p| [read(&p[0..16]), read(&p[16..32]), read(&p[32..48])]).collect())
    }

    /// Mean radiance of pixel `i`, or zero where no sample landed.
    pub fn mean(&self, i: usize) -> Vec3 {
        let n = self.counts[i];
        if n == 0 {
            return Vec3::ZERO;
        }
        let s = self.sums[i];
        let k = 1.0 / (FIXED_ONE * n as f64);
        Vec3::new((s[0] as f64 * k) as f32, (s[1] as f64 * k) as f32, (s[2] as f64 * k) as f32)
    }
}

/// Where an image's pixels come from, read one at a time: an assembled [`Image`], or a
/// [`Mosaic`] of tile accumulations (which a large render writes from, so that no
/// second copy of the image is made).
pub trait Pixels: Sync {
    fn size(&self) -> (u32, u32);
    /// Mean radiance and sample count of pixel (x, y).
    fn pixel(&self, x: u32, y: u32) -> (Vec3, u32);
    /// The sample count alone (no mean computed).
    fn count(&self, x: u32, y: u32) -> u32;
    /// Whether the pixels carry AOV layers.
    fn has_layers(&self) -> bool;
    /// The AOV layers of pixel (x, y) (default values where there are none).
    fn layers(&self, x: u32, y: u32) -> PixelLayers;
    /// The denoised value of pixel (x, y), where a denoiser ran ([`Image::denoised`]).
    fn denoised(&self, _x: u32, _y: u32) -> Option<Vec3> {
        None
    }
}

/// A whole image as its tiles' accumulations (laid out by [`Tile::grid`]), read in
/// place: the same means as [`Image::put`] gives, without assembling them.
pub struct Mosaic<'a, A = Accumulation> {
    width: u32,
    height: u32,
    tile_size: u32,
    tiles_x: u32,
    tiles: &'a [A],
}

impl<'a, A: std::borrow::Borrow<Accumulation>> Mosaic<'a, A> {
    /// `tiles` must be `Tile::grid(width, height, tile_size)`'s, in order (owned or
    /// shared accumulations).
    pub fn new(width: u32, height: u32, tile_size: u32, tiles: &'a [A]) -> Option<Self> {
        let size = tile_size.max(1);
        let (tiles_x, tiles_y) = (width.div_ceil(size), height.div_ceil(size));
        let ok = tiles.len() == (tiles_x * tiles_y) as usize
            && tiles.iter().enumerate().all(|(i, a)| {
                let a = a.borrow();
                let (tx, ty) = (i as u32 % tiles_x.max(1), i as u32 / tiles_x.max(1));
                a.tile.x0 == tx * size && a.tile.y0 == ty * size
            });
        ok.then_some(Self { width, height, tile_size: size, tiles_x, tiles })
    }

    /// The tile holding pixel (x, y), and the pixel's index in it.
    fn at(&self, x: u32, y: u32) -> (&Accumulation, usize) {
        let acc = self.tiles[((y / self.tile_size) * self.tiles_x + x / self.tile_size) as usize].borrow();
        (acc, ((y - acc.tile.y0) * acc.tile.width + (x - acc.tile.x0)) as usize)
    }
}

impl<A: std::borrow::Borrow<Accumulation> + Sync> Pixels for Mosaic<'_, A> {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn pixel(&self, x: u32, y: u32) -> (Vec3, u32) {
        let (acc, i) = self.at(x, y);
        (acc.mean(i), acc.counts[i])
    }

    fn count(&self, x: u32, y: u32) -> u32 {
        let (acc, i) = self.at(x, y);
        acc.counts[i]
    }

    fn has_layers(&self) -> bool {
        self.tiles.first().is_some_and(|a| a.borrow().has_layers())
    }

    fn layers(&self, x: u32, y: u32) -> PixelLayers {
        let (acc, i) = self.at(x, y);
        acc.layers_at(i).unwrap_or_default()
    }
}

impl Pixels for Image {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn pixel(&self, x: u32, y: u32) -> (Vec3, u32) {
        let i = (y * self.width + x) as usize;
        (self.pixels[i], self.counts[i])
    }

    fn count(&self, x: u32, y: u32) -> u32 {
        self.counts[(y * self.width + x) as usize]
    }

    fn has_layers(&self) -> bool {
        !self.layers.is_empty()
    }

    fn layers(&self, x: u32, y: u32) -> PixelLayers {
        self.layers.get((y * self.width + x) as usize).copied().unwrap_or_default()
    }

    fn denoised(&self, x: u32, y: u32) -> Option<Vec3> {
        self.denoised.get((y * self.width + x) as usize).copied()
    }
}

/// A whole image assembled from tiles: mean radiance and sample count per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<Vec3>,
    pub counts: Vec<u32>,
    /// Per-pixel AOV layers; empty when the render kept none.
    pub layers: Vec<PixelLayers>,
    /// The denoised beauty pass (`crate::denoise`), beside the raw one; empty unless a
    /// denoiser ran.
    pub denoised: Vec<Vec3>,
}

impl Image {
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            pixels: vec![Vec3::ZERO; n],
            counts: vec![0; n],
            layers: Vec::new(),
            denoised: Vec::new(),
        }
    }

    /// Writes a tile's means (and layers, if it has them) into the image (the tile must
    /// lie inside it).
    pub fn put(&mut self, acc: &Accumulation) {
        if acc.has_layers() && self.layers.is_empty() {
            self.layers = vec![PixelLayers::default(); self.pixels.len()];
        }
        let t = acc.tile;
        for ty in 0..t.height {
            for tx in 0..t.width {
                let i = (ty * t.width + tx) as usize;
                let o = ((t.y0 + ty) * self.width + t.x0 + tx) as usize;
                self.pixels[o] = acc.mean(i);
                self.counts[o] = acc.counts[i];
                if let Some(l) = acc.layers_at(i) {
                    self.layers[o] = l;
                }
            }
        }
    }

    #[inline]
    pub fn at(&self, x: u32, y: u32) -> Vec3 {
        self.pixels[(y * self.width + x) as usize]
    }

    /// Assembles any pixel source.
    pub fn of(p: &impl Pixels) -> Self {
        let (w, h) = p.size();
        let mut img = Image::new(w, h);
        if p.has_layers() {
            img.layers = vec![PixelLayers::default(); img.pixels.len()];
        }
        if p.denoised(0, 0).is_some() {
            img.denoised = (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| p.denoised(x, y).unwrap_or_default())
                .collect();
        }
        for y in 0..h {
            for x in 0..w {
                let (v, n) = p.pixel(x, y);
                let i = (y * w + x) as usize;
                (img.pixels[i], img.counts[i]) = (v, n);
                if let Some(l) = img.layers.get_mut(i) {
                    *l = p.layers(x, y);
                }
            }
        }
        img
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An image read in place from its tiles is the assembled one, bit for bit, also
    /// where the tiles at the right and bottom edges are partial.
    #[test]
    fn a_mosaic_reads_the_same_pixels_as_the_assembled_image() {
        let (w, h, size) = (37, 21, 8);
        let tiles: Vec<Accumulation> = Tile::grid(w, h, size)
            .into_iter()
            .enumerate()
            .map(|(k, t)| {
                let mut a = Accumulation::new(t);
                for i in 0..t.pixel_count() {
                    for s in 0..(1 + (i + k) % 3) {
                        a.add_sample(i, Vec3::new(0.1 * i as f32, k as f32 / 7.0, s as f32 + 1e-3));
                    }
                }
                a
            })
            .collect();
        let mut assembled = Image::new(w, h);
        tiles.iter().for_each(|a| assembled.put(a));
        let mosaic = Mosaic::new(w, h, size, &tiles).expect("the grid's tiles");
        assert_eq!(Image::of(&mosaic), assembled);
        assert!(Mosaic::new(w, h, size + 1, &tiles).is_none());
        assert!(Mosaic::new(w, h, size, &tiles[1..]).is_none());
    }

    #[test]
    fn fixed_point_conversion_through_i64_is_the_direct_one() {
        let edge = (9.0e18 / FIXED_ONE) as f32;
        let mut values = vec![0.0, -0.0, 0.3, -0.3, 1e-10, 2.5 / FIXED_ONE as f32, 1e9, f32::MAX, f32::MIN];
        for k in -4..=4 {
            values.push(f32::from_bits((edge.to_bits() as i32 + k) as u32));
        }
        for x in (0..2000u32).map(|i| f32::from_bits(i.wrapping_mul(2_654_435_761) >> 1)) {
            values.extend([x, -x]);
        }
        for v in values.into_iter().filter(|v| v.is_finite()) {
            assert_eq!(to_fixed(v), (v as f64 * FIXED_ONE).round() as i128, "{v:e}");
        }
    }

    #[test]
    fn merge_is_exact_regardless_of_grouping() {
        let tile = Tile::new(0, 0, 3, 1);
        let samples: Vec<Vec3> = (0..64).map(|i| Vec3::splat(((i * 7919) % 113) as f32 * 0.0137 + 1e-7)).collect();
        let mut whole = Accumulation::new(tile);
        for s in &samples {
            whole.add_sample(1, *s);
        }
        let (mut a, mut b) = (Accumulation::new(tile), Accumulation::new(tile));
        for s in &samples[..23] {
            a.add_sample(1, *s);
        }
        for s in samples[23..].iter().rev() {
            b.add_sample(1, *s);
        }
        let mut ba = b.clone();
        ba.merge(&a).unwrap();
        a.merge(&b).unwrap();
        assert_eq!(a, whole);
        assert_eq!(ba, whole);
        let mean = samples.iter().map(|s| s.x as f64).sum::<f64>() / 64.0;
        assert!((whole.mean(1).x as f64 - mean).abs() < 1e-6);
    }

    #[test]
    fn sums_round_trip_through_bytes() {
        let mut a = Accumulation::new(Tile::new(0, 0, 2, 1));
        a.add_sample(0, Vec3::new(1.5, -2.0, 1e30));
        a.add_sample(1, Vec3::new(3.0e-9, 0.0, 7.0));
        assert_eq!(Accumulation::sums_from_bytes(&a.sums_to_bytes()).unwrap(), a.sums);
        assert!(Accumulation::sums_from_bytes(&[0u8; 47]).is_none());
    }

    #[test]
    fn nonfinite_samples_are_counted_not_kept() {
        let mut a = Accumulation::new(Tile::new(0, 0, 1, 1));
        a.add_sample(0, Vec3::new(f32::NAN, 1.0, 1.0));
        a.add_sample(0, Vec3::splat(f32::INFINITY));
        a.add_sample(0, Vec3::ONE);
        assert_eq!(a.nonfinite, 2);
        assert_eq!(a.counts[0], 3);
        assert!(a.mean(0).is_finite());
    }

    #[test]
    fn mismatched_tiles_do_not_merge() {
        let mut a = Accumulation::new(Tile::new(0, 0, 2, 2));
        let b = Accumulation::new(Tile::new(2, 0, 2, 2));
        assert!(a.merge(&b).is_err());
        let mut bad = Accumulation::new(Tile::new(0, 0, 2, 2));
        bad.counts.pop();
        assert!(a.merge(&bad).is_err());
    }

    #[test]
    fn grid_covers_image_once() {
        let tiles = Tile::grid(100, 70, 32);
        let mut cover = vec![0u8; 100 * 70];
        for t in &tiles {
            for y in t.y0..t.y0 + t.height {
                for x in t.x0..t.x0 + t.width {
                    cover[(y * 100 + x) as usize] += 1;
                }
            }
        }
        assert!(cover.iter().all(|&c| c == 1));
    }
}
