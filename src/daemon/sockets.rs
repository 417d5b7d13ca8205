//! Datagram sockets the daemon listens on, UDP or Unix alike, and the Unix socket files it owns.

use std::io;
use std::net::SocketAddr;
use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::path::{Path, PathBuf};

use tokio::net::{UdpSocket, UnixDatagram, UnixListener};
use tracing::warn;

use crate::protocol::address::Address;

/// Largest datagram read; longer ones are truncated by the kernel and then refused by the decoders.
pub const MAX_DATAGRAM: usize = 65_536;

/// Who sent a datagram, to answer them.
#[derive(Debug)]
pub enum Peer {
    /// A UDP sender.
    Udp(SocketAddr),
    /// A Unix datagram sender bound to a path.
    Unix(PathBuf),
    /// A Unix sender that cannot be answered (unbound).
    Unnamed,
}

/// A bound datagram socket.
#[derive(Debug)]
pub enum Datagram {
    /// UDP.
    Udp(UdpSocket),
    /// Unix datagram, with the file it removes when dropped.
    Unix(UnixDatagram, SocketFile),
}

impl Datagram {
    /// Binds `address`. Unix sockets replace a stale socket file and are made owner/group-only.
    pub fn bind(address: &Address) -> io::Result<Self> {
        match address {
            Address::Udp(address) => bind_udp(*address, false).map(Self::Udp),
            Address::Unix(path) => {
                let file = SocketFile::prepare(path)?;
                let socket = UnixDatagram::bind(path)?;
                file.restrict()?;
                Ok(Self::Unix(socket, file))
            }
        }
    }

    /// Receives one datagram into `buffer`.
    pub async fn recv_from(&self, buffer: &mut [u8]) -> io::Result<(usize, Peer)> {
        match self {
            Self::Udp(socket) => {
                let (length, peer) = socket.recv_from(buffer).await?;
                Ok((length, Peer::Udp(peer)))
            }
            Self::Unix(socket, _) => {
                let (length, peer) = socket.recv_from(buffer).await?;
                Ok((length, peer.as_pathname().map_or(Peer::Unnamed, |path| Peer::Unix(path.into()))))
            }
        }
    }

    /// Answers `peer` without waiting: a peer whose queue is full (one that never reads) loses the
    /// answer instead of stalling the socket. An unnamed peer cannot be answered and is skipped.
    pub fn try_send_to(&self, bytes: &[u8], peer: &Peer) -> io::Result<()> {
        match (self, peer) {
            (Self::Udp(socket), Peer::Udp(address)) => socket.try_send_to(bytes, *address).map(drop),
            (Self::Unix(socket, _), Peer::Unix(path)) => socket.try_send_to(bytes, path).map(drop),
            _ => Ok(()),
        }
    }
}

/// Binds a UDP socket; a `shared` one lets other processes bind the same port (SO_REUSEADDR and
/// SO_REUSEPORT), as the team's process and relocd both hear the GameController's broadcasts.
pub fn bind_udp(address: SocketAddr, shared: bool) -> io::Result<UdpSocket> {
    let socket = socket2::Socket::new(
        socket2::Domain::for_address(address),
        socket2::Type::DGRAM,
        Some(socket2::Protocol::UDP),
    )?;
    if shared {
        socket.set_reuse_address(true)?;
        socket.set_reuse_port(true)?;
    }
    socket.set_nonblocking(true)?;
    socket.bind(&address.into())?;
    UdpSocket::from_std(socket.into())
}

/// A Unix stream listener (forwarded frames) with the file it removes when dropped.
#[derive(Debug)]
pub struct StreamListener {
    /// The listener.
    pub listener: UnixListener,
    _file: SocketFile,
}

/// Binds a Unix stream listener with the same rules as [`Datagram::bind`].
pub fn bind_stream(path: &Path) -> io::Result<StreamListener> {
    let file = SocketFile::prepare(path)?;
    let listener = UnixListener::bind(path)?;
    file.restrict()?;
    Ok(StreamListener { listener, _file: file })
}

/// A Unix socket file relocd created; removed when dropped.
#[derive(Debug)]
pub struct SocketFile(PathBuf);

impl SocketFile {
    /// Removes a stale socket left by an earlier run; refuses to replace a socket something still
    /// listens on, or anything that is not a socket.
    fn prepare(path: &Path) -> io::Result<Self> {
        match std::fs::symlink_metadata(path) {
            Ok(metadata) if metadata.file_type().is_socket() => {
                let probe = std::os::unix::net::UnixDatagram::unbound()?;
                match probe.connect(path) {
                    Err(error) if error.kind() == io::ErrorKind::ConnectionRefused => {
                        std::fs::remove_file(path)?
                    }
                    _ => {
                        return Err(io::Error::new(
                            io::ErrorKind::AddrInUse,
                            format!("{} is in use by another process", path.display()),
                        ));
                    }
                }
            }
            Ok(_) => {
                return Err(io::Error::new(
                    io::ErrorKind::AlreadyExists,
                    format!("{} exists and is not a socket; relocd will not replace it", path.display()),
                ));
            }
            Err(error) if error.kind() == io::ErrorKind::NotFound => {}
            Err(error) => return Err(error),
        }
        Ok(Self(path.to_path_buf()))
    }

    /// Owner and group only.
    fn restrict(&self) -> io::Result<()> {
        std::fs::set_permissions(&self.0, std::fs::Permissions::from_mode(0o660))
    }
}

impl Drop for SocketFile {
    fn drop(&mut self) {
        if let Err(error) = std::fs::remove_file(&self.0)
            && error.kind() != io::ErrorKind::NotFound
        {
            warn!("cannot remove {}: {error}", self.0.display());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn unix_sockets_are_private_replace_stale_files_and_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("control");
        let stale = std::os::unix::net::UnixDatagram::bind(&path).unwrap();
        drop(stale);
        let socket = Datagram::bind(&Address::Unix(path.clone())).unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o660);

        let client_path = dir.path().join("client");
        let client = std::os::unix::net::UnixDatagram::bind(&client_path).unwrap();
        client.send_to(b"ping", &path).unwrap();
        let mut buffer = [0u8; 16];
        let (length, peer) = socket.recv_from(&mut buffer).await.unwrap();
        assert_eq!(&buffer[..length], b"ping");
        socket.try_send_to(b"pong", &peer).unwrap();
        assert_eq!(client.recv(&mut buffer).unwrap(), 4);

        drop(socket);
        assert!(!path.exists(), "the socket file goes with the socket");
    }

    #[test]
    fn a_live_socket_is_never_taken_over() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sensors");
        let _owner = std::os::unix::net::UnixDatagram::bind(&path).unwrap();
        let error = SocketFile::prepare(&path).unwrap_err();
        assert!(error.to_string().contains("in use"), "{error}");
        assert!(path.exists());
    }

    #[test]
    fn a_regular_file_is_never_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("precious");
        std::fs::write(&path, "data").unwrap();
        let error = Datagram::bind(&Address::Unix(path.clone())).unwrap_err();
        assert!(error.to_string().contains("not a socket"));
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "data");
    }
}
