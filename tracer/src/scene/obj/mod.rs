//! OBJ/MTL loading.
//!
//! The OBJ's statements are read by a line pass of our own (`scan`, on all threads:
//! `parallel`) that validates with line numbers and records smoothing groups; tobj
//! parses the MTL statements. Polygons are triangulated here as fans (counter-clockwise
//! order kept), all groups are merged into one [`TriangleMesh`], and shading normals
//! come from `vn`, from smoothing groups, or are left flat.

mod check;
mod deps;
mod mtl;
mod parallel;
mod pbr;
mod scan;
mod smoothing;
#[cfg(test)]
mod tests;

use std::collections::HashMap;
use std::path::Path;

use glam::Vec3;

pub use self::check::{ObjCheck, check_obj_as};
pub use self::deps::{obj_dependencies, obj_dependencies_where};
pub use self::mtl::{MtlLibrary, load_mtl};
use self::mtl::{RawMaterial, TextureCache};
pub(crate) use self::pbr::PbrKeys;
use self::scan::{Corner, FaceInfo, ObjScan};
use self::smoothing::SmoothNormals;
use super::{NONE, Tri, TriangleMesh};
use crate::material::MaterialDesc;
use crate::texture::Texture;

/// What an OBJ file yields: its triangles (object space), their materials, the textures
/// those materials use, and warnings (missing MTL file, unknown material, ...).
#[derive(Clone, Debug, Default)]
pub struct ObjModel {
    pub mesh: TriangleMesh,
    pub materials: Vec<MaterialDesc>,
    pub textures: Vec<Texture>,
    pub warnings: Vec<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum ObjError {
    #[error("{path}: {message}")]
    Io { path: String, message: String },
    #[error("{path}:{line}: {message}")]
    Parse { path: String, line: usize, message: String },
}

/// Name of the grey material given to faces without `usemtl`.
pub const DEFAULT_MATERIAL_NAME: &str = "default";

/// Loads an OBJ file, its MTL libraries (relative to the OBJ's folder) and their `map_Kd`
/// textures (relative to each MTL's folder).
pub fn load_obj(path: &Path) -> Result<ObjModel, ObjError> {
    load_obj_as(path, &path.display().to_string())
}

/// [`load_obj`], naming the file `display` in errors and warnings (and the files it
/// refers to relative to that name), e.g. as the user wrote it rather than where a job's
/// copy of it lies.
pub fn load_obj_as(path: &Path, display: &str) -> Result<ObjModel, ObjError> {
    let (t, shown) = (std::time::Instant::now(), display);
    let text = mtl::read_text(path, display, crate::scene::files::MAX_OBJ_BYTES)?;
    tracing::debug!("{shown}: read in {:.2?}", t.elapsed());
    load_obj_from_str(&text, path.parent().unwrap_or(Path::new("")), display)
}

/// How a file referred to as `name` from the file shown as `from` is shown: beside it.
pub(crate) fn shown_beside(from: &str, name: &str) -> String {
    match Path::new(from).parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir.join(name).display().to_string(),
        _ => name.to_string(),
    }
}

/// Loads OBJ text; `base_dir` is where `mtllib` paths are resolved, `display_name` names
/// the file in errors and warnings.
pub fn load_obj_from_str(text: &str, base_dir: &Path, display_name: &str) -> Result<ObjModel, ObjError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let t = std::time::Instant::now();
    let mut scan = parallel::scan(text, display_name)?;
    tracing::debug!("{display_name}: scanned in {:.2?}", t.elapsed());
    let mut warnings = scan.warnings.clone();
    let library = load_libraries(&scan, base_dir, display_name, &mut warnings)?;
    let t = std::time::Instant::now();
    let (corners, faces) = (std::mem::take(&mut scan.corners), std::mem::take(&mut scan.faces));
    let model = Builder::new(&scan, display_name, library, warnings).build(corners, &faces);
    tracing::debug!("{display_name}: {} triangles made in {:.2?}", model.mesh.tris.len(), t.elapsed());
    Ok(model)
}

/// A triangle's unnormalised normal and its length, or `None` when it has no area (it
/// is dropped).
fn area_normal(p: [Vec3; 3]) -> Option<(Vec3, f32)> {
    let cross = (p[1] - p[0]).cross(p[2] - p[0]);
    let len = cross.length();
    (len > 0.0 && len.is_finite()).then_some((cross, len))
}

/// A `vn` normal that cannot shade (zero length, or not finite once normalised): its
/// faces get computed normals.
fn unusable_normal(n: Vec3) -> bool {
    let n = n.normalize_or_zero();
    n == Vec3::ZERO || !n.is_finite()
}

/// The materials of all `mtllib` files, by name (a later definition wins).
#[derive(Default)]
struct Library {
    materials: Vec<RawMaterial>,
    by_name: HashMap<String, usize>,
}

