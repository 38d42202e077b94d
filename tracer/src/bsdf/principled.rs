//! Blender's Principled BSDF (4.x), layered as Cycles layers it.
//!
//! Seen from wo, the layers are set up top to bottom, each taking its share of a running
//! weight w (starting at 1) and leaving the rest to those below:
//!
//! 0. **sheen** (weight `sheen` · `sheen_tint`): the microfiber sheen lobe (see
//!    [`super::sheen`]) scaled by its albedo at wo; below it w shrinks by
//!    1 − max(sheen · sheen_tint · albedo);
//! 1. **coat** (weight `coat`): a GGX reflection with exact Fresnel of `coat_ior`, always
//!    energy-compensated; below it w shrinks by the coat's albedo at wo, and by
//!    `coat_tint` raised to the optical depth of the refracted view ray;
//! 2. **metal** (w · `metallic`): GGX with the F82-tint Fresnel (F0 = base colour, edge
//!    tint = `specular_tint`); then w ← w (1 − metallic);
//! 3. **glass** (w · `transmission`): a rough dielectric interface (reflection and
//!    refraction), F0 tinted by `specular_tint`, refraction tinted by √base colour (twice
//!    through a surface: the base colour); then w ← w (1 − transmission);
//! 4. **specular** (w): a GGX reflection whose Fresnel is exact for the IOR that
//!    `specular_ior_level` gives (0.5: `ior` itself; F0 scales by 2 · level), tinted by
//!    `specular_tint`; below it w shrinks by its albedo at wo ("albedo scaling");
//! 5. **diffuse** (w · base colour): Lambertian.
//!
//! GGX lobes use α = roughness². With `multiscatter` (Blender's default "Multiscatter
//! GGX") each lobe is scaled by 1/E(r, μo), restoring the energy that single scattering
//! loses, and coloured by its multiple-bounce Fresnel (see [`energy::compensation`]).
//!
//! The BSDF is the sum of its lobes; sampling picks a lobe in proportion to its
//! estimated albedo and evaluates the whole sum for the sampled direction (one-sample
//! MIS over the lobes). Smooth lobes (roughness ≈ 0) are delta lobes: sampled, never
//! evaluated.

use glam::{Vec2, Vec3};

use super::BsdfSample;
use super::bump_shadowing;
use super::energy;
use super::fresnel::{dielectric_average, f0_from_ior, f82_average, f82_b, ior_from_f0};
use super::ggx_lobe::{Fresnel, GgxLobe};
use super::lambert::Lambert;
use super::microfacet::Ggx;
use super::sheen::SheenLobe;
use crate::geometry::{Azimuth, Frame};
use crate::math::powf;
use crate::sampling::sample_cosine_hemisphere;

/// Below this, a layer's weight counts as zero (Cycles' CLOSURE_WEIGHT_CUTOFF).
const CUTOFF: f32 = 1e-5;

/// The Principled BSDF's inputs (Blender's names; the values after textures).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Principled {
    pub base_color: Vec3,
    pub metallic: f32,
    pub roughness: f32,
    pub ior: f32,
    pub specular_ior_level: f32,
    pub specular_tint: Vec3,
    pub transmission: f32,
    pub coat: f32,
    pub coat_roughness: f32,
    pub coat_ior: f32,
    pub coat_tint: Vec3,
    pub sheen: f32,
    pub sheen_roughness: f32,
    pub sheen_tint: Vec3,
    pub multiscatter: bool,
}

