//! The glue between the runtime and the clients: one loop (the caller's thread) that reads
//! the runtime's events and shown map, as `view` does through its `LightSource`, and
//! sends each client the scene and the pages that changed since what it has; the clients'
//! poses move the runtime's camera (the latest pose of any client wins).
//!
//! Flow control: while a client holds [`ServeConfig::in_flight_bytes`] of updates it has not
//! acknowledged as uploaded, what changes waits, and goes as one update against what the
//! client has once it acknowledges: a page that keeps up never waits; one that falls behind
//! (a headset on a slow link) gets fewer, larger updates, each page once however often it was
//! rewritten meanwhile, and the server keeps no growing queue of them for it.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender, TrySendError};
use glam::Vec3;
use serde::Serialize;
use tungstenite::{Bytes, Message};

use super::protocol::{AckStage, ClientMessage, StartPose, changed_cells, encode_update};
use super::scene::{scene_messages, start_pose};
use super::{ServeConfig, ServeError};
use crate::runtime::shown::{Page, PageChange, ShownLightmap};
use crate::runtime::{CameraView, Runtime, RuntimeEvent};
use crate::scene::Scene;

/// What the acceptor and the clients tell the hub.
pub enum HubCommand {
    /// A client connected; `to` is its outgoing queue.
    Join {
        id: u64,
        to: Sender<Message>,
    },
    Message {
        id: u64,
        message: ClientMessage,
    },
    Leave {
        id: u64,
    },
}

/// Messages a client may have waiting before it counts as fallen behind and is let go (it
/// can reconnect and gets the whole map again). Updates are flow-controlled
/// ([`ServeConfig::in_flight_bytes`]), so only a client that stopped reading its socket
/// fills it.
pub const CLIENT_QUEUE: usize = 4096;

/// The default [`ServeConfig::in_flight_bytes`]: the page's shared ring (`RING_BYTES` in
/// web/livebake.js), so that what is in flight fits it. Not fewer: the page applies at each
/// frame's start whatever arrived, so updates held for an acknowledgement would wait a whole
/// frame more (under software GL, a real scene's burst of publishes at first light).
pub const IN_FLIGHT_BYTES: usize = 16 << 20;

/// An update unacknowledged this long (ms) stops counting as in flight: a client that never
/// acknowledges (or lost an update to a reload) still gets the changes, this often at most.
const IN_FLIGHT_TIMEOUT_MS: f64 = 2000.0;

/// The serve run's figures (`--stats`, the bench, `/status.json`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct ServeStats {
    pub clients_joined: u64,
    pub clients_now: usize,
    /// Scene generation (1 at first light, +1 a reload that replaced the world).
    pub generation: u32,
    pub reloads: u64,
    /// Incremental updates sent, one per client each (not the whole maps sent to joining
    /// clients or after a reload).
    pub updates: u64,
    pub update_pages: u64,
    pub update_bytes: u64,
    /// What those updates' pages hold (their texels alone): `update_bytes` minus this is
    /// the headers'.
    pub update_page_bytes: u64,
    /// Publish to texture: the runtime's publish (the hub's noticing of the new snapshot; for
    /// an update that waited for the client's acknowledgements, of the first snapshot it
    /// carries) to the page's acknowledgement that a fence placed after the update's upload
    /// calls is signalled (the GPU has written the pages), ms, one a received ack.
    pub ack_latency_ms: Vec<f64>,
    /// The runtime's publish to the page's acknowledgement that the update's upload calls
    /// returned (the GL has the texels; its GPU may still be drawing earlier frames), ms.
    pub upload_latency_ms: Vec<f64>,
    /// Updates that waited for the client's acknowledgements
    /// ([`ServeConfig::in_flight_bytes`]) before going.
    pub updates_held: u64,
    /// Frame times the pages reported (mean over their reports, ms) and frames counted.
    pub page_frame_ms: Option<f64>,
    pub page_frames: u64,
    /// The last pose a client sent (eye, target).
    pub last_pose: Option<([f32; 3], [f32; 3])>,
    pub start: Option<StartPose>,
    pub first_light: bool,
}

