//! The relocalisation thread: waits for triggers, coalesces those that arrive together, waits for a
//! steady robot, captures a burst, relocalises every frame (and finds its line points), fuses,
//! refines against the field lines, applies the game prior, and publishes one message that answers
//! every trigger it took. The only place inference runs.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tracing::{info, warn};

use super::config::{BurstConfig, PriorsConfig};
use super::context::priors_for_batch;
use super::publish::Publisher;
use super::queue::{TriggerEvent, TriggerQueue};
use super::source::{CaptureRequest, FrameSource, capture, sleep_unless_stopped, unix_now};
use super::status::Status;
use super::triggers::Sensed;
use crate::geometry::{CameraMounting, FieldPose, Representation};
use crate::pipeline::{Pipeline, Priors, StageTimes};
use crate::protocol::message::{FrameCounts, Latency, Message, ModelInfo, SCHEMA_VERSION, Trigger};
use crate::refine::CalibrationTracker;
use crate::relocaliser::Model;

/// How often the settle wait looks at the sensors.
const SETTLE_POLL: Duration = Duration::from_millis(20);

/// Everything the relocalisation thread owns.
pub struct Worker {
    /// The network and the line checks.
    pub pipeline: Pipeline,
    /// Where frames come from.
    pub source: Box<dyn FrameSource>,
    /// Where messages go.
    pub publisher: Publisher,
    /// Burst size and timing.
    pub burst: BurstConfig,
    /// How the camera sits on the robot (and the head yaw assumed when neither frame, trigger nor
    /// sensors give one).
    pub mounting: CameraMounting,
    /// What the sensor task last saw: steadiness and the body angles that turn the camera.
    pub sensed: Arc<Sensed>,
    /// Counters.
    pub status: Arc<Status>,
    /// Set on shutdown.
    pub stop: Arc<AtomicBool>,
    /// A model loaded on SIGHUP, taken before the next burst.
    pub replacement: Arc<ModelSlot>,
    /// How the triggers' context becomes priors.
    pub priors: PriorsConfig,
    /// We are the goalkeeper: own half unless a request says otherwise.
    pub goalkeeper: bool,
    /// The camera calibration learnt over the bursts, where it is learnt.
    pub calibration: Option<CalibrationTracker>,
}

/// Hands a newly loaded model to the relocalisation thread, which switches to it between bursts.
#[derive(Debug, Default)]
pub struct ModelSlot(Mutex<Option<Model>>);

impl ModelSlot {
    /// Offers `model` for the next burst (replacing one offered before and not yet taken).
    pub fn offer(&self, model: Model) {
        *self.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner()) = Some(model);
    }

    fn take(&self) -> Option<Model> {
        self.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).take()
    }
}

/// Where the time of one burst went.
struct BurstTimes {
    capture_started: Instant,
    capture_ms: f64,
    stages: StageTimes,
}

impl Worker {
    /// Takes triggers from `triggers` until `stop` is set.
    pub fn run(mut self, triggers: &TriggerQueue) {
        let mut seq = 0;
        let mut last_burst: Option<Instant> = None;
        while let Some(first) = triggers.next(&self.stop) {
            let mut batch = vec![first];
            if let Some(last) = last_burst {
                let ready = last + Duration::from_millis(self.burst.min_interval_ms);
                if !sleep_unless_stopped(&self.stop, ready) {
                    break;
                }
            }
            self.settle();
            batch.extend(triggers.drain());
            if self.stop.load(Ordering::Relaxed) {
                break;
            }
            if batch.len() > 1 {
                self.status.update(|report| report.coalesced += batch.len() as u64 - 1);
            }
            if let Some(model) = self.replacement.take() {
                info!("relocalising with model {} from now on", model.contract().model_id);
                self.pipeline.replace_model(model);
            }
            last_burst = Some(Instant::now());
            seq += 1;
            let message = self.relocalise(seq, &batch);
            // Counted before sending, so a status request that follows the message sees it.
            self.status.update(|report| {
                report.bursts += 1;
                report.published += 1;
                report.failures += u64::from(message.failure.is_some());
                report.last_latency_ms = Some(message.latency_ms);
            });
            let refused = self.publisher.publish(&message);
            self.status.update(|report| report.publish_errors += refused);
        }
    }

    /// Waits until the sensors say the robot stands still, they go quiet, or the settle timeout.
    fn settle(&self) {
        let deadline = Instant::now() + Duration::from_millis(self.burst.settle_timeout_ms);
        while Instant::now() < deadline && !self.stop.load(Ordering::Relaxed) {
            if self.sensed.settled() != Some(false) {
                return;
            }
            std::thread::sleep(SETTLE_POLL);
        }
        if self.stop.load(Ordering::Relaxed) {
            return;
        }
        info!("the robot did not settle within {} ms; capturing anyway", self.burst.settle_timeout_ms);
    }

