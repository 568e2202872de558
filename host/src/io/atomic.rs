//! Atomic file writes, the one place every command's outputs go through: write a temporary
//! file in the target's directory, then rename it over the target, so readers see either the
//! old file or the complete new one, never a partial one.
//!
//! The target is what a plain write would write: an output path that is a symbolic link is
//! followed (the temporary goes beside the link's target, which the rename replaces; the link
//! stays), and a target that exists and is not a regular file (a directory, a device node such
//! as `/dev/null`, a fifo, a socket) is refused before anything is written, never replaced.
//!
//! Every temporary file or staging folder is listed while it exists, and
//! [`remove_temporaries_on_signals`] (called first in `main`) removes them when SIGINT, SIGTERM
//! or SIGHUP ends the process; an error or a panic removes them as its values drop.

use super::{FileError, Result};
use anyhow::Context;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, PoisonError};

/// The temporary files and staging folders of this process that exist now.
static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Lists `path` as a temporary (before it is created, so that none exists unlisted).
fn track(path: &Path) {
    LIVE.lock()
        .unwrap_or_else(PoisonError::into_inner)
        .push(path.to_path_buf());
}

/// Takes `path` off the list (renamed over its target, or removed).
fn untrack(path: &Path) {
    let mut live = LIVE.lock().unwrap_or_else(PoisonError::into_inner);
    if let Some(i) = live.iter().rposition(|p| p == path) {
        live.swap_remove(i);
    }
}

/// Removes `path` (a file, or a folder with everything in it) and takes it off the list.
fn remove_temporary(path: &Path) {
    let _ = std::fs::remove_file(path).or_else(|_| std::fs::remove_dir_all(path));
    untrack(path);
}

/// Removes every temporary that exists now; the list stays locked, so that no new one starts.
#[cfg(unix)]
fn remove_all_temporaries() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    let mut live = LIVE.lock().unwrap_or_else(PoisonError::into_inner);
    for path in live.drain(..) {
        let _ = std::fs::remove_file(&path).or_else(|_| std::fs::remove_dir_all(&path));
    }
    live
}

/// Makes SIGINT, SIGTERM and SIGHUP remove this process's temporary files before it ends (by
/// the same signal, so that a shell sees an interrupted command): the signals are blocked in
/// every thread (call this first in `main`, before any other thread starts: threads inherit the
/// mask; child processes get an empty mask from `std::process::Command`) and one thread waits
/// for them.
#[cfg(unix)]
pub fn remove_temporaries_on_signals() {
    // SAFETY: sigset_t is plain data that sigemptyset initialises; the set and the mask are
    // only read by the calls below, which take valid pointers to them.
    let set = unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
            libc::sigaddset(&mut set, signal);
        }
        libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut());
        set
    };
    let waiter = std::thread::Builder::new().name("signals".into());
    let _ = waiter.spawn(move || loop {
        let mut signal = 0;
        // SAFETY: `set` is an initialised signal set and `signal` a valid place for the result.
        if unsafe { libc::sigwait(&set, &mut signal) } != 0 {
            continue;
        }
        let _locked = remove_all_temporaries();
        // SAFETY: SIG_DFL installs no handler code; unblocking the signal in this thread and
        // raising it ends the process by it, as it would have without this thread.
        unsafe {
            libc::signal(signal, libc::SIG_DFL);
            libc::pthread_sigmask(libc::SIG_UNBLOCK, &set, std::ptr::null_mut());
            libc::raise(signal);
        }
        std::process::exit(128 + signal);
    });
}

