//! Deterministic low-discrepancy sampler: shuffled, Owen-scrambled 2D Sobol per dimension pair.
//!
//! The render farm splits a pixel's samples into arbitrary ranges of sample indices rendered on
//! different machines, and the merged result must be bit-identical to a single-machine render. So
//! every random number here is a pure function of `(scene seed, pixel x, pixel y, sample index,
//! dimension)`: there is no state besides a dimension counter, and nothing depends on which
//! samples were drawn before.
//!
//! # Construction
//!
//! This follows Burley 2020, "Practical Hash-based Owen Scrambling", JCGT 9(4) (the scheme behind
//! pbrt-v4's `PaddedSobolSampler`/`ZSobolSampler` and Cycles' sampler):
//!
//! * Each `next_1d`/`next_2d` call consumes one *dimension slot* `d` (0, 1, 2, … in call order).
//!   A per-slot 64-bit key is the `d`-th SplitMix64 output of a per-pixel key, which is itself a
//!   SplitMix64 mix of the scene seed and the pixel coordinates.
//! * The sample index is shuffled by a nested-uniform (Owen) scramble of its bits keyed by the
//!   slot key. Because bit `i` of the shuffled index depends only on bits `>= i` of the index, every
//!   aligned block of `2^k` indices maps onto another aligned block of `2^k` indices, so stratification
//!   of any aligned range survives the shuffle, while different slots see different, decorrelated
//!   orders ("padding", Burley §4).
//! * The shuffled index is pushed through the generator matrices of the first two Sobol dimensions
//!   (van der Corput and the Pascal-matrix dimension): together they form a (0,2)-sequence, so the
//!   first `2^k` points put exactly one point in each elementary interval of area `2^-k`.
//! * Each output coordinate is then Owen-scrambled again with its own key, which keeps the net
//!   property, makes every point uniformly distributed (so estimators are unbiased), and gives the
//!   `O(N^-3/2)` error of scrambled nets for smooth integrands (Owen 1997).
//!
//! The Owen scrambles use Laine & Karras' bit-reversed hash formulation with the improved hash of
//! Nathan Vegdahl, "Building a Better LK Hash" (2021), the same as pbrt-v4's `FastOwenScrambler`.
//!
//! Past [`SOBOL_DIMENSIONS`] slots (very deep paths, whose contribution is small and already
//! randomised by Russian roulette) we fall back to a plain counter-based SplitMix64 hash of
//! `(pixel key, slot, sample index)`: still a pure function, one mix instead of three scrambles.

use glam::Vec2;

use crate::simd::{F8, M8, Simd, U8, V2w, W, lanes};

/// Number of dimension slots (each `next_1d` or `next_2d` call is one) served by scrambled Sobol;
/// later slots use the hash fallback.
pub const SOBOL_DIMENSIONS: u32 = 64;

/// Largest `f32` below one, `0x1.fffffep-1`; samples are clamped to it so `[0, 1)` is guaranteed.
pub const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON / 2.0;

/// Weyl increment of SplitMix64 (Steele, Lea & Flood 2014): odd, so `key + n * GAMMA` never repeats.
const GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// Per-sample random number source; see the module documentation for the construction.
///
/// Cheap to create (two 64-bit mixes, 16 bytes, no allocation): meant to be built once per sample.
#[derive(Clone, Debug)]
pub struct Sampler {
    /// Mix of the scene seed and the pixel coordinates; every slot key derives from it.
    pixel_key: u64,
    /// Sample index within the pixel, bit-reversed: the index shuffle consumes it in this form, so
    /// reversing once here saves a reversal per draw.
    index_reversed: u32,
    /// Next dimension slot to hand out.
    dimension: u32,
}

