//! A client for the team's Rust code: receive relocd's hypotheses and ask it to relocalise.
//!
//! Blocking std sockets, nothing else: call [`Subscriber::try_recv`] once per cycle of your
//! localisation, or [`Subscriber::recv`] from a thread of its own.
//!
//! ```no_run
//! use std::time::Duration;
//! use relocd::client::{Control, Subscriber};
//!
//! # fn main() -> Result<(), relocd::client::ClientError> {
//! let mut hypotheses = Subscriber::bind(&"udp:127.0.0.1:5454".parse()?)?;
//! let control = Control::connect(&"unix:/tmp/relocd-control".parse()?)?;
//! let trigger = control.relocalise(Some("particle filter diverged"), None)?;
//! let message = hypotheses.recv_answer(trigger, Duration::from_secs(5))?;
//! if let Some(best) = message.hypotheses.first() {
//!     println!("x {:.2} m, y {:.2} m, θ {:.2} rad, weight {:.2}", best.x, best.y, best.theta, best.weight);
//! }
//! # Ok(())
//! # }
//! ```

use std::io;
use std::net::{Ipv4Addr, Ipv6Addr, SocketAddr, UdpSocket};
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use thiserror::Error;

pub use crate::protocol::address::Address;
pub use crate::protocol::control::{
    BallInput, OwnBallInput, PoseInput, PriorInput, RelocaliseRequest, SigmaInput, TeamBallInput,
};
use crate::protocol::control::{ControlRequest, StatusRequest};
pub use crate::protocol::message::{Hypothesis, Message, MessageError, Trigger, TriggerKind};

/// Largest datagram relocd sends.
const MAX_DATAGRAM: usize = 65_536;
/// How long [`Control`] waits for the daemon's answer.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(2);