impl Default for Principled {
    /// Blender 4.2's defaults.
    fn default() -> Self {
        Self {
            base_color: Vec3::splat(0.8),
            metallic: 0.0,
            roughness: 0.5,
            ior: 1.5,
            specular_ior_level: 0.5,
            specular_tint: Vec3::ONE,
            transmission: 0.0,
            coat: 0.0,
            coat_roughness: 0.03,
            coat_ior: 1.5,
            coat_tint: Vec3::ONE,
            sheen: 0.0,
            sheen_roughness: 0.5,
            sheen_tint: Vec3::ONE,
            multiscatter: true,
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    Diffuse,
    Ggx(GgxLobe),
    /// The coat: a GGX lobe about the coat's own normal ([`Lobes::coat_frame`]).
    Coat(GgxLobe),
    Sheen(SheenLobe),
}

/// Sheen, coat, metal, glass, specular, diffuse.
const MAX_LOBES: usize = 6;

#[derive(Clone, Copy, Debug)]
struct Lobe {
    kind: Kind,
    /// The lobe's colour: layer weight × Fresnel darkening (× base colour for diffuse).
    weight: Vec3,
    /// 1/E for compensated GGX lobes, else 1.
    scale: f32,
    /// Unnormalised probability of sampling this lobe.
    sample_weight: f32,
}

/// The lobes of a Principled BSDF seen from one wo (in a frame where wo.z > 0).
#[derive(Clone, Copy, Debug)]
pub struct Lobes {
    lobes: [Lobe; MAX_LOBES],
    n: usize,
    total: f32,
    /// wo was below the surface: both directions are mirrored (see [`Principled::at`]).
    flipped: bool,
    /// With normal or bump maps: the tilted normal the diffuse lobe keeps (Cycles turns
    /// it for the glossy lobes only; the lobe is then Cycles' diffuse about it, front
    /// side only) and the surface's own shading normal, in the lobes' frame.
    tilted: Option<Tilted>,
    /// The coat's frame within the lobes' frame, where its normal differs from theirs
    /// (Blender's Coat Normal: a normal map on the surface's Normal leaves the coat
    /// smooth).
    coat_frame: Option<Frame>,
    /// The tangent's direction (cos, sin) in the frame's xy plane: anisotropic lobes are
    /// evaluated with it turned to x.
    tangent: Azimuth,
}

#[derive(Clone, Copy, Debug)]
struct Tilted {
    diffuse: Vec3,
    smooth: Vec3,
}

#[inline]
fn average(v: Vec3) -> f32 {
    (v.x + v.y + v.z) * (1.0 / 3.0)
}

#[inline]
fn saturate(v: Vec3) -> Vec3 {
    v.clamp(Vec3::ZERO, Vec3::ONE)
}

fn clean(x: f32, lo: f32, hi: f32, default: f32) -> f32 {
    if x.is_finite() { x.clamp(lo, hi) } else { default }
}

fn clean3(v: Vec3) -> Vec3 {
    Vec3::new(clean(v.x, 0.0, f32::MAX, 0.0), clean(v.y, 0.0, f32::MAX, 0.0), clean(v.z, 0.0, f32::MAX, 0.0))
}

impl Principled {
    /// Inputs held to their ranges (NaN to defaults), as Cycles clamps them.
    pub fn sanitized(mut self) -> Self {
        let d = Self::default();
        self.base_color = clean3(self.base_color);
        self.metallic = clean(self.metallic, 0.0, 1.0, 0.0);
        self.roughness = clean(self.roughness, 0.0, 1.0, d.roughness);
        self.ior = clean(self.ior, 1e-5, 1e5, d.ior);
        self.specular_ior_level = clean(self.specular_ior_level, 0.0, 1e5, d.specular_ior_level);
        self.specular_tint = clean3(self.specular_tint);
        self.transmission = clean(self.transmission, 0.0, 1.0, 0.0);
        self.coat = clean(self.coat, 0.0, 1e5, 0.0);
        self.coat_roughness = clean(self.coat_roughness, 0.0, 1.0, d.coat_roughness);
        self.coat_ior = clean(self.coat_ior, 1.0, 1e5, d.coat_ior);
        self.coat_tint = clean3(self.coat_tint);
        self.sheen = clean(self.sheen, 0.0, 1e5, 0.0);
        self.sheen_roughness = clean(self.sheen_roughness, 0.0, 1.0, d.sheen_roughness);
        self.sheen_tint = clean3(self.sheen_tint);
        self
    }

    /// Whether light can pass through (the surface then knows its inside from its
    /// outside, as glass does).
    pub fn transmits(&self) -> bool {
        self.transmission * (1.0 - self.metallic) > CUTOFF
    }

    /// Whether every lobe is a delta lobe (no point sampling lights).
    pub fn is_delta(&self) -> bool {
        let smooth = Ggx::is_delta(self.roughness * self.roughness);
        let no_diffuse = self.metallic >= 1.0 || self.transmission >= 1.0;
        let coat_smooth = self.coat <= CUTOFF || Ggx::is_delta(self.coat_roughness * self.coat_roughness);
        smooth && no_diffuse && coat_smooth && self.sheen <= CUTOFF
    }

    /// The albedo layer's colour.
    pub fn albedo(&self) -> Vec3 {
        saturate(self.base_color)
    }

    /// The lobes seen from `wo` (local frame, z = the shading normal). A surface that
    /// transmits is oriented (z = outside) and wo below it sees the interface from
    /// inside (IOR inverted); otherwise it is two-sided. Either way the lobes live in
    /// a frame where wo is above.
    pub fn at(&self, wo: Vec3) -> Lobes {
        self.at_with(wo, None, None)
    }

    /// [`Self::at`], with the coat about its own unit normal `coat_normal` (same frame),
    /// as Blender's Coat Normal (unlinked: the surface's normal before normal maps); and
    /// with `anisotropy` (Blender's Anisotropic in [0, 1], and the tangent's direction in
    /// the frame's xy plane as (cos, sin)): the metal and specular lobes stretch along the
    /// tangent, α_x = α / √(1 − 0.9 a) and α_y = α √(1 − 0.9 a), as Cycles does.
    // Long on purpose: Cycles' layer stack in its order, one running weight through it; split, the order would be harder to check against the source.
    pub fn at_with(&self, wo: Vec3, coat_normal: Option<Vec3>, anisotropy: Option<(f32, Vec2)>) -> Lobes {
        let p = self;
        let flipped = wo.z < 0.0;
        let mu = wo.z.abs().min(1.0);
        let mirror = |v: Vec3| if flipped { Vec3::new(v.x, v.y, -v.z) } else { v };
        let coat_frame = coat_normal.filter(|_| p.coat > CUTOFF).map(|n| Frame::from_normal(mirror(n)));
        let mut lobes = Lobes {
            lobes: [Lobe { kind: Kind::Diffuse, weight: Vec3::ZERO, scale: 1.0, sample_weight: 0.0 }; MAX_LOBES],
            n: 0,
            total: 0.0,
            flipped,
            tilted: None,
            coat_frame,
            tangent: Azimuth::X,
        };
        let push = |lobes: &mut Lobes, kind: Kind, weight: Vec3, scale: f32, albedo: f32| {
            let sample_weight = average(weight) * albedo;
            if lobes.n < MAX_LOBES && sample_weight > 0.0 && sample_weight.is_finite() {
                lobes.lobes[lobes.n] = Lobe { kind, weight, scale, sample_weight };
                lobes.n += 1;
                lobes.total += sample_weight;
            }
        };
        let ggx_lobe = |roughness: f32, fresnel: Fresnel, eta: f32, transmits: bool| {
            let alpha = roughness * roughness;
            GgxLobe { ggx: Ggx::new(alpha), fresnel, eta, transmits, delta: Ggx::is_delta(alpha) }
        };
        // Anisotropic lobes (metal, specular) in the tangent's frame.
        let anisotropy = anisotropy.filter(|(a, t)| *a > 0.0 && t.is_finite() && t.length_squared() > 0.0);
        if let Some((_, t)) = anisotropy {
            lobes.tangent = Azimuth(t.normalize());
        }
        let stretched = |mut lobe: GgxLobe| {
            if let Some((a, _)) = anisotropy
                && !lobe.delta
            {
                let (alpha, aspect) = (lobe.ggx.alpha, (1.0 - 0.9 * a.min(1.0)).sqrt());
                lobe.ggx = Ggx::anisotropic(alpha / aspect, alpha * aspect);
            }
            lobe
        };
        let mut w = Vec3::ONE;

        // 0. Sheen, on top.
        if p.sheen > CUTOFF
            && let Some((lobe, albedo)) = SheenLobe::at(p.sheen_roughness, Vec3::new(wo.x, wo.y, mu))
        {
            let layer = p.sheen * p.sheen_tint * albedo;
            push(&mut lobes, Kind::Sheen(lobe), w * layer, 1.0, 1.0);
            w *= (1.0 - layer.max_element()).clamp(0.0, 1.0);
        }

        // 1. Coat (seen from wo in its own frame, if it has one).
        if p.coat > CUTOFF {
            let mu = coat_frame.map_or(mu, |f| f.to_local(mirror(wo)).z.clamp(0.0, 1.0));
            let r = p.coat_roughness;
            let lobe = ggx_lobe(r, Fresnel::Dielectric { eta: p.coat_ior }, p.coat_ior, false);
            let (scale, dark) = energy::compensation(
                energy::reflection_albedo(r, mu),
                energy::reflection_albedo_average(r),
                Vec3::splat(dielectric_average(p.coat_ior)),
            );
            let f0 = f0_from_ior(p.coat_ior);
            let estimate = f0 + (1.0 - f0) * energy::dielectric_fresnel_mean(r, mu, p.coat_ior);
            let weight = w * p.coat * dark;
            push(&mut lobes, Kind::Coat(lobe), weight, scale, estimate);
            w *= (1.0 - (p.coat * dark * estimate).max_element()).clamp(0.0, 1.0);
            if p.coat_tint != Vec3::ONE {
                let inv = 1.0 / p.coat_ior;
                let cos_t = (1.0 - inv * inv * (1.0 - mu * mu)).max(0.0).sqrt();
                let depth = 1.0 / cos_t.max(1e-4);
                let through =
                    Vec3::new(powf(p.coat_tint.x, depth), powf(p.coat_tint.y, depth), powf(p.coat_tint.z, depth));
                w *= Vec3::ONE.lerp(through, p.coat.min(1.0));
            }
        }
        let base = saturate(p.base_color);
        let r = p.roughness;
        let compensate = |e: f32, e_avg: f32, fss: Vec3| {
            if p.multiscatter { energy::compensation(e, e_avg, fss) } else { (1.0, Vec3::ONE) }
        };

        // 2. Metal.
        if p.metallic > CUTOFF {
            let b = f82_b(base, p.specular_tint.min(Vec3::ONE));
            let lobe = stretched(ggx_lobe(r, Fresnel::F82 { f0: base, b }, 1.0, false));
            let (scale, dark) = compensate(
                energy::reflection_albedo(r, mu),
                energy::reflection_albedo_average(r),
                saturate(f82_average(base, b)),
            );
            let estimate = average(base.lerp(Vec3::ONE, energy::schlick_fresnel_mean(r, mu)));
            push(&mut lobes, Kind::Ggx(lobe), w * p.metallic * dark, scale, estimate);
            w *= 1.0 - p.metallic;
        }

        // 3. Glass.
        if p.transmission > CUTOFF {
            let eta = if flipped { 1.0 / p.ior } else { p.ior };
            let f0 = saturate(Vec3::splat(f0_from_ior(p.ior)) * p.specular_tint);
            let transmit = Vec3::new(base.x.sqrt(), base.y.sqrt(), base.z.sqrt());
            let lobe = ggx_lobe(r, Fresnel::Tinted { eta, f0, transmit }, eta, true);
            let (scale, dark) =
                compensate(energy::glass_albedo(r, mu, eta), energy::glass_albedo_average(r, eta), transmit);
            let s = energy::dielectric_fresnel_mean(r, mu, eta);
            let reflected = f0.lerp(Vec3::ONE, s);
            let estimate = average(reflected + (Vec3::ONE - reflected) * transmit);
            push(&mut lobes, Kind::Ggx(lobe), w * p.transmission * dark, scale, estimate);
            w *= 1.0 - p.transmission;
        }

        // 4. Dielectric specular, with the IOR that Specular IOR Level implies.
        let (mut eta, mut f0) = (p.ior, f0_from_ior(p.ior));
        if p.specular_ior_level != 0.5 {
            f0 *= 2.0 * p.specular_ior_level;
            eta = ior_from_f0(f0);
            if p.ior < 1.0 {
                eta = 1.0 / eta;
            }
        }
        if eta != 1.0 && w.max_element() > CUTOFF {
            let f0 = saturate(Vec3::splat(f0) * p.specular_tint);
            let lobe = stretched(ggx_lobe(r, Fresnel::Tinted { eta, f0, transmit: Vec3::ZERO }, eta, false));
            let real0 = f0_from_ior(eta);
            let s_avg = ((dielectric_average(eta) - real0) / (1.0 - real0)).clamp(0.0, 1.0);
            let (scale, dark) = compensate(
                energy::reflection_albedo(r, mu),
                energy::reflection_albedo_average(r),
                f0.lerp(Vec3::ONE, s_avg),
            );
            let reflected = f0.lerp(Vec3::ONE, energy::dielectric_fresnel_mean(r, mu, eta));
            push(&mut lobes, Kind::Ggx(lobe), w * dark, scale, average(reflected));
            w *= (1.0 - (dark * reflected).max_element()).clamp(0.0, 1.0);
        }

        // 5. Diffuse: the base colour as given (Cycles does not clamp it here).
        push(&mut lobes, Kind::Diffuse, w * p.base_color, 1.0, 1.0);
        lobes
    }
}

impl Lobes {
    #[inline]
    fn local(&self, v: Vec3) -> Vec3 {
        if self.flipped { Vec3::new(v.x, v.y, -v.z) } else { v }
    }

    /// The lobes of a surface whose normal maps tilted its shading normal `smooth` to
    /// `diffuse` (both unit, in the frame the lobes were set up in): the diffuse lobe is
    /// about `diffuse`, and diffuse and sheen lobes are shadowed as Cycles shadows them
    /// ([`bump_shadowing`]).
    pub fn with_tilted_normal(mut self, diffuse: Vec3, smooth: Vec3) -> Self {
        self.tilted = Some(Tilted { diffuse: self.local(diffuse), smooth: self.local(smooth) });
        self
    }

    /// The diffuse lobe's f cos θi and its pdf at `wi`.
    #[inline]
    fn diffuse(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        match self.tilted {
            Some(t) => {
                let c = (wi.dot(t.diffuse) * std::f32::consts::FRAC_1_PI).max(0.0);
                (Vec3::splat(c * bump_shadowing(t.smooth, t.diffuse, wi)), c)
            }
            None => {
                let l = Lambert { kd: Vec3::ONE };
                (l.eval(wo, wi), l.pdf(wo, wi))
            }
        }
    }

    /// f cos θi and the pdf of [`Self::sample`] (the non-delta lobes').
    pub fn eval_pdf(&self, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        let (wo, wi) = (self.local(wo), self.local(wi));
        let (mut f, mut pdf) = (Vec3::ZERO, 0.0);
        for lobe in &self.lobes[..self.n] {
            let (lf, lp) = match lobe.kind {
                Kind::Diffuse => self.diffuse(wo, wi),
                Kind::Ggx(g) if g.ggx.is_anisotropic() => {
                    g.eval_pdf(self.tangent.to_local(wo), self.tangent.to_local(wi))
                }
                Kind::Ggx(g) => g.eval_pdf(wo, wi),
                Kind::Coat(g) => match self.coat_frame {
                    Some(c) => g.eval_pdf(c.to_local(wo), c.to_local(wi)),
                    None => g.eval_pdf(wo, wi),
                },
                Kind::Sheen(s) => {
                    let d = s.density(wi);
                    let shadow = self.tilted.map_or(1.0, |t| bump_shadowing(t.smooth, t.diffuse, wi));
                    (Vec3::splat(d * shadow), d)
                }
            };
            f += lobe.weight * lobe.scale * lf;
            pdf += lobe.sample_weight * lp;
        }
        if self.total > 0.0 { (f, pdf / self.total) } else { (Vec3::ZERO, 0.0) }
    }

    /// Picks a lobe with `u_lobe` (rescaled within the lobe's share to choose reflection
    /// or refraction), samples it with `u`, and weights by the whole BSDF over the
    /// mixture's pdf; a delta lobe's sample is weighted by that lobe alone.
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if !(self.total > 0.0) || wo.z == 0.0 || !wo.is_finite() {
            return None;
        }
        let target = u_lobe * self.total;
        let mut start = 0.0;
        let mut pick = self.n - 1;
        for (k, lobe) in self.lobes[..self.n].iter().enumerate() {
            if target < start + lobe.sample_weight || k == self.n - 1 {
                pick = k;
                break;
            }
            start += lobe.sample_weight;
        }
        let lobe = &self.lobes[pick];
        let u_choice = ((target - start) / lobe.sample_weight).clamp(0.0, 1.0 - f32::EPSILON);
        let wo_l = self.local(wo);
        let wi_l = match lobe.kind {
            Kind::Diffuse => match self.tilted {
                Some(t) => Frame::from_normal(t.diffuse).to_world(sample_cosine_hemisphere(u)),
                None => Lambert { kd: Vec3::ONE }.sample(wo_l, u)?.wi,
            },
            Kind::Sheen(s) => s.sample(u)?,
            Kind::Ggx(g) | Kind::Coat(g) => {
                // The coat in its own frame: there and back.
                let frame = match lobe.kind {
                    Kind::Coat(_) => self.coat_frame,
                    _ => None,
                };
                let wo_g = frame.map_or(wo_l, |f| f.to_local(wo_l));
                if g.ggx.is_anisotropic() {
                    let (wi, _, _) = g.sample_direction(self.tangent.to_local(wo_g), u_choice, u)?;
                    self.tangent.to_world(wi)
                } else if !g.delta {
                    // The direction only: the whole mixture is evaluated there below.
                    let (wi, _, _) = g.sample_direction(wo_g, u_choice, u)?;
                    frame.map_or(wi, |f| f.to_world(wi))
                } else {
                    let s = g.sample(wo_g, u_choice, u)?;
                    let wi_g = frame.map_or(s.wi, |f| f.to_world(s.wi));
                    let p = lobe.sample_weight / self.total * s.pdf;
                    let weight = lobe.weight * lobe.scale * s.value / p;
                    return weight.is_finite().then_some(BsdfSample {
                        wi: self.local(wi_g),
                        weight,
                        pdf: p,
                        delta: true,
                    });
                }
            }
        };
        let wi = self.local(wi_l);
        let (f, pdf) = self.eval_pdf(wo, wi);
        if !(pdf > 0.0 && pdf.is_finite()) {
            return None;
        }
        let weight = f / pdf;
        weight.is_finite().then_some(BsdfSample { wi, weight, pdf, delta: false })
    }
}
