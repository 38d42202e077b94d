//! Eight lanes of `f32` / `u32` for the eight-path integrator (`integrator/packet.rs`):
//! plain arrays whose operations are written lane by lane with the scalar operations
//! themselves (`+`, `f32::max`, `f32::sqrt`, ...).
//!
//! Each operation is one straight line of eight independent lane operations, which the
//! compiler turns into one AVX2 instruction (or a short sequence) where the caller is
//! compiled for AVX2, and into scalar code elsewhere. Either way lane `l` of a result is
//! exactly what the scalar operation gives for lane `l` of the inputs: vectorising
//! preserves the semantics of every operation used here, including `f32::max`'s NaN
//! rule and IEEE rounding. So a function written with these types in the same order of
//! operations as its scalar twin gives the twin's bits in every lane; the twins sit next
//! to each other in their modules, and tests hold them equal.
//!
//! Transcendental functions (CORE-MATH) have no vector form: they run lane by lane
//! (`sampling::wide::sin_cos`, for one).

use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

use glam::Vec3;

/// Lanes of a wide value.
pub const W: usize = 8;

/// Eight `f32`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(32))]
pub struct F8(pub [f32; W]);

/// Eight `u32`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(32))]
pub struct U8(pub [u32; W]);

/// Eight lane conditions, as all-ones / all-zeros words (what vector compares produce
/// and blends consume).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(32))]
pub struct M8(pub [u32; W]);

/// `[f(0), f(1), ..]`: a lane-by-lane map, which the compiler vectorises when `f` is
/// straight-line code of vector-friendly operations.
#[inline(always)]
pub fn lanes<T: Copy + Default, const N: usize>(f: impl Fn(usize) -> T) -> [T; N] {
    let mut r = [T::default(); N];
    for (l, x) in r.iter_mut().enumerate() {
        *x = f(l);
    }
    r
}

macro_rules! f8_binop {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for F8 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: F8) -> F8 {
                F8(lanes(|l| self.0[l] $op o.0[l]))
            }
        }
        impl $tr<f32> for F8 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: f32) -> F8 {
                F8(lanes(|l| self.0[l] $op o))
            }
        }
        impl $tr<F8> for f32 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: F8) -> F8 {
                F8(lanes(|l| self $op o.0[l]))
            }
        }
    };
}
f8_binop!(Add, add, +);
f8_binop!(Sub, sub, -);
f8_binop!(Mul, mul, *);
f8_binop!(Div, div, /);

impl Neg for F8 {
    type Output = F8;
    #[inline(always)]
    fn neg(self) -> F8 {
        F8(lanes(|l| -self.0[l]))
    }
}

macro_rules! f8_cmp {
    ($f:ident, $op:tt) => {
        #[inline(always)]
        pub fn $f(self, o: impl Into<F8>) -> M8 {
            let o = o.into();
            M8(lanes(|l| u32::from(self.0[l] $op o.0[l]).wrapping_neg()))
        }
    };
}

impl From<f32> for F8 {
    #[inline(always)]
    fn from(x: f32) -> F8 {
        F8([x; W])
    }
}

impl F8 {
    pub const ZERO: F8 = F8([0.0; W]);
    pub const ONE: F8 = F8([1.0; W]);

    #[inline(always)]
    pub fn splat(x: f32) -> F8 {
        F8([x; W])
    }

    f8_cmp!(lt, <);
    f8_cmp!(le, <=);
    f8_cmp!(gt, >);
    f8_cmp!(ge, >=);
    f8_cmp!(eq, ==);
    f8_cmp!(ne, !=);

    /// `f32::max` lane by lane (NaN takes the other operand).
    #[inline(always)]
    pub fn max(self, o: impl Into<F8>) -> F8 {
        let o = o.into();
        F8(lanes(|l| self.0[l].max(o.0[l])))
    }

    /// `f32::min` lane by lane.
    #[inline(always)]
    pub fn min(self, o: impl Into<F8>) -> F8 {
        let o = o.into();
        F8(lanes(|l| self.0[l].min(o.0[l])))
    }

    /// `f32::clamp` lane by lane.
    #[inline(always)]
    pub fn clamp(self, lo: f32, hi: f32) -> F8 {
        F8(lanes(|l| self.0[l].clamp(lo, hi)))
    }

    #[inline(always)]
    pub fn abs(self) -> F8 {
        F8(lanes(|l| self.0[l].abs()))
    }

    #[inline(always)]
    pub fn sqrt(self) -> F8 {
        F8(lanes(|l| self.0[l].sqrt()))
    }

