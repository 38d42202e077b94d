//! Lights with a size. `[[light]] type = "area"`: Blender's area light, placed by its
//! matrix or by position, direction and up, as a [`Light::Area`] — or, with
//! `visible = true`, as the emissive surface it used to be (seen by the camera, casting
//! shadows). A point or spot light's `radius` and a directional light's `angle`: the
//! soft lights of `light/soft.rs`.

use std::f32::consts::PI;

use glam::{Mat3, Vec3};

use super::builder::Builder;
use super::error::SceneError;
use super::file::{AreaDesc, AreaShapeDesc, AreaSize, LightDesc};
use super::placement::from_rows;
use super::{NONE, Tri};
use crate::light::{Area, AreaShape, Cone, Light, SoftPoint, Sun};
use crate::material::{Material, MaterialDesc};

/// `hard`, the light `desc` describes without its size, with its size: a point or spot
/// with `radius` > 0 as a disk, a directional light with `angle` > 0 as a sun's disc. A
/// size of 0 (or none) keeps the hard light, bit for bit.
pub(super) fn soften(
    hard: Light,
    desc: &LightDesc,
    field: &dyn Fn(&str) -> String,
    invalid: &dyn Fn(String, String) -> SceneError,
) -> Result<Light, SceneError> {
    let size = match *desc {
        LightDesc::Point { radius, .. } | LightDesc::Spot { radius, .. } => radius.map(|r| ("radius", r)),
        LightDesc::Directional { angle, .. } => angle.map(|a| ("angle", a)),
        LightDesc::Area(_) => None,
    };
    let Some((key, size)) = size.filter(|&(_, s)| s != 0.0) else { return Ok(hard) };
    if key == "angle" && !(size > 0.0 && size < 180.0) {
        return Err(invalid(
            field(key),
            format!("must be in [0, 180) degrees (the sun's angular diameter), got {size}"),
        ));
    }
    if !(size > 0.0 && size.is_finite()) {
        return Err(invalid(field(key), format!("must be finite and ≥ 0, got {size}")));
    }
    let disk = |position: Vec3, intensity: Vec3, cone| {
        let radiance = intensity / (PI * size * size);
        Light::SoftPoint(SoftPoint { position, radius: size, radiance, cone })
    };
    Ok(match hard {
        Light::Point { position, intensity } => disk(position, intensity, None),
        Light::Spot { position, direction, intensity, cos_total, cos_falloff_start } => {
            disk(position, intensity, Some(Cone { direction, cos_total, cos_falloff_start }))
        }
        Light::Directional { direction, irradiance } => {
            let half = 0.5 * size.to_radians();
            let sin_half = crate::math::sin(half);
            let one_minus_cos = 2.0 * crate::math::sin(0.5 * half).powi(2);
            Light::Sun(Sun { direction, radiance: irradiance / (PI * sin_half * sin_half), one_minus_cos })
        }
        other => other,
    })
}

/// Segments of a visible ellipse's outline.
const ELLIPSE_SEGMENTS: usize = 64;

/// The light of `desc` (`field(key)` names its keys in errors), or `None` when it is
/// visible and was added to `b` as an emissive surface.
pub(super) fn area_light(
    desc: &AreaDesc,
    b: &mut Builder,
    field: &dyn Fn(&str) -> String,
    invalid: &dyn Fn(String, String) -> SceneError,
) -> Result<Option<Light>, SceneError> {
    let err = |k: &str, m: String| invalid(field(k), m);
    let (w, h) = match desc.size {
        AreaSize::Both(s) => (s, s),
        AreaSize::Each([w, h]) => (w, h),
    };
    if !(w > 0.0 && h > 0.0 && w.is_finite() && h.is_finite()) {
        return Err(err("size", format!("must be finite and > 0, got {w} × {h}")));
    }
    let (linear, center) = placement(desc, &err)?;
    let ex = linear * Vec3::new(0.5 * w, 0.0, 0.0);
    let ey = linear * Vec3::new(0.0, 0.5 * h, 0.0);
    let normal = (linear.inverse().transpose() * -Vec3::Z).normalize_or_zero();
    let key = if desc.matrix.is_some() { "matrix" } else { "up" };
    if ex.dot(ey).abs() > 1e-4 * ex.length() * ey.length() || normal == Vec3::ZERO {
        return Err(err(key, "must keep the light's x and y axes at right angles (no shear)".into()));
    }
    let shape = match desc.shape {
        AreaShapeDesc::Rectangle => AreaShape::Rectangle,
        AreaShapeDesc::Disk | AreaShapeDesc::Ellipse => AreaShape::Ellipse,
    };
    if desc.shape == AreaShapeDesc::Disk && (w != h) {
        return Err(err("size", format!("a disk has one diameter, got {w} × {h} (an ellipse has two)")));
    }
    let area = match shape {
        AreaShape::Rectangle => 4.0 * ex.length() * ey.length(),
        AreaShape::Ellipse => PI * ex.length() * ey.length(),
    };
    let color = desc.color.unwrap_or([1.0; 3]);
    if !color.iter().all(|c| c.is_finite() && *c >= 0.0) {
        return Err(err("color", "must be finite and ≥ 0".into()));
    }
    let radiance = match (desc.power, desc.radiance) {
        (Some(p), None) if p.is_finite() && p >= 0.0 => Vec3::from_array(color) * (p / (PI * area)),
        (Some(p), None) => return Err(err("power", format!("must be finite and ≥ 0, got {p}"))),
        (None, Some(r)) if r.iter().all(|c| c.is_finite() && *c >= 0.0) => {
            if desc.color.is_some() {
                return Err(err("color", "multiplies `power`; give the colour in `radiance` itself".into()));
            }
            Vec3::from_array(r)
        }
        (None, Some(_)) => return Err(err("radiance", "must be finite and ≥ 0".into())),
        _ => return Err(err("power", "give either `power` (watts) or `radiance`".into())),
    };
    let geometry = Area { shape, center, ex, ey, normal, area };
    if desc.visible {
        add_surface(b, &geometry, radiance);
        return Ok(None);
    }
    Ok(Some(Light::Area { geometry, radiance }))
}

