//! Scene input: the TOML scene file, OBJ/MTL meshes, and the assembled [`Scene`].

pub mod geometry;
pub mod mesh;
pub mod obj;

pub use geometry::{Geometry, PrimRef, Sphere};
pub use mesh::{NONE, Tri, TriangleMesh};