/// What went wrong talking to relocd.
#[derive(Debug, Error)]
pub enum ClientError {
    /// A socket call failed.
    #[error("{0}")]
    Io(#[from] io::Error),
    /// Nothing arrived in time.
    #[error("no answer from relocd within {0:?}")]
    Timeout(Duration),
    /// A datagram that is not a valid relocd message.
    #[error(transparent)]
    Message(#[from] MessageError),
    /// The daemon refused a control request.
    #[error("relocd refused the request: {0}")]
    Refused(String),
    /// An answer that is not in the protocol.
    #[error("unexpected answer from relocd: {0}")]
    Unexpected(String),
    /// An address that is not `udp:IP:PORT` or `unix:PATH`.
    #[error("{0}")]
    Address(String),
}

impl From<String> for ClientError {
    fn from(reason: String) -> Self {
        Self::Address(reason)
    }
}

/// A datagram socket, UDP or Unix; a Unix one removes its file when dropped.
#[derive(Debug)]
enum Socket {
    Udp(UdpSocket),
    Unix(UnixDatagram, PathBuf),
}

impl Socket {
    fn bind(address: &Address) -> io::Result<Self> {
        match address {
            Address::Udp(address) => UdpSocket::bind(address).map(Self::Udp),
            Address::Unix(path) => {
                remove_stale_socket(path)?;
                UnixDatagram::bind(path).map(|socket| Self::Unix(socket, path.clone()))
            }
        }
    }

    fn set_read_timeout(&self, timeout: Option<Duration>) -> io::Result<()> {
        match self {
            Self::Udp(socket) => socket.set_read_timeout(timeout),
            Self::Unix(socket, _) => socket.set_read_timeout(timeout),
        }
    }

    fn set_nonblocking(&self, nonblocking: bool) -> io::Result<()> {
        match self {
            Self::Udp(socket) => socket.set_nonblocking(nonblocking),
            Self::Unix(socket, _) => socket.set_nonblocking(nonblocking),
        }
    }

    fn recv(&self, buffer: &mut [u8]) -> io::Result<usize> {
        match self {
            Self::Udp(socket) => socket.recv(buffer),
            Self::Unix(socket, _) => socket.recv(buffer),
        }
    }
}

impl Drop for Socket {
    fn drop(&mut self) {
        if let Self::Unix(_, path) = self {
            let _ = std::fs::remove_file(path);
        }
    }
}

/// Removes a socket file left behind by a process that died; refuses a live socket (another
/// process receives on it) and anything that is not a socket.
fn remove_stale_socket(path: &Path) -> io::Result<()> {
    use std::os::unix::fs::FileTypeExt;
    match std::fs::symlink_metadata(path) {
        Ok(metadata) if metadata.file_type().is_socket() => {
            if UnixDatagram::unbound()?.connect(path).is_ok() {
                return Err(io::Error::new(
                    io::ErrorKind::AddrInUse,
                    format!("{} is in use by another process", path.display()),
                ));
            }
            std::fs::remove_file(path)
        }
        Ok(_) => Err(io::Error::new(
            io::ErrorKind::AlreadyExists,
            format!("{} exists and is not a socket", path.display()),
        )),
        Err(error) if error.kind() == io::ErrorKind::NotFound => Ok(()),
        Err(error) => Err(error),
    }
}

/// Receives the hypotheses messages relocd publishes to one of its `publish.targets`.
#[derive(Debug)]
pub struct Subscriber {
    socket: Socket,
    buffer: Vec<u8>,
}

impl Subscriber {
    /// Binds the address relocd publishes to (`udp:IP:PORT`, or `unix:PATH` for a socket file this
    /// subscriber creates and removes when dropped).
    pub fn bind(address: &Address) -> Result<Self, ClientError> {
        Ok(Self { socket: Socket::bind(address)?, buffer: vec![0; MAX_DATAGRAM] })
    }

    /// The UDP address bound (useful after binding port 0); `None` for a Unix socket.
    pub fn local_udp_address(&self) -> Option<SocketAddr> {
        match &self.socket {
            Socket::Udp(socket) => socket.local_addr().ok(),
            Socket::Unix(..) => None,
        }
    }

    /// Waits up to `timeout` for the next message. A datagram that is not a valid message is an
    /// error; the next call reads the next datagram.
    pub fn recv(&mut self, timeout: Duration) -> Result<Message, ClientError> {
        self.socket.set_nonblocking(false)?;
        self.socket.set_read_timeout(Some(timeout.max(Duration::from_millis(1))))?;
        match self.socket.recv(&mut self.buffer) {
            Ok(length) => Ok(Message::decode(&self.buffer[..length])?),
            Err(error) if is_timeout(&error) => Err(ClientError::Timeout(timeout)),
            Err(error) => Err(error.into()),
        }
    }

    /// The next message if one is waiting, without blocking.
    pub fn try_recv(&mut self) -> Result<Option<Message>, ClientError> {
        self.socket.set_nonblocking(true)?;
        match self.socket.recv(&mut self.buffer) {
            Ok(length) => Ok(Some(Message::decode(&self.buffer[..length])?)),
            Err(error) if is_timeout(&error) => Ok(None),
            Err(error) => Err(error.into()),
        }
    }

    /// Waits up to `timeout` for the message that answers trigger `id` (from [`Control::relocalise`]),
    /// skipping messages for other triggers and datagrams that are not messages.
    pub fn recv_answer(&mut self, id: u64, timeout: Duration) -> Result<Message, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(ClientError::Timeout(timeout));
            }
            match self.recv(left) {
                Ok(message) if message.triggers.iter().any(|trigger| trigger.id == id) => return Ok(message),
                Ok(_) | Err(ClientError::Message(_)) => continue,
                Err(ClientError::Timeout(_)) => return Err(ClientError::Timeout(timeout)),
                Err(error) => return Err(error),
            }
        }
    }
}

fn is_timeout(error: &io::Error) -> bool {
    matches!(error.kind(), io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut)
}

/// Talks to relocd's control socket: asks for relocalisations and for its status.
#[derive(Debug)]
pub struct Control {
    socket: Socket,
    daemon: Address,
}

impl Control {
    /// Opens a socket to send requests to `daemon` (relocd's `control` address) and receive its answers.
    /// For a Unix control socket, the answers come to a socket file in the temporary directory,
    /// removed when this is dropped.
    pub fn connect(daemon: &Address) -> Result<Self, ClientError> {
        static CLIENTS: AtomicU64 = AtomicU64::new(0);
        let own = match daemon {
            Address::Udp(address) => Address::Udp(match (address.ip().is_loopback(), address) {
                (true, SocketAddr::V4(_)) => (Ipv4Addr::LOCALHOST, 0).into(),
                (true, SocketAddr::V6(_)) => (Ipv6Addr::LOCALHOST, 0).into(),
                (false, SocketAddr::V4(_)) => (Ipv4Addr::UNSPECIFIED, 0).into(),
                (false, SocketAddr::V6(_)) => (Ipv6Addr::UNSPECIFIED, 0).into(),
            }),
            Address::Unix(_) => {
                let number = CLIENTS.fetch_add(1, Ordering::Relaxed);
                let name = format!("relocd-client-{}-{number}", std::process::id());
                Address::Unix(std::env::temp_dir().join(name))
            }
        };
        let socket = Socket::bind(&own)?;
        socket.set_read_timeout(Some(ANSWER_TIMEOUT))?;
        Ok(Self { socket, daemon: daemon.clone() })
    }

