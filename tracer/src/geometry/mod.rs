//! Geometric building blocks: rays, boxes, the two primitive shapes and shading frames.

pub mod aabb;
pub mod clip;
pub mod frame;
pub mod ray;
pub mod sphere;
pub mod triangle;

pub use aabb::Aabb;
pub use frame::{Frame, FrameW};
pub use ray::{Ray, offset_origin, offset_origin_wide};
