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
    /// Materials by name: Principled materials and mixes (README.md, "Principled
    /// materials"); they override an MTL material of the same name.
    #[serde(default)]
    pub materials: std::collections::BTreeMap<String, MaterialTable>,
}

/// One `[materials.NAME]` table: Blender's Principled BSDF inputs, or a mix of two
/// other materials of the table.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MaterialTable {
    pub base_color: Option<[f32; 3]>,
    pub base_color_map: Option<TextureRef>,
    pub metallic: Option<f32>,
    pub metallic_map: Option<TextureRef>,
    pub roughness: Option<f32>,
    pub roughness_map: Option<TextureRef>,
    pub ior: Option<f32>,
    pub specular_ior_level: Option<f32>,
    pub specular_tint: Option<[f32; 3]>,
    pub transmission: Option<f32>,
    pub transmission_map: Option<TextureRef>,
    pub coat: Option<f32>,
    pub coat_map: Option<TextureRef>,
    pub coat_roughness: Option<f32>,
    pub coat_ior: Option<f32>,
    pub coat_tint: Option<[f32; 3]>,
    pub sheen: Option<f32>,
    pub sheen_map: Option<TextureRef>,
    pub sheen_roughness: Option<f32>,
    pub sheen_tint: Option<[f32; 3]>,
    pub anisotropic: Option<f32>,
    pub anisotropic_rotation: Option<f32>,
    pub alpha: Option<f32>,
    pub alpha_map: Option<TextureRef>,
    pub emission_color: Option<[f32; 3]>,
    pub emission_strength: Option<f32>,
    /// Also `emission_color_map` (the input's name + `_map`, as the add-on writes it).
    #[serde(alias = "emission_color_map")]
    pub emission_map: Option<TextureRef>,
    /// `"multiscatter_ggx"` (the default) or `"ggx"`.
    pub distribution: Option<String>,
    pub normal_map: Option<TextureRef>,
    pub bump_map: Option<TextureRef>,
    /// A mix: `(1 − factor) · first + factor · second`.
    pub mix: Option<[String; 2]>,
    pub factor: Option<f32>,
    pub factor_map: Option<TextureRef>,
}

impl MaterialTable {
    /// Every texture the table refers to.
    pub fn textures(&self) -> impl Iterator<Item = &TextureRef> {
        [
            &self.base_color_map,
            &self.metallic_map,
            &self.roughness_map,
            &self.transmission_map,
            &self.coat_map,
            &self.sheen_map,
            &self.alpha_map,
            &self.emission_map,
            &self.normal_map,
            &self.bump_map,
            &self.factor_map,
        ]
        .into_iter()
        .flatten()
    }
}

/// A texture on a material input: the image and how it is placed and read.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TextureRef {
    pub file: String,
    pub scale: Option<[f32; 2]>,
    pub offset: Option<[f32; 2]>,
    /// Degrees, counter-clockwise, after scaling and before the offset.
    pub rotation: Option<f32>,
    /// `"srgb"` or `"non-color"`.
    pub colorspace: Option<String>,
    /// `"linear"` or `"closest"`.
    pub interpolation: Option<String>,
    /// `"rgb"`, `"luminance"` or `"alpha"`.
    pub channel: Option<String>,
    pub clamp: Option<bool>,
    /// Normal and bump maps only.
    pub strength: Option<f32>,
    /// Bump maps only.
    pub distance: Option<f32>,
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
    /// Largest channel value one sample may add (biased firefly control); absent: none.
    #[serde(default)]
    pub clamp: Option<f32>,
    /// Keep the AOV layers (albedo, normal, depth, variance) beside the beauty pass.
    #[serde(default)]
    pub aovs: bool,
    /// Adaptive sampling's noise target (relative error); absent: every pixel gets spp.
    #[serde(default)]
    pub noise: Option<f32>,
}

fn default_spp() -> u32 {
    64
}
fn default_max_depth() -> i32 {
    8
}

