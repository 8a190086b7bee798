//! The Foxglove WebSocket server: the `foxglove.websocket.v1` protocol
//! (messages from the `foxglove` crate's protocol module) over blocking
//! sockets, one writer and one reader thread per client.
//!
//! Why not the SDK's server: it queues every client's messages in one
//! bounded queue and drops the oldest, whatever their topic, without
//! telling anyone. Here each client has two lanes: a bounded stream queue
//! (oldest dropped, counted) and one newest-value slot per map and pose
//! channel, sent first; so a busy scan topic can never starve the map or
//! the pose, and every drop is counted per client. [`ViewServer::publish`]
//! never blocks on a client: a client that reads nothing only fills its
//! own queue.

use crate::channels::{ChannelDef, Lane};
use foxglove::websocket::ws_protocol::client::ClientMessage;
use foxglove::websocket::ws_protocol::schema::Schema;
use foxglove::websocket::ws_protocol::server::server_info::Capability;
use foxglove::websocket::ws_protocol::server::{Advertise, Channel, MessageData, ServerInfo};
use foxglove::websocket::ws_protocol::{BinaryMessage, JsonMessage};
use smokenav_platform_recording::initial_pose::{self, PlanarPose};
use std::collections::HashMap;
use std::collections::VecDeque;
use std::io::{self, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{SyncSender, TrySendError};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;
use thiserror::Error;
use tungstenite::handshake::server::{ErrorResponse, Request, Response};
use tungstenite::http::{HeaderValue, StatusCode};
use tungstenite::protocol::Role;
use tungstenite::{Message, WebSocket};

/// The subprotocols served, in order of preference; both carry the same
/// messages with inline schemas.
pub const SUBPROTOCOLS: [&str; 2] = ["foxglove.websocket.v1", "foxglove.sdk.v1"];

/// Why the server could not start.
#[derive(Debug, Error)]
pub enum ServerError {
    #[error("cannot listen on {addr}: {source}")]
    Bind { addr: String, source: io::Error },
    #[error("channel `{topic}`: {reason}")]
    Channel { topic: String, reason: String },
    #[error("cannot start a thread: {0}")]
    Thread(io::Error),
}

/// Per-client limits.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Stream messages queued per client before the oldest is dropped.
    pub stream_queue: usize,
    /// A client whose socket takes no data for this long is disconnected.
    pub write_timeout: Duration,
    /// The kernel's send buffer per client socket, bytes. Small, so a
    /// stalled client backs up into its queue here, where drops are
    /// counted and the map and pose overtake, instead of megabytes of
    /// stale messages in the kernel.
    pub send_buffer: Option<usize>,
    /// Clients served at once; more are refused (each costs two threads).
    pub max_clients: usize,
}

impl Default for Limits {
    fn default() -> Self {
        // 512 messages ≈ 3 s of every topic at 10 Hz; a client that stalls
        // longer loses the oldest stream messages, never the map or pose.
        Limits {
            stream_queue: 512,
            write_timeout: Duration::from_secs(30),
            send_buffer: Some(64 * 1024),
            max_clients: 8,
        }
    }
}

/// One encoded message, shared by every client it goes to.
#[derive(Debug, Clone)]
struct Frame {
    channel: u32,
    log_time: u64,
    data: Arc<[u8]>,
}

/// What one client was sent and lost.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ClientStats {
    pub id: u64,
    pub addr: Option<SocketAddr>,
    /// Messages written to its socket.
    pub sent: u64,
    /// Stream messages dropped because its queue was full.
    pub dropped: u64,
    /// Map/pose values replaced by a newer one before they were sent.
    pub superseded: u64,
    /// Messages waiting in its queue now.
    pub queued: u64,
}

#[derive(Default)]
struct Outbox {
    stream: VecDeque<Frame>,
    /// Newest unsent value per channel of the latest-value lane (by channel id).
    latest: Vec<Option<Frame>>,
    latest_pending: usize,
    closed: bool,
}

impl Outbox {
    fn pop(&mut self) -> Option<Frame> {
        if self.latest_pending > 0
            && let Some(f) = self.latest.iter_mut().find_map(Option::take)
        {
            self.latest_pending -= 1;
            return Some(f);
        }
        self.stream.pop_front()
    }
}

