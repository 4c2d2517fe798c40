//! Prerendering: cube-map colour, radial depth and slab layers at reference viewpoints.
//!
//! - [`store`]: the prerender directory layout shared with later stages.
//! - [`agreement`]: how two reference panoramas agree on the surfaces both see (lighting
//!   computed per render shows there).
//! - [`pov`]: POV-Ray import: unmodified `.pov` scenes rendered into the same layout.
//! - [`scene`]: the scene model ([`scene::Scene`], [`scene::Shape`], materials, lights, sky)
//!   with exact f64 ray queries ([`scene::Scene::first_hit`]).
//! - [`parse`]: the TOML scene format (read and write).
//! - [`job`]: rendering a track into a prerender directory (resume, shards, report, merge).
//! - [`runlog`]: the run log (`runs/*.jsonl`): timings kept apart from the content.
//! - [`scenes`]: built-in procedural scenes (`castle`, `nature`) with their tracks.
//! - [`erode`]: segments against solids shrunk by a distance (occluder shrinking for culling).
//! - [`render`]: cube maps of colour + radial depth, slab layers in one pass, low-res depth,
//!   perspective views.
//! - [`sky`]: the complete sky of a track (rendered alone, or assembled from the panoramas).
//! - [`truth`]: anti-aliased ground truth of any scene kind (built-in, TOML, POV-Ray import)
//!   from any camera, by the renderer that made the panoramas.

mod accel;
pub mod agreement;
pub mod erode;
mod geom;
pub mod job;
pub mod parse;
pub mod pov;
pub mod render;
pub mod runlog;
pub mod scene;
pub mod scenes;
mod shade;
pub mod sky;
pub mod store;
pub mod truth;

pub use accel::Hit;