struct Client {
    to: Sender<Message>,
    /// The shown map as this client has it: what its next update is the difference from.
    has: Arc<ShownLightmap>,
    /// Its updates not yet acknowledged as uploaded: sequence number, when sent (ms), bytes.
    in_flight: VecDeque<(u32, f64, usize)>,
    /// When the hub noticed the first snapshot this client lacks while its updates are held.
    held_since: Option<f64>,
}

struct Hub<'a> {
    runtime: &'a Runtime,
    config: &'a ServeConfig,
    clients: HashMap<u64, Client>,
    /// Joined before there was a scene to send.
    waiting: Vec<(u64, Sender<Message>)>,
    /// The scene's messages, sent to every joining client.
    scene: Vec<Message>,
    scene_of: Option<Arc<Scene>>,
    exposure: Option<f32>,
    /// The runtime's shown map as last read, and when the hub noticed it (ms).
    last: Option<Arc<ShownLightmap>>,
    noticed_ms: f64,
    seq: u32,
    sent_at: HashMap<u32, f64>,
    stats: ServeStats,
    frame_sum: f64,
    frame_reports: u64,
}

fn now_ms(runtime: &Runtime) -> f64 {
    runtime.elapsed() * 1e3
}

impl Hub<'_> {
    /// Sends to one client; a full queue or a gone client drops it.
    fn send(&mut self, id: u64, m: Message) {
        let Some(c) = self.clients.get(&id) else { return };
        match c.to.try_send(m) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                tracing::warn!("client {id} fell behind ({CLIENT_QUEUE} messages queued); letting it go");
                self.clients.remove(&id);
            }
            Err(TrySendError::Disconnected(_)) => {
                self.clients.remove(&id);
            }
        }
    }

    fn broadcast(&mut self, m: &Message) {
        let ids: Vec<u64> = self.clients.keys().copied().collect();
        for id in ids {
            self.send(id, m.clone());
        }
    }

    /// The whole current map as one update (a joining client, or everyone after a reload).
    fn full_update(&self) -> Option<Message> {
        let last = self.last.as_ref()?;
        // Seq 0: a whole map's acknowledgement measures no publish.
        let bytes = encode_update(
            0,
            self.stats.generation,
            now_ms(self.runtime),
            true,
            &changed_cells(last, None),
            &last.changed_pages(None),
        );
        Some(Message::Binary(Bytes::from(bytes)))
    }

    /// Takes client `id` in (its queue `to`) with the scene and the whole map: it has the
    /// last map read, nothing in flight. Only once there is a scene (first light).
    fn welcome(&mut self, id: u64, to: Sender<Message>) {
        let Some(has) = self.last.clone() else { return };
        self.clients.insert(id, Client { to, has, in_flight: VecDeque::new(), held_since: None });
        for m in self.scene.clone() {
            self.send(id, m);
        }
        if let Some(full) = self.full_update() {
            self.send(id, full);
        }
    }

    /// Sends everyone the scene and the whole map (a reload replaced the world): each then
    /// has the last map read, and what was in flight is of the old scene (the page drops it
    /// unacknowledged).
    fn rewelcome(&mut self) {
        let Some(has) = self.last.clone() else { return };
        let mut msgs = self.scene.clone();
        msgs.extend(self.full_update());
        for c in self.clients.values_mut() {
            c.has = has.clone();
            c.in_flight.clear();
            c.held_since = None;
        }
        for m in &msgs {
            self.broadcast(m);
        }
    }

    /// (Re)builds the scene's messages from the runtime's world when it is not the one sent.
    fn follow_world(&mut self) -> bool {
        let world = self.runtime.world();
        if self.scene_of.as_ref().is_some_and(|s| Arc::ptr_eq(s, &world.scene)) {
            return false;
        }
        let shown = self.runtime.shown();
        let exposure = *self.exposure.get_or_insert_with(|| {
            self.config.exposure.unwrap_or_else(|| crate::viewer::render::auto_exposure(&shown))
        });
        let start = start_pose(&world.scene, self.config.pose);
        if self.stats.last_pose.is_none() {
            self.runtime.set_camera(start_camera(&start));
        }
        self.stats.generation += 1;
        self.stats.start = Some(start);
        let msgs = scene_messages(&world.scene, &world.atlas, &shown, self.stats.generation, exposure, start);
        let text = serde_json::to_string(&msgs.description).unwrap_or_default();
        let mut scene = vec![Message::text(text), Message::Binary(Bytes::from(msgs.geometry))];
        scene.extend(msgs.textures.into_iter().chain(msgs.sky).map(|t| Message::Binary(Bytes::from(t))));
        self.scene = scene;
        self.scene_of = Some(world.scene.clone());
        // The new scene's map is sent whole.
        self.last = Some(shown);
        self.noticed_ms = now_ms(self.runtime);
        true
    }

    fn handle(&mut self, cmd: HubCommand) {
        match cmd {
            HubCommand::Join { id, to } => {
                self.stats.clients_joined += 1;
                if self.scene.is_empty() {
                    self.waiting.push((id, to));
                } else {
                    self.welcome(id, to);
                }
            }
            HubCommand::Leave { id } => {
                self.clients.remove(&id);
                self.waiting.retain(|(w, _)| *w != id);
            }
            HubCommand::Message { id, message } => match message {
                ClientMessage::Pose(p) => {
                    self.runtime.set_camera(CameraView {
                        eye: p.eye,
                        target: p.target,
                        up: Vec3::Y,
                        yfov: p.yfov,
                        aspect: p.aspect,
                        height_px: p.height_px,
                    });
                    self.stats.last_pose = Some((p.eye.to_array(), p.target.to_array()));
                }
                ClientMessage::Ack { seq, stage: AckStage::Uploaded, .. } => {
                    if let Some(t) = self.sent_at.get(&seq) {
                        self.stats.upload_latency_ms.push(now_ms(self.runtime) - t);
                    }
                    // The page applies updates in order: this one and every earlier one are in.
                    if let Some(c) = self.clients.get_mut(&id) {
                        c.in_flight.retain(|&(s, _, _)| s > seq);
                    }
                }
                ClientMessage::Ack { seq, stage: AckStage::Done, .. } => {
                    if let Some(t) = self.sent_at.remove(&seq) {
                        self.stats.ack_latency_ms.push(now_ms(self.runtime) - t);
                    }
                }
                ClientMessage::Frames { frames, mean_ms } => {
                    self.frame_sum += mean_ms;
                    self.frame_reports += 1;
                    self.stats.page_frames += frames as u64;
                    self.stats.page_frame_ms = Some(self.frame_sum / self.frame_reports as f64);
                }
            },
        }
    }

    /// Reads the runtime's shown map and sends each client what changed since what it has,
    /// unless its updates are held ([`ServeConfig::in_flight_bytes`]).
    fn publish(&mut self) {
        let Some(last) = self.last.clone() else { return };
        let now = self.runtime.shown();
        let t = now_ms(self.runtime);
        if !Arc::ptr_eq(&now, &last) && now.version != last.version {
            self.last = Some(now.clone());
            self.noticed_ms = t;
        }
        let ids: Vec<u64> = self.clients.keys().copied().collect();
        for id in ids {
            let Some(c) = self.clients.get_mut(&id) else { continue };
            if Arc::ptr_eq(&c.has, &now) || c.has.version == now.version {
                continue;
            }
            c.in_flight.retain(|&(_, sent, _)| t - sent < IN_FLIGHT_TIMEOUT_MS);
            // Since when the client lacks what it lacks: the first snapshot after its map.
            let since = *c.held_since.get_or_insert(self.noticed_ms);
            let out: usize = c.in_flight.iter().map(|f| f.2).sum();
            if !c.in_flight.is_empty() && out >= self.config.in_flight_bytes {
                continue;
            }
            let pages = now.changed_pages(Some(&c.has));
            let cells = changed_cells(&now, Some(&c.has));
            c.has = now.clone();
            c.held_since = None;
            if pages.is_empty() && cells.is_empty() {
                continue;
            }
            self.seq = self.seq.checked_add(1).unwrap_or(1);
            let bytes = encode_update(self.seq, self.stats.generation, since, false, &cells, &pages);
            c.in_flight.push_back((self.seq, t, bytes.len()));
            let written = pages.iter().filter(|p| matches!(p, PageChange::Written(..))).count() as u64;
            self.stats.updates += 1;
            self.stats.updates_held += u64::from(since < t);
            self.stats.update_pages += written;
            self.stats.update_bytes += bytes.len() as u64;
            self.stats.update_page_bytes += written * Page::BYTES as u64;
            if self.sent_at.len() > 4096 {
                self.sent_at.clear();
            }
            self.sent_at.insert(self.seq, since);
            self.send(id, Message::Binary(Bytes::from(bytes)));
        }
    }
}