struct Client {
    id: u64,
    addr: SocketAddr,
    outbox: Mutex<Outbox>,
    wake: Condvar,
    /// Subscription id per channel id.
    subs: Mutex<Vec<Option<u32>>>,
    sent: AtomicU64,
    dropped: AtomicU64,
    superseded: AtomicU64,
}

impl Client {
    fn outbox(&self) -> MutexGuard<'_, Outbox> {
        self.outbox.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn subs(&self) -> MutexGuard<'_, Vec<Option<u32>>> {
        self.subs.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn push(&self, f: Frame, lane: Lane, limit: usize) {
        let mut o = self.outbox();
        if o.closed {
            return;
        }
        match lane {
            Lane::Stream => {
                if o.stream.len() >= limit {
                    o.stream.pop_front();
                    self.dropped.fetch_add(1, Ordering::Relaxed);
                }
                o.stream.push_back(f);
            }
            Lane::Latest => {
                let i = f.channel as usize;
                if o.latest.len() <= i {
                    o.latest.resize(i + 1, None);
                }
                if o.latest[i].replace(f).is_some() {
                    self.superseded.fetch_add(1, Ordering::Relaxed);
                } else {
                    o.latest_pending += 1;
                }
            }
        }
        drop(o);
        self.wake.notify_one();
    }

    fn close(&self) {
        self.outbox().closed = true;
        self.wake.notify_one();
    }

    fn stats(&self) -> ClientStats {
        let o = self.outbox();
        ClientStats {
            id: self.id,
            addr: Some(self.addr),
            sent: self.sent.load(Ordering::Relaxed),
            dropped: self.dropped.load(Ordering::Relaxed),
            superseded: self.superseded.load(Ordering::Relaxed),
            queued: (o.stream.len() + o.latest_pending) as u64,
        }
    }
}

/// The topic and type a Foxglove or RViz "2D Pose Estimate" publishes.
pub const INITIAL_POSE_TOPIC: &str = "/initialpose";
pub const INITIAL_POSE_SCHEMA: &str = "geometry_msgs/msg/PoseWithCovarianceStamped";
/// Channels one client may advertise at once.
const MAX_CLIENT_CHANNELS: usize = 16;

/// What became of the poses clients published.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PoseStats {
    /// Handed on (`slam/initial_pose`).
    pub taken: u64,
    /// Refused: another topic or type, undecodable, not in `map`, or the hand-over full.
    pub refused: u64,
}

struct Shared {
    channels: Vec<ChannelDef>,
    /// Where a client's `/initialpose` goes; `None`: clients only subscribe.
    poses: Option<SyncSender<PlanarPose>>,
    poses_taken: AtomicU64,
    poses_refused: AtomicU64,
    server_info: String,
    advertise: String,
    limits: Limits,
    clients: Mutex<Vec<Arc<Client>>>,
    /// Last message of each latched channel, for late subscribers.
    last: Mutex<Vec<Option<Frame>>>,
    /// Per channel: how many clients subscribe (publish skips unwatched ones).
    watched: Vec<AtomicU64>,
    next_id: AtomicU64,
    stop: AtomicBool,
    /// Clients that have gone, with what they had been sent and lost.
    gone: Mutex<Vec<ClientStats>>,
}

impl Shared {
    fn clients(&self) -> MutexGuard<'_, Vec<Arc<Client>>> {
        self.clients.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The server: a listening socket and the clients connected to it.
pub struct ViewServer {
    shared: Arc<Shared>,
    addr: SocketAddr,
    accept: Option<JoinHandle<()>>,
}

impl ViewServer {
    /// Listens on `addr` (`127.0.0.1:8765`; port 0 picks a free one) and
    /// advertises `channels` to every client.
    pub fn start(
        addr: &str,
        name: &str,
        channels: Vec<ChannelDef>,
        limits: Limits,
    ) -> Result<Self, ServerError> {
        Self::start_inner(addr, name, channels, limits, None)
    }

    /// [`ViewServer::start`], and clients may publish a "2D Pose Estimate"
    /// ([`INITIAL_POSE_TOPIC`], CDR): each valid one is handed to `poses`
    /// (the server advertises `clientPublish`; any other topic is refused).
    pub fn start_taking_poses(
        addr: &str,
        name: &str,
        channels: Vec<ChannelDef>,
        limits: Limits,
        poses: SyncSender<PlanarPose>,
    ) -> Result<Self, ServerError> {
        Self::start_inner(addr, name, channels, limits, Some(poses))
    }

