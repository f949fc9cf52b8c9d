//! The `edgenerf` command-line tool: argument parsing, progress display and file
//! output. All math lives in the engine crate; each subcommand is a module of `cmd`.

mod cmd;
mod output;
mod plot;
mod presets;
mod report;
mod slurm;
mod suite;
mod video;

use clap::{Parser, Subcommand};

/// Sparse-view neural radiance fields with edge-guided regularization, on a hash-grid
/// engine running in Vulkan compute (an NVIDIA GPU, or lavapipe on the CPU).
#[derive(Parser)]
#[command(name = "edgenerf", version, about)]
struct Cli {
    /// Use the Vulkan adapter whose name contains this (default: a discrete NVIDIA GPU,
    /// else any GPU, else lavapipe). Same as the WGPU_ADAPTER_NAME variable.
    #[arg(long, global = true, value_name = "NAME")]
    adapter: Option<String>,

    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print what a scene directory holds: format, images, split, near/far, adapter.
    Info(cmd::info::Args),
    /// Train a field on a scene (progress, checkpoints, log, test evaluation).
    Train(cmd::train::Args),
    /// Render views of a trained run (RGB, depth, normals, opacity), or a camera path
    /// (spiral, orbit, interpolate) as frames and videos.
    Render(cmd::render::Args),
    /// Every image and geometry metric of a trained run, with error maps.
    Eval(cmd::eval::Args),
    /// Run a benchmark suite (scenes x configurations), then write results and a report.
    Bench(cmd::bench::Args),
    /// Training speed on this adapter: steps/s and time per stage of a step (demo and
    /// sparse-view preset, or a scene and config of your own), as a table and JSON.
    Speed(cmd::speed::Args),
    /// Geometry of a trained run as PLY: the density field's surface (`mesh`) or
    /// rendered depth as points (`points`).
    #[command(subcommand)]
    Export(cmd::export::Command),
    /// Edge masks of a scene's views (what the edge-guided losses see), with overlays.
    Edges(cmd::edges::Args),
    /// Synthetic ground-truth scenes (Mitsuba): render them.
    #[command(subcommand)]
    Scenes(cmd::scenes::Command),
    /// A local web viewer of a run: orbit the scene (RGB, depth, normals, opacity),
    /// dataset views beside their ground truth, loss curves; follows a run in progress.
    View(cmd::view::Args),
}

fn main() -> std::process::ExitCode {
    // Rust ignores SIGPIPE, so printing into a closed pipe (`edgenerf info ... | head`)
    // panicked with a backtrace; restore the default: the process ends quietly.
    #[cfg(unix)]
    // SAFETY: called first thing in main, before any thread exists; SIG_DFL is a valid action.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // The chain of causes, one per line; no backtrace (users act on the message).
            // Write errors ignored: after SIGHUP the terminal may be gone (eprintln!
            // would panic).
            use std::io::Write;
            let mut err = std::io::stderr().lock();
            let _ = writeln!(err, "error: {e}");
            for cause in e.chain().skip(1) {
                let _ = writeln!(err, "  caused by: {cause}");
            }
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    let gpu_opts = edgenerf::gpu::GpuOptions { adapter: cli.adapter.clone(), disable_float_atomics: false };
    match cli.command {
        Command::Info(args) => cmd::info::run(args, &gpu_opts),
        Command::Train(args) => cmd::train::run(args, &gpu_opts),
        Command::Render(args) => cmd::render::run(args, &gpu_opts),
        Command::Eval(args) => cmd::eval::run(args, &gpu_opts),
        Command::Bench(args) => cmd::bench::run(args, cli.adapter.as_deref()),
        Command::Speed(args) => cmd::speed::run(args, &gpu_opts),
        Command::Export(c) => cmd::export::run(c, &gpu_opts),
        Command::Edges(args) => cmd::edges::run(args),
        Command::Scenes(c) => cmd::scenes::run(c),
        Command::View(args) => cmd::view::run(args, &gpu_opts),
    }
}