impl Default for RenderDesc {
    fn default() -> Self {
        Self { spp: default_spp(), max_depth: default_max_depth(), seed: 0, clamp: None, aovs: false, noise: None }
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

/// Which axis of a model points up. Many CAD, robotics and 3D-scanning tools write Z-up
/// files; the scene (and the auto-framed camera) is Y-up.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    #[default]
    Y,
    Z,
}

impl UpAxis {
    /// The rotation that brings the model's coordinates into the scene's Y-up frame:
    /// for Z-up, (x, y, z) → (x, z, −y), a proper rotation (−90° about x), so faces
    /// keep their winding.
    pub fn to_y_up(self) -> glam::Mat3 {
        match self {
            UpAxis::Y => glam::Mat3::IDENTITY,
            UpAxis::Z => glam::Mat3::from_cols(glam::Vec3::X, -glam::Vec3::Z, glam::Vec3::Y),
        }
    }
}

impl std::str::FromStr for UpAxis {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "y" => Ok(UpAxis::Y),
            "z" => Ok(UpAxis::Z),
            _ => Err(format!("'{s}' is not an up axis: expected y or z")),
        }
    }
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MeshDesc {
    /// Path of the OBJ file, relative to the scene file.
    pub obj: String,
    /// The model's up axis (`"y"`, the default, or `"z"`), applied before scale, rotation
    /// and translation.
    pub up: Option<UpAxis>,
    pub translate: Option<[f32; 3]>,
    pub scale: Option<Scale>,
    /// Rotation about +y in degrees (right-handed).
    pub rotate_y: Option<f32>,
    /// Rotation about any axis (instead of `rotate_y`).
    pub rotate: Option<RotateDesc>,
    /// A 4×4 affine matrix, row by row (the last row `[0, 0, 0, 1]`), instead of `scale`,
    /// `rotate` and `translate`; `up` still applies first.
    pub matrix: Option<[[f32; 4]; 4]>,
    /// Copies of the model, each placed by its own transform after the fields above
    /// have placed the model. An OBJ placed more than once (here or by several `[[mesh]]`
    /// tables) is stored once.
    #[serde(default)]
    pub instance: Vec<InstanceDesc>,
}

/// `rotate = { axis = [x, y, z], degrees = a }`: right-handed, about an axis through the
/// origin.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RotateDesc {
    pub axis: [f32; 3],
    pub degrees: f32,
}

