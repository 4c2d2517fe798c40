//! One module per subcommand.

pub mod demo;
pub mod import_pov;
pub mod load;
pub mod prerender;
pub mod serve;
pub mod walk;
pub mod verify;