    fn start_inner(
        addr: &str,
        name: &str,
        channels: Vec<ChannelDef>,
        limits: Limits,
        poses: Option<SyncSender<PlanarPose>>,
    ) -> Result<Self, ServerError> {
        let listener = TcpListener::bind(addr).map_err(|source| ServerError::Bind {
            addr: addr.to_owned(),
            source,
        })?;
        let local = listener.local_addr().map_err(|source| ServerError::Bind {
            addr: addr.to_owned(),
            source,
        })?;
        let advertised: Vec<Channel> = channels
            .iter()
            .map(|c| {
                Channel::builder(u64::from(c.id), c.topic.as_str(), "cdr")
                    .with_schema(Schema::new(
                        c.schema.name,
                        "ros2msg",
                        c.schema.schema_text().into_bytes(),
                    ))
                    .build()
                    .map_err(|e| ServerError::Channel {
                        topic: c.topic.clone(),
                        reason: e.to_string(),
                    })
            })
            .collect::<Result<_, _>>()?;
        // Clients only subscribe, unless poses are taken: then they may
        // publish (one topic, in CDR); never services or parameters.
        let info = match &poses {
            Some(_) => ServerInfo::new(name)
                .with_capabilities([Capability::ClientPublish])
                .with_supported_encodings(["cdr"]),
            None => ServerInfo::new(name),
        };
        let shared = Arc::new(Shared {
            server_info: info.to_string(),
            poses,
            poses_taken: AtomicU64::new(0),
            poses_refused: AtomicU64::new(0),
            advertise: Advertise::new(advertised).to_string(),
            last: Mutex::new(vec![None; channels.len()]),
            watched: channels.iter().map(|_| AtomicU64::new(0)).collect(),
            channels,
            limits,
            clients: Mutex::new(Vec::new()),
            next_id: AtomicU64::new(1),
            stop: AtomicBool::new(false),
            gone: Mutex::new(Vec::new()),
        });
        let accept = {
            let shared = shared.clone();
            std::thread::Builder::new()
                .name("view-accept".into())
                .spawn(move || accept_loop(&listener, &shared))
                .map_err(ServerError::Thread)?
        };
        Ok(ViewServer {
            shared,
            addr: local,
            accept: Some(accept),
        })
    }

    /// The address it listens on.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// What became of the poses clients published.
    pub fn pose_stats(&self) -> PoseStats {
        PoseStats {
            taken: self.shared.poses_taken.load(Ordering::Relaxed),
            refused: self.shared.poses_refused.load(Ordering::Relaxed),
        }
    }

    /// The advertised channels.
    pub fn channels(&self) -> &[ChannelDef] {
        &self.shared.channels
    }

    /// Whether any client subscribes to channel `id`, or it is latched
    /// (its last value is kept for later subscribers).
    pub fn wanted(&self, id: u32) -> bool {
        let i = id as usize;
        self.shared.channels.get(i).is_some_and(|c| c.latched)
            || self
                .shared
                .watched
                .get(i)
                .is_some_and(|w| w.load(Ordering::Relaxed) > 0)
    }

    /// Queues `data` (CDR) on channel `id` for every subscribed client;
    /// never waits for one.
    pub fn publish(&self, id: u32, log_time: u64, data: &[u8]) {
        let Some(def) = self.shared.channels.get(id as usize) else {
            return;
        };
        if !self.wanted(id) {
            return;
        }
        let frame = Frame {
            channel: id,
            log_time,
            data: Arc::from(data),
        };
        if def.latched {
            self.shared.last.lock().unwrap_or_else(|p| p.into_inner())[id as usize] =
                Some(frame.clone());
        }
        let limit = self.shared.limits.stream_queue;
        for c in self.shared.clients().iter() {
            if c.subs().get(id as usize).copied().flatten().is_some() {
                c.push(frame.clone(), def.lane, limit);
            }
        }
    }

    /// The clients connected now.
    pub fn client_stats(&self) -> Vec<ClientStats> {
        self.shared.clients().iter().map(|c| c.stats()).collect()
    }

