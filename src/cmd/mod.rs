//! One module per subcommand.

pub mod bench_viewer;
pub mod build;
pub mod cull;
pub mod demo;
pub mod eval;
pub mod flythrough;
pub mod import_pov;
pub mod load;
pub mod prerender;
pub mod render;
pub mod serve;
pub mod slabs;
pub mod tune;
pub mod verify;
pub mod view;
pub mod walk;
