//! Animations of rendered frames (`render --path`): MP4 (H.264, yuv420p, padded to even
//! dimensions) through `ffmpeg` when it is on PATH, else an animated GIF written with
//! the image crate. A file is encoded beside its final name and renamed, so an
//! interrupted encode never leaves a broken file under it (nor removes an older one).

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame};

/// The container of an animation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VideoFormat {
    Mp4,
    Gif,
}

impl VideoFormat {
    pub fn extension(self) -> &'static str {
        match self {
            VideoFormat::Mp4 => "mp4",
            VideoFormat::Gif => "gif",
        }
    }
}

/// Whether `ffmpeg` runs.
pub fn ffmpeg_available() -> bool {
    Command::new("ffmpeg").arg("-version").output().is_ok_and(|o| o.status.success())
}

/// The format `--video` asks for: `auto` (MP4 with ffmpeg, else GIF), `mp4`, `gif`, or
/// `none` (frames only).
pub fn choose(mode: &str) -> anyhow::Result<Option<VideoFormat>> {
    Ok(match mode {
        "auto" if ffmpeg_available() => Some(VideoFormat::Mp4),
        "auto" | "gif" => Some(VideoFormat::Gif),
        "mp4" if ffmpeg_available() => Some(VideoFormat::Mp4),
        "mp4" => bail!("--video mp4 needs ffmpeg on PATH, which was not found: install it (apt-get install ffmpeg) or pass --video gif"),
        "none" => None,
        other => bail!("unknown --video {other} (auto, mp4, gif or none)"),
    })
}

/// `<dir>/0000.png`, `<dir>/0001.png`, ...: frame `i` of a sequence.
pub fn frame_path(dir: &Path, i: usize) -> PathBuf {
    dir.join(format!("{i:04}.png"))
}

/// Encodes the `n` frames `frame_path(frames, 0..n)` at `fps` into `out`.
pub fn encode(format: VideoFormat, frames: &Path, n: usize, fps: f32, out: &Path) -> anyhow::Result<()> {
    let mut partial = out.as_os_str().to_owned();
    partial.push(".partial");
    let partial = PathBuf::from(partial);
    match format {
        VideoFormat::Mp4 => mp4(frames, n, fps, &partial)?,
        VideoFormat::Gif => gif(frames, n, fps, &partial)?,
    }
    std::fs::rename(&partial, out).with_context(|| format!("renaming {} to {}", partial.display(), out.display()))
}

fn mp4(frames: &Path, n: usize, fps: f32, out: &Path) -> anyhow::Result<()> {
    let o = Command::new("ffmpeg")
        .args(["-y", "-v", "error", "-framerate", &fps.to_string(), "-start_number", "0", "-i"])
        .arg(frames.join("%04d.png"))
        .args(["-frames:v", &n.to_string()])
        // yuv420p halves the chroma resolution: H.264 then needs even dimensions.
        .args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264", "-pix_fmt", "yuv420p"])
        .args(["-movflags", "+faststart", "-f", "mp4"])
        .arg(out)
        .output()
        .context("running ffmpeg")?;
    if !o.status.success() {
        let _ = std::fs::remove_file(out);
        bail!(
            "ffmpeg failed to encode {} ({}): {}; pass --video gif to write a GIF instead",
            out.display(),
            o.status,
            String::from_utf8_lossy(&o.stderr).trim()
        );
    }
    Ok(())
}

fn gif(frames: &Path, n: usize, fps: f32, out: &Path) -> anyhow::Result<()> {
    let mut bytes = Vec::new();
    {
        // Speed 10 of 1..30: NeuQuant palettes a few times faster than the best quality,
        // with no visible difference on renders.
        let mut enc = GifEncoder::new_with_speed(&mut bytes, 10);
        enc.set_repeat(Repeat::Infinite)?;
        // 1000 / fps milliseconds (GIF stores centiseconds: 30 fps plays at 33).
        let delay = Delay::from_numer_denom_ms(100_000, (100.0 * fps).round().max(1.0) as u32);
        for i in 0..n {
            let path = frame_path(frames, i);
            let img = image::open(&path).with_context(|| format!("reading frame {}", path.display()))?.into_rgba8();
            enc.encode_frame(Frame::from_parts(img, 0, 0, delay)).with_context(|| format!("encoding {}", out.display()))?;
        }
    }
    std::fs::write(out, bytes).with_context(|| format!("writing {}", out.display()))
}