/// What an output path writes to: the path itself, or, for a symbolic link, the file it points
/// to (links followed to the end, a dangling link's missing target included). An existing
/// target that is not a regular file is refused.
pub fn output_target(path: &Path) -> Result<PathBuf> {
    let mut target = path.to_path_buf();
    for _ in 0..40 {
        match std::fs::symlink_metadata(&target) {
            Ok(m) if m.file_type().is_symlink() => {
                let link = std::fs::read_link(&target)
                    .map_err(|e| FileError::whole(path, format!("cannot read the link: {e}")))?;
                target = match target.parent() {
                    Some(dir) => dir.join(link),
                    None => link,
                };
            }
            Ok(m) if m.is_file() => return Ok(target),
            Ok(m) => {
                let kind = file_kind(&m.file_type());
                let through = if target == path {
                    String::new()
                } else {
                    format!(" (the link's target {})", target.display())
                };
                return Err(FileError::whole(
                    path,
                    format!("cannot write: it is {kind}{through}, not a regular file"),
                ));
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(target),
            Err(e) => return Err(FileError::whole(path, format!("cannot write: {e}"))),
        }
    }
    Err(FileError::whole(
        path,
        "cannot write: too many levels of symbolic links",
    ))
}

/// A file type in words.
fn file_kind(t: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_fifo() {
            return "a fifo";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() {
        "a directory"
    } else {
        "not a regular file"
    }
}

/// A new temporary file beside `target` (named after it, with `tag` and the process id),
/// listed while it exists.
fn create_temporary(target: &Path, tag: &str) -> Result<(PathBuf, std::fs::File)> {
    let dir = match target.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = target
        .file_name()
        .ok_or_else(|| FileError::whole(target, "not a file name"))?;
    let tmp = dir.join(format!(
        ".{}.{tag}tmp{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    track(&tmp);
    match std::fs::File::create(&tmp) {
        Ok(file) => Ok((tmp, file)),
        Err(e) => {
            untrack(&tmp);
            Err(FileError::whole(target, format!("cannot write: {e}")))
        }
    }
}

/// Renames a complete temporary over its target and takes it off the list.
fn rename_over(tmp: &Path, target: &Path) -> std::io::Result<()> {
    std::fs::rename(tmp, target)?;
    untrack(tmp);
    Ok(())
}

/// Writes `bytes` to `path` atomically (temporary file in the same directory + rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_all_atomic(&[(path, bytes)])
}

/// Writes several files all or nothing: every temporary file is written first, and only when all
/// of them are complete are they renamed over their targets. A failure (a missing directory, a
/// full disk) leaves none of the targets created or changed.
pub fn write_all_atomic(files: &[(&Path, &[u8])]) -> Result<()> {
    let mut staged = Staged::default();
    for (path, bytes) in files {
        staged.add(path, bytes)?;
    }
    staged.commit()
}

/// Files written one by one as complete temporaries beside their targets, renamed over the
/// targets together by [`Staged::commit`]; dropped uncommitted (a failure on the way), the
/// temporaries are removed and no target is created or changed.
#[derive(Debug, Default)]
pub struct Staged {
    /// (temporary, the output path, the file it writes: see [`output_target`]).
    files: Vec<(PathBuf, PathBuf, PathBuf)>,
}

impl Staged {
    /// Writes `bytes` to a temporary file for `path`.
    pub fn add(&mut self, path: &Path, bytes: &[u8]) -> Result<()> {
        let target = output_target(path)?;
        let tmp = write_temporary(path, &target, bytes)?;
        self.files.push((tmp, path.to_path_buf(), target));
        Ok(())
    }

    /// Renames every temporary over its target.
    pub fn commit(mut self) -> Result<()> {
        for index in 0..self.files.len() {
            let (tmp, path, target) = &self.files[index];
            if let Err(e) = rename_over(tmp, target) {
                let e = FileError::whole(path, format!("cannot write: {e}"));
                // The ones before are in place; this one's and the later temporaries go.
                self.files.drain(..index);
                return Err(e);
            }
        }
        self.files.clear();
        Ok(())
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        for (tmp, _, _) in &self.files {
            remove_temporary(tmp);
        }
    }
}

/// A directory of files written all or nothing: `fill` writes into a fresh staging directory
/// inside `out` (`out` created if missing), and only when it succeeds is every file it wrote
/// moved to the same place under `out` (replacing files of the same name). When `fill` fails,
/// the staging directory goes, and `out` too if it was created here, so `out` is as it was.
pub fn write_dir_all_or_nothing<T>(
    out: &Path,
    fill: impl FnOnce(&Path) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    let created = !out.exists();
    std::fs::create_dir_all(out)
        .map_err(|e| FileError::whole(out, format!("cannot create the directory: {e}")))?;
    let staging = out.join(format!(".staging{}", std::process::id()));
    track(&staging);
    let result = std::fs::create_dir(&staging)
        .map_err(|e| FileError::whole(&staging, format!("cannot create: {e}")).into())
        .and_then(|()| fill(&staging))
        .and_then(|value| move_tree(&staging, out).map(|()| value));
    remove_temporary(&staging);
    if result.is_err() && created {
        let _ = std::fs::remove_dir_all(out);
    }
    result
}

/// Moves every file below `from` to the same relative place below `to` (renames within one
/// directory tree: only a filesystem failure part-way could leave some moved).
fn move_tree(from: &Path, to: &Path) -> anyhow::Result<()> {
    let unreadable = |e: std::io::Error| FileError::whole(from, format!("cannot read: {e}"));
    for entry in std::fs::read_dir(from).map_err(unreadable)? {
        let entry = entry.map_err(unreadable)?;
        let target = to.join(entry.file_name());
        if entry.file_type().map_err(unreadable)?.is_dir() {
            std::fs::create_dir_all(&target)
                .map_err(|e| FileError::whole(&target, format!("cannot create: {e}")))?;
            move_tree(&entry.path(), &target)?;
        } else {
            std::fs::rename(entry.path(), output_target(&target)?)
                .map_err(|e| FileError::whole(&target, format!("cannot write: {e}")))?;
        }
    }
    Ok(())
}

/// `bytes` in a complete, synced temporary file beside `target` (what `path` writes to); its
/// name.
fn write_temporary(path: &Path, target: &Path, bytes: &[u8]) -> Result<PathBuf> {
    let (tmp, mut file) = create_temporary(target, "")?;
    let result = file.write_all(bytes).and_then(|()| file.sync_all());
    result.map(|()| tmp.clone()).map_err(|e| {
        remove_temporary(&tmp);
        FileError::whole(path, format!("cannot write: {e}"))
    })
}

/// Serialises `value` as pretty JSON (with a final newline) and writes it atomically.
pub fn write_json_atomic<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    let mut text = serde_json::to_string_pretty(value)
        .map_err(|e| FileError::whole(path, format!("cannot serialise: {e}")))?;
    text.push('\n');
    write_atomic(path, text.as_bytes())
}

/// A temporary file next to its target, removed on drop unless renamed over the target.
pub struct Pending {
    /// The temporary file.
    pub tmp: PathBuf,
    /// The output path.
    pub target: PathBuf,
    /// The file it writes (see [`output_target`]).
    resolved: PathBuf,
    done: bool,
}

impl Pending {
    /// A temporary file for `target` (named with `tag`), and a buffered writer to it. A target
    /// that cannot be written (see [`output_target`]) is refused now, not at the rename, when
    /// another output may already be in place.
    pub fn new(target: &Path, tag: &str) -> anyhow::Result<(Self, BufWriter<std::fs::File>)> {
        let resolved = output_target(target)?;
        let (tmp, file) = create_temporary(&resolved, &format!("{tag}."))?;
        let pending = Self {
            tmp,
            target: target.to_path_buf(),
            resolved,
            done: false,
        };
        Ok((pending, BufWriter::with_capacity(1 << 20, file)))
    }

    /// Flushes and syncs the writer, then renames the temporary over the target.
    pub fn commit(mut self, writer: BufWriter<std::fs::File>) -> anyhow::Result<()> {
        let file = writer
            .into_inner()
            .map_err(|e| e.into_error())
            .and_then(|f| f.sync_all().map(|_| f))
            .with_context(|| format!("{}: cannot write", self.target.display()))?;
        drop(file);
        rename_over(&self.tmp, &self.resolved)
            .with_context(|| format!("{}: cannot write", self.target.display()))?;
        self.done = true;
        Ok(())
    }
}

impl Drop for Pending {
    fn drop(&mut self) {
        if !self.done {
            remove_temporary(&self.tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_whole_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_atomic(&path, b"first version, longer").unwrap();
        write_atomic(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn missing_directory_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("no/such/dir/a.txt");
        let e = write_atomic(&path, b"x").unwrap_err();
        assert!(e.to_string().contains("a.txt"), "{e}");
        assert!(!path.exists());
    }

    #[test]
    fn a_directory_all_or_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let failed = write_dir_all_or_nothing::<()>(&out, |d| {
            std::fs::create_dir(d.join("images"))?;
            std::fs::write(d.join("images/a.png"), b"a")?;
            anyhow::bail!("rendering failed")
        });
        assert!(failed.is_err());
        assert!(!out.exists());
        std::fs::create_dir(&out).unwrap();
        std::fs::write(out.join("kept.csv"), b"old").unwrap();
        let n = write_dir_all_or_nothing(&out, |d| {
            std::fs::create_dir(d.join("images"))?;
            std::fs::write(d.join("images/a.png"), b"a")?;
            std::fs::write(d.join("kept.csv"), b"new")?;
            Ok(2)
        })
        .unwrap();
        assert_eq!(n, 2);
        assert_eq!(std::fs::read(out.join("images/a.png")).unwrap(), b"a");
        assert_eq!(std::fs::read(out.join("kept.csv")).unwrap(), b"new");
        assert_eq!(std::fs::read_dir(&out).unwrap().count(), 2);
    }

    #[test]
    fn several_files_all_or_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let kept = dir.path().join("kept.ply");
        write_atomic(&kept, b"old").unwrap();
        let missing = dir.path().join("nodir/c.csv");
        let e = write_all_atomic(&[(&kept, b"new"), (&missing, b"x")]).unwrap_err();
        assert!(e.to_string().contains("nodir/c.csv"), "{e}");
        assert_eq!(std::fs::read(&kept).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let other = dir.path().join("c.csv");
        write_all_atomic(&[(&kept, b"new"), (&other, b"y")]).unwrap();
        assert_eq!(std::fs::read(&kept).unwrap(), b"new");
        assert_eq!(std::fs::read(&other).unwrap(), b"y");
    }
}
