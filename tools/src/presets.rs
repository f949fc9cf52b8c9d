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
//! penalty for captures without alpha, from 3 views a longer run and from 5 the
//! foreground opacity prior; docs/guide/presets.md,
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
    use edgenerf::render::Background;
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
        // The object preset is sparse-small.toml with its opacity penalty and its
        // [[with_views]] table before it, without sparse-small.toml's visibility pass
        // (its table up to the blank line after it), its rendering in segments and
        // through a finer grid (each comment and key) and their resets inside out
        // (comment and key): not measured on captures without alpha.
        let (mut in_visibility, mut in_render_keys, mut in_render_grid_reset) = (false, false, false);
        let small = SPARSE_SMALL
            .text
            .lines()
            .skip_while(|l| !l.starts_with("[field]"))
            .filter(|l| {
                in_visibility |= l.starts_with("[sampler.visibility]");
                in_render_keys |= l.starts_with("# Renders march ");
                in_render_grid_reset |= l.trim_start().starts_with("# Renders through the training grid inside out");
                let keep = !in_visibility && !in_render_keys && !l.contains("sampler.render_segment=0") && !in_render_grid_reset;
                in_visibility &= !l.is_empty();
                in_render_keys &= !(l.starts_with("render_segment =") || l.starts_with("render_resolution ="));
                in_render_grid_reset &= !l.contains("sampler.render_resolution=0");
                keep
            })
            .collect::<Vec<_>>();
        assert!(small.len() + 5 < SPARSE_SMALL.text.lines().skip_while(|l| !l.starts_with("[field]")).count(), "the visibility table was cut");
        let object = SPARSE_OBJECT.text.lines().skip_while(|l| !l.starts_with("[field]")).collect::<Vec<_>>();
        assert_eq!(object, small, "sparse-object.toml's tables from [field] on must be sparse-small.toml's");
    }

    /// `preset` as `train --views VIEWS` runs it: its `[[with_views]]` tables applied,
    /// resolved and valid.
    fn preset_for_views(preset: Preset, views: usize) -> RunConfig {
        let mut c = RunConfig::from_text_for(preset.text, true, preset.path, None).unwrap();
        c.apply_with_views(views, preset.path).unwrap();
        c.resolve();
        c.validate().unwrap();
        c
    }

    /// The DTU preset's `[[with_views]]`: below 9 views the view-independent colour,
    /// 1600 steps, the visibility pass's opacity floor of 0.05 and the stereo priors;
    /// the protocol's 9 views get band-2 colour, 4800 steps, a floor of 0.02 and no
    /// stereo priors. The foreground opacity prior is on at every view count (unlike
    /// the object preset's). The decay keeps its shape at every length. The grid's
    /// warm-up forgets at 0.7 below 9 views and at the grid's own 0.95 from 9.
    #[test]
    fn dtu_preset_follows_the_view_count() {
        for (views, sh, iters, min_alpha, stereo) in [(3, 0, 1600, 0.05, true), (8, 0, 1600, 0.05, true), (9, 2, 4800, 0.02, false)] {
            let c = preset_for_views(SPARSE_DTU, views);
            assert_eq!((c.field.sh_degree, c.train.iters), (sh, iters), "{views} views");
            let warmup_decay = if views < 9 { 0.7 } else { 0.95 };
            assert_eq!((c.sampler.warmup_decay, c.sampler.decay), (Some(warmup_decay), 0.95), "{views} views");
            assert_eq!((c.sampler.decay_at(0), c.sampler.decay_at(c.sampler.warmup_steps)), (warmup_decay, 0.95), "{views} views");
            assert_eq!(c.sampler.visibility.min_alpha, min_alpha, "{views} views");
            let want = if stereo { (0.1, 0.03, 0.9) } else { (0.0, 0.0, 0.9) };
            assert_eq!((c.priors.stereo_depth, c.priors.stereo_free_space, c.priors.stereo_uniqueness), want, "{views} views");
            // The decay written for 1600 steps (from step 1000, every 200) scaled to the run.
            let (k, lr) = (iters / 1600, &c.optim.schedule);
            assert_eq!(lr.lr(1000 * k - 1), lr.lr(100), "{views} views: no decay before step {}", 1000 * k);
            assert!(lr.lr(1200 * k) < lr.lr(1000 * k - 1), "{views} views: decayed by step {}", 1200 * k);
            assert!(c.sampler.visibility.train, "{views} views");
            assert_eq!(c.priors.foreground_opacity, 0.01, "{views} views");
        }
    }

    /// Three views see a point from at most three directions: `sparse-small.toml` and the
    /// object preset (whose `[field]` is the same) keep the colour to band 1 at every
    /// view count (inside-out captures: `inside_out_captures_get_the_background_on_the_box`);
    /// the DTU preset's own colour is untouched.
    #[test]
    fn sparse_presets_colour_up_to_band_1() {
        for views in [2, 3, 5, 8] {
            assert_eq!(preset_for_views(SPARSE_SMALL, views).field.sh_degree, 1, "sparse-small, {views} views");
            assert_eq!(preset_for_views(SPARSE_OBJECT, views).field.sh_degree, 1, "sparse-object, {views} views");
        }
        assert_eq!(preset_for_views(SPARSE_DTU, 3).field.sh_degree, 0);
    }

    /// `sparse-small.toml` runs the pass from step 64 (inside-out captures from 256:
    /// `inside_out_captures_get_the_background_on_the_box`) and drops faint samples with the bound on the opacity a ray may lose to them;
    /// the object preset, not measured with it, has no pass.
    #[test]
    fn small_preset_bounds_its_visibility_floor_and_the_object_preset_has_none() {
        let small = preset_for_views(SPARSE_SMALL, 3).sampler.visibility;
        assert!(small.train && !small.render);
        assert_eq!((small.min_alpha, small.max_dropped_opacity, small.start_step, small.min_alpha_start_step), (0.01, 0.05, 64, 64));
        // Objects render in segments (DTU too); the object preset, not measured with them, in one pass.
        assert_eq!(preset_for_views(SPARSE_SMALL, 3).sampler.render_segment, 16);
        assert_eq!(preset_for_views(SPARSE_DTU, 3).sampler.render_segment, 16);
        assert_eq!(preset_for_views(SPARSE_OBJECT, 3).sampler.render_segment, 0);
        // Objects render through a 64^3 grid; the object preset (and rooms seen from
        // within, below) through the training grid.
        for views in [3, 24] {
            assert_eq!(preset_for_views(SPARSE_SMALL, views).sampler.render_resolution, 64, "{views} views");
        }
        assert_eq!(preset_for_views(SPARSE_OBJECT, 3).sampler.render_resolution, 0);
        for views in [2, 3, 5, 8] {
            assert!(!preset_for_views(SPARSE_OBJECT, views).sampler.visibility.train, "{views} views");
        }
    }

    /// The LLFF preset's `[[with_views]]`: up to 13 views keep the 3-view batches of
    /// 2x2 patches, colour up to band 3, 2000 steps and the stereo depth prior; from 14
    /// views three quarters of each batch are single pixels, the colour stops at band 1,
    /// the learning rate is doubled, the run is 6000 steps with the decay stretched to
    /// them, and there is no stereo prior.
    #[test]
    fn llff_preset_follows_the_view_count() {
        for (views, share, sh, iters, lr, stereo) in [(3, 1.0, 3, 2000, 0.01, 0.1), (13, 1.0, 3, 2000, 0.01, 0.1), (14, 0.25, 1, 6000, 0.02, 0.0)] {
            let c = preset_for_views(SPARSE_LLFF, views);
            assert_eq!((c.train.patch_share, c.field.sh_degree, c.train.iters), (share, sh, iters), "{views} views");
            // The stereo depth prior along the NDC rays below 14 views, none of the
            // world-space-only stereo terms.
            let p = &c.priors;
            assert_eq!((p.stereo_depth, p.stereo_free_space, p.stereo_horizontal), (stereo, 0.0, false), "{views} views");
            // Below 14 views rays end past the far bound onto a learned background; from
            // 14 at infinity on black, as measured before.
            let bounded = views < 14;
            assert_eq!(c.scene.ndc_far_bound, bounded, "{views} views");
            let background = if bounded { Background::Learned } else { Background::Black };
            assert_eq!(c.render.background, background, "{views} views");
            let (lr_start, lr_end) = (c.optim.schedule.lr(100), c.optim.schedule.lr(iters));
            assert!((lr_start - lr).abs() < 1e-6, "{views} views: lr {lr_start}");
            // The preset's decay (0.7 at step 1200 and every 200 after, written for 2000
            // steps) ends at 0.7^5 of the rate whatever the length.
            assert!((lr_end / lr - 0.7f32.powi(5)).abs() < 1e-3, "{views} views: lr {lr_end} at the end");
        }
    }

    /// The object preset's `[[with_views]]`: with 2 views 800 steps of 2x2 patches (and
    /// `[field]`'s colour up to band 1); from 3 views 2400 steps, half of each batch single
    /// pixels, and the decay (written for 800 steps) stretched to the run: it starts 3x
    /// later and ends where the 800-step run's ends; from 5 views the foreground
    /// opacity prior.
    #[test]
    fn object_preset_follows_the_view_count() {
        let short = preset_for_views(SPARSE_OBJECT, 2);
        assert_eq!((short.train.iters, short.field.sh_degree, short.train.patch_share), (800, 1, 1.0));
        let long = preset_for_views(SPARSE_OBJECT, 3);
        assert_eq!((long.train.iters, long.field.sh_degree, long.train.patch_share), (2400, 1, 0.5));
        let (s, l) = (&short.optim.schedule, &long.optim.schedule);
        assert!(s.lr(700) < s.lr(100), "the 800-step run decays from step 500");
        assert_eq!(l.lr(1400), l.lr(100), "the 2400-step run keeps its rate until step 1500");
        assert!((l.lr(2400) / l.lr(100) - s.lr(800) / s.lr(100)).abs() < 1e-6, "both runs end at the same fraction of the rate");
        // The opacity penalty is the same at every view count.
        assert_eq!((long.priors.sparsity, long.priors.sparsity_steps), (short.priors.sparsity, short.priors.sparsity_steps));
        // The foreground opacity prior from 5 views on (with 3 it made floaters opaque).
        for (views, weight) in [(2, 0.0), (3, 0.0), (4, 0.0), (5, 0.01), (8, 0.01)] {
            assert_eq!(preset_for_views(SPARSE_OBJECT, views).priors.foreground_opacity, weight, "{views} views");
        }
    }

    /// `[with_cameras_inside]` of the Blender and object presets: an inside-out capture
    /// gets the learned background on the box itself (3 maps up to 64 x 128, started at
    /// a plain colour, not from the frames, learning at 0.3 times the field's rate), a
    /// constant opacity penalty of 0.01, an occupancy grid that forgets in half the
    /// steps (decay 0.9, 0.7 during the warm-up), the DTU preset's stereo
    /// priors with planes across the up direction as well, and the foreground opacity
    /// prior at 0.01, and colour up to band 3 (in the object preset its 3-view table,
    /// applied after, keeps band 1); a capture seen from outside keeps the preset's own
    /// background, penalty, grid, band-1 colour and stereo priors (sparse-small.toml's
    /// depth prior alone, none in the object preset). The LLFF and DTU
    /// presets have no such table.
    #[test]
    fn inside_out_captures_get_the_background_on_the_box() {
        use edgenerf::render::{Prefit, ShellShape};
        for preset in [SPARSE_SMALL, SPARSE_OBJECT] {
            for inside in [false, true] {
                let mut c = RunConfig::from_text_for(preset.text, true, preset.path, None).unwrap();
                let (sparsity, steps, decay) = (c.priors.sparsity, c.priors.sparsity_steps, c.sampler.decay);
                let applied = c.apply_with_cameras_inside(inside, preset.path).unwrap();
                c.apply_with_views(3, preset.path).unwrap();
                c.resolve();
                c.validate().unwrap();
                let bg = c.render.learned_background;
                if inside {
                    // sparse-small.toml also renders in one pass and through the training grid
                    // again inside out.
                    let n_set = if preset.path == SPARSE_SMALL.path { 20 } else { 18 };
                    assert_eq!(applied.len(), n_set, "{}", preset.path);
                    assert_eq!(c.sampler.render_segment, 0, "{}: one pass inside out", preset.path);
                    assert_eq!(c.sampler.warmup_decay, Some(0.7), "{}: the warm-up forgets faster inside out", preset.path);
                    let v = &c.sampler.visibility;
                    assert_eq!((v.start_step, v.min_alpha_start_step), (256, 256), "{}: the visibility pass from step 256 inside out", preset.path);
                    if preset.path == SPARSE_SMALL.path {
                        assert_eq!((v.min_alpha, v.max_dropped_opacity), (0.01, 0.05), "the floor and its bound kept inside out");
                        assert_eq!(c.sampler.render_resolution, 0, "rooms render through the training grid");
                    }
                    let dtu = preset_for_views(SPARSE_DTU, 3).priors;
                    let p = &c.priors;
                    assert_eq!((p.stereo_depth, p.stereo_free_space, p.stereo_uniqueness), (dtu.stereo_depth, dtu.stereo_free_space, dtu.stereo_uniqueness), "{}", preset.path);
                    assert_eq!((bg.shell_shape, bg.shell_radius, bg.levels, bg.finest_height, bg.lr_scale), (ShellShape::Box, 1.0, 3, 64, 0.3), "{}", preset.path);
                    assert_eq!(bg.prefit, Prefit::None, "{}: the map starts plain, not from the frames", preset.path);
                    // Band 3 inside out; the object preset's [[with_views]] from 3 views,
                    // applied after this table (as `train` does), sets band 1 again.
                    let sh = if preset.path == SPARSE_SMALL.path { 3 } else { 1 };
                    assert_eq!(c.field.sh_degree, sh, "{}: colour band inside out", preset.path);
                    assert_eq!((c.priors.sparsity, c.priors.sparsity_steps, c.sampler.decay), (0.01, 0, 0.9), "{}", preset.path);
                    assert_eq!((p.stereo_horizontal, p.foreground_opacity), (true, 0.01), "{}: planes across up, the foreground held opaque", preset.path);
                    assert!(!dtu.stereo_horizontal, "DTU's neighbouring views sweep along the rays alone");
                } else {
                    assert!(applied.is_empty(), "{}", preset.path);
                    assert_eq!((bg.shell_shape, bg.shell_radius, bg.lr_scale, bg.prefit), (ShellShape::Sphere, 0.0, 1.0, Prefit::All), "{}", preset.path);
                    assert_eq!(c.field.sh_degree, 1, "{}: colour up to band 1 outside", preset.path);
                    assert_eq!((c.priors.sparsity, c.priors.sparsity_steps, c.sampler.decay), (sparsity, steps, decay), "{}", preset.path);
                    assert_eq!(decay, 0.95, "{}: the grid's own decay outside", preset.path);
                    assert_eq!(c.sampler.warmup_decay, None, "{}: the warm-up keeps the grid's decay outside", preset.path);
                    // Seen from outside sparse-small.toml pulls toward the sweep's depths
                    // (objects and forward-facing scenes since 2026-12-07) without carving
                    // or the other checks; the object preset, not measured on captures
                    // without alpha, has no stereo prior.
                    let p = &c.priors;
                    let want = if preset.path == SPARSE_SMALL.path { (0.1, 0.0, 1.0, false) } else { (0.0, 0.0, 1.0, false) };
                    assert_eq!((p.stereo_depth, p.stereo_free_space, p.stereo_uniqueness, p.stereo_horizontal), want, "{}: stereo priors outside", preset.path);
                    assert_eq!(c.priors.foreground_opacity, 0.0, "{}: 3 views seen from outside leave the foreground alone", preset.path);
                }
            }
        }
        for preset in [SPARSE_LLFF, SPARSE_DTU] {
            assert!(RunConfig::from_text_for(preset.text, true, preset.path, None).unwrap().with_cameras_inside.is_none(), "{}", preset.path);
        }
    }
}
