//! The AOV layers' sums: what a render keeps per pixel beside the beauty pass when it
//! is asked for layers (`[render] aovs`, `--aovs`). They merge exactly like the beauty
//! sums (fixed point, integer addition), so they too are the same bits for any
//! grouping of samples.
//!
//! Per pixel: the sum of each sample's squared radiance (for the variance estimate),
//! and at the first surface each camera ray meets, its albedo, shading normal and
//! distance, with the number of samples that met one (for the depth's mean).

use glam::Vec3;

use super::to_fixed;

/// Channels of a pixel's layer sums, in order (see the `*_AT` indices).
pub const CHANNELS: usize = 11;
/// Σ L² per colour channel: three, from here.
pub const SQUARES_AT: usize = 0;
/// Σ albedo: three.
pub const ALBEDO_AT: usize = 3;
/// Σ shading normal: three.
pub const NORMAL_AT: usize = 6;
/// Σ distance to the first hit (over samples that hit something).
pub const DEPTH_AT: usize = 9;
/// How many samples hit something (a plain count, not fixed point).
pub const HITS_AT: usize = 10;

/// One pixel's layer sums.
pub type LayerSums = [i128; CHANNELS];

/// What a camera ray found at the first surface it met: the first-hit AOVs of one
/// sample. Computed from the ray the sample's path starts with, so it costs no ray.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FirstHit {
    /// The surface's reflectance (each channel in [0, 1]); zero where the ray escaped.
    pub albedo: Vec3,
    /// World-space shading normal; zero where the ray escaped.
    pub normal: Vec3,
    /// Distance from the camera along the ray; `None` where the ray escaped.
    pub depth: Option<f32>,
}

/// Adds one sample's layer values to a pixel's sums. The squares saturate instead of
/// wrapping (they are never negative, so saturating addition is still associative).
/// Always inlined: into the render loop's instruction-set variants, where the ten
/// conversions to fixed point below run four to a vector instruction.
#[inline(always)]
pub(super) fn add(s: &mut LayerSums, radiance: Vec3, first: &FirstHit) {
    let depth = first.depth.filter(|d| d.is_finite());
    let r2 = radiance * radiance;
    let (a, n) = (first.albedo, first.normal);
    let v = to_fixed_all([r2.x, r2.y, r2.z, a.x, a.y, a.z, n.x, n.y, n.z, depth.unwrap_or(0.0)]);
    for k in 0..3 {
        s[SQUARES_AT + k] = s[SQUARES_AT + k].saturating_add(v[k]);
        s[ALBEDO_AT + k] += v[3 + k];
        s[NORMAL_AT + k] += v[6 + k];
    }
    if depth.is_some() {
        s[DEPTH_AT] += v[9];
        s[HITS_AT] += 1;
    }
}

/// [`to_fixed`] of each of `v`: the same integers. Where every value is below 2^19 in
/// magnitude (as a sample's layer values nearly always are), each rounded product is an
/// integer below 2^51, whose bits in the mantissa of the product plus 1.5 · 2^52 are the
/// integer itself: conversions the compiler can do four at a time, where the
/// float-to-integer conversion has no vector instruction before AVX-512.
#[inline(always)]
fn to_fixed_all<const N: usize>(v: [f32; N]) -> [i128; N] {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 · 2^52
    const EXACT_BELOW: f64 = 2_251_799_813_685_248.0; // 2^51
    let x: [f64; N] = std::array::from_fn(|k| (v[k] as f64 * super::FIXED_ONE).round());
    // Not `all`, whose early exit would keep the test from being vectorised; false for NaN.
    if x.iter().fold(true, |ok, x| ok & (x.abs() < EXACT_BELOW)) {
        std::array::from_fn(|k| ((x[k] + MAGIC).to_bits() as i64 - MAGIC.to_bits() as i64) as i128)
    } else {
        v.map(to_fixed)
    }
}

/// Adds another pixel's layer sums (exact; the squares saturate as in [`add`]).
#[inline]
pub(super) fn merge(s: &mut LayerSums, o: &LayerSums) {
    for k in 0..CHANNELS {
        s[k] = if (SQUARES_AT..SQUARES_AT + 3).contains(&k) { s[k].saturating_add(o[k]) } else { s[k] + o[k] };
    }
}

/// A pixel's layers as an image shows them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PixelLayers {
    /// Mean first-hit albedo (escaped samples count as zero).
    pub albedo: Vec3,
    /// Mean first-hit shading normal (not renormalised: an edge pixel averages two).
    pub normal: Vec3,
    /// Mean distance to the first hit over the samples that hit; infinite where none did.
    pub depth: f32,
    /// Estimated variance of the pixel's value (its mean): the unbiased sample variance
    /// divided by the sample count. Infinite with fewer than two samples (unknown).
    pub variance: Vec3,
}

/// Fixed point back to a real number.
fn real(v: i128) -> f64 {
    v as f64 / super::FIXED_ONE
}

