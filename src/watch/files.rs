//! The files that make up a watched scene, how they are named so that event paths match,
//! and the checks that tell a consistent set of files from a save caught half-way.

use std::collections::BTreeSet;
use std::path::{Component, Path, PathBuf};
use std::time::{Duration, SystemTime};

use crate::scene::{ExternalFile, ExternalKind};

/// The scene file and the external files its last parsed document refers to, all
/// [normalised](normalise).
#[derive(Clone, Debug)]
pub(super) struct SceneFiles {
    pub scene: PathBuf,
    pub external: Vec<ExternalFile>,
}

impl SceneFiles {
    pub fn new(scene: PathBuf) -> SceneFiles {
        SceneFiles { scene, external: Vec::new() }
    }

    /// Replaces the external files with those of a freshly parsed document.
    pub fn set_external(&mut self, external: Vec<ExternalFile>) {
        self.external = external.into_iter().map(|f| ExternalFile { path: normalise(&f.path), ..f }).collect();
    }

    pub fn contains(&self, path: &Path) -> bool {
        path == self.scene || self.external.iter().any(|f| f.path == path)
    }

    /// The scene file, then every external file.
    pub fn paths(&self) -> impl Iterator<Item = &Path> {
        std::iter::once(self.scene.as_path()).chain(self.external.iter().map(|f| f.path.as_path()))
    }

    /// The directories to watch: those holding the scene file or any file it refers to.
    pub fn dirs(&self) -> BTreeSet<PathBuf> {
        self.paths().filter_map(|p| p.parent()).map(Path::to_path_buf).collect()
    }
}

/// `path` made absolute with its directory canonicalised (symbolic links and `..` resolved
/// when the directory exists, lexically otherwise) and its file name kept as it is. Event
/// paths are the watched (canonical) directory joined with a file name, so a file named
/// this way compares equal to the paths of its events. The file itself is not resolved:
/// the name is what an editor saves to, whatever inode it points at.
pub(super) fn normalise(path: &Path) -> PathBuf {
    let absolute = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().map(|d| d.join(path)).unwrap_or_else(|_| path.to_path_buf())
    };
    let lexical = lexical_clean(&absolute);
    match (lexical.parent(), lexical.file_name()) {
        (Some(dir), Some(name)) => match dir.canonicalize() {
            Ok(dir) => dir.join(name),
            Err(_) => lexical,
        },
        _ => lexical,
    }
}

/// Drops `.` components and folds `..` into its parent, without touching the file system.
fn lexical_clean(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            // `..` of the root is the root.
            Component::ParentDir => {
                if !out.pop() && !out.has_root() {
                    out.push(c);
                }
            }
            _ => out.push(c),
        }
    }
    out
}

/// What a file looks like from outside: enough to tell that it was written or replaced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Stamp {
    pub len: u64,
    pub modified: Option<SystemTime>,
    /// The inode (Unix): a rename over the file changes it even when size and time agree.
    pub inode: u64,
}

/// The stamp of `path`, or `None` when it does not exist or cannot be inspected.
pub(super) fn stamp(path: &Path) -> Option<Stamp> {
    let meta = std::fs::metadata(path).ok()?;
    #[cfg(unix)]
    let inode = std::os::unix::fs::MetadataExt::ino(&meta);
    #[cfg(not(unix))]
    let inode = 0;
    Some(Stamp { len: meta.len(), modified: meta.modified().ok(), inode })
}

/// Stamps of every file of `files`, in [`SceneFiles::paths`] order: one snapshot that the
/// checks below all read, so they judge the same state of the files.
pub(super) fn stamps(files: &SceneFiles) -> Vec<Option<Stamp>> {
    files.paths().map(stamp).collect()
}

/// How long ago `stamp`'s file was modified, by the wall clock; `None` when unknown or in the
/// future (a skewed clock on a network file system), which the rules treat as long ago so a
/// bad clock never stalls a reload.
fn age(stamp: &Option<Stamp>, now: SystemTime) -> Option<Duration> {
    now.duration_since(stamp.as_ref()?.modified?).ok()
}

