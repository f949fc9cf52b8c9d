//! The shipped sparse-view presets (`tools/configs/sparse-*.toml`), embedded in the
//! binary, and which one `edgenerf train --views K` uses when no `--config` is given.
//!
//! Invariant: the embedded text is the file's (`include_str!` at build time), so a
//! preset run without `--config` and one with `--config tools/configs/NAME` run the
//! same configuration. The choice is by scene format only: LLFF gets `sparse-llff.toml`,
//! DTU `sparse-dtu.toml`, Blender-format scenes `sparse-small.toml` (the measured
//! defaults: docs/guide/presets.md); nerfstudio and COLMAP scenes, for
//! which no preset has been measured, keep the engine defaults.

use edgenerf::data::SceneFormat;

/// A shipped preset: its path in the repository and its text.
#[derive(Clone, Copy, Debug)]
pub struct Preset {
    pub path: &'static str,
    pub text: &'static str,
}

const SPARSE_SMALL: Preset =
    Preset { path: "tools/configs/sparse-small.toml", text: include_str!("../configs/sparse-small.toml") };
const SPARSE_LLFF: Preset =
    Preset { path: "tools/configs/sparse-llff.toml", text: include_str!("../configs/sparse-llff.toml") };
const SPARSE_DTU: Preset =
    Preset { path: "tools/configs/sparse-dtu.toml", text: include_str!("../configs/sparse-dtu.toml") };

/// The preset a sparse-view run (`--views K`) of a grid field on a scene of `format`
/// uses when no `--config` is given; `None` where none has been measured.
pub fn sparse_preset(format: SceneFormat) -> Option<Preset> {
    match format {
        SceneFormat::Llff => Some(SPARSE_LLFF),
        SceneFormat::DtuIdr | SceneFormat::DtuPixelNerf => Some(SPARSE_DTU),
        SceneFormat::Blender => Some(SPARSE_SMALL),
        SceneFormat::Nerfstudio | SceneFormat::Colmap => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgenerf::train::RunConfig;

    #[test]
    fn every_preset_parses_and_names_its_file() {
        for format in [SceneFormat::Llff, SceneFormat::DtuIdr, SceneFormat::Blender] {
            let p = sparse_preset(format).unwrap();
            RunConfig::from_text_for(p.text, true, p.path, None).unwrap();
            let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(p.path);
            assert_eq!(std::fs::read_to_string(file).unwrap(), p.text, "{}", p.path);
        }
        assert!(sparse_preset(SceneFormat::Colmap).is_none());
    }
}