fn load_libraries(
    scan: &ObjScan,
    base_dir: &Path,
    display: &str,
    warnings: &mut Vec<String>,
) -> Result<Library, ObjError> {
    let mut lib = Library::default();
    for (line, arg) in &scan.mtllibs {
        // `mtllib a.mtl b.mtl` names several files; a single name may contain spaces.
        let files: Vec<&str> = if mtl::resolve_path(base_dir, arg).is_file() {
            vec![arg.as_str()]
        } else {
            arg.split_whitespace().collect()
        };
        for file in files {
            let path = mtl::resolve_path(base_dir, file);
            let mtl_display = shown_beside(display, file);
            let text = match crate::scene::files::read_bounded(&path, crate::scene::files::MAX_MTL_BYTES) {
                Ok(bytes) => mtl::decode_utf8(bytes, &mtl_display)?,
                Err(e) => {
                    warnings.push(format!(
                        "{display}:{line}: material library '{file}' could not be read ({}); its materials will be \
                         grey diffuse",
                        crate::scene::textures::io_reason(&e)
                    ));
                    continue;
                }
            };
            let dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
            for raw in mtl::parse_mtl_str(&text, &mtl_display, &dir, warnings)? {
                lib.by_name.insert(raw.desc.name.clone(), lib.materials.len());
                lib.materials.push(raw);
            }
        }
    }
    Ok(lib)
}

/// What the corner pass learns of a face: every corner has a texture coordinate, and
/// every corner a usable (non-zero) `vn` normal. One byte a face, beside the scan's
/// faces, rather than a second copy of them (files have millions).
const HAS_UV: u8 = 1;
const HAS_N: u8 = 2;

struct Builder<'a> {
    scan: &'a ObjScan,
    display: &'a str,
    library: Library,
    warnings: Vec<String>,
    mesh: TriangleMesh,
    materials: Vec<MaterialDesc>,
    textures: TextureCache,
    /// Output material per `usemtl` name (index = name index), and for "no usemtl".
    material_slots: Vec<Option<u32>>,
    default_slot: Option<u32>,
}

impl<'a> Builder<'a> {
    fn new(scan: &'a ObjScan, display: &'a str, library: Library, warnings: Vec<String>) -> Self {
        Self {
            scan,
            display,
            library,
            warnings,
            mesh: TriangleMesh::default(),
            materials: Vec::new(),
            textures: TextureCache::default(),
            material_slots: vec![None; scan.material_names.len()],
            default_slot: None,
        }
    }

    /// The output material index for a face's `usemtl` slot, resolving it on first use.
    fn material(&mut self, slot: u32) -> u32 {
        if slot == NONE {
            if let Some(i) = self.default_slot {
                return i;
            }
            let i = self.push_material(MaterialDesc::default_grey(DEFAULT_MATERIAL_NAME));
            self.default_slot = Some(i);
            return i;
        }
        let s = slot as usize;
        if let Some(Some(i)) = self.material_slots.get(s) {
            return *i;
        }
        let Some((name, line)) = self.scan.material_names.get(s) else {
            return self.material(NONE);
        };
        let desc = match self.library.by_name.get(name) {
            Some(&m) => mtl::resolve_material(&self.library.materials[m], &mut self.textures, &mut self.warnings),
            None => {
                self.warnings.push(format!(
                    "{}:{line}: unknown material '{name}' (not defined in any loaded MTL file); using grey diffuse",
                    self.display
                ));
                MaterialDesc::default_grey(name)
            }
        };
        let i = self.push_material(desc);
        self.material_slots[s] = Some(i);
        i
    }

    fn note_zero_vn(&mut self, faces: usize) {
        if faces > 0 {
            self.warnings.push(format!(
                "{}: {faces} faces refer to zero-length vn normals; their normals are computed instead",
                self.display
            ));
        }
    }

    fn note_degenerate(&mut self, triangles: usize) {
        if triangles > 0 {
            self.warnings.push(format!("{}: dropped {triangles} degenerate (zero-area) triangles", self.display));
        }
    }

    fn push_material(&mut self, desc: MaterialDesc) -> u32 {
        self.materials.push(desc);
        self.materials.len() as u32 - 1
    }

