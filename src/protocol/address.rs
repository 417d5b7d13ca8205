//! Datagram addresses as relocd's configuration and clients write them: `udp:IP:PORT` or `unix:PATH`.

use std::fmt;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::str::FromStr;

use serde::Deserialize;

/// A datagram address: `udp:IP:PORT` or `unix:PATH` (a Unix datagram socket); where messages are
/// published to and where requests are sent.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(try_from = "String")]
pub enum Address {
    /// A UDP address (numeric: relocd resolves no host names).
    Udp(SocketAddr),
    /// A Unix datagram socket path.
    Unix(PathBuf),
}

impl FromStr for Address {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text.split_once(':') {
            Some(("udp", address)) => address.parse().map(Self::Udp).map_err(|_| {
                format!("{text:?}: expected udp:IP:PORT with a numeric address, e.g. udp:127.0.0.1:5454")
            }),
            Some(("unix", "")) => Err(format!("{text:?} names no socket path")),
            Some(("unix", path)) => Ok(Self::Unix(PathBuf::from(path))),
            _ => Err(format!("{text:?}: expected udp:IP:PORT or unix:PATH")),
        }
    }
}

impl TryFrom<String> for Address {
    type Error = String;

    fn try_from(text: String) -> Result<Self, Self::Error> {
        text.parse()
    }
}

impl fmt::Display for Address {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Udp(address) => write!(formatter, "udp:{address}"),
            Self::Unix(path) => write!(formatter, "unix:{}", path.display()),
        }
    }
}
