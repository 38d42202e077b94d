//! tilefarm's tracer: scenes, acceleration, camera, sampling, light transport, film.
//!
//! The one entry point the farm needs is [`render::render_unit`]: it renders a tile over
//! a range of sample indices into an [`film::Accumulation`] that merges exactly.

// `!(x > 0.0)` is deliberate in numeric code: it is also true for NaN, which the
// rewrite clippy suggests would hide.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod accel;
pub mod bsdf;
pub mod camera;
pub mod denoise;
pub mod film;
pub mod geometry;
pub mod integrator;
pub mod light;
pub mod material;
pub mod math;
pub mod memory;
pub mod output;
pub mod render;
pub mod sampler;
pub mod sampling;
pub mod scene;
pub mod shapes;
pub(crate) mod simd;
pub mod texture;
