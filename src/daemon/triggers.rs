//! The trigger inputs, one task each: GameController packets (a penalty return), LoLA sensor data
//! (fall and pick-up, and whether the robot stands still), and the control socket (requests and
//! status). They decode, decide, and hand a [`TriggerEvent`] to the relocalisation thread; bad input
//! is counted and logged, never fatal.

use std::net::{IpAddr, Ipv4Addr};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::AsyncReadExt;
use tokio::net::UnixStream;
use tracing::{debug, info, warn};

use super::context::{BeliefLog, TriggerContext};
use super::queue::{Queued, TriggerEvent, TriggerQueue};
use super::sockets::{Datagram, MAX_DATAGRAM, Peer};
use super::source::unix_now;
use super::status::{GameInfo, Status};
use crate::geometry::BodyAngles;
use crate::posture::{PostureDetector, PostureEvent};
use crate::protocol::control::{ControlError, ControlRequest};
use crate::protocol::gamecontroller::{GameControlData, PacketOrder, PenaltyEnd, PenaltyWatch};
use crate::protocol::lola::{LolaState, next_msgpack_value};
use crate::protocol::message::TriggerKind;

/// Sensor data older than this says nothing about whether the robot stands still now.
const SENSORS_FRESH: Duration = Duration::from_millis(300);
/// LoLA's stream is dropped and re-read when this much arrives without a whole message.
const MAX_LOLA_BUFFER: usize = 64 * 1024;

/// Hands triggers to the relocalisation thread.
#[derive(Clone, Debug)]
pub struct Triggers {
    queue: Arc<TriggerQueue>,
    next_id: Arc<AtomicU64>,
    status: Arc<Status>,
    beliefs: Arc<BeliefLog>,
    belief_max_age_s: f64,
}

impl Triggers {
    /// A handle on `queue`; beliefs from before a fall or pick-up older than `belief_max_age_s` are
    /// not used.
    pub fn new(queue: Arc<TriggerQueue>, status: Arc<Status>, belief_max_age_s: f64) -> Self {
        Self {
            queue,
            next_id: Arc::new(AtomicU64::new(1)),
            status,
            beliefs: Arc::new(BeliefLog::default()),
            belief_max_age_s,
        }
    }

    /// Queues a trigger; returns its id and the id of the trigger whose message will answer it (its
    /// own, or a waiting one of its kind when the queue is full, whose context then counts).
    pub fn fire(
        &self,
        kind: TriggerKind,
        reason: Option<String>,
        head_yaw: Option<f64>,
        context: TriggerContext,
    ) -> (u64, u64) {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        self.status.count_trigger(kind);
        let event = TriggerEvent { id, kind, reason, head_yaw, context, at: Instant::now(), t: unix_now() };
        let reason = event.reason.as_deref().map(|r| format!(" ({r})")).unwrap_or_default();
        match self.queue.push(event) {
            Queued::Waiting => {
                info!("trigger {id}: {kind:?}{reason}");
                (id, id)
            }
            Queued::Joined(answered_by) => {
                debug!("trigger {id}: {kind:?}{reason}, joins waiting trigger {answered_by} (queue full)");
                self.status.update(|report| report.coalesced += 1);
                (id, answered_by)
            }
        }
    }
}

/// What the sensor task last saw: whether the robot stands still and, when its messages carry the head
/// joints, the body angles that turn the camera.
#[derive(Debug, Default)]
pub struct Sensed(Mutex<Option<Reading>>);

#[derive(Clone, Copy, Debug)]
struct Reading {
    at: Instant,
    settled: bool,
    body: Option<BodyAngles>,
}