    /// One burst for `batch`, as a message.
    fn relocalise(&mut self, seq: u64, batch: &[TriggerEvent]) -> Message {
        let model = match self.pipeline.relocaliser() {
            Some(relocaliser) => {
                let contract = relocaliser.model().contract();
                ModelInfo { id: contract.model_id.clone(), representation: contract.representation }
            }
            None => ModelInfo { id: "none".into(), representation: Representation::Full },
        };
        let head_yaw = batch.iter().rev().find_map(|trigger| trigger.head_yaw);
        let priors = priors_for_batch(batch, &self.priors, self.goalkeeper);
        let mut message = Message {
            schema: SCHEMA_VERSION,
            seq,
            published: 0.0,
            captured: None,
            triggers: batch
                .iter()
                .map(|trigger| Trigger {
                    id: trigger.id,
                    kind: trigger.kind,
                    reason: trigger.reason.clone(),
                    t: trigger.t,
                })
                .collect(),
            model,
            frames: FrameCounts { requested: self.burst.frames as u32, used: 0, agreeing: 0 },
            prior: None,
            priors: Vec::new(),
            latency_ms: Latency::default(),
            hypotheses: Vec::new(),
            failure: None,
        };
        let first_at = batch[0].at;
        let mut times =
            BurstTimes { capture_started: Instant::now(), capture_ms: 0.0, stages: StageTimes::default() };
        match self.estimate(head_yaw, &priors, &mut times, &mut message) {
            Ok(()) => {}
            Err(failure) => {
                warn!("relocalisation {seq} failed: {failure}");
                message.hypotheses.clear();
                message.failure = Some(failure);
            }
        }
        let ms = |duration: Duration| duration.as_secs_f64() * 1e3;
        message.latency_ms = Latency {
            wait: ms(times.capture_started - first_at),
            capture: times.capture_ms,
            preprocess: times.stages.preprocess_ms,
            inference: times.stages.inference_ms,
            fusion: times.stages.fusion_ms,
            refine: times.stages.lines_ms,
            total: ms(first_at.elapsed()),
        };
        message.published = unix_now();
        message
    }

    /// Captures a burst and runs it through the pipeline into `message`; the failure reason otherwise.
    fn estimate(
        &mut self,
        head_yaw: Option<f64>,
        priors: &Priors,
        times: &mut BurstTimes,
        message: &mut Message,
    ) -> Result<(), String> {
        let request = CaptureRequest {
            count: self.burst.frames,
            spacing: Duration::from_millis(self.burst.spacing_ms),
            deadline: times.capture_started + Duration::from_millis(self.burst.timeout_ms),
            stop: &self.stop,
        };
        // Each frame goes through the network as it arrives, while the source waits for the next one.
        let mut burst = match &self.calibration {
            Some(tracker) => self.pipeline.calibrated_burst(tracker.calibration()),
            None => self.pipeline.burst(),
        };
        let mut first_taken = None;
        let mut truth = None;
        let (checks_lines, mounting, sensed) = (self.pipeline.checks_lines(), self.mounting, &self.sensed);
        let captured = capture(self.source.as_mut(), &request, &mut |captured| {
            first_taken.get_or_insert(captured.taken);
            truth = truth.or(captured.truth);
            let camera = captured.camera.map_or_else(|| mounting.pose_on(sensed.body_angles(), head_yaw), Ok);
            let yaw = match &camera {
                Ok(camera) => camera.head_yaw(),
                Err(_) => head_yaw.unwrap_or(mounting.head_yaw),
            };
            if let (Err(error), true) = (&camera, checks_lines) {
                warn!("frame not used for line refinement: {error}");
            }
            // A frame the network fails on is counted by the burst and reported below.
            let _ = burst.add(&captured.frame, yaw, camera.as_ref().ok());
        });
        times.capture_ms = times.capture_started.elapsed().as_secs_f64() * 1e3;
        let frames = captured.map_err(|error| format!("no frames: {error}"))?;
        message.captured = first_taken;

        if let Some(error) = burst.failures().first() {
            warn!("{} of {frames} frames could not be relocalised: {error}", burst.failures().len());
        }
        let (estimate, stages) = burst.finish(priors);
        times.stages = stages;
        let estimate = estimate.map_err(|error| error.to_string())?;
        if let (Some(tracker), Some(measured)) = (&mut self.calibration, &estimate.camera) {
            tracker.learn(measured);
            info!("camera calibration: {tracker}");
        }
        message.prior = estimate.priors.names();
        message.priors = estimate.priors.applied.iter().map(Into::into).collect();
        message.frames.used = estimate.frames as u32;
        message.frames.agreeing = estimate.agreeing as u32;
        message.hypotheses = estimate.hypotheses.iter().map(Into::into).collect();
        log_result(message, truth);
        Ok(())
    }
}

/// Logs the best hypothesis, and its error where the source knows the truth (replay, sim).
fn log_result(message: &Message, truth: Option<FieldPose>) {
    let Some(best) = message.hypotheses.first() else { return };
    let error = truth.map(|truth| {
        let closest = message
            .hypotheses
            .iter()
            .map(|h| (h.x - truth.x()).hypot(h.y - truth.y()))
            .fold(f64::INFINITY, f64::min);
        format!(
            "; truth ({:.2} m, {:.2} m, {:.0}°), closest hypothesis {:.0} cm off",
            truth.x(),
            truth.y(),
            truth.heading().to_degrees(),
            closest * 100.0
        )
    });
    info!(
        "relocalisation {}: ({:.2} m, {:.2} m, {:.0}°) weight {:.2} from {}/{} frames{}",
        message.seq,
        best.x,
        best.y,
        best.theta.to_degrees(),
        best.weight,
        message.frames.agreeing,
        message.frames.used,
        error.unwrap_or_default()
    );
}
