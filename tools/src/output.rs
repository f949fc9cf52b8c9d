//! Output directories given on the command line (the files of a rendered view are
//! written by the engine, `edgenerf::train::output`).

use std::path::{Path, PathBuf};

use anyhow::Context;

/// Creates the output directory `dir` (given as `flag`) before any work, with a clear
/// error when a file is in the way (found only after rendering before).
pub fn ensure_dir(dir: &Path, flag: &str) -> anyhow::Result<()> {
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!("{flag} {} is a file; pass a directory (it is created when missing)", dir.display());
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {flag} {}", dir.display()))
}

/// Refuses an output directory `dir` (given as `flag`) that is a file, creating nothing.
pub fn refuse_file(dir: &Path, flag: &str) -> anyhow::Result<()> {
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!("{flag} {} is a file; pass a directory (it is created when missing)", dir.display());
    }
    Ok(())
}

/// An output directory created for a command: removed again when the value drops if
/// this created it and it is still empty (a failed `render` or `eval` left an empty
/// `--out` behind).
pub struct OutDir {
    created: Option<PathBuf>,
}

impl OutDir {
    /// Creates `dir` (given as `flag`) when missing, as [`ensure_dir`].
    pub fn create(dir: &Path, flag: &str) -> anyhow::Result<OutDir> {
        let created = (!dir.exists()).then(|| dir.to_path_buf());
        ensure_dir(dir, flag)?;
        Ok(OutDir { created })
    }
}

impl Drop for OutDir {
    fn drop(&mut self) {
        if let Some(dir) = &self.created {
            // Fails, as meant, on a directory holding anything.
            let _ = std::fs::remove_dir(dir);
        }
    }
}

/// `path` absolute, `.` and `..` removed, and links resolved through its longest
/// existing ancestor (an output directory need not exist yet).
pub fn resolved(path: &Path) -> PathBuf {
    use std::path::Component;
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut lexical = PathBuf::new();
    for c in abs.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                lexical.pop();
            }
            c => lexical.push(c),
        }
    }
    let mut head = lexical.clone();
    let mut tail = Vec::new();
    loop {
        if let Ok(real) = head.canonicalize() {
            return tail.into_iter().rev().fold(real, |p, c: std::ffi::OsString| p.join(c));
        }
        match (head.file_name().map(|n| n.to_os_string()), head.parent()) {
            (Some(name), Some(parent)) => {
                tail.push(name);
                head = parent.to_path_buf();
            }
            _ => return lexical,
        }
    }
}

/// Refuses an output `out` (given as `flag`) that is one of the directories holding
/// the command's inputs, or inside one: `inputs` pairs each with what it is ("the
/// scene directory"). No command writes where its inputs are, `--overwrite` or not
/// (renders into `SCENE/train` replaced the ground-truth images and EXRs).
pub fn refuse_inside_inputs(out: &Path, flag: &str, inputs: &[(&Path, &str)]) -> anyhow::Result<()> {
    let o = resolved(out);
    for (dir, what) in inputs {
        let d = resolved(dir);
        if o.starts_with(&d) {
            let place = if o == d { "is" } else { "lies inside" };
            anyhow::bail!(
                "{flag} {} {place} {what} {}, which holds this command's inputs; nothing was written. No command writes \
                 into its inputs (--overwrite or not): pass an {flag} outside it",
                out.display(),
                dir.display()
            );
        }
    }
    Ok(())
}

/// The lock file of a run directory, held by the `train` writing into it.
pub const RUN_LOCK: &str = "train.lock";

/// An exclusive lock on a run directory, held while the value lives: one writer per
/// run directory. An advisory `flock` on `<dir>/train.lock`, which the kernel releases
/// when the process ends however it ends, so a crashed or killed run never leaves the
/// directory locked (the file itself stays; it is not a sign of a run). Holds the
/// writer's process id, for the message of the one refused.
pub struct RunLock {
    _file: std::fs::File,
}

/// Takes the lock of the run directory `dir` (which must exist), or refuses with what
/// holds it (two `train` runs into one directory interleaved their log rows and left
/// one run's config beside the other's checkpoint).
pub fn lock_run_dir(dir: &Path) -> anyhow::Result<RunLock> {
    use std::io::{Read, Seek, Write};
    let path = dir.join(RUN_LOCK);
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .with_context(|| format!("creating the run's lock file {}", path.display()))?;
    if !try_lock(&file).with_context(|| format!("locking {}", path.display()))? {
        let mut holder = String::new();
        let _ = file.read_to_string(&mut holder);
        let holder = match holder.trim() {
            "" => "another process".to_string(),
            pid => format!("another edgenerf process (pid {pid})"),
        };
        anyhow::bail!(
            "{} is in use: {holder} is training into it (it holds {}); nothing was changed. Wait for that run to \
             end, stop it (Ctrl-C or kill: it saves a checkpoint), or choose another --out",
            dir.display(),
            path.display()
        );
    }
    // Ours now: record who holds it (best effort; the lock, not the text, is what counts).
    let _ = file.set_len(0);
    let _ = file.rewind();
    let _ = write!(file, "{}", std::process::id());
    let _ = file.flush();
    Ok(RunLock { _file: file })
}

/// A non-blocking exclusive `flock`: `Ok(false)` when another process holds it.
#[cfg(unix)]
fn try_lock(file: &std::fs::File) -> std::io::Result<bool> {
    use std::os::fd::AsRawFd;
    loop {
        // SAFETY: flock on a file descriptor this function borrows open; no memory is passed.
        let r = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
        if r == 0 {
            return Ok(true);
        }
        let e = std::io::Error::last_os_error();
        match e.raw_os_error() {
            Some(libc::EWOULDBLOCK) => return Ok(false),
            Some(libc::EINTR) => continue,
            _ => return Err(e),
        }
    }
}

/// Without `flock` (not Unix) no lock is taken: std's `File::try_lock` is newer than
/// the workspace's rust-version.
#[cfg(not(unix))]
fn try_lock(_file: &std::fs::File) -> std::io::Result<bool> {
    Ok(true)
}
