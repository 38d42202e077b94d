//! Tables of what single-scattering GGX lobes reflect, for the Principled BSDF's energy
//! compensation and layering (the quantities Cycles tabulates; computed here, once per
//! process and only when a scene uses them, by stratified quadrature over the visible
//! normals: a pure function of the grid, so every machine gets the same bits).
//!
//! Axes as Cycles lays them out: roughness r = √α and μ = cos θo on [0, 1], and for
//! dielectrics z = √|(η − 1)/(η + 1)| on [0, 0.99] (η = the IOR whose F0 is z⁴), so that
//! the common IORs get most of the resolution. Lookups interpolate linearly.

use std::sync::OnceLock;

use glam::{Vec2, Vec3};

use super::fresnel::{f0_from_ior, fresnel_dielectric, ior_from_f0};
use super::ggx_lobe::{Fresnel, GgxLobe};
use super::microfacet::Ggx;

/// Stratified samples per table entry (a square grid of visible normals).
const STRATA: usize = 24;

struct Table {
    n: [usize; 3],
    values: Vec<f32>,
}

impl Table {
    /// Entry (x, y, z) is `f(r, μ, η)` at the grid's node. On the calling thread: a table
    /// is built inside a `OnceLock`, and work-stealing there could run another render
    /// task that waits on the same lock (a deadlock).
    fn build(n: [usize; 3], f: impl Fn(f32, f32, f32) -> f32) -> Self {
        let node =
            |i: usize, n: usize, lo: f32, hi: f32| if n == 1 { 0.0 } else { (i as f32 / (n - 1) as f32).clamp(lo, hi) };
        let values = (0..n[0] * n[1] * n[2])
            .map(|k| {
                let (x, y, z) = (k % n[0], (k / n[0]) % n[1], k / (n[0] * n[1]));
                let r = node(x, n[0], 1e-4, 1.0);
                let mu = node(y, n[1], 1e-4, 1.0);
                let zz = node(z, n[2], 1e-4, 0.99);
                f(r, mu, ior_from_f0(zz * zz * zz * zz))
            })
            .collect();
        Self { n, values }
    }

    /// Linear interpolation at (x, y, z), each in [0, 1].
    fn lookup(&self, x: f32, y: f32, z: f32) -> f32 {
        let axis = |t: f32, n: usize| {
            let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 } * (n - 1) as f32;
            let i = (t as usize).min(n.saturating_sub(2));
            (i, (i + 1).min(n - 1), t - i as f32)
        };
        let [nx, ny, nz] = self.n;
        let (x0, x1, fx) = axis(x, nx);
        let (y0, y1, fy) = axis(y, ny);
        let (z0, z1, fz) = axis(z, nz);
        let at = |x: usize, y: usize, z: usize| self.values[(z * ny + y) * nx + x];
        let line = |y: usize, z: usize| at(x0, y, z) + (at(x1, y, z) - at(x0, y, z)) * fx;
        // A flat axis (one node) interpolates between a value and itself: skipping it
        // gives the same bits, for half the reads of a 2D table.
        let plane = |z: usize| {
            let a = line(y0, z);
            if y1 == y0 {
                return a;
            }
            a + (line(y1, z) - a) * fy
        };
        let p0 = plane(z0);
        if z1 == z0 {
            return p0;
        }
        p0 + (plane(z1) - p0) * fz
    }

    /// ∫₀¹ 2μ T(x, μ, z) dμ over the interpolated table (the cosine-weighted average).
    fn average_over_mu(&self, x: f32, z: f32) -> f32 {
        let n = 256;
        (0..n).map(|i| (i as f32 + 0.5) / n as f32).map(|mu| 2.0 * mu * self.lookup(x, mu, z)).sum::<f32>() / n as f32
    }
}

/// The mean over stratified visible normals seen from cos θo = `mu` of `f(lobe, wo, h)`.
fn visible_mean(lobe: &GgxLobe, mu: f32, f: impl Fn(&GgxLobe, Vec3, Vec3) -> f64) -> f32 {
    let wo = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let mut sum = 0.0f64;
    for i in 0..STRATA {
        for j in 0..STRATA {
            let u = Vec2::new((i as f32 + 0.5) / STRATA as f32, (j as f32 + 0.5) / STRATA as f32);
            let h = lobe.ggx.sample_visible(wo, u);
            sum += f(lobe, wo, h);
        }
    }
    (sum / (STRATA * STRATA) as f64).clamp(0.0, 1.0) as f32
}

