//! Hot reload groundwork: watch a glTF scene's files, load each complete save on a worker
//! thread, and tell what changed.
//!
//! [`SceneWatcher`] reports [`WatchEvent`]s on a channel: `Started` when a change to the
//! scene's files is seen, then `Loaded` with the new [`Scene`](crate::scene::Scene) or
//! `Failed` with the file and the error. Nothing is half-applied: a scene is only ever
//! reported whole, from a set of files that fit together and did not change while loading.
//! [`SceneDiff`] compares the last good scene with the new one by content.
//!
//! # What is watched
//!
//! The scene file's **directory**, not the file: editors save by writing a temporary file and
//! renaming it over the original, which replaces the inode a watch on the file would hold. The
//! directory is watched non-recursively; each other directory holding a referenced file
//! (`textures/`, `../shared/`) is watched too, non-recursively. Events are filtered to the
//! scene file and the files its document refers to (external buffers and images by URI).
//! That list is re-read from every version of the document the watcher parses, so a save
//! that renames the `.bin` is followed. Open and read events are ignored (the watcher's own
//! loads make them).
//!
//! # Debounce, quiet, settle
//!
//! - **Debounce** ([`WatchConfig::debounce`], 150 ms): `notify-debouncer-full` holds each
//!   file event for this long and merges a burst (the many writes of one save, the create,
//!   write and rename of a temp-file save) into one. 150 ms is far below what a person notices
//!   after pressing save and above the gaps inside one save.
//! - **Quiet**: before loading, every one of the scene's files must have a modification time at
//!   least `debounce` in the past; otherwise the load waits until it has. The debouncer lets a
//!   long continuous write through while it is still going (it times events one by one), so
//!   this is what keeps a large file from being read half-written.
//! - **Settle** ([`WatchConfig::settle`], 2 s, counted from the first event of the change):
//!   how long a set of files that does not fit together may take to become one. Every
//!   external buffer must exist and be exactly as long as its `byteLength` (a `.bin` shorter
//!   *or longer* than declared is a save caught mid-write or a `.bin` from another save than
//!   the `.gltf`; the loader alone would accept a longer one and read the wrong bytes), and
//!   every referenced image must exist. A mismatch that could still resolve is waited for;
//!   one that outlasts the settle time is reported as `Failed` ([`FailureKind::Incomplete`]).
//!   And when a change touches a buffer but not the scene file, the load waits up to the
//!   settle time for the scene file: Blender's exporter writes the `.bin` first, then the
//!   images, then the `.gltf`, so a `.bin` alone is most likely the first half of a save
//!   (a `.bin` that is the whole save still loads, `settle` later). 2 s covers an export
//!   that writes images between the two files and costs only that rare lone-`.bin` save.
//! - **Stability**: the stamps (length, modification time, inode) of every file are taken
//!   before and after loading; if any changed, the result (success or error) is dropped and the
//!   load is repeated once the files are quiet again.
//! - **Errors**: a document that does not parse or a load that fails on files that were stable
//!   throughout is reported at once ([`FailureKind::Load`]); the last good scene is the
//!   caller's to keep, and the next save is tried as usual.
//!
//! A change episode is one `Started`, then exactly one `Loaded` or `Failed`; changes arriving
//! while an episode is open join it, those arriving during a load open the next one.
//!
//! # Threads and memory
//!
//! notify's backend thread and the debouncer's thread (which wakes every `debounce / 4`)
//! feed a worker thread through a merged set of changed paths (one entry per file, however
//! many events), and the worker sleeps on channels and timers, never polling. Reports go out
//! on a bounded channel: a reader that falls behind holds the worker back rather than letting
//! scenes pile up. Dropping the watcher stops and joins its threads (after a load under way).
//!
//! # Limits
//!
//! A writer that saves the `.gltf` first and then a `.bin` of the *same length* (a geometry
//! edit that keeps every accessor's size) can be caught between the two after the quiet time:
//! that pair loads with the old numbers and the `.bin`'s own events load the right one right
//! after. Lengths are the only cross-file check the format affords without decoding.

mod diff;
mod files;
mod watcher;

pub use diff::{Aabb, ChangedMesh, MeshAt, SceneDiff};
pub use watcher::{FailureKind, SceneWatcher, WatchConfig, WatchError, WatchEvent};
