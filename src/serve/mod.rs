//! `livebake serve`: the live runtime behind a small HTTP + WebSocket server, for a browser
//! or a standalone headset (WebXR). See docs/SERVE.md for the protocol and the security
//! model.
//!
//! Threads: an acceptor (one short-lived thread per HTTP request; a socket upgrade becomes a
//! client thread, [`socket`]), and the hub ([`hub`]) on the caller's thread, which owns the
//! view of the runtime and broadcasts to the clients' queues. Only std's `TcpListener` and
//! `tungstenite` (sync) are used: no async runtime.

pub mod export;
pub mod http;
pub mod hub;
pub mod protocol;
pub mod scene;
pub mod socket;

use std::io::Read;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender};
use glam::Vec3;

pub use hub::ServeStats;

use crate::runtime::Runtime;

/// How to serve.
#[derive(Clone, Debug)]
pub struct ServeConfig {
    pub addr: SocketAddr,
    /// Every request and the socket must carry it (query `?token=` or the cookie the page
    /// gets with it); `None` only on a loopback address.
    pub token: Option<String>,
    /// Radiance scale before the tone curve; `None`: `view`'s automatic exposure from the
    /// first light map shown.
    pub exposure: Option<f32>,
    /// Start pose (eye, target); `None`: `view`'s (glTF camera, else a framing view).
    pub pose: Option<(Vec3, Vec3)>,
    /// Bytes of updates a client may hold unacknowledged before changes wait for it and go
    /// merged (flow control, [`hub`]); [`hub::IN_FLIGHT_BYTES`] by default. One update is
    /// always let through, whatever its size.
    pub in_flight_bytes: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("cannot listen on {addr}: {source}")]
    Bind { addr: SocketAddr, source: std::io::Error },
    #[error("cannot start the server: {0}")]
    Io(#[from] std::io::Error),
    #[error("cannot make an access token: {0}")]
    Token(std::io::Error),
    #[error("the runtime stopped: {0}")]
    Runtime(String),
    #[error("the connection acceptor stopped")]
    AcceptorGone,
}