/// The light's frame: the linear part (its columns the light's x, y, z) and its centre.
fn placement(desc: &AreaDesc, err: &dyn Fn(&str, String) -> SceneError) -> Result<(Mat3, Vec3), SceneError> {
    let finite = |k: &str, v: [f32; 3]| {
        let v = Vec3::from_array(v);
        if v.is_finite() { Ok(v) } else { Err(err(k, "must be finite".into())) }
    };
    if let Some(m) = &desc.matrix {
        for (k, given) in
            [("position", desc.position.is_some()), ("direction", desc.direction.is_some()), ("up", desc.up.is_some())]
        {
            if given {
                return Err(err(k, "give either `matrix` or position, direction and up, not both".into()));
            }
        }
        let p = from_rows(m).map_err(|e| err("matrix", e))?;
        return Ok((p.linear, p.translate));
    }
    let (Some(position), Some(direction)) = (desc.position, desc.direction) else {
        return Err(err("position", "an area light needs `matrix`, or `position` and `direction`".into()));
    };
    let n = finite("direction", direction)?.normalize_or_zero();
    if n == Vec3::ZERO {
        return Err(err("direction", "must not be zero".into()));
    }
    let up = match desc.up {
        Some(u) => finite("up", u)?,
        None if n.y.abs() > 0.999 => Vec3::Z,
        None => Vec3::Y,
    };
    let y = (up - n * n.dot(up)).normalize_or_zero();
    if y == Vec3::ZERO {
        return Err(err("up", "must not be parallel to `direction`".into()));
    }
    // The light's own z points away from the side it lights (Blender's: it emits along −Z).
    let z = -n;
    Ok((Mat3::from_cols(y.cross(z), y, z), finite("position", position)?))
}

/// The light as an emissive polygon, wound so that its front faces the lit side.
fn add_surface(b: &mut Builder, a: &Area, radiance: Vec3) {
    let desc = MaterialDesc { kd: Vec3::ZERO, ke: radiance, ..MaterialDesc::default() };
    b.materials.push(Material::from_desc(&desc));
    b.material_names.push("area light".into());
    let material = b.materials.len() as u32 - 1;
    let outline: Vec<Vec3> = match a.shape {
        AreaShape::Rectangle => {
            vec![a.center - a.ex - a.ey, a.center + a.ex - a.ey, a.center + a.ex + a.ey, a.center - a.ex + a.ey]
        }
        AreaShape::Ellipse => (0..ELLIPSE_SEGMENTS)
            .map(|k| {
                let (s, c) = crate::sampling::sin_cos_turns(k as f32 / ELLIPSE_SEGMENTS as f32);
                a.center + c * a.ex + s * a.ey
            })
            .collect(),
    };
    let base = b.mesh.positions.len() as u32;
    b.mesh.positions.extend(&outline);
    let front = (outline[1] - outline[0]).cross(outline[2] - outline[0]).dot(a.normal) > 0.0;
    for k in 1..outline.len() as u32 - 1 {
        let (i, j) = if front { (k, k + 1) } else { (k + 1, k) };
        b.mesh.tris.push(Tri { v: [base, base + i, base + j], n: [NONE; 3], uv: [NONE; 3], material });
    }
}