impl Sensed {
    fn report(&self, settled: bool, body: Option<BodyAngles>) {
        let reading = Reading { at: Instant::now(), settled, body };
        *self.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner()) = Some(reading);
    }

    fn fresh(&self) -> Option<Reading> {
        let last = *self.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        last.filter(|reading| reading.at.elapsed() < SENSORS_FRESH)
    }

    /// `Some(settled)` from fresh sensor data, `None` when there is none.
    pub fn settled(&self) -> Option<bool> {
        self.fresh().map(|reading| reading.settled)
    }

    /// The body angles from fresh sensor data, when it carried the head joints.
    pub fn body_angles(&self) -> Option<BodyAngles> {
        self.fresh().and_then(|reading| reading.body)
    }
}

/// Logs the first of a run of rejected inputs at `warn`, the rest at `debug`, so garbage cannot flood
/// the log.
#[derive(Debug, Default)]
struct RejectLog(Option<Instant>);

impl RejectLog {
    fn log(&mut self, what: &str, error: &dyn std::fmt::Display) {
        if self.0.is_none_or(|last| last.elapsed() > Duration::from_secs(10)) {
            self.0 = Some(Instant::now());
            warn!("{what} refused: {error} (more within 10 s are logged at debug level)");
        } else {
            debug!("{what} refused: {error}");
        }
    }
}

/// A buffer for datagrams of at most `limit` bytes; one more byte tells a longer datagram apart.
fn datagram_buffer(limit: usize) -> Vec<u8> {
    vec![0u8; limit.min(MAX_DATAGRAM) + 1]
}

/// Why a datagram was dropped unread.
#[derive(Debug)]
struct Oversized(usize);

impl std::fmt::Display for Oversized {
    fn fmt(&self, formatter: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(formatter, "datagram longer than max_datagram_bytes = {}", self.0)
    }
}