/// The runtime's camera until a page sends its pose: the page's start pose on a 720-pixel
/// high 16:9 screen (as `run` assumes).
fn start_camera(start: &StartPose) -> CameraView {
    CameraView {
        eye: Vec3::from(start.eye),
        target: Vec3::from(start.target),
        up: Vec3::Y,
        yfov: start.yfov,
        aspect: 16.0 / 9.0,
        height_px: 720,
    }
}

/// Runs the hub until `stop` says so; returns the run's figures.
pub fn run(
    runtime: &Runtime,
    config: &ServeConfig,
    commands: &Receiver<HubCommand>,
    status: &Mutex<ServeStats>,
    mut stop: impl FnMut(&ServeStats) -> bool,
) -> Result<ServeStats, ServeError> {
    let mut hub = Hub {
        runtime,
        config,
        clients: HashMap::new(),
        waiting: Vec::new(),
        scene: Vec::new(),
        scene_of: None,
        exposure: None,
        last: None,
        noticed_ms: 0.0,
        seq: 0,
        sent_at: HashMap::new(),
        stats: ServeStats::default(),
        frame_sum: 0.0,
        frame_reports: 0,
    };
    // Refinement starts from the page's start pose (before any page joins).
    let world = runtime.world();
    runtime.set_camera(start_camera(&start_pose(&world.scene, config.pose)));
    drop(world);
    loop {
        let mut reloaded = false;
        while let Ok(ev) = runtime.events().try_recv() {
            match ev.event {
                RuntimeEvent::Failed { error } => return Err(ServeError::Runtime(error)),
                RuntimeEvent::ReloadApplied { .. } => {
                    hub.stats.reloads += 1;
                    reloaded = true;
                }
                _ => {}
            }
        }
        if !hub.stats.first_light && runtime.has_first_light() {
            hub.stats.first_light = true;
            hub.follow_world();
            for (id, to) in std::mem::take(&mut hub.waiting) {
                hub.welcome(id, to);
            }
        } else if hub.stats.first_light && reloaded && hub.follow_world() {
            // "Scene changed": the new description, geometry, textures and whole map.
            hub.rewelcome();
        }
        if hub.stats.first_light {
            hub.publish();
        }
        match commands.recv_timeout(Duration::from_millis(2)) {
            Ok(cmd) => {
                hub.handle(cmd);
                while let Ok(cmd) = commands.try_recv() {
                    hub.handle(cmd);
                }
            }
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {}
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => return Err(ServeError::AcceptorGone),
        }
        hub.stats.clients_now = hub.clients.len();
        if let Ok(mut s) = status.lock() {
            let latencies = std::mem::take(&mut hub.stats.ack_latency_ms);
            let uploads = std::mem::take(&mut hub.stats.upload_latency_ms);
            *s = hub.stats.clone();
            s.ack_latency_ms = latencies.iter().rev().take(64).copied().collect();
            s.upload_latency_ms = uploads.iter().rev().take(64).copied().collect();
            hub.stats.ack_latency_ms = latencies;
            hub.stats.upload_latency_ms = uploads;
        }
        if stop(&hub.stats) {
            return Ok(hub.stats);
        }
    }
}
