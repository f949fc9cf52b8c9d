//! The shipped sparse-view presets (`tools/configs/sparse-*.toml`), embedded in the
//! binary, and which one `edgenerf train --views K` uses when no `--config` is given.
//!
//! Invariant: the embedded text is the file's (`include_str!` at build time), so a
//! preset run without `--config` and one with `--config tools/configs/NAME` run the
//! same configuration. The choice is by scene format and layout: LLFF gets
//! `sparse-llff.toml`, DTU `sparse-dtu.toml`, Blender-format scenes `sparse-small.toml`;
//! a nerfstudio or COLMAP capture gets the preset of the layout it loads as
//! (`data::bounds`): a forward-facing one is an LLFF scene (`sparse-llff.toml`), an
//! object-centric one gets `sparse-object.toml` (`sparse-small.toml` with an opacity
//! penalty for captures without alpha; docs/guide/presets.md,
//! docs/results/real-captures.md).

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
const SPARSE_OBJECT: Preset =
    Preset { path: "tools/configs/sparse-object.toml", text: include_str!("../configs/sparse-object.toml") };
const SPARSE_DTU: Preset =
    Preset { path: "tools/configs/sparse-dtu.toml", text: include_str!("../configs/sparse-dtu.toml") };

/// The preset a sparse-view run (`--views K`) of a grid field on a scene of `format`
/// uses when no `--config` is given; `forward_facing`: whether the scene loads with NDC
/// rays (decides for nerfstudio and COLMAP captures).
pub fn sparse_preset(format: SceneFormat, forward_facing: bool) -> Preset {
    match format {
        SceneFormat::Llff => SPARSE_LLFF,
        SceneFormat::DtuIdr | SceneFormat::DtuPixelNerf => SPARSE_DTU,
        SceneFormat::Blender => SPARSE_SMALL,
        SceneFormat::Nerfstudio | SceneFormat::Colmap if forward_facing => SPARSE_LLFF,
        SceneFormat::Nerfstudio | SceneFormat::Colmap => SPARSE_OBJECT,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgenerf::train::RunConfig;

    #[test]
    fn every_preset_parses_and_names_its_file() {
        for (format, ff) in [(SceneFormat::Llff, true), (SceneFormat::DtuIdr, false), (SceneFormat::Blender, false), (SceneFormat::Colmap, false), (SceneFormat::Colmap, true)] {
            let p = sparse_preset(format, ff);
            RunConfig::from_text_for(p.text, true, p.path, None).unwrap();
            let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(p.path);
            assert_eq!(std::fs::read_to_string(file).unwrap(), p.text, "{}", p.path);
        }
        assert_eq!(sparse_preset(SceneFormat::Colmap, true).path, SPARSE_LLFF.path);
        assert_eq!(sparse_preset(SceneFormat::Nerfstudio, false).path, SPARSE_OBJECT.path);
        // The object preset is sparse-small.toml with its opacity penalty before it.
        let small = SPARSE_SMALL.text.lines().skip_while(|l| !l.starts_with("[field]")).collect::<Vec<_>>();
        let object = SPARSE_OBJECT.text.lines().skip_while(|l| !l.starts_with("[field]")).collect::<Vec<_>>();
        assert_eq!(object, small, "sparse-object.toml's tables from [field] on must be sparse-small.toml's");
    }

    /// The DTU preset's `[[with_views]]`: 3 views keep the view-independent colour and
    /// 800 steps; the protocol's 9 views get band-2 colour and 4800 steps.
    #[test]
    fn dtu_preset_follows_the_view_count() {
        let dtu = RunConfig::from_text_for(SPARSE_DTU.text, true, SPARSE_DTU.path, None).unwrap();
        for (views, sh, iters) in [(3, 0, 800), (8, 0, 800), (9, 2, 4800)] {
            let mut c = dtu.clone();
            c.apply_with_views(views, SPARSE_DTU.path).unwrap();
            c.resolve();
            c.validate().unwrap();
            assert_eq!((c.field.sh_degree, c.train.iters), (sh, iters), "{views} views");
        }
    }
}
