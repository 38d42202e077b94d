//! What can be wrong with a scene: its own module, so that the parts of the loader that
//! report errors need not import the loader that calls them.

use super::obj::ObjError;

#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("{path}: {message}")]
    Io { path: String, message: String },
    /// TOML syntax or schema errors; the message names the line and the key.
    #[error("{path}: {message}")]
    Syntax { path: String, message: String },
    #[error("{path}: {field}: {message}")]
    Invalid { path: String, field: String, message: String },
    #[error(transparent)]
    Obj(#[from] ObjError),
}