impl Sampler {
    /// Positions the sampler at sample `index` of pixel (x, y); the dimension counter starts at 0.
    #[inline]
    pub fn new(seed: u64, x: u32, y: u32, index: u32) -> Self {
        // The inner mix spreads the seed; xor-ing in the pixel and mixing again is a bijection in the
        // pixel for a fixed seed, so two pixels of one scene never share a key.
        let pixel = (u64::from(x) << 32) | u64::from(y);
        let pixel_key = mix64(mix64(seed.wrapping_add(GAMMA)) ^ pixel);
        Self { pixel_key, index_reversed: index.reverse_bits(), dimension: 0 }
    }

    /// Sample index this sampler was positioned at.
    #[inline]
    pub fn index(&self) -> u32 {
        self.index_reversed.reverse_bits()
    }

    /// Number of dimension slots consumed so far.
    #[inline]
    pub fn dimension(&self) -> u32 {
        self.dimension
    }

    /// Next 1D sample in `[0, 1)`.
    ///
    /// Uses one fresh slot: its shuffled, Owen-scrambled van der Corput coordinate (bit-identical
    /// to the `x` that `next_2d` would return for that slot), so it is stratified across indices.
    #[inline]
    pub fn next_1d(&mut self) -> f32 {
        let d = self.take_dimension();
        if d >= SOBOL_DIMENSIONS {
            return unit_f32(self.fallback_hash(d) as u32);
        }
        let key = self.slot_key(d, 1);
        let shuffled_rev = laine_karras(self.index_reversed, key as u32);
        // Van der Corput of the shuffled index is `shuffled_rev`; its Owen scramble is
        // `reverse(LK(reverse(shuffled_rev)))`, as in `next_2d`.
        let x = laine_karras(shuffled_rev.reverse_bits(), (key >> 32) as u32).reverse_bits();
        unit_f32(x)
    }

    /// Next 2D sample in `[0, 1)^2`, stratified jointly across sample indices: for any aligned
    /// range of `2^k` indices, the points of one slot form a `(0, k, 2)`-net.
    #[inline]
    pub fn next_2d(&mut self) -> Vec2 {
        let d = self.take_dimension();
        if d >= SOBOL_DIMENSIONS {
            let h = self.fallback_hash(d);
            return Vec2::new(unit_f32(h as u32), unit_f32((h >> 32) as u32));
        }
        let key = self.slot_key(d, 1);
        let key_y = self.slot_key(d, 2);
        // Shuffle (Owen-scramble) the index; Burley 2020 §4, keyed per slot to decorrelate slots.
        let shuffled_rev = laine_karras(self.index_reversed, key as u32);
        let shuffled = shuffled_rev.reverse_bits();
        // Dimension 0 (van der Corput) of `shuffled` is `shuffled_rev`; its Owen scramble is
        // `reverse(LK(reverse(shuffled_rev)))` = `reverse(LK(shuffled))`.
        let x = laine_karras(shuffled, (key >> 32) as u32).reverse_bits();
        // Dimension 1 straight in bit-reversed form, which is what LK consumes.
        let y = laine_karras(sobol1_reversed(shuffled), key_y as u32).reverse_bits();
        Vec2::new(unit_f32(x), unit_f32(y))
    }

    #[inline]
    fn take_dimension(&mut self) -> u32 {
        let d = self.dimension;
        // Saturating: after 2^32 requests the last slot repeats instead of wrapping to slot 0.
        self.dimension = d.saturating_add(1);
        d
    }

    /// Key `part` (1 or 2) of Sobol slot `d`.
    #[inline]
    fn slot_key(&self, d: u32, part: u64) -> u64 {
        slot_key(self.pixel_key, d, part)
    }

    /// Counter-based fallback for slots past [`SOBOL_DIMENSIONS`]: SplitMix64 output number
    /// `(d << 32) | reverse(index)` of the pixel key (reversed or not, the index is a unique
    /// counter). These counters are `>= 2^38`, disjoint from the `< 2^8` ones of Sobol slot keys.
    #[inline]
    fn fallback_hash(&self, d: u32) -> u64 {
        let counter = (u64::from(d) << 32) | u64::from(self.index_reversed);
        mix64(self.pixel_key.wrapping_add(counter.wrapping_mul(GAMMA)))
    }
}