    /// Totals over every client so far, connected or gone.
    pub fn totals(&self) -> ClientStats {
        let gone = self.shared.gone.lock().unwrap_or_else(|p| p.into_inner());
        let mut t = ClientStats::default();
        for s in gone.iter().copied().chain(self.client_stats()) {
            t.sent += s.sent;
            t.dropped += s.dropped;
            t.superseded += s.superseded;
            t.queued += s.queued;
        }
        t
    }
}

impl Drop for ViewServer {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        for c in self.shared.clients().iter() {
            c.close();
        }
        // Wake the accept loop with a connection of our own.
        let _ = TcpStream::connect_timeout(&self.addr, Duration::from_millis(200));
        if let Some(a) = self.accept.take() {
            let _ = a.join();
        }
    }
}

fn accept_loop(listener: &TcpListener, shared: &Arc<Shared>) {
    for stream in listener.incoming() {
        if shared.stop.load(Ordering::Relaxed) {
            return;
        }
        let stream = match stream {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!("accept failed: {e}");
                std::thread::sleep(Duration::from_millis(50));
                continue;
            }
        };
        if shared.clients().len() >= shared.limits.max_clients {
            tracing::warn!(
                "refusing {:?}: already {} clients",
                stream.peer_addr().ok(),
                shared.limits.max_clients
            );
            continue;
        }
        let shared = shared.clone();
        let spawned = std::thread::Builder::new()
            .name("view-client".into())
            .spawn(move || serve(stream, &shared));
        if let Err(e) = spawned {
            tracing::warn!("cannot start a client thread: {e}");
        }
    }
}

/// Picks the first subprotocol the client offers that is served here.
// The signature is tungstenite's handshake callback's.
#[allow(clippy::result_large_err)]
fn negotiate(req: &Request, mut resp: Response) -> Result<Response, ErrorResponse> {
    let offered: Vec<&str> = req
        .headers()
        .get_all("Sec-WebSocket-Protocol")
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(',').map(str::trim))
        .collect();
    match SUBPROTOCOLS.iter().find(|p| offered.contains(p)) {
        Some(p) => {
            resp.headers_mut()
                .insert("Sec-WebSocket-Protocol", HeaderValue::from_static(p));
            Ok(resp)
        }
        None => {
            let mut e = ErrorResponse::new(Some(format!(
                "offer a subprotocol among {}",
                SUBPROTOCOLS.join(", ")
            )));
            *e.status_mut() = StatusCode::BAD_REQUEST;
            Err(e)
        }
    }
}

/// The reading side of a client's socket: writes (pongs, close replies)
/// are discarded, the writer thread owns the socket's writing side.
struct ReadSide(TcpStream);

impl Read for ReadSide {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.0.read(buf)
    }
}