fn lobe(r: f32, eta: f32, transmits: bool) -> GgxLobe {
    GgxLobe { ggx: Ggx::new(r * r), fresnel: Fresnel::One, eta, transmits, delta: false }
}

fn reflection_e() -> &'static Table {
    static T: OnceLock<Table> = OnceLock::new();
    T.get_or_init(|| {
        Table::build([32, 32, 1], |r, mu, _| visible_mean(&lobe(r, 1.0, false), mu, GgxLobe::table_weight))
    })
}

fn glass_e(inverse: bool) -> &'static Table {
    static T: [OnceLock<Table>; 2] = [OnceLock::new(), OnceLock::new()];
    T[usize::from(inverse)].get_or_init(|| {
        Table::build([16, 16, 16], |r, mu, eta| {
            let eta = if inverse { 1.0 / eta } else { eta };
            visible_mean(&lobe(r, eta, true), mu, GgxLobe::table_weight)
        })
    })
}

/// The mean position s of a reflection's exact dielectric Fresnel between its F0 and 1
/// (so that a tinted F0 gives F = f0 + (1 − f0) s).
fn dielectric_s() -> &'static Table {
    static T: OnceLock<Table> = OnceLock::new();
    T.get_or_init(|| {
        Table::build([16, 16, 16], |r, mu, eta| {
            let f0 = f0_from_ior(eta);
            visible_mean(&lobe(r, eta, false), mu, |_, wo, h| {
                let cos = wo.dot(h);
                let wi = 2.0 * cos * h - wo;
                if !(cos > 0.0 && wi.z > 0.0) {
                    return 0.0;
                }
                f64::from(((fresnel_dielectric(cos, eta) - f0) / (1.0 - f0)).clamp(0.0, 1.0))
            })
        })
    })
}

/// The mean of Schlick's (1 − wo·h)⁵ over a reflection (for metals' albedo estimate).
fn schlick_s() -> &'static Table {
    static T: OnceLock<Table> = OnceLock::new();
    T.get_or_init(|| {
        Table::build([16, 16, 1], |r, mu, _| {
            visible_mean(&lobe(r, 1.0, false), mu, |_, wo, h| {
                let cos = wo.dot(h);
                let wi = 2.0 * cos * h - wo;
                if !(cos > 0.0 && wi.z > 0.0) {
                    return 0.0;
                }
                f64::from((1.0 - cos).clamp(0.0, 1.0).powi(5))
            })
        })
    })
}

/// Builds every table now (the scene loader calls this for scenes with Principled
/// materials, so that no render thread waits for a table).
pub fn prepare() {
    reflection_e();
    reflection_albedo_average(0.5);
    glass_e_avg(false);
    glass_e_avg(true);
    dielectric_s();
    schlick_s();
}

fn z_of(eta: f32) -> f32 {
    ((eta - 1.0) / (eta + 1.0)).abs().sqrt()
}

/// E(r, μ): the fraction of light a GGX reflection lobe with F = 1 reflects once.
pub fn reflection_albedo(roughness: f32, mu: f32) -> f32 {
    reflection_e().lookup(roughness, mu, 0.0)
}

/// E_avg(r): the cosine-weighted average of [`reflection_albedo`] over μ.
pub fn reflection_albedo_average(roughness: f32) -> f32 {
    static AVG: OnceLock<Vec<f32>> = OnceLock::new();
    let avg = AVG.get_or_init(|| (0..64).map(|i| reflection_e().average_over_mu(i as f32 / 63.0, 0.0)).collect());
    interpolate(avg, roughness)
}

/// E(r, μ, η) of a rough dielectric interface (reflection plus refraction, exact Fresnel).
pub fn glass_albedo(roughness: f32, mu: f32, eta: f32) -> f32 {
    glass_e(eta < 1.0).lookup(roughness, mu, z_of(eta.max(1.0 / eta)))
}

/// E_avg(r, η) of a rough dielectric interface (tabulated from [`glass_albedo`] on its
/// own grid of r and z).
pub fn glass_albedo_average(roughness: f32, eta: f32) -> f32 {
    glass_e_avg(eta < 1.0).lookup(roughness, 0.0, z_of(eta.max(1.0 / eta)))
}