/// The next datagram, `Err` when it is longer than the buffer allows (then it is not parsed); a
/// socket error is logged and the read retried after a pause.
async fn receive(socket: &Datagram, buffer: &mut [u8], input: &str) -> (Result<usize, Oversized>, Peer) {
    loop {
        match socket.recv_from(buffer).await {
            Ok((length, peer)) if length == buffer.len() => return (Err(Oversized(length - 1)), peer),
            Ok((length, peer)) => return (Ok(length), peer),
            Err(error) => {
                warn!("{input} socket: {error}");
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    }
}

/// GameController packets: our player's return from a penalty that moved it.
pub async fn gamecontroller(
    socket: Datagram,
    limit: usize,
    mut watch: PenaltyWatch,
    team: u8,
    triggers: Triggers,
    status: Arc<Status>,
) {
    let mut buffer = datagram_buffer(limit);
    let mut rejects = RejectLog::default();
    let mut order = PacketOrder::default();
    let started = Instant::now();
    loop {
        let (received, peer) = receive(&socket, &mut buffer, "GameController").await;
        let length = match received {
            Ok(length) => length,
            Err(oversized) => {
                status.update(|report| report.rejected.gamecontroller += 1);
                rejects.log("GameController packet", &oversized);
                continue;
            }
        };
        let packet = match GameControlData::parse(&buffer[..length]) {
            Ok(packet) => packet,
            Err(error) => {
                status.update(|report| report.rejected.gamecontroller += 1);
                rejects.log("GameController packet", &error);
                continue;
            }
        };
        let Some(ours) = packet.team_info(team) else { continue };
        let source = match peer {
            Peer::Udp(address) => address.ip(),
            Peer::Unix(_) | Peer::Unnamed => IpAddr::V4(Ipv4Addr::LOCALHOST),
        };
        if let Err(ignored) = order.accept(source, packet.packet_number, started.elapsed().as_secs_f64()) {
            status.update(|report| report.rejected.gamecontroller += 1);
            rejects.log("GameController packet", &ignored);
            continue;
        }
        let ended = watch.update(&packet, started.elapsed().as_secs_f64());
        if let Some(penalty) = watch.penalty() {
            status.set_game(GameInfo { state: packet.state, set_play: packet.set_play, penalty, age_s: 0.0 });
        }
        debug!("GameController: {:?}, our team's score {}", packet.state, ours.score);
        match ended {
            Some(PenaltyEnd::Returned(returned)) => {
                let reason =
                    serde_json::to_value(returned.penalty).ok().and_then(|v| v.as_str().map(String::from));
                triggers.fire(TriggerKind::PenaltyReturn, reason, None, TriggerContext::default());
            }
            Some(PenaltyEnd::Revoked { penalty, seconds }) => {
                info!(
                    "penalty {penalty:?} ended after {seconds:.1} s, under gamecontroller.min_penalty_s: revoked, nothing to do"
                );
            }
            None => {}
        }
    }
}

/// Feeds one sensor sample to the detector; fires a trigger for a fall or pick-up.
fn take_sample(
    state: &LolaState,
    started: Instant,
    detector: &mut PostureDetector,
    sensed: &Sensed,
    triggers: &Triggers,
) {
    let event = detector.update(started.elapsed().as_secs_f64(), state);
    sensed.report(detector.is_settled(), state.body_angles());
    if let Some(event) = event {
        let kind = match event {
            PostureEvent::Fall => TriggerKind::Fall,
            PostureEvent::PickUp => TriggerKind::PickUp,
        };
        // The team's belief from before the robot fell or was lifted, unless a referee carried it
        // off the field (then the penalty return's placement prior speaks).
        let onset = detector.onset().map(|onset| started + Duration::from_secs_f64(onset.max(0.0)));
        let penalised = triggers.status.snapshot().game.is_some_and(|game| game.penalty.moves_robot());
        let belief = onset
            .filter(|_| !penalised)
            .and_then(|onset| triggers.beliefs.before(onset, triggers.belief_max_age_s));
        match &belief {
            Some(belief) => info!(
                "{kind:?}: the belief ({:.2}, {:.2}) from {:.1} s before is the prior",
                belief.pose.x, belief.pose.y, belief.age_s
            ),
            None => debug!("{kind:?}: no belief from before it (none, too old, or penalised)"),
        }
        triggers.fire(kind, None, None, TriggerContext { belief, ..TriggerContext::default() });
    }
}

/// LoLA state messages forwarded as datagrams, one per datagram.
pub async fn sensor_datagrams(
    socket: Datagram,
    limit: usize,
    mut detector: PostureDetector,
    sensed: Arc<Sensed>,
    triggers: Triggers,
    status: Arc<Status>,
) {
    let started = Instant::now();
    let mut buffer = datagram_buffer(limit);
    let mut rejects = RejectLog::default();
    loop {
        let (received, _) = receive(&socket, &mut buffer, "sensor").await;
        let parsed = match received {
            Ok(length) => LolaState::from_msgpack(&buffer[..length]).map_err(|error| error.to_string()),
            Err(oversized) => Err(oversized.to_string()),
        };
        match parsed {
            Ok(state) => take_sample(&state, started, &mut detector, &sensed, &triggers),
            Err(error) => {
                status.update(|report| report.rejected.sensors += 1);
                rejects.log("sensor message", &error);
            }
        }
    }
}

/// LoLA's own stream socket, read as its client: reconnects with a pause when LoLA goes away.
pub async fn lola_stream(
    path: PathBuf,
    mut detector: PostureDetector,
    sensed: Arc<Sensed>,
    triggers: Triggers,
    status: Arc<Status>,
) {
    let started = Instant::now();
    let mut rejects = RejectLog::default();
    loop {
        match UnixStream::connect(&path).await {
            Ok(mut stream) => {
                info!("reading LoLA at {}", path.display());
                let mut buffer = Vec::with_capacity(4096);
                let mut chunk = [0u8; 4096];
                loop {
                    let length = match stream.read(&mut chunk).await {
                        Ok(0) | Err(_) => break,
                        Ok(length) => length,
                    };
                    buffer.extend_from_slice(&chunk[..length]);
                    while let Some(length) = next_msgpack_value(&buffer) {
                        match LolaState::from_msgpack(&buffer[..length]) {
                            Ok(state) => take_sample(&state, started, &mut detector, &sensed, &triggers),
                            Err(error) => {
                                status.update(|report| report.rejected.sensors += 1);
                                rejects.log("LoLA message", &error);
                            }
                        }
                        buffer.drain(..length);
                    }
                    if buffer.len() > MAX_LOLA_BUFFER {
                        status.update(|report| report.rejected.sensors += 1);
                        rejects.log("LoLA stream", &"no whole message in 64 KiB, skipping it");
                        buffer.clear();
                    }
                }
                warn!("LoLA at {} closed the connection", path.display());
            }
            Err(error) => debug!("cannot connect to LoLA at {}: {error}", path.display()),
        }
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
}

/// The control socket: `{"relocalise": …}` answers `{"accepted": {"trigger": ID}}`, `{"status": {}}`
/// answers the counters, anything else `{"error": …}`.
pub async fn control(socket: Datagram, limit: usize, triggers: Triggers, status: Arc<Status>) {
    let mut buffer = datagram_buffer(limit);
    let mut rejects = RejectLog::default();
    loop {
        let (received, peer) = receive(&socket, &mut buffer, "control").await;
        let request = match received {
            Ok(length) => match ControlRequest::parse(&buffer[..length]) {
                Err(error @ ControlError::Invalid { field: "belief", .. }) => {
                    // The belief stream is never answered, so that a sender need not read: a refused
                    // belief is counted and logged only.
                    status.update(|report| report.rejected.control += 1);
                    rejects.log("belief", &error);
                    continue;
                }
                parsed => parsed.map_err(|error| error.to_string()),
            },
            Err(oversized) => Err(oversized.to_string()),
        };
        let answer = match request {
            Ok(ControlRequest::Relocalise(request)) => {
                let (context, errors) = TriggerContext::of_request(&request, triggers.belief_max_age_s);
                for error in &errors {
                    rejects.log("relocalise request context", error);
                }
                let (id, answered_by) =
                    triggers.fire(TriggerKind::Request, request.reason, request.head_yaw, context);
                let mut accepted = serde_json::json!({ "trigger": id });
                if answered_by != id {
                    accepted["coalesced_into"] = answered_by.into();
                }
                if !errors.is_empty() {
                    accepted["context_errors"] = errors.into();
                }
                serde_json::json!({ "accepted": accepted })
            }
            Ok(ControlRequest::Belief(pose)) => {
                triggers.beliefs.record(pose);
                continue;
            }
            Ok(ControlRequest::Status(_)) => serde_json::json!({ "status": status.snapshot() }),
            Err(error) => {
                status.update(|report| report.rejected.control += 1);
                rejects.log("control request", &error);
                serde_json::json!({ "error": error })
            }
        };
        if let Err(error) = socket.try_send_to(answer.to_string().as_bytes(), &peer) {
            debug!("cannot answer a control request: {error}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_trigger_beyond_the_queue_is_answered_by_a_waiting_one_and_counted() {
        let status = Arc::new(Status::new("sim".into(), "model".into()));
        let queue = Arc::new(TriggerQueue::new(1));
        let triggers = Triggers::new(queue.clone(), status.clone(), 5.0);
        let fire = |kind| triggers.fire(kind, None, None, TriggerContext::default());
        assert_eq!(fire(TriggerKind::Request), (1, 1));
        assert_eq!(fire(TriggerKind::Request), (2, 1));
        assert_eq!(fire(TriggerKind::Fall), (3, 3));
        let report = status.snapshot();
        assert_eq!((report.triggers.request, report.triggers.fall, report.coalesced), (2, 1, 1));
        assert_eq!(queue.drain().iter().map(|event| event.id).collect::<Vec<_>>(), [1, 3]);
    }
}