impl Write for ReadSide {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        Ok(buf.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

fn serve(stream: TcpStream, shared: &Arc<Shared>) {
    let peer = stream
        .peer_addr()
        .unwrap_or_else(|_| SocketAddr::from(([0, 0, 0, 0], 0)));
    if shared.stop.load(Ordering::Relaxed) {
        return;
    }
    let _ = stream.set_nodelay(true);
    if let Some(size) = shared.limits.send_buffer
        && let Err(e) =
            nix::sys::socket::setsockopt(&stream, nix::sys::socket::sockopt::SndBuf, &size)
    {
        tracing::warn!("{peer}: cannot set the send buffer: {e}");
    }
    // A client has this long to complete its handshake.
    let _ = stream.set_read_timeout(Some(Duration::from_secs(5)));
    let mut ws = match tungstenite::accept_hdr(stream, negotiate) {
        Ok(ws) => ws,
        Err(e) => {
            tracing::info!("{peer}: handshake refused: {e}");
            return;
        }
    };
    let reader = match ws.get_ref().try_clone() {
        Ok(s) => s,
        Err(e) => {
            tracing::warn!("{peer}: {e}");
            return;
        }
    };
    let _ = reader.set_read_timeout(None);
    let _ = ws
        .get_ref()
        .set_write_timeout(Some(shared.limits.write_timeout));
    let client = Arc::new(Client {
        id: shared.next_id.fetch_add(1, Ordering::Relaxed),
        addr: peer,
        outbox: Mutex::new(Outbox::default()),
        wake: Condvar::new(),
        subs: Mutex::new(vec![None; shared.channels.len()]),
        sent: AtomicU64::new(0),
        dropped: AtomicU64::new(0),
        superseded: AtomicU64::new(0),
    });
    tracing::info!("client {} connected from {peer}", client.id);
    shared.clients().push(client.clone());
    let read_thread = {
        let (client, shared) = (client.clone(), shared.clone());
        std::thread::Builder::new()
            .name("view-read".into())
            .spawn(move || read_loop(reader, &client, &shared))
    };
    match read_thread {
        Ok(r) => {
            if let Err(e) = write_loop(&mut ws, &client, shared) {
                tracing::info!("client {} ({peer}): {e}", client.id);
            }
            client.close();
            let _ = ws.get_ref().shutdown(Shutdown::Both);
            let _ = r.join();
        }
        Err(e) => tracing::warn!("{peer}: cannot start its reader: {e}"),
    }
    unsubscribe_all(&client, shared);
    let stats = client.stats();
    shared.clients().retain(|c| !Arc::ptr_eq(c, &client));
    shared
        .gone
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .push(stats);
    tracing::info!(
        "client {} gone: sent {}, dropped {}, superseded {}",
        stats.id,
        stats.sent,
        stats.dropped,
        stats.superseded
    );
}

fn write_loop(
    ws: &mut WebSocket<TcpStream>,
    client: &Client,
    shared: &Shared,
) -> Result<(), tungstenite::Error> {
    ws.send(Message::text(shared.server_info.clone()))?;
    ws.send(Message::text(shared.advertise.clone()))?;
    loop {
        let frame = {
            let mut o = client.outbox();
            loop {
                if o.closed {
                    return Ok(());
                }
                if let Some(f) = o.pop() {
                    break f;
                }
                o = client.wake.wait(o).unwrap_or_else(|p| p.into_inner());
            }
        };
        // Unsubscribed while it waited: not sent.
        let Some(sub) = client.subs().get(frame.channel as usize).copied().flatten() else {
            continue;
        };
        let bytes = MessageData::new(sub, frame.log_time, &frame.data[..]).to_bytes();
        ws.send(Message::binary(bytes))?;
        client.sent.fetch_add(1, Ordering::Relaxed);
    }
}

/// A channel a client advertised for publishing: topic, schema, encoding.
type ClientChannel = (String, String, String);

fn read_loop(stream: TcpStream, client: &Client, shared: &Shared) {
    let mut ws = WebSocket::from_raw_socket(ReadSide(stream), Role::Server, None);
    let mut published: HashMap<u32, ClientChannel> = HashMap::new();
    loop {
        let msg = match ws.read() {
            Ok(m) => m,
            Err(e) => {
                tracing::debug!("client {}: {e}", client.id);
                break;
            }
        };
        let text = match &msg {
            Message::Text(t) => t.as_str(),
            Message::Binary(b) => {
                match ClientMessage::parse_binary(b) {
                    Ok(ClientMessage::MessageData(m)) => {
                        take_pose(client, shared, published.get(&m.channel_id), &m.data);
                    }
                    Ok(other) => tracing::debug!("client {}: ignored {other:?}", client.id),
                    Err(e) => tracing::info!("client {}: unreadable message: {e}", client.id),
                }
                continue;
            }
            Message::Close(_) => break,
            _ => continue,
        };
        match ClientMessage::parse_json(text) {
            Ok(ClientMessage::Advertise(a)) if shared.poses.is_some() => {
                for c in a.channels {
                    if published.len() >= MAX_CLIENT_CHANNELS && !published.contains_key(&c.id) {
                        tracing::info!(
                            "client {}: over {MAX_CLIENT_CHANNELS} channels advertised, `{}` ignored",
                            client.id,
                            c.topic
                        );
                        continue;
                    }
                    tracing::info!(
                        "client {} publishes `{}` ({}, {})",
                        client.id,
                        c.topic,
                        c.schema_name,
                        c.encoding
                    );
                    published.insert(
                        c.id,
                        (
                            c.topic.into_owned(),
                            c.schema_name.into_owned(),
                            c.encoding.into_owned(),
                        ),
                    );
                }
            }
            Ok(ClientMessage::Unadvertise(u)) => {
                for id in u.channel_ids {
                    published.remove(&id);
                }
            }
            Ok(ClientMessage::Subscribe(s)) => {
                for sub in s.subscriptions {
                    subscribe(client, shared, sub.id, sub.channel_id);
                }
            }
            Ok(ClientMessage::Unsubscribe(u)) => {
                let mut subs = client.subs();
                for slot in subs.iter_mut() {
                    if slot.is_some_and(|s| u.subscription_ids.contains(&s)) {
                        *slot = None;
                    }
                }
                drop(subs);
                recount(shared);
            }
            Ok(other) => tracing::debug!("client {}: ignored {other:?}", client.id),
            Err(e) => tracing::info!("client {}: unreadable message: {e}", client.id),
        }
    }
    client.close();
}

/// A message a client published on `channel`: a "2D Pose Estimate" on
/// [`INITIAL_POSE_TOPIC`] in CDR is decoded and handed on; anything else
/// is refused (counted, and logged with the reason).
fn take_pose(client: &Client, shared: &Shared, channel: Option<&ClientChannel>, data: &[u8]) {
    let refuse = |why: &str| {
        shared.poses_refused.fetch_add(1, Ordering::Relaxed);
        tracing::warn!("client {}: published message refused: {why}", client.id);
    };
    let Some(poses) = &shared.poses else {
        return refuse("this view takes no messages (smokenav-view --initial-pose)");
    };
    let Some((topic, schema, encoding)) = channel else {
        return refuse("on a channel it did not advertise");
    };
    if topic.trim_start_matches('/') != INITIAL_POSE_TOPIC.trim_start_matches('/')
        || schema != INITIAL_POSE_SCHEMA
        || encoding != "cdr"
    {
        return refuse(&format!(
            "`{topic}` ({schema}, {encoding}): only {INITIAL_POSE_TOPIC} ({INITIAL_POSE_SCHEMA}, cdr) is taken"
        ));
    }
    match initial_pose::decode(data) {
        Ok(pose) => match poses.try_send(pose) {
            Ok(()) => {
                shared.poses_taken.fetch_add(1, Ordering::Relaxed);
            }
            Err(TrySendError::Full(_)) => refuse("poses arrive faster than they are handed on"),
            Err(TrySendError::Disconnected(_)) => refuse("the view is shutting down"),
        },
        Err(e) => refuse(&e.to_string()),
    }
}

fn subscribe(client: &Client, shared: &Shared, sub: u32, channel: u64) {
    let Some(def) = usize::try_from(channel)
        .ok()
        .and_then(|i| shared.channels.get(i))
    else {
        tracing::info!("client {}: no channel {channel}", client.id);
        return;
    };
    client.subs()[def.id as usize] = Some(sub);
    recount(shared);
    if def.latched {
        let last = shared.last.lock().unwrap_or_else(|p| p.into_inner())[def.id as usize].clone();
        if let Some(f) = last {
            client.push(f, def.lane, shared.limits.stream_queue);
        }
    }
}

fn unsubscribe_all(client: &Client, shared: &Shared) {
    client.subs().iter_mut().for_each(|s| *s = None);
    recount(shared);
}

/// Recomputes how many clients watch each channel.
fn recount(shared: &Shared) {
    let clients = shared.clients();
    for (i, w) in shared.watched.iter().enumerate() {
        let n = clients
            .iter()
            .filter(|c| c.subs().get(i).copied().flatten().is_some())
            .count();
        w.store(n as u64, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::channels::channel_table;
    use foxglove::websocket::ws_protocol::server::ServerMessage;

    fn frame(channel: u32, n: u8) -> Frame {
        Frame {
            channel,
            log_time: u64::from(n),
            data: Arc::from(&[n][..]),
        }
    }

    fn client() -> Client {
        Client {
            id: 1,
            addr: SocketAddr::from(([127, 0, 0, 1], 1)),
            outbox: Mutex::new(Outbox::default()),
            wake: Condvar::new(),
            subs: Mutex::new(Vec::new()),
            sent: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            superseded: AtomicU64::new(0),
        }
    }

    #[test]
    fn a_full_stream_queue_drops_its_oldest_and_counts_it() {
        let c = client();
        for n in 0..5 {
            c.push(frame(0, n), Lane::Stream, 3);
        }
        assert_eq!(c.stats().dropped, 2);
        let left: Vec<u64> = std::iter::from_fn(|| c.outbox().pop())
            .map(|f| f.log_time)
            .collect();
        assert_eq!(left, [2, 3, 4]);
    }

    #[test]
    fn the_newest_map_overtakes_a_full_stream_queue() {
        let c = client();
        for n in 0..3 {
            c.push(frame(0, n), Lane::Stream, 3);
        }
        c.push(frame(7, 10), Lane::Latest, 3);
        c.push(frame(7, 11), Lane::Latest, 3);
        for n in 3..6 {
            c.push(frame(0, n), Lane::Stream, 3);
        }
        let s = c.stats();
        assert_eq!((s.dropped, s.superseded, s.queued), (3, 1, 4));
        let first = c.outbox().pop().unwrap();
        assert_eq!((first.channel, first.log_time), (7, 11));
        assert_eq!(c.outbox().pop().unwrap().log_time, 3);
    }

    fn read_json(ws: &mut WebSocket<TcpStream>) -> serde_json::Value {
        match ws.read().unwrap() {
            Message::Text(t) => serde_json::from_str(t.as_str()).unwrap(),
            other => panic!("not text: {other:?}"),
        }
    }

    #[test]
    fn a_client_gets_the_advertised_channels_and_what_it_subscribed_to() {
        let topics = vec!["laser/scan".to_owned(), "slam/map".to_owned()];
        let server = ViewServer::start(
            "127.0.0.1:0",
            "test",
            channel_table(&topics, false),
            Limits::default(),
        )
        .unwrap();
        let map = server
            .channels()
            .iter()
            .find(|c| c.topic == "/slam/map")
            .unwrap()
            .id;
        // Latched: a late subscriber gets it.
        server.publish(map, 5, b"old map");
        server.publish(map, 6, b"map");
        let (mut ws, resp) = connect(&server, "foxglove.websocket.v1").unwrap();
        assert_eq!(
            resp.headers().get("Sec-WebSocket-Protocol").unwrap(),
            "foxglove.websocket.v1"
        );
        assert_eq!(read_json(&mut ws)["op"], "serverInfo");
        let adv = read_json(&mut ws);
        assert_eq!(adv["op"], "advertise");
        let scan = adv["channels"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["topic"] == "/laser/scan")
            .unwrap();
        assert_eq!(scan["schemaName"], "sensor_msgs/msg/LaserScan");
        assert_eq!(scan["encoding"], "cdr");
        assert_eq!(scan["schemaEncoding"], "ros2msg");
        let scan_id = scan["id"].as_u64().unwrap();
        ws.send(Message::text(format!(
            r#"{{"op":"subscribe","subscriptions":[{{"id":40,"channelId":{scan_id}}},{{"id":41,"channelId":{map}}}]}}"#
        )))
        .unwrap();
        let mut got = Vec::new();
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        while got.len() < 2 && std::time::Instant::now() < deadline {
            server.publish(scan_id as u32, 9, b"scan");
            std::thread::sleep(Duration::from_millis(20));
            ws.get_ref()
                .set_read_timeout(Some(Duration::from_millis(50)))
                .unwrap();
            while let Ok(m) = ws.read() {
                let Message::Binary(b) = &m else { continue };
                if let Ok(ServerMessage::MessageData(d)) = ServerMessage::parse_binary(b) {
                    let entry = (d.subscription_id, d.log_time, d.data.to_vec());
                    if !got.contains(&entry) {
                        got.push(entry);
                    }
                }
            }
        }
        assert!(got.contains(&(41, 6, b"map".to_vec())), "{got:?}");
        assert!(got.contains(&(40, 9, b"scan".to_vec())), "{got:?}");
        assert_eq!(server.client_stats().len(), 1);
        assert_eq!(server.client_stats()[0].dropped, 0);
    }

    /// A client asking for `subprotocol`, and the server's answer.
    fn connect(
        server: &ViewServer,
        subprotocol: &'static str,
    ) -> Result<
        (
            WebSocket<TcpStream>,
            tungstenite::handshake::client::Response,
        ),
        String,
    > {
        let mut req = tungstenite::client::IntoClientRequest::into_client_request(format!(
            "ws://{}",
            server.local_addr()
        ))
        .unwrap();
        req.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            HeaderValue::from_static(subprotocol),
        );
        let tcp = TcpStream::connect(server.local_addr()).unwrap();
        tungstenite::client(req, tcp).map_err(|e| e.to_string())
    }

    /// A client message: opcode 1, channel id, payload.
    fn published(channel: u32, payload: &[u8]) -> Message {
        let mut b = vec![1u8];
        b.extend_from_slice(&channel.to_le_bytes());
        b.extend_from_slice(payload);
        Message::binary(b)
    }

    /// Foxglove's "2D Pose Estimate": a view taking poses says it accepts
    /// client publishing in CDR, hands a valid `/initialpose` on, and
    /// refuses (counting) another topic, a pose in `odom` and a channel
    /// never advertised; a view that takes none says nothing of it and
    /// refuses everything.
    #[test]
    fn a_client_pose_estimate_is_handed_on_and_nothing_else_is() {
        use smokenav_platform_recording::initial_pose::{PlanarPose, encode};
        let (tx, rx) = std::sync::mpsc::sync_channel(4);
        let server = ViewServer::start_taking_poses(
            "127.0.0.1:0",
            "test",
            Vec::new(),
            Limits::default(),
            tx,
        )
        .unwrap();
        let mut ws = connect(&server, "foxglove.websocket.v1").unwrap().0;
        let info = read_json(&mut ws);
        assert_eq!(
            info["capabilities"],
            serde_json::json!(["clientPublish"]),
            "{info}"
        );
        assert_eq!(
            info["supportedEncodings"],
            serde_json::json!(["cdr"]),
            "{info}"
        );
        ws.send(Message::text(
            r#"{"op":"advertise","channels":[{"id":7,"topic":"/initialpose","encoding":"cdr","schemaName":"geometry_msgs/msg/PoseWithCovarianceStamped"},{"id":8,"topic":"/cmd_vel","encoding":"cdr","schemaName":"geometry_msgs/msg/Twist"}]}"#,
        ))
        .unwrap();
        let pose = PlanarPose {
            x: 1.5,
            y: -2.0,
            yaw: 0.7,
            var_x: 0.25,
            var_y: 0.25,
            var_yaw: 0.07,
        };
        ws.send(published(8, &[0, 1, 0, 0])).unwrap();
        ws.send(published(9, &encode("map", &pose))).unwrap();
        ws.send(published(7, &encode("odom", &pose))).unwrap();
        ws.send(published(7, &encode("map", &pose))).unwrap();
        let got = rx.recv_timeout(Duration::from_secs(10)).unwrap();
        assert!(
            (got.x - 1.5).abs() < 1e-12 && (got.yaw - 0.7).abs() < 1e-12,
            "{got:?}"
        );
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        // The counters follow the hand-over on the client's reader thread.
        let want = PoseStats {
            taken: 1,
            refused: 3,
        };
        while server.pose_stats() != want && std::time::Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(server.pose_stats(), want);
        assert!(rx.try_recv().is_err());

        let watch_only =
            ViewServer::start("127.0.0.1:0", "test", Vec::new(), Limits::default()).unwrap();
        let mut ws = connect(&watch_only, "foxglove.websocket.v1").unwrap().0;
        let info = read_json(&mut ws);
        assert!(
            info.get("capabilities")
                .is_none_or(|c| c == &serde_json::json!([])),
            "{info}"
        );
        ws.send(Message::text(
            r#"{"op":"advertise","channels":[{"id":7,"topic":"/initialpose","encoding":"cdr","schemaName":"geometry_msgs/msg/PoseWithCovarianceStamped"}]}"#,
        ))
        .unwrap();
        ws.send(published(7, &encode("map", &pose))).unwrap();
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        while watch_only.pose_stats().refused < 1 && std::time::Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(
            watch_only.pose_stats(),
            PoseStats {
                taken: 0,
                refused: 1
            }
        );
    }

    #[test]
    fn a_client_without_the_subprotocol_is_refused() {
        let server =
            ViewServer::start("127.0.0.1:0", "test", Vec::new(), Limits::default()).unwrap();
        let tcp = TcpStream::connect(server.local_addr()).unwrap();
        let err = tungstenite::client(format!("ws://{}", server.local_addr()), tcp).unwrap_err();
        assert!(
            matches!(err, tungstenite::HandshakeError::Failure(tungstenite::Error::Http(ref r)) if r.status() == 400),
            "{err}"
        );
    }

    #[test]
    fn clients_beyond_the_limit_are_refused() {
        let limits = Limits {
            max_clients: 1,
            ..Limits::default()
        };
        let server = ViewServer::start("127.0.0.1:0", "test", Vec::new(), limits).unwrap();
        let (mut first, _) = connect(&server, "foxglove.sdk.v1").unwrap();
        assert_eq!(read_json(&mut first)["op"], "serverInfo");
        assert!(
            connect(&server, "foxglove.sdk.v1").is_err(),
            "a second client was served"
        );
        assert_eq!(server.client_stats().len(), 1);
    }
}