    #[inline(always)]
    pub fn recip(self) -> F8 {
        F8(lanes(|l| 1.0 / self.0[l]))
    }

    /// `f32::copysign` lane by lane.
    #[inline(always)]
    pub fn copysign(self, sign: F8) -> F8 {
        F8(lanes(|l| self.0[l].copysign(sign.0[l])))
    }

    /// `f32::signum` lane by lane.
    #[inline(always)]
    pub fn signum(self) -> F8 {
        F8(lanes(|l| self.0[l].signum()))
    }

    /// `f32::is_finite`, by the exponent bits (which vectorise).
    #[inline(always)]
    pub fn is_finite(self) -> M8 {
        M8(lanes(|l| u32::from(self.0[l].to_bits() & 0x7f80_0000 != 0x7f80_0000).wrapping_neg()))
    }

    /// `f32::is_nan` (unordered with itself).
    #[inline(always)]
    pub fn is_nan(self) -> M8 {
        self.ne(self)
    }

    /// `f32::is_infinite`, by the bits.
    #[inline(always)]
    pub fn is_infinite(self) -> M8 {
        M8(lanes(|l| u32::from(self.0[l].to_bits() & 0x7fff_ffff == 0x7f80_0000).wrapping_neg()))
    }
}

impl M8 {
    pub const ALL: M8 = M8([u32::MAX; W]);
    pub const NONE: M8 = M8([0; W]);

    /// The lanes set in bit mask `bits`.
    #[inline(always)]
    pub fn from_bits(bits: u32) -> M8 {
        M8(lanes(|l| ((bits >> l) & 1).wrapping_neg()))
    }

    /// The lanes as a bit mask.
    #[inline(always)]
    pub fn bits(self) -> u32 {
        self.0.iter().enumerate().fold(0, |m, (l, &x)| m | ((x & 1) << l))
    }

    #[inline(always)]
    pub fn from_bools(b: [bool; W]) -> M8 {
        M8(lanes(|l| u32::from(b[l]).wrapping_neg()))
    }

    #[inline(always)]
    pub fn any(self) -> bool {
        self.bits() != 0
    }

    /// `if self { a } else { b }` lane by lane.
    #[inline(always)]
    pub fn select(self, a: F8, b: F8) -> F8 {
        F8(lanes(|l| f32::from_bits((a.0[l].to_bits() & self.0[l]) | (b.0[l].to_bits() & !self.0[l]))))
    }

    /// [`M8::select`] for integers.
    #[inline(always)]
    pub fn select_u(self, a: U8, b: U8) -> U8 {
        U8(lanes(|l| (a.0[l] & self.0[l]) | (b.0[l] & !self.0[l])))
    }

    /// [`M8::select`] for masks.
    #[inline(always)]
    pub fn select_m(self, a: M8, b: M8) -> M8 {
        M8(lanes(|l| (a.0[l] & self.0[l]) | (b.0[l] & !self.0[l])))
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
        M8(lanes(|l| self.0[l] & o.0[l]))
    }
}

impl BitOr for M8 {
    type Output = M8;
    #[inline(always)]
    fn bitor(self, o: M8) -> M8 {
        M8(lanes(|l| self.0[l] | o.0[l]))
    }
}

impl Not for M8 {
    type Output = M8;
    #[inline(always)]
    fn not(self) -> M8 {
        M8(lanes(|l| !self.0[l]))
    }
}

impl U8 {
    #[inline(always)]
    pub fn splat(x: u32) -> U8 {
        U8([x; W])
    }

    #[inline(always)]
    pub fn eq(self, o: U8) -> M8 {
        M8(lanes(|l| u32::from(self.0[l] == o.0[l]).wrapping_neg()))
    }

    #[inline(always)]
    pub fn ge(self, o: U8) -> M8 {
        M8(lanes(|l| u32::from(self.0[l] >= o.0[l]).wrapping_neg()))
    }

    #[inline(always)]
    pub fn map(self, f: impl Fn(u32) -> u32) -> U8 {
        U8(lanes(|l| f(self.0[l])))
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

/// Eight 2-vectors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct V2w {
    pub x: F8,
    pub y: F8,
}

/// Eight 3-vectors, component by component; operations in glam's `Vec3` order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct V3w {
    pub x: F8,
    pub y: F8,
    pub z: F8,
}

impl Add for V3w {
    type Output = V3w;
    #[inline(always)]
    fn add(self, o: V3w) -> V3w {
        V3w { x: self.x + o.x, y: self.y + o.y, z: self.z + o.z }
    }
}

