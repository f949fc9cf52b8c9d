//! The stand-in for the GPUs this project cannot run on: a few training steps of a
//! regularized 3-view run (every kernel of a step: sampler, occupancy grid, field
//! forward and second-order backward, compositing with its priors, every loss,
//! gradient norm, Adam) on SwiftShader, a second Vulkan implementation with other
//! limits (10 storage buffers per stage), another subgroup size and no float atomics,
//! under the Khronos validation layer with synchronization validation; its per-step
//! losses must match lavapipe's, and the layer must log nothing.
//!
//! Needs Debian's `chromium-common` (SwiftShader's ICD) and `vulkan-validationlayers`
//! (`tools/run test` installs them). Without them the test says so and passes, unless
//! `EDGENERF_REQUIRE_OTHER_VULKAN=1` (CI) makes that a failure.
//! `tools/check-other-vulkan.sh` runs this test in a release build.

mod common;

use std::path::{Path, PathBuf};

use common::{command, repo, text};

fn swiftshader_icd() -> PathBuf {
    std::env::var_os("SWIFTSHADER_ICD").map(PathBuf::from).unwrap_or_else(|| "/usr/lib/chromium/vk_swiftshader_icd.json".into())
}

fn validation_layer_present() -> bool {
    ["/usr/share/vulkan/explicit_layer.d", "/etc/vulkan/explicit_layer.d"].iter().any(|d| {
        std::fs::read_dir(d).is_ok_and(|it| it.flatten().any(|e| e.file_name().to_string_lossy().contains("khronos_validation")))
    })
}

fn losses(log: &Path) -> Vec<[f64; 4]> {
    let text = std::fs::read_to_string(log).unwrap();
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let cols = ["loss", "loss_color", "loss_depth", "loss_normal"].map(|k| header.iter().position(|h| *h == k).unwrap());
    text.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            cols.map(|c| v[c])
        })
        .collect()
}

#[test]
fn swiftshader_under_the_validation_layer_trains_like_lavapipe() {
    let icd = swiftshader_icd();
    let required = std::env::var("EDGENERF_REQUIRE_OTHER_VULKAN").is_ok_and(|v| v == "1");
    if !icd.is_file() || !validation_layer_present() {
        let what = format!(
            "SwiftShader ({}) or the Khronos validation layer is missing: apt-get install chromium-common vulkan-validationlayers",
            icd.display()
        );
        assert!(!required, "{what}");
        eprintln!("skipped: {what}");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let layer = tmp.path().join("layer");
    std::fs::create_dir(&layer).unwrap();
    let report = layer.join("validation.txt");
    std::fs::write(
        layer.join("vk_layer_settings.txt"),
        format!(
            "khronos_validation.debug_action = VK_DBG_LAYER_ACTION_LOG_MSG\n\
             khronos_validation.report_flags = error,warn,perf\n\
             khronos_validation.enables = VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT\n\
             khronos_validation.log_filename = {}\n",
            report.display()
        ),
    )
    .unwrap();
    let scene = repo().join("synthetic-scenes/small/creases");
    let config = repo().join("tools/configs/sparse-small.toml");
    let run = |name: &str, swiftshader: bool| {
        let out = tmp.path().join(name);
        let mut c = command();
        c.args(["train", scene.to_str().unwrap(), "--views", "3", "--config", config.to_str().unwrap()])
            .args(["--out", out.to_str().unwrap(), "--iters", "3", "--no-eval"])
            // Every term from step 0 (second-order normals included), the priors on,
            // few samples per ray to keep SwiftShader quick.
            .args(["--set", "reg.start_step=0", "--set", "reg.warmup_steps=0", "--set", "sampler.steps_per_diagonal=64"])
            .args(["--set", "priors.distortion=0.01", "--set", "priors.occlusion=0.01"]);
        if swiftshader {
            c.env("VK_ICD_FILENAMES", &icd).env("VK_INSTANCE_LAYERS", "VK_LAYER_KHRONOS_validation").env("VK_LAYER_SETTINGS_PATH", &layer);
        }
        let o = c.output().unwrap();
        let t = text(&o);
        assert!(o.status.success(), "{name}: {t}");
        if swiftshader {
            assert!(t.contains("SwiftShader"), "the run did not use SwiftShader: {t}");
        }
        losses(&out.join("log.csv"))
    };
    let a = run("lavapipe", false);
    let b = run("swiftshader", true);
    assert_eq!(a.len(), 3);
    assert_eq!(a.len(), b.len());
    let mut worst = 0.0f64;
    for (ra, rb) in a.iter().zip(&b) {
        for (x, y) in ra.iter().zip(rb) {
            worst = worst.max((x - y).abs() / x.abs().max(1e-12));
        }
    }
    eprintln!("largest relative loss difference lavapipe vs SwiftShader: {worst:.2e}");
    assert!(worst < 1e-3, "losses differ by {worst:e}: {a:?} vs {b:?}");
    let messages = std::fs::read_to_string(&report).unwrap_or_default();
    assert!(messages.trim().is_empty(), "validation layer messages:\n{messages}");
}
