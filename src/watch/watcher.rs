//! [`SceneWatcher`]: the scene's directories watched through `notify` and its debouncer, and
//! a worker thread that turns debounced changes into loaded scenes or failures. The rules
//! (what is watched, debounce, quiet, settle) are in the [module documentation](super).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, TrySendError, after, bounded, never, select};
use notify_debouncer_full::notify::event::{AccessKind, AccessMode};
use notify_debouncer_full::notify::{self, EventKind, RecursiveMode};
use notify_debouncer_full::{DebounceEventResult, Debouncer, RecommendedCache, new_debouncer};

use super::files::{self, Mismatch, SceneFiles};
use crate::scene::{LoadError, LoadOptions, Scene, Surroundings, external_files, load_gltf_bytes, read_scene_file};

/// How the watcher waits before and while loading. See the module documentation.
#[derive(Clone, Debug)]
pub struct WatchConfig {
    /// The debouncer's timeout: a burst of file events is handled once its events are this
    /// old, and a file is read only once it has been left alone for twice this long.
    pub debounce: Duration,
    /// How long a set of files that does not fit together may take to become one: a `.bin`
    /// newer than its `.gltf` waits this long (from its modification) for the `.gltf` to
    /// follow; a buffer whose length disagrees with its `byteLength`, or a missing file, is
    /// reported as a failure once this long has passed since the change was first seen.
    pub settle: Duration,
    pub load: LoadOptions,
    /// The sky, environment and sun set on every loaded scene (they come from configuration,
    /// not the file).
    pub surroundings: Surroundings,
}

impl Default for WatchConfig {
    fn default() -> Self {
        WatchConfig {
            debounce: Duration::from_millis(100),
            settle: Duration::from_secs(2),
            load: LoadOptions::default(),
            surroundings: Surroundings::default(),
        }
    }
}

/// What the watcher reports, in order: every change episode is one `Started` followed by one
/// `Loaded` or one `Failed`.
#[derive(Clone, Debug)]
pub enum WatchEvent {
    /// A change to the scene's files was seen (after the debounce).
    Started {
        /// The changed files among the scene's (normalised: canonical directory + file name).
        paths: Vec<PathBuf>,
        /// When the first event of the change reached the watcher.
        seen_at: Instant,
    },
    /// The files form a consistent set again and loaded: the new scene, with the configured
    /// surroundings.
    Loaded {
        scene: Arc<Scene>,
        seen_at: Instant,
        /// Every file of the scene that changed during this episode.
        paths: Vec<PathBuf>,
    },
    /// The change cannot be loaded: the last good scene stays; the next save tries again.
    Failed {
        /// The file at fault (the scene file, or the buffer or image that does not fit it).
        path: PathBuf,
        /// What is wrong, with the error's causes, for a person.
        error: String,
        kind: FailureKind,
        seen_at: Instant,
    },
}

/// Why a change could not be loaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FailureKind {
    /// The loader rejected the files (malformed JSON, invalid glTF, undecodable image...).
    Load,
    /// The files stayed inconsistent for the whole settle time: a buffer file whose length
    /// is not its `byteLength`, a referenced file or the scene file missing.
    Incomplete,
}

