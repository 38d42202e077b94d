//! The transcendental functions the renderer's results depend on, computed the same way
//! on every machine.
//!
//! A farm merges units rendered on different machines, and the image must not depend on
//! which machine rendered which unit. `f32::sin`, `powf` and the like call the
//! platform's C library, whose results are not specified to the bit: glibc, musl and
//! macOS differ, and glibc itself picks an FMA or an SSE2 build at run time. Every
//! function here is CORE-MATH's (the `core-math` crate, which compiles the project's C
//! sources): correctly rounded, i.e. the f32 nearest to the exact value. That result is
//! unique, so it is the same whatever the compiler, the instruction set (see
//! `.cargo/config.toml`) or the operating system.
//!
//! Not the `libm` crate: it is not correctly rounded (`accurate_against_f64` finds acos
//! off by 0.83 ulp), and it is much slower than CORE-MATH (`bench/RESULTS.md`).
//!
//! Only what sample values and scene data depend on goes through here (`clippy.toml`
//! disallows the `std` functions elsewhere); tests may use `std`'s.

/// `sin(x)` and `cos(x)`.
#[inline]
pub fn sin_cos(x: f32) -> (f32, f32) {
    core_math::sincosf(x)
}

#[inline]
pub fn sin(x: f32) -> f32 {
    core_math::sinf(x)
}

#[inline]
pub fn cos(x: f32) -> f32 {
    core_math::cosf(x)
}

#[inline]
pub fn tan(x: f32) -> f32 {
    core_math::tanf(x)
}

/// `acos(x)`, NaN outside `[-1, 1]`.
#[inline]
pub fn acos(x: f32) -> f32 {
    core_math::acosf(x)
}

/// The angle of `(x, y)`, as `y.atan2(x)`.
#[inline]
pub fn atan2(y: f32, x: f32) -> f32 {
    core_math::atan2f(y, x)
}

/// `x^y`.
#[inline]
pub fn powf(x: f32, y: f32) -> f32 {
    core_math::powf(x, y)
}

#[inline]
pub fn exp(x: f32) -> f32 {
    core_math::expf(x)
}

/// `e^x - 1`, precise for small `x`.
#[inline]
pub fn exp_m1(x: f32) -> f32 {
    core_math::expm1f(x)
}

/// Natural logarithm.
#[inline]
pub fn ln(x: f32) -> f32 {
    core_math::logf(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `|got - reference|` in ulps of an f32 of magnitude `max(|reference|, floor)`: near
    /// a zero of a function (sin at pi) a relative error says little, so `floor` is 1
    /// there.
    fn ulps(got: f32, reference: f64, floor: f64) -> f64 {
        let scale = reference.abs().max(floor).max(f32::MIN_POSITIVE as f64);
        let ulp = 2f64.powi(scale.log2().floor() as i32 - 23);
        (got as f64 - reference).abs() / ulp
    }

    /// Correctly rounded over the ranges the renderer uses: within half an ulp of the f64
    /// result (itself far more precise). That is what makes the bits platform-free, and
    /// it also catches a mix-up of two functions or a call to a less precise library.
    #[test]
    fn accurate_against_f64() {
        let mut worst = (0.0f64, "");
        let mut check = |what, got: f32, reference: f64, floor| {
            let e = ulps(got, reference, floor);
            if e > worst.0 {
                worst = (e, what);
            }
        };
        for i in 1..20_000 {
            let u = i as f32 / 20_000.0;
            let (uf, phi) = (u as f64, std::f32::consts::TAU * u);
            let (s, c) = sin_cos(phi);
            assert_eq!((s, c), (sin(phi), cos(phi)));
            check("sin", s, (phi as f64).sin(), 1.0);
            check("cos", c, (phi as f64).cos(), 1.0);
            let x = 2.0 * u - 1.0;
            // Negative angles too (the concentric disk map's span from -π/4).
            let (s, c) = sin_cos(4.0 * x);
            check("sin", s, (4.0 * x as f64).sin(), 1.0);
            check("cos", c, (4.0 * x as f64).cos(), 1.0);
            check("acos", acos(x), (x as f64).acos(), 0.0);
            check("atan2", atan2(x, 0.5 - u), (x as f64).atan2((0.5 - u) as f64), 1.0);
            let (a, b) = (1.5 * u, -20.0 * u);
            check("tan", tan(a), (a as f64).tan(), 0.0);
            check("ln", ln(u), uf.ln(), 0.0);
            check("exp", exp(b), (b as f64).exp(), 0.0);
            check("exp_m1", exp_m1(-u), (-u as f64).exp_m1(), 0.0);
            check("powf", powf(u, 37.5), uf.powf(37.5), 0.0);
        }
        assert!(worst.0 <= 0.5 + 1e-6, "{} is off by {} ulps", worst.1, worst.0);
    }

    /// Pinned results: the same bits on every platform is what this module is for, so a
    /// change of implementation that changes them shows here on whichever machine runs
    /// the tests. The last five are inputs where glibc 2.36 (`std` on Linux) or the
    /// `libm` crate return the neighbouring float, so a switch back to either fails.
    #[test]
    fn the_same_bits_everywhere() {
        // Through black_box: LLVM folds std's functions of constants at compile time (in
        // double precision), which would hide the C library's results.
        let b = std::hint::black_box::<f32>;
        let got = [
            sin_cos(b(1.234_567)).0.to_bits(),
            sin_cos(b(1.234_567)).1.to_bits(),
            tan(b(0.342_9)).to_bits(),
            acos(b(-0.777)).to_bits(),
            atan2(b(-0.3), b(-0.91)).to_bits(),
            powf(b(0.913), 117.0).to_bits(),
            exp(b(-3.75)).to_bits(),
            exp_m1(b(-1e-3)).to_bits(),
            ln(b(0.0061)).to_bits(),
            acos(b(f32::from_bits(0xbf7f_dbc2))).to_bits(), // glibc and libm: ...ef2
            exp(b(f32::from_bits(0xbc61_1dbc))).to_bits(),  // glibc: ...1b2
            exp(b(f32::from_bits(0xbb37_8035))).to_bits(),  // libm: ...8c2
            ln(b(f32::from_bits(0x3aac_9f30))).to_bits(),   // glibc: ...c9d
            sin(b(f32::from_bits(0xc0bf_ffce))).to_bits(),  // glibc: ...28d
        ];
        assert_eq!(got, PINNED, "{got:#010x?}");
    }

    const PINNED: [u32; 14] = [
        0x3f71aa57, 0x3ea8ec91, 0x3eb6c91d, 0x401d7bd2, 0xc034ae5e, 0x37c6f647, 0x3cc0a84a, 0xba8301a9, 0xc0a32ed4,
        0x4046eef3, 0x3f7c81b1, 0x3f7f48c1, 0xc0d43c9c, 0x3e8f128c,
    ];
}
