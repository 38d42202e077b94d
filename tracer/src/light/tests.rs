//! Tests of `light.rs`.
#![allow(clippy::disallowed_methods)] // values checked, not platform-free bits

use super::*;

#[test]
fn selection_follows_power() {
    let lights = vec![
        Light::Point { position: Vec3::ZERO, intensity: Vec3::ONE },
        Light::Point { position: Vec3::ZERO, intensity: Vec3::ZERO },
        Light::Point { position: Vec3::ZERO, intensity: Vec3::splat(3.0) },
    ];
    let set = LightSet::new(lights, 0, 1.0);
    assert!((set.pmf(0) - 0.25).abs() < 1e-6 && set.pmf(1) == 0.0 && (set.pmf(2) - 0.75).abs() < 1e-6);
    assert_eq!(set.select(0.1).unwrap().0, 0);
    assert_eq!(set.select(0.25).unwrap().0, 2);
    assert_eq!(set.select(0.999_999_9).unwrap().0, 2);
    assert!(LightSet::new(vec![], 0, 1.0).select(0.5).is_none());
}

#[test]
fn area_lights_are_found_by_primitive() {
    let tri = |prim: u32| Light::Triangle {
        prim,
        p0: Vec3::ZERO,
        e1: Vec3::X,
        e2: Vec3::Z,
        normal: -Vec3::Y,
        area: 0.5,
        radiance: Vec3::ONE,
    };
    // Lights in file order, primitives in storage order (not sorted).
    let lights = vec![
        tri(9),
        Light::Point { position: Vec3::ZERO, intensity: Vec3::ONE },
        tri(2),
        Light::Sphere { prim: 12, center: Vec3::ZERO, radius: 1.0, radiance: Vec3::ONE },
        tri(5),
        Light::Environment { radiance: Vec3::ONE },
    ];
    let set = LightSet::new(lights, 13, 1.0);
    let found: Vec<Option<usize>> = (0..14).map(|p| set.light_of_prim(p)).collect();
    let mut expect = vec![None; 14];
    (expect[9], expect[2], expect[12], expect[5]) = (Some(0), Some(2), Some(3), Some(4));
    assert_eq!(found, expect);
    assert_eq!(set.environment(), Some(5));
    assert_eq!(LightSet::new(vec![], 0, 1.0).light_of_prim(0), None);
}

fn mixed_lights() -> Vec<Light> {
    vec![
        Light::Point { position: Vec3::new(0.0, 3.0, 0.0), intensity: Vec3::ONE },
        Light::Triangle {
            prim: 0,
            p0: Vec3::new(-1.0, 2.0, -1.0),
            e1: Vec3::new(2.0, 0.0, 0.0),
            e2: Vec3::new(0.0, 0.0, 2.0),
            normal: -Vec3::Y,
            area: 2.0,
            radiance: Vec3::splat(5.0),
        },
        Light::Sphere { prim: 1, center: Vec3::new(4.0, 1.0, 0.0), radius: 0.5, radiance: Vec3::splat(20.0) },
        Light::Directional { direction: -Vec3::Y, irradiance: Vec3::splat(0.5) },
        Light::Environment { radiance: Vec3::splat(0.1) },
    ]
}

#[test]
fn selection_at_a_point_matches_its_pmf() {
    let set = LightSet::new(mixed_lights(), 2, 10.0);
    const N: usize = 1 << 16;
    for p in [Vec3::ZERO, Vec3::new(3.5, 1.0, 0.2), Vec3::new(0.0, 2.5, 0.0), Vec3::new(4.0, 1.1, 0.0)] {
        let pmfs: Vec<f32> = (0..set.lights.len()).map(|i| set.pmf_at(p, i)).collect();
        assert!((pmfs.iter().sum::<f32>() - 1.0).abs() < 1e-5, "{pmfs:?}");
        let mut counts = vec![0usize; set.lights.len()];
        let mut remapped_sum = vec![0.0f64; set.lights.len()];
        for k in 0..N {
            let u = (k as f32 + 0.5) / N as f32;
            let (i, pmf, ur) = set.select_at(p, u).unwrap();
            assert_eq!(pmf, pmfs[i], "the pmf returned is pmf_at's, bit for bit");
            assert!((0.0..1.0).contains(&ur));
            counts[i] += 1;
            remapped_sum[i] += f64::from(ur);
        }
        for i in 0..set.lights.len() {
            let freq = counts[i] as f32 / N as f32;
            assert!((freq - pmfs[i]).abs() < 1e-3, "light {i} at {p}: {freq} vs {}", pmfs[i]);
            if counts[i] > 100 {
                // The rescaled coordinate is uniform within the light's interval.
                assert!((remapped_sum[i] / counts[i] as f64 - 0.5).abs() < 0.01);
            }
        }
    }
    // Above the downward-facing triangle and inside the sphere nothing is selected.
    let above = Vec3::new(0.0, 2.5, 0.0);
    assert_eq!(set.pmf_at(above, 1), 0.0);
    assert_eq!(set.pmf_at(Vec3::new(4.0, 1.1, 0.0), 2), 0.0);
    // The closer light is preferred.
    assert!(set.pmf_at(Vec3::new(3.2, 1.0, 0.0), 2) > set.pmf_at(Vec3::new(-3.0, 1.0, 0.0), 2));
}