/// How long until every file of the snapshot has gone unmodified for `quiet`, or `None` when
/// all have.
pub(super) fn time_to_quiet(snapshot: &[Option<Stamp>], quiet: Duration) -> Option<Duration> {
    let now = SystemTime::now();
    snapshot.iter().filter_map(|s| age(s, now)).filter(|&a| a < quiet).map(|a| quiet - a).max()
}

/// When a buffer file is newer than the scene file: how long until the newest such buffer is
/// `settle` old. Blender writes the `.bin` first and the `.gltf` last, so a complete save has
/// the `.gltf` no older than its `.bin`s; a newer `.bin` is a save whose `.gltf` is still
/// to come (or, after `settle`, a `.bin` edited on its own).
pub(super) fn time_for_scene_to_follow(
    files: &SceneFiles,
    snapshot: &[Option<Stamp>],
    settle: Duration,
) -> Option<Duration> {
    let scene_modified = snapshot.first()?.as_ref()?.modified?;
    let now = SystemTime::now();
    files
        .external
        .iter()
        .zip(snapshot.get(1..).unwrap_or_default())
        .filter(|(f, _)| matches!(f.kind, ExternalKind::Buffer { .. }))
        .filter(|(_, s)| s.as_ref().and_then(|s| s.modified).is_some_and(|m| m > scene_modified))
        .filter_map(|(_, s)| age(s, now))
        .filter(|&a| a < settle)
        .map(|a| settle - a)
        .max()
}

/// Why the files on disk are not (yet) a set that can be loaded together.
#[derive(Clone, Debug)]
pub(super) struct Mismatch {
    /// The file at fault.
    pub path: PathBuf,
    pub message: String,
}

/// Checks that every external file exists and that every external buffer is exactly as long
/// as its `byteLength`. The loader itself only rejects a short buffer; a longer one would
/// load, but under a watcher it means the `.bin` and the `.gltf` come from different saves
/// (or the `.bin` is being written), so the pair is not loaded.
pub(super) fn check_external(files: &SceneFiles, snapshot: &[Option<Stamp>]) -> Result<(), Mismatch> {
    for (f, s) in files.external.iter().zip(snapshot.get(1..).unwrap_or_default()) {
        let Some(s) = s else {
            return Err(Mismatch {
                path: f.path.clone(),
                message: format!("'{}' (referred to as '{}') is missing", f.path.display(), f.uri),
            });
        };
        if let ExternalKind::Buffer { index, byte_length } = f.kind
            && s.len != byte_length
        {
            return Err(Mismatch {
                path: f.path.clone(),
                message: format!(
                    "buffer {index} ('{}') is {} bytes but {} declares byteLength {byte_length}: the .bin and the \
                     .gltf are from different saves, or one is still being written",
                    f.path.display(),
                    s.len,
                    files.scene.display(),
                ),
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lexical_clean_folds_dots() {
        assert_eq!(lexical_clean(Path::new("/a/b/../c/./d.bin")), PathBuf::from("/a/c/d.bin"));
        assert_eq!(lexical_clean(Path::new("/a/../../x")), PathBuf::from("/x"));
    }

    #[test]
    fn normalise_resolves_the_directory_not_the_name() {
        let dir = tempfile::tempdir().unwrap();
        let canonical = dir.path().canonicalize().unwrap();
        std::fs::create_dir(canonical.join("sub")).unwrap();
        let via_dots = dir.path().join("sub").join("..").join("scene.gltf");
        assert_eq!(normalise(&via_dots), canonical.join("scene.gltf"));
        // A directory that does not exist is cleaned lexically.
        assert_eq!(normalise(&canonical.join("nope/../x.bin")), canonical.join("x.bin"));
    }
}
