//! Atomic file replacement: write to a temporary file in the target's directory, then rename.
//!
//! Readers (ParaView polling a directory, `treacle snapshot`, a plotting script tailing
//! `metrics.csv`) therefore see either the old file or the complete new one, never a partial
//! file. The temporary file is named `.<file name>.<pid>-<n>.tmp` (hidden, same directory so the
//! rename never crosses a file system) and is removed on every error path, including a panic
//! inside the writer callback.
//!
//! Durability: the data is *not* `fsync`ed before the rename (that would cost tens of
//! milliseconds per large frame). The replacement is atomic with respect to other processes and
//! to a crash of this process; after an operating-system crash or power loss the newest file may
//! be empty or missing.
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::error::OutputError;

/// Buffer between the writer callback and the temporary file.
const BUFFER_BYTES: usize = 1 << 16;

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Atomically replace (or create) `path` with `bytes`. The parent directory must exist.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Atomically replace (or create) `path` with whatever `write` writes.
///
/// `write` gets a buffered writer to the temporary file; if it returns an error (or panics),
/// the temporary file is removed and `path` is left untouched. I/O errors are reported as
/// [`OutputError::Io`] naming `path`. The parent directory must exist.
pub fn write_atomic_with<F>(path: &Path, write: F) -> Result<(), OutputError>
where
    F: FnOnce(&mut dyn Write) -> io::Result<()>,
{
    let (file, temp) = create_temp(path)?;
    // From here on the guard removes the temporary file unless it is disarmed.
    let mut guard = TempGuard(Some(temp));
    let mut writer = BufWriter::with_capacity(BUFFER_BYTES, file);
    write(&mut writer).map_err(|e| OutputError::io("write", path, e))?;
    let file = writer
        .into_inner()
        .map_err(|e| OutputError::io("write", path, e.into_error()))?;
    drop(file);
    let temp = guard.0.as_deref().expect("guard is armed");
    fs::rename(temp, path)
        .map_err(|e| OutputError::io("rename temporary file into place at", path, e))?;
    guard.0 = None;
    Ok(())
}

/// Create a fresh temporary file next to `path`.
fn create_temp(path: &Path) -> Result<(File, PathBuf), OutputError> {
    let file_name = path.file_name().ok_or_else(|| {
        OutputError::io(
            "write",
            path,
            io::Error::new(io::ErrorKind::InvalidInput, "path has no file name"),
        )
    })?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let pid = std::process::id();
    let mut last_err = None;
    for _ in 0..16 {
        let n = TEMP_COUNTER.fetch_add(1, Ordering::Relaxed);
        let mut name = std::ffi::OsString::from(".");
        name.push(file_name);
        name.push(format!(".{pid}-{n}.tmp"));
        let temp = dir.join(name);
        match OpenOptions::new().write(true).create_new(true).open(&temp) {
            Ok(file) => return Ok((file, temp)),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => last_err = Some(e),
            Err(e) => return Err(OutputError::io("create temporary file for", path, e)),
        }
    }
    Err(OutputError::io(
        "create temporary file for",
        path,
        last_err.expect("loop ran"),
    ))
}

/// Whether `name` is the name of a temporary file [`write_atomic_with`] creates for a file
/// named `target_prefix…` (`.<file name>.<pid>-<n>.tmp`), e.g. one left behind by a process
/// killed during a write.
pub fn is_temp_name(name: &str, target_prefix: &str) -> bool {
    name.strip_prefix('.')
        .and_then(|rest| rest.strip_suffix(".tmp"))
        .is_some_and(|stem| {
            stem.starts_with(target_prefix)
                && stem.rsplit_once('.').is_some_and(|(_, id)| {
                    id.split_once('-').is_some_and(|(pid, n)| {
                        !pid.is_empty()
                            && !n.is_empty()
                            && pid.bytes().all(|b| b.is_ascii_digit())
                            && n.bytes().all(|b| b.is_ascii_digit())
                    })
                })
        })
}

/// Removes the temporary file on drop unless disarmed (`.0 = None`).
struct TempGuard(Option<PathBuf>);

impl Drop for TempGuard {
    fn drop(&mut self) {
        if let Some(temp) = self.0.take() {
            let _ = fs::remove_file(temp);
        }
    }
}

/// `create_dir_all` with an [`OutputError`] naming the directory.
pub(crate) fn ensure_dir(dir: &Path) -> Result<(), OutputError> {
    if dir.as_os_str().is_empty() {
        return Ok(());
    }
    fs::create_dir_all(dir).map_err(|e| OutputError::io("create directory", dir, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temporary_names_are_recognised() {
        let dir = scratch("names");
        let (_, temp) = create_temp(&dir.join("frame_00003.ply")).unwrap();
        let name = temp.file_name().unwrap().to_string_lossy().into_owned();
        assert!(is_temp_name(&name, "frame_"), "{name}");
        assert!(!is_temp_name(&name, "metrics.csv"), "{name}");
        assert!(is_temp_name(".metrics.csv.12-0.tmp", "metrics.csv"));
        for other in [
            "frame_00003.ply",
            ".frame_00003.tmp",
            ".frame_1.ply.x-1.tmp",
            ".frame_1.ply.1-.tmp",
        ] {
            assert!(!is_temp_name(other, "frame_"), "{other}");
        }
    }

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!(
            "treacle-output-atomic-{name}-{}",
            std::process::id()
        ));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn entries(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn replaces_and_cleans_up() {
        let dir = scratch("replace");
        let path = dir.join("a.txt");
        write_atomic(&path, b"one").unwrap();
        write_atomic(&path, b"two").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"two");
        assert_eq!(entries(&dir), ["a.txt"]);

        let err = write_atomic_with(&path, |w| {
            w.write_all(b"partial")?;
            Err(io::Error::other("boom"))
        })
        .unwrap_err();
        assert!(err.to_string().contains("a.txt"), "{err}");
        assert_eq!(fs::read(&path).unwrap(), b"two");
        assert_eq!(entries(&dir), ["a.txt"]);

        let r = std::panic::catch_unwind(|| {
            let _ = write_atomic_with(&path, |_| panic!("writer panicked"));
        });
        assert!(r.is_err());
        assert_eq!(entries(&dir), ["a.txt"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn missing_directory_is_an_io_error() {
        let dir = scratch("missing");
        let path = dir.join("nope").join("a.txt");
        let err = write_atomic(&path, b"x").unwrap_err();
        assert!(matches!(err, OutputError::Io { .. }));
        assert_eq!(err.path(), Some(path.as_path()));
        fs::remove_dir_all(&dir).unwrap();
    }
}