impl Sub for V3w {
    type Output = V3w;
    #[inline(always)]
    fn sub(self, o: V3w) -> V3w {
        V3w { x: self.x - o.x, y: self.y - o.y, z: self.z - o.z }
    }
}

/// Component by component (glam's `Vec3 * Vec3`).
impl Mul for V3w {
    type Output = V3w;
    #[inline(always)]
    fn mul(self, o: V3w) -> V3w {
        V3w { x: self.x * o.x, y: self.y * o.y, z: self.z * o.z }
    }
}

/// glam's `Vec3 * f32`.
impl Mul<F8> for V3w {
    type Output = V3w;
    #[inline(always)]
    fn mul(self, s: F8) -> V3w {
        V3w { x: self.x * s, y: self.y * s, z: self.z * s }
    }
}

/// glam's `f32 * Vec3`.
impl Mul<V3w> for F8 {
    type Output = V3w;
    #[inline(always)]
    fn mul(self, v: V3w) -> V3w {
        V3w { x: self * v.x, y: self * v.y, z: self * v.z }
    }
}

/// glam's `Vec3 / f32`.
impl Div<F8> for V3w {
    type Output = V3w;
    #[inline(always)]
    fn div(self, s: F8) -> V3w {
        V3w { x: self.x / s, y: self.y / s, z: self.z / s }
    }
}

impl Neg for V3w {
    type Output = V3w;
    #[inline(always)]
    fn neg(self) -> V3w {
        V3w { x: -self.x, y: -self.y, z: -self.z }
    }
}

impl V3w {
    #[inline(always)]
    pub fn splat(v: Vec3) -> V3w {
        V3w { x: F8::splat(v.x), y: F8::splat(v.y), z: F8::splat(v.z) }
    }

    #[inline(always)]
    pub fn new(x: F8, y: F8, z: F8) -> V3w {
        V3w { x, y, z }
    }

    /// Lane `l`.
    #[inline(always)]
    pub fn get(&self, l: usize) -> Vec3 {
        Vec3::new(self.x.0[l], self.y.0[l], self.z.0[l])
    }

    #[inline(always)]
    pub fn set(&mut self, l: usize, v: Vec3) {
        (self.x.0[l], self.y.0[l], self.z.0[l]) = (v.x, v.y, v.z);
    }

    /// Lane `l` of the result is `f(l)`.
    #[inline(always)]
    pub fn from_fn(f: impl Fn(usize) -> Vec3) -> V3w {
        let mut r = V3w::splat(Vec3::ZERO);
        for l in 0..W {
            r.set(l, f(l));
        }
        r
    }

    /// `(x * o.x + y * o.y) + z * o.z`, as glam's `dot`.
    #[inline(always)]
    pub fn dot(self, o: V3w) -> F8 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }

    #[inline(always)]
    pub fn length_squared(self) -> F8 {
        self.dot(self)
    }

    #[inline(always)]
    pub fn length(self) -> F8 {
        self.dot(self).sqrt()
    }

    /// glam's `cross`.
    #[inline(always)]
    pub fn cross(self, o: V3w) -> V3w {
        V3w { x: self.y * o.z - o.y * self.z, y: self.z * o.x - o.z * self.x, z: self.x * o.y - o.x * self.y }
    }

    /// glam's `normalize`: times the reciprocal of the length.
    #[inline(always)]
    pub fn normalize(self) -> V3w {
        self * self.length().recip()
    }

    /// glam's `normalize_or_zero`.
    #[inline(always)]
    pub fn normalize_or_zero(self) -> V3w {
        let rcp = self.length().recip();
        let ok = rcp.is_finite() & rcp.gt(0.0);
        ok.select3(self * rcp, V3w::splat(Vec3::ZERO))
    }

    /// glam's `max_element`: `max(x, max(y, z))` with `if a > b { a } else { b }`.
    #[inline(always)]
    pub fn max_element(self) -> F8 {
        let max = |a: F8, b: F8| a.gt(b).select(a, b);
        max(self.x, max(self.y, self.z))
    }

    /// glam's `is_finite` (all three components).
    #[inline(always)]
    pub fn is_finite(self) -> M8 {
        self.x.is_finite() & self.y.is_finite() & self.z.is_finite()
    }

    /// glam's `abs`.
    #[inline(always)]
    pub fn abs(self) -> V3w {
        V3w { x: self.x.abs(), y: self.y.abs(), z: self.z.abs() }
    }
}
