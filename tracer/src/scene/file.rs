//! The TOML scene file: the schema, exactly as documented in README.md. Every table
//! denies unknown fields, so a typo is an error that names the key.

use serde::Deserialize;

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub camera: CameraDesc,
    #[serde(default)]
    pub render: RenderDesc,
    #[serde(default)]
    pub mesh: Vec<MeshDesc>,
    #[serde(default)]
    pub sphere: Vec<SphereDesc>,
    #[serde(default)]
    pub light: Vec<LightDesc>,
    #[serde(default)]
    pub background: BackgroundDesc,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraDesc {
    pub position: [f32; 3],
    pub look_at: [f32; 3],
    #[serde(default = "default_up")]
    pub up: [f32; 3],
    /// Vertical field of view in degrees.
    #[serde(default = "default_fov")]
    pub fov: f32,
    #[serde(default = "default_width")]
    pub width: u32,
    #[serde(default = "default_height")]
    pub height: u32,
    /// Thin-lens radius; 0 is a pinhole.
    #[serde(default)]
    pub aperture: f32,
    /// Distance of the plane in focus; defaults to |look_at - position|.
    pub focus_distance: Option<f32>,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}
fn default_fov() -> f32 {
    40.0
}
fn default_width() -> u32 {
    512
}
fn default_height() -> u32 {
    512
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RenderDesc {
    #[serde(default = "default_spp")]
    pub spp: u32,
    /// Path segments from the camera, Mitsuba 3 `path` semantics; -1 = unlimited.
    #[serde(default = "default_max_depth")]
    pub max_depth: i32,
    #[serde(default)]
    pub seed: u64,
}

fn default_spp() -> u32 {
    64
}
fn default_max_depth() -> i32 {
    8
}

impl Default for RenderDesc {
    fn default() -> Self {
        Self { spp: default_spp(), max_depth: default_max_depth(), seed: 0 }
    }
}

/// `scale = s` or `scale = [x, y, z]`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum Scale {
    Uniform(f32),
    PerAxis([f32; 3]),
}

impl Scale {
    pub fn to_vec(self) -> [f32; 3] {
        match self {
            Scale::Uniform(s) => [s; 3],
            Scale::PerAxis(v) => v,
        }
    }
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MeshDesc {
    /// Path of the OBJ file, relative to the scene file.
    pub obj: String,
    pub translate: Option<[f32; 3]>,
    pub scale: Option<Scale>,
    /// Rotation about +y in degrees (right-handed).
    pub rotate_y: Option<f32>,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SphereDesc {
    pub center: [f32; 3],
    pub radius: f32,
    pub kd: Option<[f32; 3]>,
    pub ks: Option<[f32; 3]>,
    pub ns: Option<f32>,
    pub ke: Option<[f32; 3]>,
    pub ni: Option<f32>,
    pub d: Option<f32>,
    pub tf: Option<[f32; 3]>,
    pub illum: Option<u32>,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum LightDesc {
    /// Radiant intensity in W/sr.
    Point { position: [f32; 3], intensity: [f32; 3] },
    /// A cone: full intensity inside `falloff_start`, smooth falloff to zero at `cone_angle`
    /// (both half-angles in degrees from `direction`, the way the light points).
    Spot { position: [f32; 3], direction: [f32; 3], intensity: [f32; 3], cone_angle: f32, falloff_start: Option<f32> },
    /// Parallel light travelling along `direction`, irradiance in W/m² on a surface
    /// facing it.
    Directional { direction: [f32; 3], irradiance: [f32; 3] },
}

#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BackgroundDesc {
    #[serde(default)]
    pub radiance: [f32; 3],
}

#[cfg(test)]
mod tests {
    use super::*;

    const EXAMPLE: &str = r#"
[camera]
position = [278.0, 273.0, -800.0]
look_at  = [278.0, 273.0, 0.0]
up       = [0.0, 1.0, 0.0]
fov      = 39.3
width    = 512
height   = 512
[render]
spp = 64
max_depth = 8
seed = 0
[[mesh]]
obj = "cbox.obj"
scale = 2.0
[[mesh]]
obj = "b.obj"
scale = [1.0, 2.0, 3.0]
rotate_y = 30
translate = [1, 2, 3]
[[sphere]]
center = [0.0, 1.0, 0.0]
radius = 0.5
kd = [0.8, 0.8, 0.8]
[[light]]
type = "point"
position = [0.0, 5.0, 0.0]
intensity = [10.0, 10.0, 10.0]
[[light]]
type = "spot"
position = [0.0, 5.0, 0.0]
direction = [0.0, -1.0, 0.0]
intensity = [10.0, 10.0, 10.0]
cone_angle = 30
falloff_start = 20
[[light]]
type = "directional"
direction = [0.0, -1.0, 0.0]
irradiance = [1.0, 1.0, 1.0]
[background]
radiance = [0.0, 0.0, 0.0]
"#;

    #[test]
    fn documented_example_parses() {
        let f: SceneFile = toml::from_str(EXAMPLE).unwrap();
        assert_eq!(f.camera.width, 512);
        assert_eq!(f.mesh[0].scale, Some(Scale::Uniform(2.0)));
        assert_eq!(f.mesh[1].scale, Some(Scale::PerAxis([1.0, 2.0, 3.0])));
        assert_eq!(f.light.len(), 3);
        assert!(matches!(f.light[1], LightDesc::Spot { cone_angle: 30.0, .. }));
    }

    #[test]
    fn typos_are_errors_naming_the_key() {
        for (bad, key) in [
            (EXAMPLE.replace("look_at ", "lookat "), "lookat"),
            (EXAMPLE.replace("spp = 64", "sppp = 64"), "sppp"),
            (EXAMPLE.replace("kd = [0.8", "kdd = [0.8"), "kdd"),
            (EXAMPLE.replace("irradiance", "irradience"), "irradience"),
            (EXAMPLE.replace("type = \"point\"", "type = \"pointy\""), "pointy"),
        ] {
            let e = toml::from_str::<SceneFile>(&bad).unwrap_err().to_string();
            assert!(e.contains(key), "{e}");
            assert!(e.contains("line"), "{e}");
        }
    }
}
