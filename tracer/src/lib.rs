//! tilefarm's tracer: scenes, acceleration, camera, sampling, light transport, film.
//!
//! The one entry point the farm needs is [`render::render_unit`]: it renders a tile over
//! a range of sample indices into an [`film::Accumulation`] that merges exactly.

pub mod accel;
pub mod bsdf;
pub mod geometry;
pub mod material;
pub mod scene;
pub mod texture;