/// Key `part` (1 or 2) of Sobol slot `d` of a pixel: SplitMix64 output number `2d + part` of
/// the pixel key.
#[inline(always)]
fn slot_key(pixel_key: u64, d: u32, part: u64) -> u64 {
    mix64(pixel_key.wrapping_add((2 * u64::from(d) + part).wrapping_mul(GAMMA)))
}

/// Eight samplers, one per lane, for the eight-path integrator: [`Sampler`]'s state as
/// arrays, and its draws for several lanes at once, each lane taking its own next slot.
/// Lane by lane the same operations as [`Sampler::next_1d`] and [`Sampler::next_2d`]
/// (which the compiler vectorises), so the same numbers.
#[derive(Clone, Debug)]
pub(crate) struct SamplerLanes {
    pixel_key: [u64; W],
    index_reversed: U8,
    dimension: U8,
}

impl SamplerLanes {
    pub fn new(simd: Simd) -> Self {
        Self { pixel_key: [0; W], index_reversed: simd.splat_u(0), dimension: simd.splat_u(0) }
    }

    /// Lane `l` becomes `s`.
    #[inline(always)]
    pub fn set(&mut self, l: usize, s: &Sampler) {
        self.pixel_key[l] = s.pixel_key;
        self.index_reversed.0[l] = s.index_reversed;
        self.dimension.0[l] = s.dimension;
    }

    /// Lane `l`'s sampler.
    #[inline(always)]
    pub fn get(&self, l: usize) -> Sampler {
        Sampler {
            pixel_key: self.pixel_key[l],
            index_reversed: self.index_reversed.0[l],
            dimension: self.dimension.0[l],
        }
    }

    /// The slots the lanes of `mask` take (their dimension counters move on), and the
    /// mask of those past [`SOBOL_DIMENSIONS`] (drawn by the scalar fallback).
    #[inline(always)]
    fn take(&mut self, mask: M8) -> (U8, u32) {
        let d = self.dimension;
        self.dimension = mask.select_u(d.map(|x| x.saturating_add(1)), d);
        (d, (mask & d.ge(d.simd().splat_u(SOBOL_DIMENSIONS))).bits())
    }

    /// [`Sampler::next_1d`] for the lanes of `mask` (the others' values are unspecified).
    #[inline(always)]
    pub fn next_1d(&mut self, mask: M8) -> F8 {
        let (d, deep) = self.take(mask);
        let simd = d.simd();
        let key: [u64; W] = lanes(|l| slot_key(self.pixel_key[l], d.0[l], 1));
        let shuffled_rev = simd.u8(lanes(|l| laine_karras(self.index_reversed.0[l], key[l] as u32)));
        let x =
            simd.u8(lanes(|l| laine_karras(shuffled_rev.0[l].reverse_bits(), (key[l] >> 32) as u32).reverse_bits()));
        let mut u = simd.f8(lanes(|l| unit_f32(x.0[l])));
        for l in crate::simd::each(deep) {
            u.0[l] = unit_f32(self.get(l).fallback_hash(d.0[l]) as u32);
        }
        u
    }

    /// [`Sampler::next_2d`] for the lanes of `mask` (the others' values are unspecified).
    #[inline(always)]
    pub fn next_2d(&mut self, mask: M8) -> V2w {
        let (d, deep) = self.take(mask);
        let simd = d.simd();
        let key: [u64; W] = lanes(|l| slot_key(self.pixel_key[l], d.0[l], 1));
        let key_y: [u64; W] = lanes(|l| slot_key(self.pixel_key[l], d.0[l], 2));
        let shuffled_rev = simd.u8(lanes(|l| laine_karras(self.index_reversed.0[l], key[l] as u32)));
        let shuffled = shuffled_rev.map(u32::reverse_bits);
        let x = simd.u8(lanes(|l| laine_karras(shuffled.0[l], (key[l] >> 32) as u32).reverse_bits()));
        let y = simd.u8(lanes(|l| laine_karras(sobol1_reversed(shuffled.0[l]), key_y[l] as u32).reverse_bits()));
        let mut u = V2w { x: simd.f8(lanes(|l| unit_f32(x.0[l]))), y: simd.f8(lanes(|l| unit_f32(y.0[l]))) };
        for l in crate::simd::each(deep) {
            let h = self.get(l).fallback_hash(d.0[l]);
            (u.x.0[l], u.y.0[l]) = (unit_f32(h as u32), unit_f32((h >> 32) as u32));
        }
        u
    }
}

