//! One module per subcommand.
pub mod edges;
pub mod info;
pub mod render;
pub mod scenes;
pub mod train;