/// A random access token: 128 bits from the system's generator, as hex.
pub fn random_token() -> Result<String, ServeError> {
    let mut b = [0u8; 16];
    std::fs::File::open("/dev/urandom").and_then(|mut f| f.read_exact(&mut b)).map_err(ServeError::Token)?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

/// Most HTTP connections handled at once (more are refused with 503).
const MAX_CONNECTIONS: usize = 64;

/// A bound server: accepting, its hub not yet running ([`Server::run`]).
pub struct Server {
    addr: SocketAddr,
    config: ServeConfig,
    commands: Receiver<HubCommand>,
    status: Arc<Mutex<ServeStats>>,
    stop: Arc<AtomicBool>,
    acceptor: Option<JoinHandle<()>>,
}

use hub::HubCommand;

struct Shared {
    scene_path: PathBuf,
    token: Option<String>,
    hub: Sender<HubCommand>,
    status: Arc<Mutex<ServeStats>>,
    next_client: AtomicU64,
    connections: AtomicUsize,
    stop: Arc<AtomicBool>,
}

impl Server {
    /// Listens on `config.addr` (port 0: any free one) and starts accepting; the scene's
    /// own files are served from beside `scene_path`.
    pub fn bind(scene_path: &Path, config: ServeConfig) -> Result<Server, ServeError> {
        let listener =
            TcpListener::bind(config.addr).map_err(|source| ServeError::Bind { addr: config.addr, source })?;
        let addr = listener.local_addr()?;
        listener.set_nonblocking(true)?;
        let (tx, rx) = crossbeam_channel::unbounded();
        let status = Arc::new(Mutex::new(ServeStats::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let shared = Arc::new(Shared {
            scene_path: scene_path.to_path_buf(),
            token: config.token.clone(),
            hub: tx,
            status: status.clone(),
            next_client: AtomicU64::new(1),
            connections: AtomicUsize::new(0),
            stop: stop.clone(),
        });
        let acceptor =
            std::thread::Builder::new().name("serve-accept".into()).spawn(move || accept(listener, shared))?;
        Ok(Server { addr, config, commands: rx, status, stop, acceptor: Some(acceptor) })
    }

    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// The page's URL (with the token when there is one).
    pub fn url(&self) -> String {
        let host = if self.addr.ip().is_unspecified() { "127.0.0.1".to_string() } else { self.addr.ip().to_string() };
        let host = if self.addr.is_ipv6() && !self.addr.ip().is_unspecified() { format!("[{host}]") } else { host };
        match &self.config.token {
            Some(t) => format!("http://{host}:{}/?token={t}", self.addr.port()),
            None => format!("http://{host}:{}/", self.addr.port()),
        }
    }

    /// Serves `runtime` until `stop` returns true (it sees the figures so far, every few
    /// milliseconds); then stops accepting and lets every client go.
    pub fn run(mut self, runtime: &Runtime, stop: impl FnMut(&ServeStats) -> bool) -> Result<ServeStats, ServeError> {
        let result = hub::run(runtime, &self.config, &self.commands, &self.status, stop);
        self.stop.store(true, Ordering::SeqCst);
        if let Some(a) = self.acceptor.take() {
            let _ = a.join();
        }
        result
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

fn accept(listener: TcpListener, shared: Arc<Shared>) {
    while !shared.stop.load(Ordering::SeqCst) {
        match listener.accept() {
            Ok((stream, _)) => {
                if stream.set_nonblocking(false).is_err() {
                    continue;
                }
                if shared.connections.fetch_add(1, Ordering::SeqCst) >= MAX_CONNECTIONS {
                    shared.connections.fetch_sub(1, Ordering::SeqCst);
                    let mut stream = stream;
                    http::refuse(&mut stream, "503 Service Unavailable");
                    continue;
                }
                let shared = shared.clone();
                let spawned = std::thread::Builder::new().name("serve-conn".into()).spawn({
                    let shared = shared.clone();
                    move || {
                        handle(stream, &shared);
                        shared.connections.fetch_sub(1, Ordering::SeqCst);
                    }
                });
                if spawned.is_err() {
                    shared.connections.fetch_sub(1, Ordering::SeqCst);
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => {
                tracing::warn!("accept failed: {e}");
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    }
}

/// One HTTP request (or a socket's whole life).
fn handle(mut stream: TcpStream, shared: &Shared) {
    let req = match http::read_request(&mut stream) {
        Ok(r) => r,
        Err(e) => {
            tracing::debug!("bad request: {e}");
            http::refuse(&mut stream, "400 Bad Request");
            return;
        }
    };
    if !req.has_token(shared.token.as_deref()) {
        http::refuse(&mut stream, "403 Forbidden");
        return;
    }
    if req.path == "/socket" {
        let Some(ws) = socket::upgrade(stream, &req) else { return };
        let id = shared.next_client.fetch_add(1, Ordering::SeqCst);
        let (to, from_hub) = crossbeam_channel::bounded(hub::CLIENT_QUEUE);
        if shared.hub.send(HubCommand::Join { id, to }).is_err() {
            return;
        }
        socket::serve_client(id, ws, from_hub, shared.hub.clone());
        return;
    }
    let head_only = req.method == "HEAD";
    if req.method != "GET" && !head_only {
        http::refuse(&mut stream, "405 Method Not Allowed");
        return;
    }
    // The page gets the token as a cookie, so that its own requests and socket carry it.
    let cookie: Vec<String> = shared
        .token
        .iter()
        .map(|t| format!("Set-Cookie: {}={t}; HttpOnly; SameSite=Strict; Path=/", http::TOKEN_COOKIE))
        .collect();
    if let Some((_, ty, body)) = http::PAGE_FILES.iter().find(|(p, _, _)| *p == req.path) {
        // Cross-origin isolation (the page loads nothing from elsewhere anyway): it lets the
        // page share memory with its socket's worker (web/socket.js), so that a frame picks
        // up the updates that arrived while the main thread was busy.
        let mut extra = cookie;
        extra.extend(http::ISOLATION.iter().map(|h| h.to_string()));
        http::respond(&mut stream, "200 OK", ty, &extra, body, head_only);
        return;
    }
    if req.path == "/status.json" {
        let body = shared.status.lock().map(|s| serde_json::to_vec(&*s).unwrap_or_default()).unwrap_or_default();
        http::respond(&mut stream, "200 OK", "application/json", &[], &body, head_only);
        return;
    }
    if let Some(rest) = req.path.strip_prefix("/scene/") {
        let Some(relative) = http::percent_decode(rest) else {
            http::refuse(&mut stream, "400 Bad Request");
            return;
        };
        match http::scene_file(&shared.scene_path, &relative) {
            Ok(bytes) => http::respond(&mut stream, "200 OK", http::content_type(&relative), &[], &bytes, head_only),
            Err(http::SceneFileRefusal::Outside) => http::refuse(&mut stream, "403 Forbidden"),
            Err(http::SceneFileRefusal::NotFound) => http::refuse(&mut stream, "404 Not Found"),
        }
        return;
    }
    http::refuse(&mut stream, "404 Not Found");
}
