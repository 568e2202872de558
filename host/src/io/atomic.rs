//! Atomic file writes: write a temporary file in the target's directory, then rename it over the
//! target, so readers see either the old file or the complete new one, never a partial one.

use super::{FileError, Result};
use anyhow::{bail, Context};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

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
    /// (temporary, target).
    files: Vec<(std::path::PathBuf, std::path::PathBuf)>,
}

impl Staged {
    /// Writes `bytes` to a temporary file for `path`.
    pub fn add(&mut self, path: &Path, bytes: &[u8]) -> Result<()> {
        let tmp = write_temporary(path, bytes)?;
        self.files.push((tmp, path.to_path_buf()));
        Ok(())
    }

    /// Renames every temporary over its target.
    pub fn commit(mut self) -> Result<()> {
        for index in 0..self.files.len() {
            let (tmp, path) = &self.files[index];
            if let Err(e) = std::fs::rename(tmp, path) {
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
        for (tmp, _) in &self.files {
            let _ = std::fs::remove_file(tmp);
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
    let result = std::fs::create_dir(&staging)
        .map_err(|e| FileError::whole(&staging, format!("cannot create: {e}")).into())
        .and_then(|()| fill(&staging))
        .and_then(|value| move_tree(&staging, out).map(|()| value));
    let _ = std::fs::remove_dir_all(&staging);
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
            std::fs::rename(entry.path(), &target)
                .map_err(|e| FileError::whole(&target, format!("cannot write: {e}")))?;
        }
    }
    Ok(())
}

/// `bytes` in a complete, synced temporary file beside `path`; its name.
fn write_temporary(path: &Path, bytes: &[u8]) -> Result<std::path::PathBuf> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .ok_or_else(|| FileError::whole(path, "not a file name"))?;
    if path.is_dir() {
        return Err(FileError::whole(path, "cannot write: it is a directory"));
    }
    let tmp = dir.join(format!(
        ".{}.tmp{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| -> std::io::Result<()> {
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()
    })();
    result.map(|()| tmp.clone()).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
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
    /// The file it becomes.
    pub target: PathBuf,
    done: bool,
}

impl Pending {
    /// A temporary file for `target` (named with `tag`), and a buffered writer to it.
    pub fn new(target: &Path, tag: &str) -> anyhow::Result<(Self, BufWriter<std::fs::File>)> {
        let dir = match target.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let name = target
            .file_name()
            .with_context(|| format!("{}: not a file name", target.display()))?;
        // Refused now, not at the rename, when another output may already be in place.
        if target.is_dir() {
            bail!("{}: cannot write: it is a directory", target.display());
        }
        let tmp = dir.join(format!(
            ".{}.{tag}.tmp{}",
            name.to_string_lossy(),
            std::process::id()
        ));
        let file = std::fs::File::create(&tmp)
            .with_context(|| format!("{}: cannot write", target.display()))?;
        let pending = Self {
            tmp,
            target: target.to_path_buf(),
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
        std::fs::rename(&self.tmp, &self.target)
            .with_context(|| format!("{}: cannot write", self.target.display()))?;
        self.done = true;
        Ok(())
    }
}

impl Drop for Pending {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_file(&self.tmp);
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
