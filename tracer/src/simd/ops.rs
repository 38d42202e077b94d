//! The lane operations on plain arrays: AVX2 instructions on x86_64, lane loops
//! elsewhere. Private to `simd`: only the methods of lane values, whose `Simd` proves
//! the CPU has AVX2, call them.

/// The operations on 256-bit registers: AVX2 on x86_64.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use core::arch::x86_64::*;

    use super::super::W;

    type Fx = [f32; W];
    type Ux = [u32; W];

    // SAFETY (every function here): the arrays and the registers are 32 bytes of plain
    // data; the instructions need AVX2, which every caller has proven: each is a method
    // of a lane value, which holds a `Simd`, which only `Simd::detect` makes, after the
    // CPU reported AVX2.
    #[inline(always)]
    fn ps(a: Fx) -> __m256 {
        unsafe { core::mem::transmute::<Fx, __m256>(a) }
    }
    #[inline(always)]
    fn fx(a: __m256) -> Fx {
        unsafe { core::mem::transmute::<__m256, Fx>(a) }
    }
    #[inline(always)]
    fn si(a: Ux) -> __m256i {
        unsafe { core::mem::transmute::<Ux, __m256i>(a) }
    }
    #[inline(always)]
    fn ux(a: __m256i) -> Ux {
        unsafe { core::mem::transmute::<__m256i, Ux>(a) }
    }
    #[inline(always)]
    fn mask(a: __m256) -> Ux {
        ux(unsafe { _mm256_castps_si256(a) })
    }

    macro_rules! f2 {
        ($($name:ident => $op:ident),*) => {$(
            #[inline(always)]
            pub fn $name(a: Fx, b: Fx) -> Fx {
                fx(unsafe { $op(ps(a), ps(b)) })
            }
        )*};
    }
    f2!(add => _mm256_add_ps, sub => _mm256_sub_ps, mul => _mm256_mul_ps, div => _mm256_div_ps);

    macro_rules! cmp {
        ($($name:ident => $pred:ident),*) => {$(
            #[inline(always)]
            pub fn $name(a: Fx, b: Fx) -> Ux {
                mask(unsafe { _mm256_cmp_ps::<$pred>(ps(a), ps(b)) })
            }
        )*};
    }
    // Rust's `<`, `<=`, `>`, `>=`, `==` are false on NaN (ordered); `!=` is true.
    cmp!(lt => _CMP_LT_OQ, le => _CMP_LE_OQ, gt => _CMP_GT_OQ, ge => _CMP_GE_OQ, eq => _CMP_EQ_OQ, ne => _CMP_NEQ_UQ);

    #[inline(always)]
    pub fn sqrt(a: Fx) -> Fx {
        fx(unsafe { _mm256_sqrt_ps(ps(a)) })
    }
    #[inline(always)]
    pub fn floor(a: Fx) -> Fx {
        fx(unsafe { _mm256_floor_ps(ps(a)) })
    }
    /// `vmaxps` answers its second operand when either is NaN: right when `a` is NaN
    /// (`f32::max` takes the other), fixed up when `b` is.
    #[inline(always)]
    pub fn max(a: Fx, b: Fx) -> Fx {
        fx(unsafe {
            let m = _mm256_max_ps(ps(a), ps(b));
            _mm256_blendv_ps(m, ps(a), _mm256_cmp_ps::<_CMP_UNORD_Q>(ps(b), ps(b)))
        })
    }
    #[inline(always)]
    pub fn min(a: Fx, b: Fx) -> Fx {
        fx(unsafe {
            let m = _mm256_min_ps(ps(a), ps(b));
            _mm256_blendv_ps(m, ps(a), _mm256_cmp_ps::<_CMP_UNORD_Q>(ps(b), ps(b)))
        })
    }
    #[inline(always)]
    pub fn select(m: Ux, a: Fx, b: Fx) -> Fx {
        fx(unsafe { _mm256_blendv_ps(ps(b), ps(a), _mm256_castsi256_ps(si(m))) })
    }

    macro_rules! u2 {
        ($($name:ident => $op:ident),*) => {$(
            #[inline(always)]
            pub fn $name(a: Ux, b: Ux) -> Ux {
                ux(unsafe { $op(si(a), si(b)) })
            }
        )*};
    }
    u2!(and => _mm256_and_si256, or => _mm256_or_si256, xor => _mm256_xor_si256, eq_u => _mm256_cmpeq_epi32);

    #[inline(always)]
    pub fn select_u(m: Ux, a: Ux, b: Ux) -> Ux {
        ux(unsafe { _mm256_blendv_epi8(si(b), si(a), si(m)) })
    }
    /// Unsigned `a >= b`: `max(a, b) == a`.
    #[inline(always)]
    pub fn ge_u(a: Ux, b: Ux) -> Ux {
        ux(unsafe { _mm256_cmpeq_epi32(_mm256_max_epu32(si(a), si(b)), si(a)) })
    }
    #[inline(always)]
    pub fn bits(m: Ux) -> u32 {
        (unsafe { _mm256_movemask_ps(_mm256_castsi256_ps(si(m))) }) as u32
    }
}