    // Long on purpose: One pass over the parsed file in its order (groups, materials, faces); its steps share the per-pass index maps, so it stays one function.
    ///
    /// The output indices are written over the scan's `corners` (their file indices are
    /// read once, just before): no second array of them, which on ten million faces is
    /// hundreds of megabytes of fresh memory the kernel must clear.
    fn build(mut self, mut corners: Vec<Corner>, faces: &[FaceInfo]) -> ObjModel {
        let scan = self.scan;
        let mut pos_map = vec![NONE; scan.positions.len()];
        let mut uv_map = vec![NONE; scan.texcoords.len()];
        let mut normal_map: Vec<Option<u32>> = vec![None; scan.normals.len()];
        let mut flags: Vec<u8> = Vec::with_capacity(faces.len());
        self.mesh.positions.reserve_exact(scan.positions.len());
        let mut zero_vn_faces = 0usize;

        // The scan resolved every index (in range), so the lookups below cannot fail.
        for face in faces {
            let corners = &mut corners[face.corners()];
            let all_vt = corners.iter().all(|c| c.vt != NONE);
            let all_vn = corners.iter().all(|c| c.vn != NONE);
            let mut has_n = all_vn;
            for c in corners.iter_mut() {
                // Position.
                let o = &mut pos_map[c.v as usize];
                if *o == NONE {
                    *o = self.mesh.positions.len() as u32;
                    self.mesh.positions.push(scan.positions[c.v as usize]);
                }
                c.v = *o;
                // Texture coordinate.
                if all_vt {
                    let o = &mut uv_map[c.vt as usize];
                    if *o == NONE {
                        *o = self.mesh.uvs.len() as u32;
                        self.mesh.uvs.push(scan.texcoords[c.vt as usize]);
                    }
                    c.vt = *o;
                }
                // Given normal (a zero-length one makes the face fall back to computed normals).
                if has_n {
                    let slot = &mut normal_map[c.vn as usize];
                    if slot.is_none() {
                        let n = scan.normals[c.vn as usize];
                        *slot = Some(if unusable_normal(n) {
                            NONE
                        } else {
                            self.mesh.normals.push(n.normalize_or_zero());
                            self.mesh.normals.len() as u32 - 1
                        });
                    }
                    match *slot {
                        Some(i) if i != NONE => c.vn = i,
                        _ => {
                            has_n = false;
                            zero_vn_faces += 1;
                        }
                    }
                }
            }
            flags.push(if all_vt { HAS_UV } else { 0 } | if has_n { HAS_N } else { 0 });
        }
        self.note_zero_vn(zero_vn_faces);
        let corners = &corners;

        // Smoothing groups: accumulate per (group, position).
        let mut smooth = SmoothNormals::default();
        let (mut idx, mut pts): (Vec<u32>, Vec<Vec3>) = (Vec::new(), Vec::new());
        // Faces with their own vn still shape their neighbours' normals.
        for face in faces.iter().filter(|f| f.smoothing != 0) {
            idx.clear();
            idx.extend(corners[face.corners()].iter().map(|c| c.v));
            pts.clear();
            pts.extend(idx.iter().map(|&v| self.mesh.positions[v as usize]));
            smooth.add_polygon(face.smoothing, &idx, &pts);
        }

        // Triangulate (fans) and emit.
        let mut smooth_index: HashMap<(u32, u32), u32> = HashMap::new();
        let mut degenerate = 0usize;
        self.mesh.tris.reserve_exact(faces.iter().map(|f| f.corners().len().saturating_sub(2)).sum());
        for (face, &flags) in faces.iter().zip(&flags) {
            let at = face.corners();
            for i in 1..at.len().saturating_sub(1) {
                let c = [at.start, at.start + i, at.start + i + 1].map(|k| corners[k]);
                let v = c.map(|c| c.v);
                let Some((cross, len)) = area_normal(v.map(|k| self.mesh.positions[k as usize])) else {
                    degenerate += 1;
                    continue;
                };
                let uv = if flags & HAS_UV != 0 { c.map(|c| c.vt) } else { [NONE; 3] };
                let n = if flags & HAS_N != 0 {
                    c.map(|c| c.vn)
                } else if face.smoothing != 0 {
                    let mut n = [NONE; 3];
                    for (slot, &vi) in n.iter_mut().zip(&v) {
                        let key = (face.smoothing, vi);
                        *slot = match smooth_index.get(&key) {
                            Some(&i) => i,
                            None => {
                                // Contributions that cancel out: use this triangle's own normal.
                                let (value, cache) = match smooth.get(key.0, key.1) {
                                    Some(s) => (s, true),
                                    None => (cross / len, false),
                                };
                                self.mesh.normals.push(value);
                                let i = self.mesh.normals.len() as u32 - 1;
                                if cache {
                                    smooth_index.insert(key, i);
                                }
                                i
                            }
                        };
                    }
                    n
                } else {
                    [NONE; 3]
                };
                let material = self.material(face.material);
                self.mesh.tris.push(Tri { v, n, uv, material });
            }
        }
        self.note_degenerate(degenerate);
        ObjModel {
            mesh: self.mesh,
            materials: self.materials,
            textures: self.textures.textures,
            warnings: self.warnings,
        }
    }
}
