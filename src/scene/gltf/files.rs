//! Which files a scene may read and how they are read: the one place that decides whether a
//! file URI stays in the scene's folder ([`FileScope`]), used by the loader and by the list of
//! files a hot-reload watcher follows ([`super::external_files`]), and the one way files are
//! read ([`read_regular`]): regular files only, their length known before a byte is read.
//!
//! Scenes come from strangers. A URI may name `../elsewhere/x.png`, an absolute path, a
//! symbolic link out of the folder, `/dev/zero` (endless) or a FIFO (whose open blocks until a
//! writer comes). So a file is opened without blocking, its *opened* file's metadata must say
//! "regular file" (a path's metadata could change between the look and the open), and under
//! confinement the path the opened file really has (Linux: `/proc/self/fd`; elsewhere the
//! canonical path) must lie inside the scene's folder, canonicalised. `..` and absolute paths
//! are refused from the URI's text before anything is opened.

use std::fs::File;
use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// Why a file could not be read.
#[derive(Debug)]
pub(crate) enum FileError {
    /// The URI leaves the scene's folder (see [`Refusal`]).
    Refused(Refusal),
    /// Not a regular file: a device, FIFO, socket or directory.
    NotRegular {
        kind: &'static str,
    },
    /// Longer than the caller accepts.
    TooLong {
        len: u64,
        most: u64,
    },
    /// Shorter than the caller needs.
    TooShort {
        len: u64,
        least: u64,
    },
    Io(std::io::Error),
}

/// How a file URI leaves the scene's folder.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Refusal {
    Absolute,
    ParentEscape,
    LinksOut { target: PathBuf },
}

const OPT_IN: &str = "a scene reads only files in its own folder (--allow-outside-files lets it read others)";

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::Absolute => write!(f, "is an absolute path: {OPT_IN}"),
            Refusal::ParentEscape => write!(f, "leads out of the scene's folder through '..': {OPT_IN}"),
            Refusal::LinksOut { target } => {
                write!(f, "is a symbolic link to {}, outside the scene's folder: {OPT_IN}", target.display())
            }
        }
    }
}

impl std::fmt::Display for FileError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FileError::Refused(r) => r.fmt(f),
            FileError::NotRegular { kind } => {
                write!(f, "is not a regular file but {kind}: only regular files are read")
            }
            FileError::TooLong { len, most } => {
                write!(f, "is {len} bytes long, more than the {most} bytes it may have")
            }
            FileError::TooShort { len, least } => {
                write!(f, "is {len} bytes long, fewer than the {least} bytes it needs")
            }
            FileError::Io(e) => write!(f, "cannot be read: {e}"),
        }
    }
}

/// Where a scene's files may be: inside its folder (canonical), or anywhere when the user
/// opted in.
#[derive(Clone, Debug)]
pub(crate) struct FileScope {
    folder: Option<PathBuf>,
}

impl FileScope {
    /// The scope of a scene whose file is in `base_dir`; `allow_outside`: the user's opt-in.
    pub fn new(base_dir: &Path, allow_outside: bool) -> FileScope {
        if allow_outside {
            return FileScope { folder: None };
        }
        let dir = if base_dir.as_os_str().is_empty() { Path::new(".") } else { base_dir };
        // A folder that cannot be canonicalised holds no file either: every open fails.
        let folder = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
        FileScope { folder: Some(folder) }
    }

    /// Whether the relative path a URI names (percent-decoded, as written) stays in the
    /// folder by its text: not absolute, and no `..` climbing above it.
    pub fn admits_text(&self, decoded: &Path) -> Result<(), Refusal> {
        if self.folder.is_none() {
            return Ok(());
        }
        if decoded.has_root() || decoded.components().any(|c| matches!(c, Component::Prefix(_))) {
            return Err(Refusal::Absolute);
        }
        let mut depth = 0i64;
        for c in decoded.components() {
            match c {
                Component::ParentDir => depth -= 1,
                Component::Normal(_) => depth += 1,
                _ => {}
            }
            if depth < 0 {
                return Err(Refusal::ParentEscape);
            }
        }
        Ok(())
    }

