//! Eight lanes of `f32` / `u32` for the eight-path integrator (`integrator/eight_paths.rs`).
//!
//! Every operation gives, in each lane, exactly what the scalar operation of the same
//! name gives (`+`, `<`, `f32::sqrt`, `f32::clamp`, ...), so a function written with
//! these types in the same order of operations as its scalar twin gives the twin's bits
//! in every lane; the twins sit next to each other in their modules, and tests hold them
//! equal. Two deliberate limits: `max` and `min` follow `f32::max`/`min` for NaN but may
//! differ from them on `max(0.0, -0.0)`, whose sign Rust leaves open (the callers never
//! compare zeros of opposite sign); and transcendental functions (CORE-MATH) have no
//! vector form, so callers run them lane by lane.
//!
//! On x86_64 the operations are AVX2 instructions, written with `core::arch` (the
//! compiler's own vectoriser left plain lane loops half scalar). **They may only run
//! where the CPU has AVX2**, and the types make that so: every lane value carries a
//! [`Simd`] — a zero-sized capability that only [`Simd::detect`] creates, after asking
//! the CPU — and no lane value can be made without one (no constants, no conversions
//! from scalars; the fields that would allow it are private to this module). An
//! operation's operands therefore prove that the CPU has AVX2, and safe code cannot
//! run these instructions on a CPU without it. Elsewhere the operations are lane loops
//! and `detect` always succeeds.

use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

use glam::Vec3;

/// Lanes of a wide value.
pub const W: usize = 8;

/// Proof that this CPU runs the lane operations (AVX2 on x86_64). Zero-sized; only
/// [`Simd::detect`] makes one, so every lane value, which holds one, was made after
/// the check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Simd(());

impl Simd {
    /// `Some` where the CPU has what the lane operations use.
    #[inline]
    pub fn detect() -> Option<Simd> {
        #[cfg(target_arch = "x86_64")]
        if !std::is_x86_feature_detected!("avx2") {
            return None;
        }
        Some(Simd(()))
    }

    #[inline(always)]
    pub fn f8(self, lanes: [f32; W]) -> F8 {
        F8(lanes, self)
    }

    #[inline(always)]
    pub fn splat(self, x: f32) -> F8 {
        F8([x; W], self)
    }

    #[inline(always)]
    pub fn zero(self) -> F8 {
        self.splat(0.0)
    }

    #[inline(always)]
    pub fn one(self) -> F8 {
        self.splat(1.0)
    }

    #[inline(always)]
    pub fn u8(self, lanes: [u32; W]) -> U8 {
        U8(lanes, self)
    }

    #[inline(always)]
    pub fn splat_u(self, x: u32) -> U8 {
        U8([x; W], self)
    }

    /// Every lane set.
    #[inline(always)]
    pub fn all(self) -> M8 {
        M8([u32::MAX; W], self)
    }

    /// No lane set.
    #[inline(always)]
    pub fn none(self) -> M8 {
        M8([0; W], self)
    }

    /// The lanes set in bit mask `bits`.
    #[inline(always)]
    pub fn mask(self, bits: u32) -> M8 {
        let lane = [1, 2, 4, 8, 16, 32, 64, 128];
        M8(imp::eq_u(imp::and([bits; W], lane), lane), self)
    }

    #[inline(always)]
    pub fn mask_from_bools(self, b: [bool; W]) -> M8 {
        M8(lanes(|l| u32::from(b[l]).wrapping_neg()), self)
    }

    /// `v` in every lane.
    #[inline(always)]
    pub fn v3(self, v: Vec3) -> V3w {
        V3w { x: self.splat(v.x), y: self.splat(v.y), z: self.splat(v.z) }
    }

    /// Lane `l` of the result is `f(l)`.
    #[inline(always)]
    pub fn v3_from_fn(self, f: impl Fn(usize) -> Vec3) -> V3w {
        let mut r = self.v3(Vec3::ZERO);
        for l in 0..W {
            r.set(l, f(l));
        }
        r
    }
}

/// Eight `f32`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(32))]
pub struct F8(pub [f32; W], Simd);

/// Eight `u32`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(32))]
pub struct U8(pub [u32; W], Simd);

/// Eight lane conditions, as all-ones / all-zeros words (what vector compares produce
/// and blends consume).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(32))]
pub struct M8(pub [u32; W], Simd);