/// Why a watch could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum WatchError {
    #[error("{}: the scene's directory cannot be watched: it does not exist or cannot be read", path.display())]
    Directory {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: cannot watch the directory", path.display())]
    Notify {
        path: PathBuf,
        #[source]
        source: notify::Error,
    },
    #[error("cannot start the scene watcher's thread")]
    Thread(#[source] std::io::Error),
}

/// Watches one glTF scene and its external files; reports changes on [`SceneWatcher::events`].
///
/// The watch is in place when [`start`](SceneWatcher::start) returns: a caller that loads the
/// scene itself should start the watcher first, so that no save falls between the two.
/// Dropping the watcher (or [`stop`](SceneWatcher::stop)) stops and joins its threads; a load
/// under way is finished first.
pub struct SceneWatcher {
    events: Receiver<WatchEvent>,
    stop: Option<Sender<()>>,
    worker: Option<JoinHandle<()>>,
    scene: PathBuf,
}

/// How many reports may wait unread. A full queue holds the worker back (it stops loading)
/// instead of piling up scenes, so memory stays bounded however slow the reader is.
const EVENT_QUEUE: usize = 4;

impl SceneWatcher {
    /// Starts watching `scene` (a `.gltf` or `.glb`; it need not exist yet, its directory must).
    pub fn start(scene: impl AsRef<Path>, config: WatchConfig) -> Result<SceneWatcher, WatchError> {
        let requested = scene.as_ref();
        let mut files = SceneFiles::new(files::normalise(requested));
        let dir = files.scene.parent().map(Path::to_path_buf).unwrap_or_default();
        std::fs::read_dir(&dir).map_err(|source| WatchError::Directory { path: dir.clone(), source })?;
        // The current document names the files to watch; when it cannot be read now, the
        // first good save will.
        if let Ok(bytes) = read_scene_file(&files.scene)
            && let Ok(external) = external_files(&files.scene, &bytes, &config.load)
        {
            files.set_external(external);
        }

        let inbox = Arc::new(Inbox::default());
        let (wake_tx, wake_rx) = bounded(1);
        let handler_inbox = Arc::clone(&inbox);
        let debouncer = new_debouncer(config.debounce, None, move |result| handler_inbox.take_in(result, &wake_tx))
            .map_err(|source| WatchError::Notify { path: dir.clone(), source })?;
        let mut watch = Watch { debouncer, dirs: BTreeSet::new() };
        watch.add(&dir)?;
        watch.update(&files);

        let (events_tx, events) = bounded(EVENT_QUEUE);
        let (stop_tx, stop_rx) = bounded(0);
        let scene = files.scene.clone();
        let worker =
            Worker { config, files, watch, inbox, wake: wake_rx, stop: stop_rx, events: events_tx, episode: None };
        let worker = std::thread::Builder::new()
            .name("livebake-watch".into())
            .spawn(move || worker.run())
            .map_err(WatchError::Thread)?;
        Ok(SceneWatcher { events, stop: Some(stop_tx), worker: Some(worker), scene })
    }

    /// The reports, in order. Disconnected once the watcher stopped.
    pub fn events(&self) -> &Receiver<WatchEvent> {
        &self.events
    }

    /// The watched scene file (normalised: canonical directory + file name).
    pub fn scene_path(&self) -> &Path {
        &self.scene
    }

    /// Stops watching and joins the threads.
    pub fn stop(mut self) {
        self.shut_down();
    }

    fn shut_down(&mut self) {
        // Disconnecting the stop channel wakes the worker wherever it waits.
        self.stop.take();
        if let Some(worker) = self.worker.take()
            && worker.join().is_err()
        {
            tracing::error!("the scene watcher's thread panicked; hot reload had stopped");
        }
    }
}

impl Drop for SceneWatcher {
    fn drop(&mut self) {
        self.shut_down();
    }
}

/// Relevant paths seen by the debouncer since the worker last looked. It merges bursts into
/// one set, so it is as large as the number of distinct files touched, never a growing queue.
#[derive(Default)]
struct Inbox {
    batch: Mutex<Batch>,
}

#[derive(Default)]
struct Batch {
    /// Each path touched, with when its first event arrived.
    paths: BTreeMap<PathBuf, Instant>,
    /// The backend dropped events (then): any file may have changed.
    rescan: Option<Instant>,
}

impl Inbox {
    /// Runs on the debouncer's thread: merge, wake the worker, never block.
    fn take_in(&self, result: DebounceEventResult, wake: &Sender<()>) {
        let events = match result {
            Ok(events) => events,
            Err(errors) => {
                for e in errors {
                    tracing::warn!("file watcher: {e}");
                }
                return;
            }
        };
        let mut batch = self.batch.lock().unwrap_or_else(PoisonError::into_inner);
        let mut any = false;
        for e in events.iter().filter(|e| e.need_rescan() || is_change(e.kind)) {
            any = true;
            if e.need_rescan() {
                batch.rescan = Some(batch.rescan.map_or(e.time, |t| t.min(e.time)));
            }
            for p in &e.paths {
                let first = batch.paths.entry(p.clone()).or_insert(e.time);
                *first = (*first).min(e.time);
            }
        }
        drop(batch);
        // A full wake channel already holds a wake-up; the worker will see this batch too.
        if any && let Err(TrySendError::Disconnected(())) = wake.try_send(()) {
            tracing::trace!("scene watcher stopped; dropping file events");
        }
    }

    fn take(&self) -> Batch {
        std::mem::take(&mut *self.batch.lock().unwrap_or_else(PoisonError::into_inner))
    }
}

/// Whether an event kind can change a file's content or name. Opening and reading are left
/// out: the watcher's own loads open the files, and must not trigger the next load.
fn is_change(kind: EventKind) -> bool {
    match kind {
        EventKind::Access(AccessKind::Close(AccessMode::Write)) => true,
        EventKind::Access(_) | EventKind::Other => false,
        EventKind::Any | EventKind::Create(_) | EventKind::Modify(_) | EventKind::Remove(_) => true,
    }
}

/// The debouncer and the directories it watches (non-recursively).
struct Watch {
    debouncer: Debouncer<notify::RecommendedWatcher, RecommendedCache>,
    dirs: BTreeSet<PathBuf>,
}

impl Watch {
    fn add(&mut self, dir: &Path) -> Result<(), WatchError> {
        self.debouncer
            .watch(dir, RecursiveMode::NonRecursive)
            .map_err(|source| WatchError::Notify { path: dir.to_path_buf(), source })?;
        self.dirs.insert(dir.to_path_buf());
        Ok(())
    }

    /// Watches every directory `files` live in and drops the ones no longer needed. A
    /// directory that cannot be watched (it does not exist yet) is retried at the next update;
    /// its files show up as missing meanwhile.
    fn update(&mut self, files: &SceneFiles) {
        let wanted = files.dirs();
        for gone in self.dirs.difference(&wanted).cloned().collect::<Vec<_>>() {
            if let Err(e) = self.debouncer.unwatch(&gone) {
                tracing::debug!("unwatching {}: {e}", gone.display());
            }
            self.dirs.remove(&gone);
        }
        for dir in wanted.difference(&self.dirs).cloned().collect::<Vec<_>>() {
            if let Err(e) = self.add(&dir) {
                tracing::warn!("{e}");
            }
        }
    }
}

/// One change, from its first event to its `Loaded` or `Failed`.
struct Episode {
    seen_at: Instant,
    paths: BTreeSet<PathBuf>,
    /// When to look at the files next.
    next_attempt: Instant,
}

/// What one look at the files concluded.
enum Attempt {
    Loaded(Box<Scene>),
    Failed {
        path: PathBuf,
        error: String,
        kind: FailureKind,
    },
    /// Not ready: look again at this time (or at the next event, whichever comes first).
    Retry(Instant),
}

struct Worker {
    config: WatchConfig,
    files: SceneFiles,
    watch: Watch,
    inbox: Arc<Inbox>,
    wake: Receiver<()>,
    stop: Receiver<()>,
    events: Sender<WatchEvent>,
    episode: Option<Episode>,
}

impl Worker {
    fn run(mut self) {
        loop {
            let timer = match &self.episode {
                Some(e) => after(e.next_attempt.saturating_duration_since(Instant::now())),
                None => never(),
            };
            select! {
                recv(self.stop) -> _ => break,
                recv(self.wake) -> woken => {
                    // Disconnected: the debouncer's thread is gone and no event will come again.
                    if woken.is_err() {
                        tracing::error!("{}: the file watcher stopped; hot reload is off", self.files.scene.display());
                        break;
                    }
                    if !self.absorb() {
                        break;
                    }
                }
                recv(timer) -> _ => {}
            }
            if self.episode.as_ref().is_some_and(|e| e.next_attempt <= Instant::now()) && !self.attempt() {
                break;
            }
        }
        // Joins the debouncer's thread (at most one tick); notify's own thread ends when the
        // watcher inside is dropped.
        self.watch.debouncer.stop();
    }

    /// Takes the inbox; opens or extends an episode when one of the scene's files changed.
    /// Returns false when the watcher should stop.
    fn absorb(&mut self) -> bool {
        let batch = self.inbox.take();
        let mut touched: BTreeMap<PathBuf, Instant> =
            batch.paths.into_iter().filter(|(p, _)| self.files.contains(p)).collect();
        if let Some(at) = batch.rescan {
            touched.entry(self.files.scene.clone()).or_insert(at);
        }
        let Some(&first_seen) = touched.values().min() else { return true };
        let paths: BTreeSet<PathBuf> = touched.into_keys().collect();
        let now = Instant::now();
        match &mut self.episode {
            Some(e) => {
                e.paths.extend(paths);
                e.next_attempt = now;
            }
            None => {
                let seen_at = first_seen.min(now);
                if !self.send(WatchEvent::Started { paths: paths.iter().cloned().collect(), seen_at }) {
                    return false;
                }
                self.episode = Some(Episode { seen_at, paths, next_attempt: now });
            }
        }
        true
    }

    /// Looks at the files once and ends the episode or schedules the next look. Returns
    /// false when the watcher should stop.
    fn attempt(&mut self) -> bool {
        let Some(episode) = self.episode.as_mut() else { return true };
        let settle_deadline = episode.seen_at + self.config.settle;
        match look(&mut self.files, &self.config, settle_deadline) {
            Attempt::Retry(at) => {
                episode.next_attempt = at;
                self.watch.update(&self.files);
                true
            }
            Attempt::Loaded(scene) => {
                self.watch.update(&self.files);
                let Some(e) = self.episode.take() else { return true };
                tracing::info!(
                    "{}: reloaded ({} meshes) {:.0} ms after the change was seen",
                    self.files.scene.display(),
                    scene.meshes.len(),
                    e.seen_at.elapsed().as_secs_f64() * 1e3
                );
                self.send(WatchEvent::Loaded {
                    scene: Arc::from(scene),
                    seen_at: e.seen_at,
                    paths: e.paths.into_iter().collect(),
                })
            }
            Attempt::Failed { path, error, kind } => {
                self.watch.update(&self.files);
                let Some(e) = self.episode.take() else { return true };
                tracing::warn!("reload failed, keeping the last good scene: {error}");
                self.send(WatchEvent::Failed { path, error, kind, seen_at: e.seen_at })
            }
        }
    }

    /// Sends a report unless the watcher is stopped or nobody listens any more; waits while
    /// the queue is full. Returns false when the watcher should stop.
    fn send(&self, event: WatchEvent) -> bool {
        select! {
            send(self.events, event) -> sent => sent.is_ok(),
            recv(self.stop) -> _ => false,
        }
    }
}

/// One look at the files; see the module documentation for the rules. The scene file is
/// read once and parsed for the files it refers to (`files` takes them); then one snapshot
/// of every file's stamp is judged: all quiet, no buffer newer than the scene file, every
/// referenced file present and every buffer of its declared length. Then the bytes read
/// load, and a second snapshot must equal the first: otherwise a file changed meanwhile, its
/// events are on their way, and the look is repeated.
fn look(files: &mut SceneFiles, config: &WatchConfig, settle_deadline: Instant) -> Attempt {
    let now = Instant::now();
    let retry_soon = Attempt::Retry(now + config.debounce);
    let incomplete = |m: Mismatch| {
        if now < settle_deadline {
            tracing::debug!("waiting for the save to complete: {}", m.message);
            Attempt::Retry(settle_deadline)
        } else {
            Attempt::Failed { path: m.path, error: m.message, kind: FailureKind::Incomplete }
        }
    };
    let load_failed = |e: LoadError| Attempt::Failed {
        path: e.file().to_path_buf(),
        error: error_chain(&e),
        kind: FailureKind::Load,
    };

    let scene_before = files::stamp(&files.scene);
    let bytes = match read_scene_file(&files.scene) {
        Ok(b) => b,
        Err(e) => {
            let message = format!("cannot read the scene file: {}", error_chain(&e));
            return incomplete(Mismatch { path: files.scene.clone(), message });
        }
    };
    // The same confinement as the load: a document naming a file outside the scene's folder
    // fails here, before its directory would be watched.
    match external_files(&files.scene, &bytes, &config.load) {
        Ok(external) => files.set_external(external),
        // Still being written: its next events will say when it is done.
        Err(_) if files::stamp(&files.scene) != scene_before => return retry_soon,
        Err(e) => return load_failed(e),
    }
    let before = files::stamps(files);
    if before.first() != Some(&scene_before) {
        return retry_soon;
    }
    if let Some(wait) = files::time_to_quiet(&before, quiet_time(config)) {
        return Attempt::Retry(now + wait);
    }
    if let Some(wait) = files::time_for_scene_to_follow(files, &before, config.settle) {
        tracing::debug!("a buffer is newer than {}: waiting for it to follow", files.scene.display());
        return Attempt::Retry(now + wait);
    }
    if let Err(m) = files::check_external(files, &before) {
        return incomplete(m);
    }
    let loaded = load_gltf_bytes(&files.scene, &bytes, &config.load);
    if files::stamps(files) != before {
        return retry_soon;
    }
    match loaded {
        Ok(mut scene) => match scene.set_surroundings(&config.surroundings) {
            Ok(()) => Attempt::Loaded(Box::new(scene)),
            Err(e) => Attempt::Failed { path: files.scene.clone(), error: e.to_string(), kind: FailureKind::Load },
        },
        Err(e) => load_failed(e),
    }
}

/// How long every file must have been left alone before it is read: twice the debounce, so
/// that the debouncer (which holds an event `debounce` and hands it over at its next tick, a
/// quarter of that later) has delivered the events of any write older than that.
fn quiet_time(config: &WatchConfig) -> Duration {
    config.debounce * 2
}

/// An error and its causes on one line.
fn error_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        text.push_str(": ");
        text.push_str(&s.to_string());
        source = s.source();
    }
    text
}
