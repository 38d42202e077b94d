//! OBJ/MTL loading (PLACEHOLDER: being written).

use std::path::Path;

use super::TriangleMesh;
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

pub fn load_obj(path: &Path) -> Result<ObjModel, ObjError> {
    Err(ObjError::Io { path: path.display().to_string(), message: "not implemented".into() })
}