/// What a lane operation takes beside an `F8`: another, or one `f32` for every lane.
pub trait Operand {
    fn lanes(self) -> [f32; W];
}

impl Operand for F8 {
    #[inline(always)]
    fn lanes(self) -> [f32; W] {
        self.0
    }
}

impl Operand for f32 {
    #[inline(always)]
    fn lanes(self) -> [f32; W] {
        [self; W]
    }
}

/// `[f(0), f(1), ..]`: a lane-by-lane map (for what has no vector form).
#[inline(always)]
pub fn lanes<T: Copy + Default, const N: usize>(f: impl Fn(usize) -> T) -> [T; N] {
    let mut r = [T::default(); N];
    for (l, x) in r.iter_mut().enumerate() {
        *x = f(l);
    }
    r
}

mod ops;
mod vec;

use ops as imp;
pub use vec::{V2w, V3w};

macro_rules! f8_binop {
    ($tr:ident, $f:ident) => {
        impl $tr for F8 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: F8) -> F8 {
                F8(imp::$f(self.0, o.0), self.1)
            }
        }
        impl $tr<f32> for F8 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: f32) -> F8 {
                F8(imp::$f(self.0, [o; W]), self.1)
            }
        }
        impl $tr<F8> for f32 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: F8) -> F8 {
                F8(imp::$f([self; W], o.0), o.1)
            }
        }
    };
}
f8_binop!(Add, add);
f8_binop!(Sub, sub);
f8_binop!(Mul, mul);
f8_binop!(Div, div);

impl Neg for F8 {
    type Output = F8;
    /// Flips the sign bit, as `-x` does (also for zeros and NaN).
    #[inline(always)]
    fn neg(self) -> F8 {
        self.with_bits(imp::xor(self.to_bits(), [0x8000_0000; W]))
    }
}

macro_rules! f8_cmp {
    ($f:ident) => {
        #[inline(always)]
        pub fn $f(self, o: impl Operand) -> M8 {
            M8(imp::$f(self.0, o.lanes()), self.1)
        }
    };
}

impl F8 {
    /// The capability this value carries (to make more lane values).
    #[inline(always)]
    pub fn simd(self) -> Simd {
        self.1
    }

    #[inline(always)]
    fn to_bits(self) -> [u32; W] {
        // SAFETY: same size, plain data.
        unsafe { core::mem::transmute::<[f32; W], [u32; W]>(self.0) }
    }

    #[inline(always)]
    fn with_bits(self, b: [u32; W]) -> F8 {
        // SAFETY: same size, plain data.
        F8(unsafe { core::mem::transmute::<[u32; W], [f32; W]>(b) }, self.1)
    }

    f8_cmp!(lt);
    f8_cmp!(le);
    f8_cmp!(gt);
    f8_cmp!(ge);
    f8_cmp!(eq);
    f8_cmp!(ne);

    /// `f32::max` lane by lane (NaN takes the other operand; see the module comment on
    /// zeros).
    #[inline(always)]
    pub fn max(self, o: impl Operand) -> F8 {
        F8(imp::max(self.0, o.lanes()), self.1)
    }

    /// `f32::min` lane by lane (as [`F8::max`]).
    #[inline(always)]
    pub fn min(self, o: impl Operand) -> F8 {
        F8(imp::min(self.0, o.lanes()), self.1)
    }

    /// `f32::clamp` lane by lane: `lo` below it, `hi` above, NaN kept.
    #[inline(always)]
    pub fn clamp(self, lo: f32, hi: f32) -> F8 {
        let x = self.lt(lo).select(self.1.splat(lo), self);
        x.gt(hi).select(self.1.splat(hi), x)
    }

    /// Clears the sign bit, as `f32::abs`.
    #[inline(always)]
    pub fn abs(self) -> F8 {
        self.with_bits(imp::and(self.to_bits(), [0x7fff_ffff; W]))
    }

    /// `f32::floor` lane by lane.
    #[inline(always)]
    pub fn floor(self) -> F8 {
        F8(imp::floor(self.0), self.1)
    }

    #[inline(always)]
    pub fn sqrt(self) -> F8 {
        F8(imp::sqrt(self.0), self.1)
    }

