//! Shapes below the aggregates (as pbrt-v4 keeps them): the loaders' indexed triangle
//! mesh, and the scene's compact primitive store that the kd-tree and the packed brute
//! force are built over.

pub mod mesh;
mod store;
mod tangents;

pub use mesh::{NONE, Tri, TriangleMesh};
pub use store::{Geometry, GeometryBytes, PrimRef, Sphere};
