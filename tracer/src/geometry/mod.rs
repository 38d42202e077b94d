//! Geometric building blocks: rays, boxes, the two primitive shapes and shading frames.

pub mod aabb;
pub mod clip;
pub mod frame;
pub mod ray;
pub mod sphere;
pub mod triangle;

pub use aabb::Aabb;
pub(crate) use frame::FrameW;
pub use frame::{Azimuth, Frame};
pub(crate) use ray::offset_origin_wide;
pub use ray::{Ray, offset_origin};
