//! Publishing: one datagram per message to every target. A target that is missing or refuses is
//! logged and counted; it never blocks or stops the daemon.

use std::io;
use std::net::{Ipv4Addr, Ipv6Addr, SocketAddr, UdpSocket};
use std::os::unix::net::UnixDatagram;

use tracing::{debug, warn};

use crate::protocol::address::Address;
use crate::protocol::message::{Encoding, Message};

/// Sends messages to the configured targets.
#[derive(Debug)]
pub struct Publisher {
    targets: Vec<Address>,
    encoding: Encoding,
    udp4: UdpSocket,
    udp6: Option<UdpSocket>,
    unix: UnixDatagram,
}

impl Publisher {
    /// Sockets for `targets`; nothing is sent yet.
    pub fn new(targets: Vec<Address>, encoding: Encoding) -> io::Result<Self> {
        let udp4 = UdpSocket::bind((Ipv4Addr::UNSPECIFIED, 0))?;
        udp4.set_nonblocking(true)?;
        let wants_v6 = targets.iter().any(|target| matches!(target, Address::Udp(SocketAddr::V6(_))));
        let udp6 = if wants_v6 { Some(UdpSocket::bind((Ipv6Addr::UNSPECIFIED, 0))?) } else { None };
        if let Some(socket) = &udp6 {
            socket.set_nonblocking(true)?;
        }
        let unix = UnixDatagram::unbound()?;
        unix.set_nonblocking(true)?;
        Ok(Self { targets, encoding, udp4, udp6, unix })
    }

    /// Sends `message` to every target; returns how many refused it.
    pub fn publish(&self, message: &Message) -> u64 {
        let bytes = message.encode(self.encoding);
        let mut refused = 0;
        for target in &self.targets {
            let sent = match target {
                Address::Udp(address @ SocketAddr::V4(_)) => self.udp4.send_to(&bytes, address).map(drop),
                Address::Udp(address) => match &self.udp6 {
                    Some(socket) => socket.send_to(&bytes, address).map(drop),
                    None => Err(io::Error::other("no IPv6 socket")),
                },
                Address::Unix(path) => self.unix.send_to(&bytes, path).map(drop),
            };
            match sent {
                Ok(()) => debug!("message {} sent to {target} ({} bytes)", message.seq, bytes.len()),
                Err(error) => {
                    refused += 1;
                    warn!("message {} not delivered to {target}: {error}", message.seq);
                }
            }
        }
        refused
    }
}
