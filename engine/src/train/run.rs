//! A training run in its run directory: the loop's cadence around [`Trainer::step`] and
//! the files it writes, for the CLI (`edgenerf train`) and any library user.
//!
//! [`train_run`] writes, in the run directory:
//! * [`CONFIG`] (`config.json`): the effective config ([`RunConfig::to_json`]), first;
//! * [`LOG`] (`log.csv`): one row per step ([`StepStats::csv_row`], seconds since the
//!   start of this call in `elapsed_s`), appended, so a resumed run continues its log;
//!   the header when the file is new. Rows of steps at or after the trainer's first step
//!   (logged by an earlier run that ended after its last checkpoint: a crash, a kill -9,
//!   a second Ctrl-C) and a row cut short are dropped first, so the log holds each step
//!   once, in order;
//! * [`CHECKPOINT`] (`checkpoint.safetensors`): every `train.checkpoint_every` steps
//!   (0: never in between), and when the loop ends, however it ends.
//!
//! The loop runs until `train.iters` steps are done, or stops early after the step at
//! which `train.max_seconds` of training have passed, or after a step at which the
//! [`RunObserver`] asks it to (Ctrl-C in the CLI); steps are read back one step late
//! ([`Trainer::step_pipelined`]), so such a stop also finishes the step already
//! running. [`write_evaluation`] then renders the
//! test views into [`TEST_DIR`] (`test/`) with their `metrics.json`.
//!
//! Invariants: `config.json`, checkpoints and `metrics.json` are replaced atomically
//! ([`write_atomic`]); a step's log row is written as soon as the step is done; a step
//! that fails (a non-finite loss or gradient, or a gradient norm that overflows,
//! [`TrainError::NonFinite`]) ends the run with its error, writing no row and no
//! checkpoint, so the last good checkpoint stays; so does a run whose first
//! [`MISSED_STEPS`] steps evaluate no sample ([`TrainError::RaysMissScene`]: every ray
//! missed the scene's box). One writer per run directory is the caller's to ensure
//! (the CLI holds a lock file, `train.lock`).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::data::Scene;
use crate::gpu::Gpu;

use super::evaluate::{Evaluation, evaluate};
use super::model::Model;
use super::output::{write_atomic, write_view};
use super::{RunConfig, StepStats, TrainError, Trainer};

/// The checkpoint's file name in a run directory.
pub const CHECKPOINT: &str = "checkpoint.safetensors";
/// The effective config's file name.
pub const CONFIG: &str = "config.json";
/// The per-step log's file name.
pub const LOG: &str = "log.csv";
/// The directory of the test views' renders and `metrics.json`.
pub const TEST_DIR: &str = "test";

/// A run whose first this many steps evaluate no sample at all stops
/// ([`TrainError::RaysMissScene`]).
pub const MISSED_STEPS: u64 = 5;

/// What a caller sees of a run while it goes (progress display, stop requests). Every
/// method has a default that does nothing.
pub trait RunObserver {
    /// After each step, with its stats and the seconds since the run started.
    fn step(&mut self, _trainer: &Trainer, _stats: &StepStats, _elapsed_s: f64) {}

    /// Asked after each step: `true` stops the run there (with its checkpoint saved).
    fn stop_requested(&mut self) -> bool {
        false
    }

    /// The run stops at step `step` because `elapsed_s` reached `train.max_seconds`.
    fn time_limit_reached(&mut self, _step: u64, _elapsed_s: f64) {}
}

/// An observer that watches nothing.
impl RunObserver for () {}

/// Why a run's loop ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunEnd {
    /// `train.iters` steps are done.
    Finished,
    /// `train.max_seconds` of training passed.
    TimeLimit,
    /// The observer asked to stop.
    Stopped,
}

/// What [`train_run`] did.
#[derive(Clone, Debug)]
pub struct RunSummary {
    /// The step the run started at (0, or a resumed checkpoint's) and the one it ended at.
    pub first_step: u64,
    pub last_step: u64,
    /// Wall time of the loop and the final checkpoint.
    pub elapsed_s: f64,
    pub end: RunEnd,
    /// Where the last checkpoint is.
    pub checkpoint: PathBuf,
}