    /// Asks relocd to relocalise now; returns the trigger id that the published message will list:
    /// the request's own, or, when relocd had too many requests waiting, the waiting one it joined
    /// (`coalesced_into`). `head_yaw` (radians, positive left) is the head yaw the frames will be taken
    /// with, if known.
    pub fn relocalise(&self, reason: Option<&str>, head_yaw: Option<f64>) -> Result<u64, ClientError> {
        let request = RelocaliseRequest { reason: reason.map(str::to_owned), head_yaw, ..Default::default() };
        Ok(self.relocalise_with(&request)?.trigger)
    }

    /// Asks relocd to relocalise now with context that tells the symmetric twins apart (`prior`,
    /// `own_half`, `ball`; docs/protocol.md). Context relocd could not use is left out and named in
    /// the answer's `context_errors`; the relocalisation runs anyway.
    pub fn relocalise_with(&self, request: &RelocaliseRequest) -> Result<Accepted, ClientError> {
        let accepted = self.ask(&ControlRequest::Relocalise(request.clone()), "accepted")?;
        let id = |key: &str| accepted.get(key).and_then(serde_json::Value::as_u64);
        let trigger = id("coalesced_into")
            .or(id("trigger"))
            .ok_or_else(|| ClientError::Unexpected(accepted.to_string()))?;
        let context_errors = accepted
            .get("context_errors")
            .and_then(serde_json::Value::as_array)
            .map(|errors| errors.iter().filter_map(|e| e.as_str().map(str::to_owned)).collect())
            .unwrap_or_default();
        Ok(Accepted { trigger, context_errors })
    }

    /// Sends the team's current pose estimate (the belief stream, 1–10 Hz): relocd keeps it, and the
    /// last one from before a fall or pick-up becomes that relocalisation's prior. Not answered; a
    /// refused one is logged and counted by relocd.
    pub fn belief(&self, pose: &PoseInput) -> Result<(), ClientError> {
        self.send(&ControlRequest::Belief(*pose))
    }

    /// relocd's counters, game state and last latencies (see docs/protocol.md).
    pub fn status(&self) -> Result<serde_json::Value, ClientError> {
        self.ask(&ControlRequest::Status(StatusRequest {}), "status")
    }

    /// Sends `request` and returns the `key` member of its answer. Answers that arrived after an
    /// earlier request timed out are discarded first, so they cannot pass for this one's.
    fn ask(&self, request: &ControlRequest, key: &str) -> Result<serde_json::Value, ClientError> {
        let mut buffer = vec![0; MAX_DATAGRAM];
        self.socket.set_nonblocking(true)?;
        while self.socket.recv(&mut buffer).is_ok() {}
        self.socket.set_nonblocking(false)?;
        self.send(request)?;
        let length = match self.socket.recv(&mut buffer) {
            Ok(length) => length,
            Err(error) if is_timeout(&error) => return Err(ClientError::Timeout(ANSWER_TIMEOUT)),
            Err(error) => return Err(error.into()),
        };
        let text = String::from_utf8_lossy(&buffer[..length]);
        let mut answer: serde_json::Value = serde_json::from_str(&text)
            .map_err(|error| ClientError::Unexpected(format!("{error}: {text}")))?;
        if let Some(reason) = answer.get("error").and_then(serde_json::Value::as_str) {
            return Err(ClientError::Refused(reason.to_owned()));
        }
        answer
            .get_mut(key)
            .map(serde_json::Value::take)
            .ok_or_else(|| ClientError::Unexpected(text.into_owned()))
    }

    fn send(&self, request: &ControlRequest) -> Result<(), ClientError> {
        let bytes = serde_json::to_vec(request).expect("a request is plain data");
        match (&self.socket, &self.daemon) {
            (Socket::Udp(socket), Address::Udp(address)) => socket.send_to(&bytes, address)?,
            (Socket::Unix(socket, _), Address::Unix(path)) => socket.send_to(&bytes, path)?,
            _ => unreachable!("connect binds a socket of the daemon's kind"),
        };
        Ok(())
    }
}