/// One copy of a `[[mesh]]`'s model: `scale`, then the rotation, then `translate`, or a
/// `matrix`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InstanceDesc {
    pub translate: Option<[f32; 3]>,
    pub scale: Option<Scale>,
    pub rotate_y: Option<f32>,
    pub rotate: Option<RotateDesc>,
    pub matrix: Option<[[f32; 4]; 4]>,
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
    /// MTL's PBR keys in lower case (README.md, "Principled materials").
    pub pr: Option<f32>,
    pub pm: Option<f32>,
    pub ps: Option<f32>,
    pub pc: Option<f32>,
    pub pcr: Option<f32>,
    /// A material of the scene's `[materials]` table, instead of the keys above.
    pub material: Option<String>,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum LightDesc {
    /// Radiant intensity in W/sr.
    /// With `radius` (metres): a disk of that radius facing what it lights (soft shadows).
    Point { position: [f32; 3], intensity: [f32; 3], radius: Option<f32> },
    /// A cone: full intensity inside `falloff_start`, smooth falloff to zero at `cone_angle`
    /// (both half-angles in degrees from `direction`, the way the light points).
    Spot {
        position: [f32; 3],
        direction: [f32; 3],
        intensity: [f32; 3],
        cone_angle: f32,
        falloff_start: Option<f32>,
        radius: Option<f32>,
    },
    /// Parallel light travelling along `direction`, irradiance in W/m² on a surface
    /// facing it.
    /// With `angle` (degrees, the sun's angular diameter): a disc of directions.
    Directional { direction: [f32; 3], irradiance: [f32; 3], angle: Option<f32> },
    /// A one-sided rectangle, disk or ellipse that lights but is not a surface (README.md,
    /// "Area lights").
    Area(AreaDesc),
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AreaDesc {
    #[serde(default)]
    pub shape: AreaShapeDesc,
    /// Width along the light's x and height along its y (one number: both).
    pub size: AreaSize,
    /// Blender's `matrix_world`, row by row: the light at the origin of its own frame,
    /// emitting towards its −Z.
    pub matrix: Option<[[f32; 4]; 4]>,
    pub position: Option<[f32; 3]>,
    /// The way the light faces (it emits towards this side).
    pub direction: Option<[f32; 3]>,
    /// The general direction of the light's own +y axis.
    pub up: Option<[f32; 3]>,
    /// Watts, as Blender's Power: radiance = color × power / (π × area).
    pub power: Option<f32>,
    pub color: Option<[f32; 3]>,
    pub radiance: Option<[f32; 3]>,
    /// Seen by camera rays and casting shadows: an emissive surface instead.
    #[serde(default)]
    pub visible: bool,
}

#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum AreaShapeDesc {
    #[default]
    Rectangle,
    Disk,
    Ellipse,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum AreaSize {
    Both(f32),
    Each([f32; 2]),
}

#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BackgroundDesc {
    /// Constant radiance from every direction (black when neither this nor `map`).
    pub radiance: Option<[f32; 3]>,
    /// A latitude-longitude radiance map (README.md, "Environment maps").
    pub map: Option<String>,
    /// Multiplies the map (default 1).
    pub strength: Option<f32>,
    /// Degrees, right-handed about the up axis.
    pub rotate: Option<f32>,
    /// The world axis that is the map's zenith (default y).
    pub up: Option<UpDesc>,
    /// A note from the program that wrote the scene (an exporter) about lighting it could
    /// not reproduce: printed as a warning whenever the scene is loaded.
    pub warning: Option<String>,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum UpDesc {
    Y,
    Z,
}

/// The 1-based line of `field` (as the loader names it: `render.spp`, `mesh[2].scale`,
/// `camera`) in a scene file's text: the key's own line, else its table's header line.
/// A plain line scan: keys written as inline tables or dotted keys find their table.
pub fn line_of(text: &str, field: &str) -> Option<usize> {
    // A named table (`materials.Gold.roughness`: table `materials.Gold`, key
    // `roughness`) when its header is written so, else the first part is the table.
    if let Some((table, key)) = field.rsplit_once('.')
        && table.contains('.')
        && let Some(line) = line_in_table(text, table, Some(key))
    {
        return Some(line);
    }
    let (table, key) = match field.split_once('.') {
        Some((t, k)) => (t, Some(k)),
        None => (field, None),
    };
    line_in_table(text, table, key)
}

/// The line of `key` in the table `table` (`name` or `name[index]`), else its header's.
fn line_in_table(text: &str, table: &str, key: Option<&str>) -> Option<usize> {
    let (name, index) = match table.split_once('[') {
        Some((n, i)) => (n, i.trim_end_matches(']').parse::<usize>().ok()?),
        None => (table, 0),
    };
    let mut header = None;
    let mut seen = 0usize;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.starts_with('[') {
            if header.is_some() {
                break; // the next table: the key is not written in this one
            }
            let inner = line.trim_start_matches('[').trim_end_matches(']').trim().replace('"', "");
            if inner == name {
                if seen == index {
                    header = Some(i + 1);
                    if key.is_none() {
                        break;
                    }
                }
                seen += 1;
            }
            continue;
        }
        if let (Some(_), Some(key)) = (header, key)
            && line.strip_prefix(key).is_some_and(|rest| rest.trim_start().starts_with('='))
        {
            return Some(i + 1);
        }
    }
    header
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
    fn fields_are_found_on_their_lines() {
        let line = |f: &str| line_of(EXAMPLE, f);
        let find = |needle: &str| EXAMPLE.lines().position(|l| l.starts_with(needle)).map(|i| i + 1);
        assert_eq!(line("render.spp"), find("spp = 64"));
        assert_eq!(line("camera"), find("[camera]"));
        assert_eq!(line("camera.fov"), find("fov"));
        assert_eq!(line("mesh[1].scale"), find("scale = [1.0"));
        assert_eq!(line("mesh[0].translate"), find("obj = \"cbox.obj\"").map(|l| l - 1), "its table's header");
        let last_direction = EXAMPLE.lines().enumerate().filter(|(_, l)| l.starts_with("direction")).last();
        assert_eq!(line("light[2].direction"), last_direction.map(|(i, _)| i + 1));
        assert_eq!(line("sphere[3].radius"), None);
    }

    #[test]
    fn up_axis_z_is_a_proper_rotation_to_y_up() {
        let m = UpAxis::Z.to_y_up();
        assert_eq!(m * glam::Vec3::Z, glam::Vec3::Y);
        assert_eq!(m * glam::Vec3::X, glam::Vec3::X);
        assert_eq!(m.determinant(), 1.0);
        assert_eq!("Z".parse::<UpAxis>(), Ok(UpAxis::Z));
        assert!("x".parse::<UpAxis>().is_err());
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