/// Trains `trainer` in the run directory `dir` (which must exist) until `train.iters`
/// steps, writing `config.json`, `log.csv` and checkpoints (see the module doc).
pub fn train_run(trainer: &mut Trainer, dir: &Path, observer: &mut dyn RunObserver) -> Result<RunSummary, TrainError> {
    let config: RunConfig = trainer.config().clone();
    write_atomic(&dir.join(CONFIG), config.to_json().as_bytes())?;
    let checkpoint = dir.join(CHECKPOINT);
    let log_path = dir.join(LOG);
    let mut log = open_log(&log_path, trainer.step_count())?;
    let iters = config.train.iters;
    let start = Instant::now();
    let first_step = trainer.step_count();
    let mut end = RunEnd::Finished;
    let every = config.train.checkpoint_every;
    // Steps without a single sample since the start of this call, until one has some.
    let mut missed = 0u64;
    let mut any_samples = false;
    // Each step is read back while the next one runs (Trainer::step_pipelined); the
    // step before a checkpoint and the last one are read back at once (drained), so a
    // checkpoint holds exactly the steps the log has rows for.
    while trainer.step_count() < iters {
        let done = trainer.step_count() + 1;
        let checkpoint_due = every > 0 && done.is_multiple_of(every) && done < iters;
        let mut steps = trainer.step_pipelined(done >= iters || checkpoint_due)?;
        let mut stopping = None;
        let mut i = 0;
        while let Some(stats) = steps.get(i) {
            // A gradient whose entries are finite but whose norm overflows (a weight of
            // -8e37 in a checkpoint) is divergence too: before, such a run trained on
            // with grad_norm = inf and wrote new checkpoints.
            if !stats.grad_norm.is_finite() {
                return Err(TrainError::NonFinite { step: stats.step, what: format!("the gradient's norm ({})", stats.grad_norm) });
            }
            // Rays that all miss the scene's box give 0 samples and gradient 0: a run
            // that "trained" for its whole length on nothing. (The march's count: the
            // visibility pass may drop every sample of a faint, untrained field.)
            if stats.samples > 0 || stats.marched_samples_per_ray > 0.0 {
                any_samples = true;
            } else if !any_samples {
                missed += 1;
                if missed >= MISSED_STEPS {
                    return Err(TrainError::RaysMissScene { steps: missed });
                }
            }
            let elapsed = start.elapsed().as_secs_f64();
            writeln!(log, "{}", stats.csv_row(elapsed)).map_err(|e| TrainError::io(&log_path, e))?;
            observer.step(trainer, stats, elapsed);
            if stopping.is_none() {
                if observer.stop_requested() {
                    stopping = Some(RunEnd::Stopped);
                } else if config.train.max_seconds.is_some_and(|limit| elapsed >= limit) {
                    observer.time_limit_reached(stats.step + 1, elapsed);
                    stopping = Some(RunEnd::TimeLimit);
                }
                if stopping.is_some() {
                    // The step in flight, if any, ends the run too: its row, then the
                    // checkpoint.
                    steps.extend(trainer.finish_pending()?);
                }
            }
            i += 1;
        }
        if let Some(reason) = stopping {
            end = reason;
            break;
        }
        if checkpoint_due {
            trainer.checkpoint()?.save(&checkpoint)?;
        }
    }
    trainer.checkpoint()?.save(&checkpoint)?;
    Ok(RunSummary { first_step, last_step: trainer.step_count(), elapsed_s: start.elapsed().as_secs_f64(), end, checkpoint })
}

/// `log.csv` opened for appending, with the header written when it is new, after
/// dropping the rows of steps `first_step` and later and any row cut short (a resumed
/// run redoes those steps from its checkpoint; before, a resume after a crash logged
/// them twice).
fn open_log(path: &Path, first_step: u64) -> Result<std::fs::File, TrainError> {
    let io = |e| TrainError::io(path, e);
    if let Ok(text) = std::fs::read_to_string(path)
        && let Some(header) = text.lines().next()
    {
        let columns = header.split(',').count();
        let mut kept = format!("{header}\n");
        let mut dropped = 0usize;
        for line in text.lines().skip(1) {
            let step = line.split(',').next().and_then(|v| v.parse::<u64>().ok());
            if step.is_some_and(|s| s < first_step) && line.split(',').count() == columns {
                kept.push_str(line);
                kept.push('\n');
            } else {
                dropped += 1;
            }
        }
        if dropped > 0 || !text.ends_with('\n') {
            log::info!("{}: dropped {dropped} rows logged after the checkpoint's step {first_step}", path.display());
            write_atomic(path, kept.as_bytes())?;
        }
    }
    let mut log = std::fs::OpenOptions::new().create(true).append(true).open(path).map_err(io)?;
    if log.metadata().map_err(io)?.len() == 0 {
        writeln!(log, "{}", StepStats::CSV_HEADER).map_err(io)?;
    }
    Ok(log)
}

/// Renders the test views of `scene` with `model`, scores them ([`evaluate`]), and
/// writes the renders ([`write_view`]) and the evaluation as `metrics.json` into `dir`
/// (created when missing).
pub fn write_evaluation(gpu: &Gpu, model: &mut Model, scene: &Scene, dir: &Path) -> Result<Evaluation, TrainError> {
    let (eval, renders) = evaluate(gpu, model, scene)?;
    for (v, r) in &renders {
        write_view(dir, &scene.views[*v].name, r)?;
    }
    let json = serde_json::to_string_pretty(&eval).expect("evaluations serialize");
    std::fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
    write_atomic(&dir.join("metrics.json"), json.as_bytes())?;
    Ok(eval)
}