impl PixelLayers {
    /// The layers of a pixel with `n` samples, beauty sums `sums` and layer sums `s`.
    pub fn of(n: u32, sums: &[i128; 3], s: &LayerSums) -> Self {
        if n == 0 {
            return Self { depth: f32::INFINITY, variance: Vec3::INFINITY, ..Self::default() };
        }
        let nf = f64::from(n);
        let mean3 = |at: usize| Vec3::from_array(std::array::from_fn(|k| (real(s[at + k]) / nf) as f32));
        let depth = if s[HITS_AT] > 0 { (real(s[DEPTH_AT]) / s[HITS_AT] as f64) as f32 } else { f32::INFINITY };
        let variance = if n < 2 {
            Vec3::INFINITY
        } else {
            Vec3::from_array(std::array::from_fn(|k| {
                let (sum, squares) = (real(sums[k]), real(s[SQUARES_AT + k]));
                ((squares - sum * sum / nf).max(0.0) / (nf * (nf - 1.0))) as f32
            }))
        };
        Self { albedo: mean3(ALBEDO_AT), normal: mean3(NORMAL_AT), depth, variance }
    }

    /// The pixel's relative error: the root of the mean, over its three channels, of
    /// the variance estimate of the channel's mean over that mean squared plus [`DARK`]
    /// (the square root of the pixel's expected relMSE, as a reference comparison would
    /// measure it). What adaptive sampling judges tiles by and the dashboard's noise view
    /// shows. Infinite where the variance is unknown (fewer than two samples).
    pub fn relative_error(&self, mean: Vec3) -> f64 {
        let (v, m) = (self.variance.as_dvec3(), mean.as_dvec3());
        let e = (v / (m * m + DARK)).element_sum() / 3.0;
        if e.is_nan() { f64::INFINITY } else { e.sqrt() }
    }
}

/// What keeps dark pixels from demanding endless samples: a pixel's squared error is
/// relative to its value squared plus this ([`PixelLayers::relative_error`]), as in the
/// usual relMSE.
pub const DARK: f64 = 0.01;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversions_together_are_conversions_one_by_one() {
        // Ties at 2^-33 steps, both sides of the 2^51 switch, overflow, and non-finite
        // values, alone and mixed with ordinary ones.
        let tie = 3.0 * 2f32.powi(-33);
        let edges = [0.0, -0.0, tie, -tie, 1.0, -1.0, 0.1, 524_287.9, 524_288.0, -524_288.0, 3.0e9, -3.0e30];
        let odd = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, f32::MIN_POSITIVE, 1e-40];
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            f32::from_bits(seed as u32)
        };
        let mut cases: Vec<[f32; 4]> = edges.chunks(4).map(|c| c.try_into().unwrap()).collect();
        cases.extend(odd.iter().map(|&o| [0.5, o, -0.25, 2.0]));
        cases.extend((0..100_000).map(|_| [next(), next(), next(), next()]));
        cases.extend((0..100_000).map(|_| std::array::from_fn(|_| next() % 600_000.0)));
        for v in cases {
            assert_eq!(to_fixed_all(v), v.map(to_fixed), "{v:?}");
        }
    }

    #[test]
    fn layers_average_what_the_samples_saw() {
        let mut s = [0i128; CHANNELS];
        let mut sums = [0i128; 3];
        let hit = FirstHit { albedo: Vec3::new(1.0, 0.5, 0.25), normal: Vec3::Y, depth: Some(2.0) };
        let values = [1.0f32, 3.0, 2.0, 6.0];
        for (i, &v) in values.iter().enumerate() {
            let first = if i == 3 { FirstHit::default() } else { hit };
            add(&mut s, Vec3::splat(v), &first);
            for c in &mut sums {
                *c += to_fixed(v);
            }
        }
        let p = PixelLayers::of(4, &sums, &s);
        assert_eq!(p.albedo, Vec3::new(0.75, 0.375, 0.1875), "the escaped sample counts as zero albedo");
        assert_eq!(p.normal, Vec3::new(0.0, 0.75, 0.0));
        assert_eq!(p.depth, 2.0, "depth averages the samples that hit");
        // Sample variance of 1, 3, 2, 6 is 14/3; of their mean, 14/12.
        assert!((p.variance.x - 14.0 / 12.0).abs() < 1e-6, "{}", p.variance);
        let none = PixelLayers::of(1, &sums, &[0; CHANNELS]);
        assert_eq!((none.depth, none.variance), (f32::INFINITY, Vec3::INFINITY));
    }

    #[test]
    fn squares_saturate_and_merging_is_exact() {
        let mut a = [0i128; CHANNELS];
        add(&mut a, Vec3::splat(1e30), &FirstHit::default());
        add(&mut a, Vec3::splat(1e30), &FirstHit::default());
        assert_eq!(a[SQUARES_AT], i128::MAX);
        let mut b = [0i128; CHANNELS];
        add(&mut b, Vec3::splat(0.5), &FirstHit { depth: Some(1.5), ..FirstHit::default() });
        let mut ab = a;
        merge(&mut ab, &b);
        let mut ba = b;
        merge(&mut ba, &a);
        assert_eq!(ab, ba);
        assert_eq!(ab[SQUARES_AT], i128::MAX);
        assert_eq!(ab[HITS_AT], 1);
    }
}
