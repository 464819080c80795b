//! One WebSocket client: the upgrade (answered here from the parsed request, so the token
//! check and routing stay in one place), then a loop that writes what the hub queued for it
//! and reads what the page sends. A malformed message, a dropped connection or a client
//! that falls behind ends this client only.

use std::io::Write;
use std::net::TcpStream;
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender, TryRecvError};
use tungstenite::protocol::{Role, WebSocketConfig};
use tungstenite::{Message, WebSocket};

use super::http::Request;
use super::hub::HubCommand;
use super::protocol::parse_client;

/// Largest message a page may send (its messages are tens of bytes).
const MAX_CLIENT_MESSAGE: usize = 4096;
/// How long a read waits before the loop looks at the outgoing queue again.
const READ_SLICE: Duration = Duration::from_millis(2);

/// Answers the upgrade request `req`; `None` (after a 400) when it is not a WebSocket one.
pub fn upgrade(mut stream: TcpStream, req: &Request) -> Option<WebSocket<TcpStream>> {
    let is_upgrade = req.header("upgrade").is_some_and(|u| u.eq_ignore_ascii_case("websocket"))
        && req.header("sec-websocket-version") == Some("13");
    let Some(key) = req.header("sec-websocket-key").filter(|_| is_upgrade && req.method == "GET") else {
        super::http::refuse(&mut stream, "400 Bad Request");
        return None;
    };
    let accept = tungstenite::handshake::derive_accept_key(key.trim().as_bytes());
    let head = format!(
        "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Accept: {accept}\r\n\r\n"
    );
    stream.write_all(head.as_bytes()).ok()?;
    stream.set_nodelay(true).ok()?;
    stream.set_read_timeout(Some(READ_SLICE)).ok()?;
    stream.set_write_timeout(Some(Duration::from_secs(10))).ok()?;
    let config =
        WebSocketConfig::default().max_message_size(Some(MAX_CLIENT_MESSAGE)).max_frame_size(Some(MAX_CLIENT_MESSAGE));
    Some(WebSocket::from_raw_socket(stream, Role::Server, Some(config)))
}

fn would_block(e: &tungstenite::Error) -> bool {
    matches!(e, tungstenite::Error::Io(io) if matches!(io.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut))
}

/// Runs client `id` until it leaves, misbehaves or the hub lets it go; tells the hub.
pub fn serve_client(id: u64, mut ws: WebSocket<TcpStream>, outgoing: Receiver<Message>, hub: Sender<HubCommand>) {
    let why = client_loop(id, &mut ws, &outgoing, &hub);
    tracing::debug!("client {id} left: {why}");
    let _ = ws.close(None);
    let _ = ws.flush();
    let _ = hub.send(HubCommand::Leave { id });
}

fn client_loop(
    id: u64,
    ws: &mut WebSocket<TcpStream>,
    outgoing: &Receiver<Message>,
    hub: &Sender<HubCommand>,
) -> String {
    loop {
        let mut wrote = false;
        loop {
            match outgoing.try_recv() {
                Ok(m) => {
                    if let Err(e) = ws.write(m) {
                        return format!("cannot write: {e}");
                    }
                    wrote = true;
                }
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => return "the server let it go".into(),
            }
        }
        if wrote && let Err(e) = ws.flush() {
            return format!("cannot write: {e}");
        }
        match ws.read() {
            Ok(Message::Binary(b)) => match parse_client(&b) {
                Ok(m) => {
                    if hub.send(HubCommand::Message { id, message: m }).is_err() {
                        return "the server stopped".into();
                    }
                }
                Err(e) => {
                    tracing::warn!("client {id}: {e}; closing it");
                    return format!("malformed message: {e}");
                }
            },
            Ok(Message::Text(_)) => {
                tracing::warn!("client {id}: a text message; closing it");
                return "malformed message: text".into();
            }
            Ok(Message::Close(_)) => return "closed by the page".into(),
            Ok(_) => {}
            Err(e) if would_block(&e) => {}
            Err(e) => return format!("connection lost: {e}"),
        }
    }
}