/// relocd's answer to a relocalise request.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Accepted {
    /// The trigger id the published message will list.
    pub trigger: u64,
    /// Context left out, each naming its key and why.
    pub context_errors: Vec<String>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Representation;
    use crate::protocol::message::{Encoding, FrameCounts, Latency, ModelInfo, SCHEMA_VERSION};

    fn message(trigger: u64) -> Message {
        Message {
            schema: SCHEMA_VERSION,
            seq: trigger,
            published: 1.0,
            captured: None,
            triggers: vec![Trigger { id: trigger, kind: TriggerKind::Request, reason: None, t: 0.5 }],
            model: ModelInfo { id: "m".into(), representation: Representation::HalfPoint },
            frames: FrameCounts { requested: 1, used: 0, agreeing: 0 },
            prior: None,
            priors: vec![],
            latency_ms: Latency::default(),
            hypotheses: vec![],
            failure: Some("no frames".into()),
        }
    }

    #[test]
    fn a_subscriber_skips_to_the_answer_it_waits_for() {
        let mut subscriber = Subscriber::bind(&"udp:127.0.0.1:0".parse().unwrap()).unwrap();
        let address = subscriber.local_udp_address().unwrap();
        let sender = UdpSocket::bind("127.0.0.1:0").unwrap();
        sender.send_to(&message(1).encode(Encoding::Json), address).unwrap();
        sender.send_to(b"garbage", address).unwrap();
        sender.send_to(&message(2).encode(Encoding::Msgpack), address).unwrap();
        assert_eq!(subscriber.recv_answer(2, Duration::from_secs(5)).unwrap(), message(2));
        assert!(subscriber.try_recv().unwrap().is_none());
        assert!(matches!(subscriber.recv(Duration::from_millis(10)), Err(ClientError::Timeout(_))));
        sender.send_to(b"{\"schema\": 9}", address).unwrap();
        assert!(matches!(subscriber.recv(Duration::from_secs(5)), Err(ClientError::Message(_))));
    }

    #[test]
    fn a_unix_subscriber_removes_its_socket_and_never_takes_over_another() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("hypotheses");
        let address = Address::Unix(path.clone());
        drop(Subscriber::bind(&address).unwrap());
        assert!(!path.exists());
        let live = Subscriber::bind(&address).unwrap();
        assert!(
            matches!(Subscriber::bind(&address), Err(ClientError::Io(error)) if error.kind() == io::ErrorKind::AddrInUse)
        );
        drop(live);
        std::fs::write(&path, "not a socket").unwrap();
        assert!(matches!(Subscriber::bind(&address), Err(ClientError::Io(_))));
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "not a socket");
    }

    #[test]
    fn control_requests_are_the_protocols_json() {
        let request = ControlRequest::Relocalise(RelocaliseRequest {
            reason: Some("lost".into()),
            ..RelocaliseRequest::default()
        });
        assert_eq!(serde_json::to_string(&request).unwrap(), r#"{"relocalise":{"reason":"lost"}}"#);
        assert_eq!(
            serde_json::to_string(&ControlRequest::Status(StatusRequest {})).unwrap(),
            r#"{"status":{}}"#
        );
    }

    #[test]
    fn a_late_answer_is_not_taken_for_the_next_requests() {
        let daemon = UdpSocket::bind("127.0.0.1:0").unwrap();
        let control = Control::connect(&Address::Udp(daemon.local_addr().unwrap())).unwrap();
        assert!(matches!(control.status(), Err(ClientError::Timeout(_))));

        let mut buffer = [0u8; 512];
        let (_, client) = daemon.recv_from(&mut buffer).unwrap();
        daemon.send_to(br#"{"status": {"late": true}}"#, client).unwrap();
        let answering = std::thread::spawn(move || {
            let (length, client) = daemon.recv_from(&mut buffer).unwrap();
            assert_eq!(&buffer[..length], br#"{"relocalise":{}}"#);
            daemon.send_to(br#"{"accepted": {"trigger": 2}}"#, client).unwrap();
        });
        std::thread::sleep(Duration::from_millis(50));
        assert_eq!(control.relocalise(None, None).unwrap(), 2);
        answering.join().unwrap();
    }
}
