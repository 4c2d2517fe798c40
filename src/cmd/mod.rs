//! One module per subcommand.

pub mod prerender;
