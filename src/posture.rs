//! Fall and pick-up detection from the robot's IMU and foot-pressure sensors, as LoLA reports them.
//!
//! A robot that fell or was carried does not know where it is once it stands again. The detector
//! follows two conditions and reports each once the robot is upright and steady again, which is when a
//! camera frame is worth taking:
//! - **fallen**: the torso tilted beyond `fallen_tilt`;
//! - **picked up**: both feet carried less than `unloaded_kg` for `unloaded_for` seconds.

use crate::protocol::lola::LolaState;

/// Thresholds of the detector.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PostureConfig {
    /// Torso tilt beyond which the robot has fallen, radians.
    pub fallen_tilt: f64,
    /// Torso tilt below which it is upright again, radians.
    pub upright_tilt: f64,
    /// Angular speed below which it is steady, rad/s.
    pub steady_rate: f64,
    /// A foot carrying less than this is unloaded, kg.
    pub unloaded_kg: f64,
    /// Both feet unloaded this long means the robot was lifted, seconds.
    pub unloaded_for: f64,
    /// A foot carrying more than this stands, kg.
    pub loaded_kg: f64,
    /// Upright, steady and on both feet this long means the robot is ready to look, seconds.
    pub settled_for: f64,
}

impl Default for PostureConfig {
    fn default() -> Self {
        Self {
            fallen_tilt: 50f64.to_radians(),
            upright_tilt: 15f64.to_radians(),
            steady_rate: 0.3,
            unloaded_kg: 0.1,
            unloaded_for: 0.5,
            loaded_kg: 0.5,
            settled_for: 1.0,
        }
    }
}

/// What the robot went through before it settled.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PostureEvent {
    /// It fell and got up.
    Fall,
    /// It was lifted and put down.
    PickUp,
}

/// Follows sensor samples and reports a fall or a pick-up once the robot has settled again.
#[derive(Clone, Debug)]
pub struct PostureDetector {
    config: PostureConfig,
    pending: Option<PostureEvent>,
    onset: Option<f64>,
    unloaded_since: Option<f64>,
    settled_since: Option<f64>,
}

impl PostureDetector {
    /// A detector with these thresholds.
    pub fn new(config: PostureConfig) -> Self {
        Self { config, pending: None, onset: None, unloaded_since: None, settled_since: None }
    }

    /// When the last reported (or the pending) event began, in the samples' time: the first sample
    /// beyond the fallen tilt, or the first with both feet unloaded. What the robot believed before
    /// then still holds after a fall or a short carry.
    pub fn onset(&self) -> Option<f64> {
        self.onset
    }

    /// Whether the last sample showed the robot upright, steady and on both feet.
    pub fn is_settled(&self) -> bool {
        self.settled_since.is_some()
    }

    /// Takes the sample received at `t` seconds; returns an event once per fall or pick-up, when the
    /// robot has settled after it. A fall outranks a pick-up that happens with it.
    pub fn update(&mut self, t: f64, state: &LolaState) -> Option<PostureEvent> {
        let config = &self.config;
        let tilt = f64::from(state.angles[0]).hypot(f64::from(state.angles[1]));
        let rate = state.gyroscope.iter().map(|&w| f64::from(w).powi(2)).sum::<f64>().sqrt();
        let left: f64 = state.fsr[..4].iter().map(|&kg| f64::from(kg)).sum();
        let right: f64 = state.fsr[4..].iter().map(|&kg| f64::from(kg)).sum();

        if tilt > config.fallen_tilt {
            if self.pending.is_none() {
                self.onset = Some(self.unloaded_since.unwrap_or(t).min(t));
            }
            self.pending = Some(PostureEvent::Fall);
        }
        if left < config.unloaded_kg && right < config.unloaded_kg {
            let since = *self.unloaded_since.get_or_insert(t);
            if t - since >= config.unloaded_for && self.pending.is_none() {
                self.pending = Some(PostureEvent::PickUp);
                self.onset = Some(since);
            }
        } else {
            self.unloaded_since = None;
        }

        let settled = tilt < config.upright_tilt
            && rate < config.steady_rate
            && left > config.loaded_kg
            && right > config.loaded_kg;
        if !settled {
            self.settled_since = None;
            return None;
        }
        let since = *self.settled_since.get_or_insert(t);
        if t - since >= config.settled_for { self.pending.take() } else { None }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const STANDING: LolaState =
        LolaState { angles: [0.02, -0.03], gyroscope: [0.0, 0.01, 0.0], fsr: [1.3; 8], position: Vec::new() };

    fn lying() -> LolaState {
        LolaState { angles: [0.1, 1.5], gyroscope: [0.0; 3], fsr: [0.0; 8], position: Vec::new() }
    }

    fn carried() -> LolaState {
        LolaState { angles: [0.05, 0.2], gyroscope: [0.4, 0.2, 0.1], fsr: [0.02; 8], position: Vec::new() }
    }

    /// Feeds `state` at 83 Hz for `seconds` from `*t`, collecting events.
    fn feed(
        detector: &mut PostureDetector,
        t: &mut f64,
        seconds: f64,
        state: &LolaState,
    ) -> Vec<PostureEvent> {
        let mut events = Vec::new();
        let end = *t + seconds;
        while *t < end {
            events.extend(detector.update(*t, state));
            *t += 0.012;
        }
        events
    }

    #[test]
    fn a_fall_is_reported_once_the_robot_stands_still_again() {
        let mut detector = PostureDetector::new(PostureConfig::default());
        let mut t = 0.0;
        assert!(feed(&mut detector, &mut t, 2.0, &STANDING).is_empty());
        assert!(feed(&mut detector, &mut t, 3.0, &lying()).is_empty());
        assert!(feed(&mut detector, &mut t, 0.9, &STANDING).is_empty(), "not settled for a second yet");
        assert_eq!(feed(&mut detector, &mut t, 0.3, &STANDING), vec![PostureEvent::Fall]);
        assert!(
            (detector.onset().unwrap() - 2.0).abs() < 0.02,
            "the fall began at 2 s: {:?}",
            detector.onset()
        );
        assert!(feed(&mut detector, &mut t, 5.0, &STANDING).is_empty(), "reported once");
    }

    #[test]
    fn a_pick_up_is_reported_after_the_robot_is_put_down() {
        let mut detector = PostureDetector::new(PostureConfig::default());
        let mut t = 0.0;
        feed(&mut detector, &mut t, 1.0, &STANDING);
        assert!(feed(&mut detector, &mut t, 4.0, &carried()).is_empty());
        assert_eq!(feed(&mut detector, &mut t, 1.5, &STANDING), vec![PostureEvent::PickUp]);
        assert!((detector.onset().unwrap() - 1.0).abs() < 0.02, "lifted at 1 s: {:?}", detector.onset());
    }

    #[test]
    fn short_unloading_and_swaying_are_not_events() {
        let mut detector = PostureDetector::new(PostureConfig::default());
        let mut t = 0.0;
        // A step lifts one foot; a short hop unloads both for 0.2 s; the torso sways 20°.
        let one_foot = LolaState { fsr: [0.0, 0.0, 0.0, 0.0, 2.6, 2.6, 2.6, 2.6], ..STANDING };
        let sway = LolaState { angles: [0.35, 0.0], ..STANDING };
        for state in [&one_foot, &carried(), &sway, &STANDING] {
            let seconds = if state == &carried() { 0.2 } else { 1.5 };
            assert!(feed(&mut detector, &mut t, seconds, state).is_empty());
        }
    }
}
