//! One module per subcommand.
pub mod bench;
pub mod edges;
pub mod eval;
pub mod info;
pub mod render;
pub mod scenes;
pub mod speed;
pub mod train;

use std::path::PathBuf;

use anyhow::Context;
use edgenerf::data::{LoadOptions, Scene};

/// The scene a command reads: its directory and the sparse-view split.
#[derive(clap::Args)]
pub struct SceneArgs {
    /// Scene directory (Blender/NeRF-synthetic, LLFF or DTU layout).
    pub scene: PathBuf,
    /// Training views of the sparse-view split (default: all).
    #[arg(long, short = 'k')]
    pub views: Option<usize>,
}

impl SceneArgs {
    /// Loads the scene with the split's `views` and default options otherwise.
    pub fn load(&self) -> anyhow::Result<Scene> {
        let opts = LoadOptions { views: self.views, ..Default::default() };
        Scene::load(&self.scene, &opts).with_context(|| format!("loading {}", self.scene.display()))
    }
}
