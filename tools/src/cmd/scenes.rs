//! `edgenerf scenes render`: runs `synthetic-scenes/render.py` in its Mitsuba virtual
//! environment and shows its progress.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command as Process, Stdio};

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(clap::Subcommand)]
pub enum Command {
    /// Render synthetic scenes with Mitsuba 3 (sets up its virtual environment first).
    Render(RenderArgs),
}

#[derive(clap::Args)]
pub struct RenderArgs {
    /// Render preset: `small` (the committed 128x128 set) or `full` (512x512).
    #[arg(long, default_value = "small")]
    preset: String,
    /// Scenes to render (default: all).
    #[arg(long)]
    scene: Vec<String>,
    /// Output directory (default: the preset's directory under synthetic-scenes/).
    #[arg(long)]
    out: Option<PathBuf>,
    /// The repository's synthetic-scenes directory.
    #[arg(long, default_value = "synthetic-scenes")]
    scenes_dir: PathBuf,
}

pub fn run(cmd: Command) -> anyhow::Result<()> {
    match cmd {
        Command::Render(args) => render(args),
    }
}

fn venv_python(dir: &Path) -> anyhow::Result<PathBuf> {
    let setup = dir.join("setup-venv.sh");
    if !setup.is_file() {
        bail!("{} not found: run this from the repository root or pass --scenes-dir", setup.display());
    }
    let status = Process::new("bash").arg(&setup).stdout(Stdio::null()).status().context("running setup-venv.sh")?;
    if !status.success() {
        bail!("{} failed: see its output (it needs python3 with venv and pip)", setup.display());
    }
    Ok(dir.join(".venv/bin/python"))
}

fn render(args: RenderArgs) -> anyhow::Result<()> {
    let python = venv_python(&args.scenes_dir)?;
    let mut cmd = Process::new(&python);
    cmd.arg(args.scenes_dir.join("render.py")).arg("--preset").arg(&args.preset).arg("--progress-lines");
    for s in &args.scene {
        cmd.arg("--scene").arg(s);
    }
    if let Some(out) = &args.out {
        cmd.arg("--out").arg(out);
    }
    let mut child = cmd.stdout(Stdio::piped()).spawn().with_context(|| format!("starting {}", python.display()))?;
    let bar = ProgressBar::new(0);
    bar.set_style(ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} {msg}").unwrap());
    for line in BufReader::new(child.stdout.take().unwrap()).lines() {
        let line = line?;
        let mut parts = line.splitn(4, ' ');
        match (parts.next(), parts.next(), parts.next()) {
            (Some("progress"), Some(done), Some(total)) => {
                bar.set_length(total.parse().unwrap_or(0));
                bar.set_position(done.parse().unwrap_or(0));
                bar.set_message(parts.next().unwrap_or("").to_string());
            }
            _ => bar.println(line),
        }
    }
    let status = child.wait()?;
    bar.finish();
    if !status.success() {
        bail!("render.py failed ({status})");
    }
    Ok(())
}
