//! Prerendering: cube-map colour, radial depth and slab layers at reference viewpoints.
//!
//! - [`store`]: the prerender directory layout shared with later stages.

pub mod store;