fn glass_e_avg(inverse: bool) -> &'static Table {
    static T: [OnceLock<Table>; 2] = [OnceLock::new(), OnceLock::new()];
    T[usize::from(inverse)].get_or_init(|| {
        let e = glass_e(inverse);
        let (nx, nz) = (e.n[0], e.n[2]);
        let values = (0..nx * nz)
            .map(|k| e.average_over_mu((k % nx) as f32 / (nx - 1) as f32, (k / nx) as f32 / (nz - 1) as f32))
            .collect();
        Table { n: [nx, 1, nz], values }
    })
}

/// s(r, μ, η): a rough dielectric reflection reflects f0 + (1 − f0) s of the light
/// (with F0 replaced by f0).
pub fn dielectric_fresnel_mean(roughness: f32, mu: f32, eta: f32) -> f32 {
    dielectric_s().lookup(roughness, mu, z_of(eta.max(1.0 / eta)))
}

/// s(r, μ) for Schlick's curve: a metal reflects about f0 + (1 − f0) s.
pub fn schlick_fresnel_mean(roughness: f32, mu: f32) -> f32 {
    schlick_s().lookup(roughness, mu, 0.0)
}

fn interpolate(values: &[f32], t: f32) -> f32 {
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 } * (values.len() - 1) as f32;
    let i = (t as usize).min(values.len() - 2);
    values[i] + (values[i + 1] - values[i]) * (t - i as f32)
}

/// Cycles' multiple-scattering compensation of a lobe seen from μ: the factor 1/E that
/// restores the energy single scattering loses, and the colour `darkening` that the
/// extra bounces' Fresnel (average `fss`) takes back (Kulla & Conty 2017's F_ms).
pub fn compensation(e: f32, e_avg: f32, fss: Vec3) -> (f32, Vec3) {
    let e = e.max(1e-3);
    let missing = (1.0 - e) / e;
    let scale = 1.0 + missing;
    if fss == Vec3::ONE {
        return (scale, Vec3::ONE);
    }
    let fms = fss * e_avg / (Vec3::ONE - fss * (1.0 - e_avg));
    (scale, (Vec3::ONE + fms * missing) / scale)
}

#[cfg(test)]
// Tests may use the C library's functions: they check values, not platform-free bits.
#[allow(clippy::disallowed_methods)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn tables_build_on_the_calling_thread() {
        let t = std::time::Instant::now();
        prepare();
        println!("tables built in {:.3} s", t.elapsed().as_secs_f64());
        // Inside rayon's pool, as a render's tiles would first touch them.
        let sum: f32 = (0..64).into_par_iter().map(|i| reflection_albedo(i as f32 / 63.0, 0.5)).sum();
        assert!(sum > 0.0);
    }

    #[test]
    fn smooth_lobes_lose_nothing_and_rough_ones_match_a_quadrature() {
        assert!((reflection_albedo(0.0, 0.5) - 1.0).abs() < 1e-3);
        assert!((reflection_albedo(0.05, 1.0) - 1.0).abs() < 2e-3);
        // α = 1, against a direct quadrature of ∫ D G2 / (4 μo) dωi over the hemisphere
        // (400 × 800 midpoints): 0.3069 at μ = 1, 0.4507 at 0.5, 0.7602 at 0.1.
        for (mu, expected) in [(1.0, 0.3069), (0.5, 0.4507), (0.1, 0.7602)] {
            let e = reflection_albedo(1.0, mu);
            assert!((e - expected).abs() < 0.01 * expected, "μ {mu}: {e} vs {expected}");
        }
        let avg = reflection_albedo_average(1.0);
        assert!(avg > 0.3 && avg < 0.76, "{avg}");
    }

    #[test]
    fn a_smooth_interface_keeps_all_energy_and_the_fresnel_mean_is_its_own() {
        for eta in [1.33f32, 1.5, 1.0 / 1.5] {
            for mu in [0.3f32, 0.8] {
                assert!(
                    (glass_albedo(0.0, mu, eta) - 1.0).abs() < 2e-3,
                    "η {eta} μ {mu}: {}",
                    glass_albedo(0.0, mu, eta)
                );
            }
        }
        // Smooth: s is the exact curve's own position at μ (on the grid's nodes: μ = 1).
        let eta = ior_from_f0(0.6f32.powi(4).min(0.99));
        let s = dielectric_fresnel_mean(0.0, 1.0, eta);
        assert!(s.abs() < 1e-3, "{s}");
    }
}
