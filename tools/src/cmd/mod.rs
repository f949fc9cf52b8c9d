//! One module per subcommand.
pub mod bench;
pub mod edges;
pub mod eval;
pub mod export;
pub mod info;
pub mod render;
pub mod scenes;
pub mod speed;
pub mod train;
pub mod view;

use std::path::PathBuf;

use anyhow::Context;
use edgenerf::data::{LoadOptions, Scene};

/// The scene a command reads: its directory and the sparse-view split.
#[derive(clap::Args)]
pub struct SceneArgs {
    /// Scene directory (Blender/NeRF-synthetic, nerfstudio transforms.json, COLMAP
    /// sparse model, LLFF or DTU layout).
    pub scene: PathBuf,
    /// Training views of the sparse-view split (default: all).
    #[arg(long, short = 'k')]
    pub views: Option<usize>,
    /// Image downsampling factor (LLFF, COLMAP, nerfstudio): read images_N, or
    /// downsample images/ by N on load when there is no images_N (default 8 for LLFF,
    /// 1 otherwise). Recorded in the run's config (scene.llff_factor).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=64))]
    pub llff_factor: Option<u32>,
}

impl SceneArgs {
    /// Loads the scene with the split's `views` and default options otherwise.
    pub fn load(&self) -> anyhow::Result<Scene> {
        let opts = LoadOptions { views: self.views, llff_factor: self.llff_factor, ..Default::default() };
        Scene::load(&self.scene, &opts).with_context(|| format!("loading {}", self.scene.display()))
    }
}
