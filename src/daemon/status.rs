//! The daemon's counters, answered to `{"status": {}}` on the control socket.

use std::sync::Mutex;
use std::time::Instant;

use serde::Serialize;

use crate::protocol::gamecontroller::{GameState, Penalty, SetPlay};
use crate::protocol::message::{Latency, TriggerKind};

/// Triggers received, by kind.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TriggerCounts {
    /// GameController penalty returns.
    pub penalty_return: u64,
    /// Falls.
    pub fall: u64,
    /// Pick-ups.
    pub pick_up: u64,
    /// Control requests.
    pub request: u64,
}

/// Inputs refused by their decoder, by input.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Rejected {
    /// GameController packets: malformed, or about our team but from a second GameController, a
    /// duplicate or an old packet replayed.
    pub gamecontroller: u64,
    /// Sensor messages.
    pub sensors: u64,
    /// Control datagrams.
    pub control: u64,
    /// Forwarded frames.
    pub frames: u64,
}

/// The last GameController packet for our team.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GameInfo {
    /// Game state.
    pub state: GameState,
    /// Set play.
    pub set_play: SetPlay,
    /// Our player's penalty.
    pub penalty: Penalty,
    /// Seconds since the packet arrived.
    pub age_s: f64,
}

/// What `status` reports.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StatusReport {
    /// Seconds since start.
    pub uptime_s: f64,
    /// The frame source.
    pub source: String,
    /// The model id.
    pub model: String,
    /// Why the last SIGHUP reload of the model file failed (the running model was kept); cleared by a
    /// reload that succeeds.
    pub model_error: Option<String>,
    /// Triggers received.
    pub triggers: TriggerCounts,
    /// Triggers answered by another trigger's burst: they arrived together, or joined a waiting
    /// trigger of their kind because the queue was full. None is ever dropped.
    pub coalesced: u64,
    /// Bursts run.
    pub bursts: u64,
    /// Messages published (successes and failures).
    pub published: u64,
    /// Messages that carry a failure.
    pub failures: u64,
    /// Datagrams a target refused (unreachable, no receiver).
    pub publish_errors: u64,
    /// Inputs refused by their decoder.
    pub rejected: Rejected,
    /// Forwarded frames dropped because the queue was full.
    pub frames_dropped: u64,
    /// The last burst's latency breakdown.
    pub last_latency_ms: Option<Latency>,
    /// The last GameController packet for our team.
    pub game: Option<GameInfo>,
}

/// Shared counters.
#[derive(Debug)]
pub struct Status {
    started: Instant,
    report: Mutex<StatusReport>,
    game_received: Mutex<Option<Instant>>,
}

impl Status {
    /// Counters starting now, for this source and model.
    pub fn new(source: String, model: String) -> Self {
        Self {
            started: Instant::now(),
            report: Mutex::new(StatusReport { source, model, ..StatusReport::default() }),
            game_received: Mutex::new(None),
        }
    }

    /// Changes counters.
    pub fn update(&self, change: impl FnOnce(&mut StatusReport)) {
        change(&mut self.report.lock().unwrap_or_else(|poisoned| poisoned.into_inner()));
    }

    /// Counts a trigger.
    pub fn count_trigger(&self, kind: TriggerKind) {
        self.update(|report| {
            let counts = &mut report.triggers;
            *match kind {
                TriggerKind::PenaltyReturn => &mut counts.penalty_return,
                TriggerKind::Fall => &mut counts.fall,
                TriggerKind::PickUp => &mut counts.pick_up,
                TriggerKind::Request => &mut counts.request,
            } += 1;
        });
    }

    /// Records the last GameController packet for our team.
    pub fn set_game(&self, game: GameInfo) {
        *self.game_received.lock().unwrap_or_else(|poisoned| poisoned.into_inner()) = Some(Instant::now());
        self.update(|report| report.game = Some(game));
    }

    /// A copy of the counters, now.
    pub fn snapshot(&self) -> StatusReport {
        let mut report = self.report.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).clone();
        report.uptime_s = self.started.elapsed().as_secs_f64();
        let received = *self.game_received.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        if let (Some(game), Some(received)) = (report.game.as_mut(), received) {
            game.age_s = received.elapsed().as_secs_f64();
        }
        report
    }
}