#[test]
fn many_lights_walk_the_hierarchy_and_its_pmf_is_the_walk() {
    // 300 lights of every bounded kind and a sun, scattered over a box: the chosen
    // light's pmf equals pmf_at bit for bit, and the choices' frequencies follow the pmfs.
    // Their sum may fall short of 1 where a node's bounds reach a point that none of its
    // children's do (the walk then chooses nothing, as pbrt-v4's does).
    let mut lights = Vec::new();
    for i in 0..300u32 {
        let f = |k: u32| ((i * 7919 + k * 104_729) % 1000) as f32 / 1000.0;
        let pos = Vec3::new(10.0 * f(1) - 5.0, 4.0 * f(2), 10.0 * f(3) - 5.0);
        lights.push(match i % 4 {
            0 => Light::Point { position: pos, intensity: Vec3::splat(0.1 + f(4)) },
            1 => Light::Triangle {
                prim: i,
                p0: pos,
                e1: Vec3::new(0.2, 0.0, 0.0),
                e2: Vec3::new(0.0, 0.0, 0.2),
                normal: -Vec3::Y,
                area: 0.02,
                radiance: Vec3::splat(5.0 * f(5)),
            },
            2 => Light::Spot {
                position: pos,
                direction: -Vec3::Y,
                intensity: Vec3::splat(2.0),
                cos_total: 0.7,
                cos_falloff_start: 0.9,
            },
            _ => Light::Sphere { prim: i, center: pos, radius: 0.1, radiance: Vec3::splat(1.0 + f(6)) },
        });
    }
    lights.push(Light::Directional { direction: -Vec3::Y, irradiance: Vec3::splat(0.5) });
    let set = LightSet::new(lights, 300, 8.0);
    assert!(set.tree_bytes() > 0);
    let p = Vec3::new(0.5, 1.0, -0.3);
    let total: f64 = (0..set.lights.len()).map(|i| f64::from(set.pmf_at(p, i))).sum();
    assert!(total > 0.99 && total < 1.0 + 1e-4, "pmfs sum to {total}");
    let n = 200_000;
    let mut counts = vec![0u32; set.lights.len()];
    for k in 0..n {
        let u = (k as f32 + 0.5) / n as f32;
        let Some((i, pmf, ur)) = set.select_at(p, u) else { continue };
        assert_eq!(pmf, set.pmf_at(p, i), "light {i}");
        assert!((0.0..1.0).contains(&ur));
        counts[i] += 1;
    }
    for (i, &c) in counts.iter().enumerate() {
        let expect = f64::from(set.pmf_at(p, i)) * f64::from(n);
        assert!((f64::from(c) - expect).abs() <= 4.0 * expect.sqrt() + 2.0, "light {i}: {c} against {expect}");
    }
    // Nothing is chosen that cannot reach p (the downward triangles above it can).
    let below = Vec3::new(0.0, 10.0, 0.0);
    for i in (1..300).step_by(4) {
        assert_eq!(set.pmf_at(below, i), 0.0, "a triangle facing away from {below}");
    }
    // By power alone once the hierarchy is dropped.
    let mut power = set.clone();
    power.use_power_selection();
    assert_eq!(power.pmf_at(p, 7), power.pmf(7));
}

#[test]
fn sphere_cone_samples_lie_on_sphere_with_matching_pdf() {
    let (c, r) = (Vec3::new(0.3, 4.0, -1.0), 0.7);
    let l = Light::Sphere { prim: 0, center: c, radius: r, radiance: Vec3::ONE };
    let p = Vec3::new(0.0, 0.0, 0.5);
    for i in 0..64 {
        let u = Vec2::new((i % 8) as f32 / 8.0 + 0.03, (i / 8) as f32 / 8.0 + 0.05);
        let s = l.sample_li(p, u).unwrap();
        let (_, q, pdf) = sample_sphere_cone(p, c, r, u).unwrap();
        assert!(((q - c).length() - r).abs() < 1e-4);
        // The sampled point is visible from p (on the near side).
        assert!((q - c).dot(p - q) >= -1e-4);
        assert!((l.pdf_li(p, s.wi, q) - pdf).abs() / pdf < 1e-4);
    }
    assert!(l.sample_li(c, Vec2::splat(0.5)).is_none());
}

#[test]
fn triangle_light_is_one_sided() {
    let l = Light::Triangle {
        prim: 0,
        p0: Vec3::ZERO,
        e1: Vec3::X,
        e2: Vec3::Y,
        normal: Vec3::Z,
        area: 0.5,
        radiance: Vec3::ONE,
    };
    assert!(l.sample_li(Vec3::new(0.2, 0.2, 1.0), Vec2::splat(0.3)).is_some());
    assert!(l.sample_li(Vec3::new(0.2, 0.2, -1.0), Vec2::splat(0.3)).is_none());
}