#[cfg(test)]
mod tests {
    use crate::light::Light;
    use crate::scene::scene_from_toml;

    const CAMERA: &str = "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nwidth = 8\nheight = 8\n";

    fn load(light: &str) -> Result<crate::scene::Scene, String> {
        let toml = format!("{CAMERA}[[light]]\ntype = \"area\"\n{light}");
        scene_from_toml(&toml, "s.toml", std::path::Path::new(".")).map_err(|e| e.to_string())
    }

    #[test]
    fn bad_area_lights_are_errors_naming_the_key() {
        let at = "position = [0, 2, 0]\ndirection = [0, -1, 0]\n";
        let cases = [
            (format!("size = 1\n{at}"), "light[0].power: give either `power` (watts) or `radiance`"),
            (format!("size = 1\n{at}power = 5\nradiance = [1, 1, 1]\n"), "light[0].power: give either"),
            (format!("shape = \"disk\"\nsize = [1, 2]\n{at}power = 5\n"), "light[0].size: a disk has one diameter"),
            (format!("size = [1, 0]\n{at}power = 5\n"), "light[0].size: must be finite and > 0"),
            ("size = 1\npower = 5\n".into(), "light[0].position: an area light needs `matrix`"),
            (format!("size = 1\n{at}up = [0, 1, 0]\npower = 5\n"), "light[0].up: must not be parallel"),
            (
                "size = 1\npower = 5\nmatrix = [[1, 1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n".into(),
                "light[0].matrix: must keep the light's x and y axes at right angles",
            ),
            (
                format!("size = 1\n{at}power = 5\nmatrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n"),
                "light[0].position: give either `matrix` or position",
            ),
            (format!("size = 1\n{at}power = 5\nshape = \"star\"\n"), "unknown variant `star`"),
        ];
        for (light, expected) in cases {
            let e = load(&light).err().unwrap_or_default();
            assert!(e.contains(expected), "{light:?}: {e}");
        }
    }

    #[test]
    fn a_size_of_zero_keeps_the_hard_light_and_bad_sizes_are_errors() {
        let light = |keys: &str| {
            let toml = format!("{CAMERA}[[light]]\n{keys}");
            scene_from_toml(&toml, "s.toml", std::path::Path::new(".")).map(|s| s.lights.lights[0])
        };
        let point = "type = \"point\"\nposition = [0, 1, 0]\nintensity = [1, 1, 1]\n";
        let sun = "type = \"directional\"\ndirection = [0, -1, 0]\nirradiance = [1, 1, 1]\n";
        assert!(matches!(light(&format!("{point}radius = 0\n")), Ok(Light::Point { .. })));
        assert!(matches!(light(&format!("{point}radius = 0.1\n")), Ok(Light::SoftPoint(_))));
        assert!(matches!(light(&format!("{sun}angle = 0.5\n")), Ok(Light::Sun(_))));
        let e = light(&format!("{point}radius = -1\n")).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("s.toml:10: light[0].radius: must be finite and ≥ 0"), "{e}");
        let e = light(&format!("{sun}angle = 200\n")).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("light[0].angle: must be in [0, 180) degrees"), "{e}");
    }

    #[test]
    fn power_spreads_over_the_area_as_blender_defines_it() {
        // 2 × 0.5 m, 10 W, coloured: L = colour × 10 / (π · 1).
        let s =
            load("size = [2, 0.5]\nposition = [0, 2, 0]\ndirection = [0, -1, 0]\npower = 10\ncolor = [1, 0.5, 0]\n")
                .unwrap();
        let Light::Area { geometry, radiance } = s.lights.lights[0] else { panic!("{:?}", s.lights.lights) };
        assert!((geometry.area - 1.0).abs() < 1e-6 && (geometry.normal + glam::Vec3::Y).length() < 1e-6);
        let l = 10.0 / std::f32::consts::PI;
        assert!((radiance - glam::Vec3::new(l, 0.5 * l, 0.0)).length() < 1e-5, "{radiance}");
        // A matrix's scale scales the light: the same light as a 1 × 1 square scaled 2 × 0.5.
        let m = load("size = 1\nmatrix = [[2, 0, 0, 0], [0, 0, 1, 2], [0, -0.5, 0, 0], [0, 0, 0, 1]]\npower = 10\n")
            .unwrap();
        let Light::Area { geometry: g, .. } = m.lights.lights[0] else { panic!() };
        assert!((g.area - 1.0).abs() < 1e-6 && (g.normal + glam::Vec3::Y).length() < 1e-6, "{g:?}");
    }
}