/// SplitMix64 finaliser (Steele et al. 2014; Stafford's "Mix13" variant of MurmurHash3's fmix64):
/// a bijective 64-bit mix with full avalanche.
#[inline]
const fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Laine-Karras style permutation with Vegdahl's improved constants ("Building a Better LK Hash",
/// 2021; pbrt-v4 `FastOwenScrambler`). Every step changes bit `i` only as a function of bits
/// `<= i` (xor with a multiple by an even constant, add, multiply by an odd constant), which is
/// exactly a nested-uniform (Owen) scramble when applied to bit-reversed input (Laine & Karras
/// 2011, Burley 2020 §3). `seed` must be well mixed: its high half picks the multiplier.
#[inline]
const fn laine_karras(mut x: u32, seed: u32) -> u32 {
    x ^= x.wrapping_mul(0x3d20_adea);
    x = x.wrapping_add(seed);
    x = x.wrapping_mul((seed >> 16) | 1);
    x ^= x.wrapping_mul(0x0552_6c56);
    x ^= x.wrapping_mul(0x53a2_2864);
    x
}

/// Owen scramble of a 32-bit fixed-point value in `[0, 1)` (Burley 2020, `nested_uniform_scramble`).
#[cfg(test)]
#[inline]
const fn nested_uniform_scramble(x: u32, seed: u32) -> u32 {
    laine_karras(x.reverse_bits(), seed).reverse_bits()
}

/// Sobol dimension 1 of `index`, bit-reversed: the generator matrix is the Pascal matrix mod 2,
/// so bit `j` of the reversed product is the xor of the index bits `i` with `C(i, j)` odd, which by
/// Lucas' theorem are the `i` whose binary digits include `j`'s (`i & j == j`). That superset sum
/// over the five bits of a bit position takes five shift-mask-xor steps (the zeta transform), fewer
/// operations than a 32-step product and no table lookups, so it also vectorises across lanes.
#[inline(always)]
const fn sobol1_reversed(index: u32) -> u32 {
    let mut r = index;
    r ^= (r >> 1) & 0x5555_5555;
    r ^= (r >> 2) & 0x3333_3333;
    r ^= (r >> 4) & 0x0f0f_0f0f;
    r ^= (r >> 8) & 0x00ff_00ff;
    r ^= (r >> 16) & 0x0000_ffff;
    r
}

/// Generator matrix columns of Sobol dimension 1 (primitive polynomial `x + 1`, initial direction
/// number 1), most significant bit first: `v_0 = 1/2`, `v_i = v_{i-1} ^ (v_{i-1} >> 1)`, i.e. the
/// upper-triangular Pascal matrix mod 2. Column `i` is applied for index bit `i`.
#[cfg(test)]
const fn sobol1_columns() -> [u32; 32] {
    let mut v = [0u32; 32];
    v[0] = 1 << 31;
    let mut i = 1;
    while i < 32 {
        v[i] = v[i - 1] ^ (v[i - 1] >> 1);
        i += 1;
    }
    v
}

/// Top 24 bits of a 32-bit fixed-point value as an `f32` in `[0, 1)`.
///
/// Truncating (instead of rounding `v as f32`) is exact, so a point never rounds up across a
/// stratum boundary (nor up to 1.0); the `min` merely spells out the `[0, 1)` contract.
#[inline]
fn unit_f32(v: u32) -> f32 {
    ((v >> 8) as f32 * (1.0 / (1u32 << 24) as f32)).min(ONE_MINUS_EPSILON)
}

#[cfg(test)]
mod tests;