/// The same operations lane by lane, elsewhere.
#[cfg(not(target_arch = "x86_64"))]
mod lanes {
    use super::super::{W, lanes};

    type Fx = [f32; W];
    type Ux = [u32; W];

    fn m(b: bool) -> u32 {
        u32::from(b).wrapping_neg()
    }
    macro_rules! f2 {
        ($($name:ident => $op:tt),*) => {$(
            #[inline(always)]
            pub fn $name(a: Fx, b: Fx) -> Fx {
                lanes(|l| a[l] $op b[l])
            }
        )*};
    }
    f2!(add => +, sub => -, mul => *, div => /);
    macro_rules! cmp {
        ($($name:ident => $op:tt),*) => {$(
            #[inline(always)]
            pub fn $name(a: Fx, b: Fx) -> Ux {
                lanes(|l| m(a[l] $op b[l]))
            }
        )*};
    }
    cmp!(lt => <, le => <=, gt => >, ge => >=, eq => ==, ne => !=);
    #[inline(always)]
    pub fn sqrt(a: Fx) -> Fx {
        lanes(|l| a[l].sqrt())
    }
    #[inline(always)]
    pub fn floor(a: Fx) -> Fx {
        lanes(|l| a[l].floor())
    }
    #[inline(always)]
    pub fn max(a: Fx, b: Fx) -> Fx {
        lanes(|l| a[l].max(b[l]))
    }
    #[inline(always)]
    pub fn min(a: Fx, b: Fx) -> Fx {
        lanes(|l| a[l].min(b[l]))
    }
    #[inline(always)]
    pub fn select(mask: Ux, a: Fx, b: Fx) -> Fx {
        lanes(|l| f32::from_bits((a[l].to_bits() & mask[l]) | (b[l].to_bits() & !mask[l])))
    }
    macro_rules! u2 {
        ($($name:ident => $f:expr),*) => {$(
            #[inline(always)]
            pub fn $name(a: Ux, b: Ux) -> Ux {
                lanes(|l| $f(a[l], b[l]))
            }
        )*};
    }
    u2!(and => |x: u32, y: u32| x & y, or => |x: u32, y: u32| x | y, xor => |x: u32, y: u32| x ^ y,
        eq_u => |x, y| m(x == y), ge_u => |x, y| m(x >= y));
    #[inline(always)]
    pub fn select_u(mask: Ux, a: Ux, b: Ux) -> Ux {
        lanes(|l| (a[l] & mask[l]) | (b[l] & !mask[l]))
    }
    #[inline(always)]
    pub fn bits(mask: Ux) -> u32 {
        mask.iter().enumerate().fold(0, |b, (l, &x)| b | ((x >> 31) << l))
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) use x86::*;

#[cfg(not(target_arch = "x86_64"))]
pub(super) use lanes::*;
