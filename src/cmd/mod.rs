//! One module per subcommand.

pub mod demo;
pub mod import_pov;
pub mod prerender;
pub mod verify;
