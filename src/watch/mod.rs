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
//! # Debounce, quiet, order, settle
//!
//! Every look at the files reads the scene file once, parses it for the files it refers to,
//! and judges one snapshot of every file's stamp (length, modification time, inode):
//!
//! - **Debounce** ([`WatchConfig::debounce`], 100 ms): `notify-debouncer-full` holds each
//!   file event this long and merges a burst (the writes of one save; the create, write and
//!   rename of a temp-file save, which it stitches into one rename) into one batch. 100 ms is
//!   well below what a person notices after pressing save and above the gaps inside one save.
//! - **Quiet** (twice the debounce): every file must have gone unmodified that long, else the
//!   look waits until it has. The debouncer times events one by one, so it lets a long
//!   continuous write through while it is still going; and by twice its timeout it has handed
//!   over the events of any older write (it emits at the next tick, a quarter-timeout later).
//! - **Order** ([`WatchConfig::settle`], 2 s): no external buffer may be newer than the scene
//!   file. Blender's exporter writes the `.bin` first, then the images, then the `.gltf`, so
//!   a complete save has the `.gltf` last and a newer `.bin` is a save whose `.gltf` is yet to
//!   come (the old `.gltf` with the new `.bin` would load garbage whenever the lengths happen
//!   to agree). It is waited for until the `.bin` is `settle` old; then the `.bin` is taken
//!   as an edit on its own and loads. Images are not ordered (texture painters save them
//!   alone). Judged by modification times, not by event arrival, so a slow writer or a
//!   stalled thread cannot reorder it.
//! - **Lengths** (settle again, from the first event of the change): every external buffer
//!   must exist and be exactly as long as its `byteLength` (shorter *or longer* is a save
//!   caught mid-write or a `.bin` from another save; the loader alone would accept a longer
//!   one and read the wrong bytes), and every referenced image must exist. A mismatch is
//!   waited for (the next event, or the end of the settle time); one that outlasts the settle
//!   time is reported as `Failed` ([`FailureKind::Incomplete`]). 2 s covers an export that
//!   writes images between its two files, and is the longest a lone `.bin` edit waits.
//! - **Stability**: the load reads the bytes judged; the stamps are taken again after it and
//!   must be unchanged, else the result (success or error) is dropped and the look repeated.
//! - **Errors**: a document that does not parse, or a load that fails on files that stayed
//!   put, is reported at once ([`FailureKind::Load`]), as is a document still being written
//!   only when its stamp did not move while it was parsed. The last good scene is the
//!   caller's to keep; the next save is tried as usual.
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
//! Only lengths and modification order tie a `.bin` to its `.gltf` (nothing else in the
//! format does without decoding). A writer that saves the `.gltf` first and then a `.bin` of
//! the same length can be caught between the two: that pair loads, and the `.bin`'s own
//! events load the right one right after (for such a writer each save also waits the settle
//! time, the `.bin` being newer). A file system with coarse modification times (1–2 s: FAT,
//! some network shares) makes the order rule see ties, which pass.

mod diff;
mod files;
mod watcher;

pub use diff::{Aabb, ChangedMesh, MeshAt, SceneDiff};
pub use watcher::{FailureKind, SceneWatcher, WatchConfig, WatchError, WatchEvent};