#[test]
fn spot_falls_off_smoothly_to_zero_at_the_cone() {
    let cos = |deg: f32| deg.to_radians().cos();
    let l = Light::Spot {
        position: Vec3::ZERO,
        direction: -Vec3::Y,
        intensity: Vec3::ONE,
        cos_total: cos(30.0),
        cos_falloff_start: cos(20.0),
    };
    let at = |deg: f32| {
        let p = Vec3::new(deg.to_radians().sin(), -deg.to_radians().cos(), 0.0);
        l.sample_li(p, Vec2::ZERO).map_or(0.0, |s| s.li.x)
    };
    assert!((at(0.0) - 1.0).abs() < 1e-5 && (at(19.0) - 1.0).abs() < 1e-5);
    assert!(at(25.0) > 0.0 && at(25.0) < 1.0 && at(31.0) == 0.0);
}

/// [`LightSet::select_at_wide`] and [`LightSet::sample_li_wide`] give, lane by lane,
/// their scalar twins' bits: which light, its pmf and the rescaled coordinate; whether
/// a sample exists, its direction, radiance, pdf, end point and kind — for every kind of
/// light, at points all around them (behind the one-sided triangle, inside the sphere,
/// outside the spot's cone).
#[test]
fn the_wide_light_choice_and_samples_are_their_scalar_twins() {
    let simd = crate::simd::tests::require_avx2();
    let mut lights = mixed_lights();
    lights.push(Light::Spot {
        position: Vec3::new(-2.0, 3.0, 1.0),
        direction: Vec3::new(0.3, -1.0, 0.0).normalize(),
        intensity: Vec3::splat(4.0),
        cos_total: 0.8,
        cos_falloff_start: 0.9,
    });
    let set = LightSet::new(lights, 2, 10.0);
    assert!(set.wide_ok());
    let mut h = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        h = h.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (h >> 40) as f32 / (1u64 << 24) as f32
    };
    let bits = |v: Vec3| v.to_array().map(f32::to_bits);
    let (mut chosen_lanes, mut sampled_lanes, mut kinds) = (0, 0, [0usize; 6]);
    for k in 0..4000 {
        let p: [Vec3; 8] =
            std::array::from_fn(|_| Vec3::new(10.0 * next() - 5.0, 6.0 * next() - 2.0, 4.0 * next() - 2.0));
        let u: [f32; 8] = std::array::from_fn(|_| next());
        let u2: [Vec2; 8] = std::array::from_fn(|_| Vec2::new(next(), next()));
        let pw = simd.v3_from_fn(|l| p[l]);
        let (light, pmf, ux, chosen) = set.select_at_wide(pw, simd.f8(u));
        for l in 0..8 {
            match set.select_at(p[l], u[l]) {
                Some((i, pm, ur)) => {
                    assert_ne!(chosen.0[l], 0, "lane {l} at {}: should choose", p[l]);
                    assert_eq!(
                        (light.0[l] as usize, pmf.0[l].to_bits(), ux.0[l].to_bits()),
                        (i, pm.to_bits(), ur.to_bits()),
                        "choice at {}",
                        p[l]
                    );
                    chosen_lanes += 1;
                }
                None => assert_eq!(chosen.0[l], 0, "lane {l} at {}: nothing to choose", p[l]),
            }
        }
        let which = simd.u8(std::array::from_fn(|l| ((k + l) % set.lights.len()) as u32));
        let uv = V2w { x: simd.f8(std::array::from_fn(|l| u2[l].x)), y: simd.f8(std::array::from_fn(|l| u2[l].y)) };
        let s = set.sample_li_wide(which, pw, uv, simd.all());
        for l in 0..8 {
            let i = which.0[l] as usize;
            match set.lights[i].sample_li(p[l], u2[l]) {
                Some(x) => {
                    assert_ne!(s.some.0[l], 0, "light {i} at {}: should sample", p[l]);
                    assert_eq!(
                        (bits(s.wi.get(l)), bits(s.li.get(l)), s.pdf.0[l].to_bits(), s.delta.0[l] != 0),
                        (bits(x.wi), bits(x.li), x.pdf.to_bits(), x.delta),
                        "light {i} at {}",
                        p[l]
                    );
                    match x.target {
                        Some(t) => {
                            assert_eq!(s.at_infinity.0[l], 0);
                            assert_eq!(bits(s.target.get(l)), bits(t), "light {i} target");
                        }
                        None => assert_ne!(s.at_infinity.0[l], 0),
                    }
                    sampled_lanes += 1;
                    kinds[i] += 1;
                }
                None => assert_eq!(s.some.0[l], 0, "light {i} at {}: no sample", p[l]),
            }
        }
    }
    assert!(chosen_lanes > 20_000 && sampled_lanes > 15_000, "{chosen_lanes} chosen, {sampled_lanes} sampled");
    assert!(kinds.iter().all(|&n| n > 1000), "every kind sampled: {kinds:?}");
}