    /// `1.0 / x`.
    #[inline(always)]
    pub fn recip(self) -> F8 {
        1.0 / self
    }

    /// `f32::copysign`: the magnitude of `self`, the sign bit of `sign`.
    #[inline(always)]
    pub fn copysign(self, sign: F8) -> F8 {
        self.with_bits(imp::or(imp::and(self.to_bits(), [0x7fff_ffff; W]), imp::and(sign.to_bits(), [0x8000_0000; W])))
    }

    /// `f32::signum`: NaN for NaN, else 1 with `self`'s sign.
    #[inline(always)]
    pub fn signum(self) -> F8 {
        self.is_nan().select(self.1.splat(f32::NAN), self.1.one().copysign(self))
    }

    /// `f32::is_finite`: the exponent bits are not all ones.
    #[inline(always)]
    pub fn is_finite(self) -> M8 {
        let exp = imp::and(self.to_bits(), [0x7f80_0000; W]);
        !M8(imp::eq_u(exp, [0x7f80_0000; W]), self.1)
    }

    /// `f32::is_nan` (unordered with itself).
    #[inline(always)]
    pub fn is_nan(self) -> M8 {
        self.ne(self)
    }

    /// `f32::is_infinite`: the magnitude is the infinity's bits.
    #[inline(always)]
    pub fn is_infinite(self) -> M8 {
        M8(imp::eq_u(imp::and(self.to_bits(), [0x7fff_ffff; W]), [0x7f80_0000; W]), self.1)
    }
}

impl M8 {
    #[inline(always)]
    pub fn simd(self) -> Simd {
        self.1
    }

    /// The lanes as a bit mask.
    #[inline(always)]
    pub fn bits(self) -> u32 {
        imp::bits(self.0)
    }

    #[inline(always)]
    pub fn any(self) -> bool {
        self.bits() != 0
    }

    /// `if self { a } else { b }` lane by lane.
    #[inline(always)]
    pub fn select(self, a: F8, b: F8) -> F8 {
        F8(imp::select(self.0, a.0, b.0), self.1)
    }

    /// [`M8::select`] for integers.
    #[inline(always)]
    pub fn select_u(self, a: U8, b: U8) -> U8 {
        U8(imp::select_u(self.0, a.0, b.0), self.1)
    }

    /// [`M8::select`] for masks.
    #[inline(always)]
    pub fn select_m(self, a: M8, b: M8) -> M8 {
        M8(imp::select_u(self.0, a.0, b.0), self.1)
    }

    /// [`M8::select`] for vectors.
    #[inline(always)]
    pub fn select3(self, a: V3w, b: V3w) -> V3w {
        V3w { x: self.select(a.x, b.x), y: self.select(a.y, b.y), z: self.select(a.z, b.z) }
    }
}

impl BitAnd for M8 {
    type Output = M8;
    #[inline(always)]
    fn bitand(self, o: M8) -> M8 {
        M8(imp::and(self.0, o.0), self.1)
    }
}

impl BitOr for M8 {
    type Output = M8;
    #[inline(always)]
    fn bitor(self, o: M8) -> M8 {
        M8(imp::or(self.0, o.0), self.1)
    }
}

impl Not for M8 {
    type Output = M8;
    #[inline(always)]
    fn not(self) -> M8 {
        M8(imp::xor(self.0, [u32::MAX; W]), self.1)
    }
}

impl U8 {
    #[inline(always)]
    pub fn simd(self) -> Simd {
        self.1
    }

    #[inline(always)]
    pub fn eq(self, o: U8) -> M8 {
        M8(imp::eq_u(self.0, o.0), self.1)
    }

    /// Unsigned `>=`.
    #[inline(always)]
    pub fn ge(self, o: U8) -> M8 {
        M8(imp::ge_u(self.0, o.0), self.1)
    }

    /// Any function lane by lane.
    #[inline(always)]
    pub fn map(self, f: impl Fn(u32) -> u32) -> U8 {
        U8(lanes(|l| f(self.0[l])), self.1)
    }
}

/// The lanes set in bit mask `mask`, lowest first.
#[inline(always)]
pub fn each(mut mask: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (mask != 0).then(|| {
            let l = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            l
        })
    })
}

#[cfg(test)]
pub(crate) mod tests;
