//! One module per subcommand.
pub mod info;
pub mod render;
pub mod scenes;
pub mod train;
