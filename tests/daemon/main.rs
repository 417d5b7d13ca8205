//! `relocd run` end to end: a real daemon on loopback sockets, real GameController packets, LoLA
//! sensor messages, control requests and forwarded frames; the published messages are decoded with
//! the library's reference decoder, and the example clients in `examples/` talk to the daemon;
//! `relocd record` takes frames from the same sockets; `faults` holds the faults it must survive.

mod clients;
mod faults;
mod harness;
mod priors;
mod record;
mod triggers;
