//! `edgenerf render --path`: a tiny run of `creases` rendered along camera paths, the
//! frames, `path.json` and the animations it writes (the GIF always; the MP4 when
//! ffmpeg is on PATH), and its refusals. Without ffmpeg the MP4 part is skipped with a
//! message, unless `EDGENERF_REQUIRE_FFMPEG=1` (CI, through `.ci/run`; `tools/run test`
//! installs ffmpeg) makes that a failure.

mod common;

use std::path::Path;

use common::{edgenerf, text, train_creases_3v};

/// The PNG files of `dir`, sorted, with their sizes.
fn frames(dir: &Path) -> Vec<(String, (u32, u32))> {
    let mut names: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    names.into_iter().map(|n| (n.clone(), image::image_dimensions(dir.join(&n)).unwrap())).collect()
}

fn render(run: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["render", run.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    edgenerf(&args)
}

#[test]
fn render_path_writes_frames_cameras_and_a_looping_gif() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    // Two steps, coarse marching: an untrained grid is occupied everywhere.
    let o = train_creases_3v(&run, 2, &["--set", "sampler.steps_per_diagonal=48"]);
    assert!(o.status.success(), "{}", text(&o));

    let out = tmp.path().join("orbit");
    let o = render(&run, &out, &["--path", "orbit", "--frames", "4", "--fps", "10", "--video", "gif", "--scale", "0.5"]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("orbit path: 4 frames of 64x64 from the 3 training views"), "{t}");
    for s in ["rgb", "depth", "normals"] {
        let f = frames(&out.join(s));
        let want: Vec<(String, (u32, u32))> = (0..4).map(|i| (format!("{i:04}.png"), (64, 64))).collect();
        assert_eq!(f, want, "{s}");
        // The GIF decodes to the same number of frames, of the same size, 100 ms each (GIF counts centiseconds).
        let gif = std::fs::File::open(out.join(format!("{s}.gif"))).unwrap();
        let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(gif)).unwrap();
        let gif_frames = image::AnimationDecoder::into_frames(decoder).collect_frames().unwrap();
        assert_eq!(gif_frames.len(), 4, "{s}.gif");
        for fr in &gif_frames {
            assert_eq!(fr.buffer().dimensions(), (64, 64));
            assert_eq!(fr.delay().numer_denom_ms(), (100, 1));
        }
    }
    // The frames differ: the camera moves.
    let a = image::open(out.join("rgb/0000.png")).unwrap().into_rgb8();
    let b = image::open(out.join("rgb/0002.png")).unwrap().into_rgb8();
    assert_ne!(a, b, "frames 0 and 2 of an orbit are different views");
    let path: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("path.json")).unwrap()).unwrap();
    assert_eq!(path["path"], "orbit");
    assert_eq!(path["cameras"].as_array().unwrap().len(), 4);
    assert_eq!(path["cameras"][0]["width"], 64);

    // An earlier path render is kept unless --overwrite, which replaces all of it.
    let before = std::fs::read(out.join("rgb.gif")).unwrap();
    let o = render(&run, &out, &["--path", "interpolate", "--frames", "3", "--video", "none", "--scale", "0.25"]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("already holds a path render") && t.contains("--overwrite"), "{t}");
    assert_eq!(std::fs::read(out.join("rgb.gif")).unwrap(), before);
    let o = render(&run, &out, &["--path", "interpolate", "--frames", "3", "--video", "none", "--scale", "0.25", "--overwrite"]);
    assert!(o.status.success(), "{}", text(&o));
    let want: Vec<(String, (u32, u32))> = (0..3).map(|i| (format!("{i:04}.png"), (32, 32))).collect();
    assert_eq!(frames(&out.join("depth")), want, "the new frames, none left of the earlier render");
    assert!(!out.join("rgb.gif").exists(), "--video none writes no animation, the old one is gone");

    // Bad requests: clear errors, nothing written.
    let bad = tmp.path().join("bad");
    for (args, msg) in [
        (&["--path", "interpolate", "--frames", "2"][..], "at least 3 frames"),
        (&["--path", "spiral", "--split", "train"], "cannot be used with"),
        (&["--frames", "10"], "--path"),
        (&["--path", "orbit", "--scale", "0"], "outside (0, 4]"),
    ] {
        let o = render(&run, &bad, args);
        assert!(!o.status.success() && text(&o).contains(msg), "{args:?}: {}", text(&o));
        assert!(!bad.join("rgb").exists(), "{args:?}");
    }

    // MP4 through ffmpeg (odd frame sizes are padded to even ones for yuv420p).
    if !std::process::Command::new("ffmpeg").arg("-version").output().is_ok_and(|o| o.status.success()) {
        let msg = "ffmpeg is not on PATH: 'apt-get install ffmpeg' (tools/run test does it as root) enables the MP4 part";
        assert!(std::env::var("EDGENERF_REQUIRE_FFMPEG").as_deref() != Ok("1"), "EDGENERF_REQUIRE_FFMPEG=1: {msg}");
        eprintln!("skipping the MP4 part: {msg}");
        return;
    }
    let mp4 = tmp.path().join("spiral");
    let o = render(&run, &mp4, &["--path", "spiral", "--frames", "3", "--video", "mp4", "--scale", "0.18"]);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(frames(&mp4.join("rgb"))[0].1, (23, 23));
    let probe = std::process::Command::new("ffprobe")
        .args(["-v", "error", "-count_frames", "-select_streams", "v:0", "-show_entries", "stream=codec_name,pix_fmt,width,height,nb_read_frames", "-of", "csv=p=0"])
        .arg(mp4.join("rgb.mp4"))
        .output()
        .unwrap();
    assert_eq!(String::from_utf8_lossy(&probe.stdout).trim(), "h264,24,24,yuv420p,3");
}