    /// Whether a file whose real path (symbolic links resolved) is `real` is in the folder.
    pub fn admits_real(&self, real: &Path) -> Result<(), Refusal> {
        match &self.folder {
            Some(folder) if !real.starts_with(folder) => Err(Refusal::LinksOut { target: real.to_path_buf() }),
            _ => Ok(()),
        }
    }

    /// Where `path` (resolved from a URI) really leads, checked against the folder without
    /// opening it: for a list of the scene's files. A file that does not exist yet is
    /// admitted (reading it later checks again).
    pub fn admits_path(&self, path: &Path) -> Result<(), Refusal> {
        match (&self.folder, path.canonicalize()) {
            (Some(_), Ok(real)) => self.admits_real(&real),
            _ => Ok(()),
        }
    }
}

/// Reads the regular file at `path`: at least `least` and at most `most` bytes long (else an
/// error before anything is read); returns its first `take` bytes (or all of it when `None`).
/// Under `scope`, the opened file must really be inside the scene's folder.
pub(crate) fn read_regular(
    path: &Path,
    scope: Option<&FileScope>,
    least: u64,
    most: u64,
    take: Option<u64>,
) -> Result<Vec<u8>, FileError> {
    let file = open_nonblocking(path).map_err(FileError::Io)?;
    let meta = file.metadata().map_err(FileError::Io)?;
    if !meta.is_file() {
        return Err(FileError::NotRegular { kind: file_kind(&meta) });
    }
    if let Some(scope) = scope {
        scope.admits_real(&real_path(&file, path)).map_err(FileError::Refused)?;
    }
    let len = meta.len();
    if len > most {
        return Err(FileError::TooLong { len, most });
    }
    if len < least {
        return Err(FileError::TooShort { len, least });
    }
    let want = take.map_or(len, |t| t.min(len));
    // `want` is at most the file's real length, so the allocation is honest.
    let mut bytes = Vec::with_capacity(usize::try_from(want).unwrap_or(0));
    file.take(want).read_to_end(&mut bytes).map_err(FileError::Io)?;
    if (bytes.len() as u64) < want.max(least) {
        // It shrank while being read.
        return Err(FileError::TooShort { len: bytes.len() as u64, least: want.max(least) });
    }
    Ok(bytes)
}

/// Opens for reading without waiting: a FIFO with no writer would block `open` forever; on a
/// regular file the flag changes nothing.
fn open_nonblocking(path: &Path) -> std::io::Result<File> {
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    options.open(path)
}

/// The path of what `file` (opened from `path`) is, symbolic links resolved: on Linux the
/// kernel's own record of the open file (no window between the check and the read),
/// elsewhere the canonical `path`.
fn real_path(file: &File, path: &Path) -> PathBuf {
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        if let Ok(p) = std::fs::read_link(format!("/proc/self/fd/{}", file.as_raw_fd())) {
            return p;
        }
    }
    let _ = file;
    path.canonicalize().unwrap_or_else(|_| path.to_path_buf())
}

fn file_kind(meta: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if meta.is_dir() { "a directory" } else { "not a regular file" }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_checks_refuse_absolute_paths_and_climbing_out() {
        let scope = FileScope::new(Path::new("/scenes/room"), false);
        assert_eq!(scope.admits_text(Path::new("/etc/passwd")), Err(Refusal::Absolute));
        assert_eq!(scope.admits_text(Path::new("../x.png")), Err(Refusal::ParentEscape));
        assert_eq!(scope.admits_text(Path::new("tex/../../x.png")), Err(Refusal::ParentEscape));
        assert_eq!(scope.admits_text(Path::new("tex/../x.png")), Ok(()));
        assert_eq!(scope.admits_text(Path::new("./tex/a.png")), Ok(()));
        let anywhere = FileScope::new(Path::new("/scenes/room"), true);
        assert_eq!(anywhere.admits_text(Path::new("/etc/passwd")), Ok(()));
        assert_eq!(anywhere.admits_text(Path::new("../x.png")), Ok(()));
    }
}
