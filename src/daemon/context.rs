//! The context a burst is relocalised with: the belief stream's recent poses, what a trigger brings
//! (the belief from before a fall or pick-up, a request's prior, own half and ball), and how a batch of
//! triggers turns into the pipeline's [`Priors`].

use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use nalgebra::Point2;

use super::config::PriorsConfig;
use super::queue::TriggerEvent;
use crate::geometry::{FieldPose, PoseSigma};
use crate::pipeline::priors::{BallPrior, BeliefPrior, OwnHalfPrior, PlacementPrior, Priors};
use crate::protocol::control::{BallInput, PoseInput, RelocaliseRequest};
use crate::protocol::message::TriggerKind;

/// Beliefs kept: 10 Hz for 25 s.
const BELIEFS_KEPT: usize = 256;
/// A belief must be this much older than the event's onset: the team's localisation may already have
/// followed the fall or the lift.
pub const BELIEF_MARGIN: Duration = Duration::from_millis(300);

/// A belief, as old as it was at the event.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AgedBelief {
    /// The pose the team sent.
    pub pose: PoseInput,
    /// Its age at the event, seconds (its own `age_s` included).
    pub age_s: f64,
}

/// What a trigger brings to its burst.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriggerContext {
    /// The team's belief: from a request's `prior`, or the stream's last one before a fall or pick-up.
    pub belief: Option<AgedBelief>,
    /// A request's `own_half`.
    pub own_half: Option<bool>,
    /// A request's `ball`.
    pub ball: Option<BallInput>,
}

impl TriggerContext {
    /// The context of a relocalise request, and an error for each part left out (the request's own and
    /// a prior older than `max_age_s`).
    pub fn of_request(request: &RelocaliseRequest, max_age_s: f64) -> (Self, Vec<String>) {
        let mut errors = request.context_errors.clone();
        let belief = request.prior.and_then(|prior| {
            let age_s = prior.pose.age_s.unwrap_or(0.0);
            if age_s > max_age_s {
                errors.push(format!(
                    "relocalise.prior.pose.age_s: {age_s} s is older than priors.belief_max_age_s = {max_age_s} s; ignored"
                ));
                return None;
            }
            Some(AgedBelief { pose: prior.pose, age_s })
        });
        (Self { belief, own_half: request.own_half, ball: request.ball }, errors)
    }
}

/// The belief stream's recent poses, newest last.
#[derive(Debug, Default)]
pub struct BeliefLog(Mutex<VecDeque<(Instant, PoseInput)>>);

impl BeliefLog {
    /// Keeps `pose`, received now.
    pub fn record(&self, pose: PoseInput) {
        let mut beliefs = self.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        if beliefs.len() == BELIEFS_KEPT {
            beliefs.pop_front();
        }
        beliefs.push_back((Instant::now(), pose));
    }

    /// The last belief received at least [`BELIEF_MARGIN`] before `onset`, unless it was older than
    /// `max_age_s` then.
    pub fn before(&self, onset: Instant, max_age_s: f64) -> Option<AgedBelief> {
        let beliefs = self.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        let cutoff = onset.checked_sub(BELIEF_MARGIN)?;
        let (at, pose) = beliefs.iter().rev().find(|(at, _)| *at <= cutoff)?;
        let age_s = onset.duration_since(*at).as_secs_f64() + pose.age_s.unwrap_or(0.0);
        (age_s <= max_age_s).then_some(AgedBelief { pose: *pose, age_s })
    }
}

fn belief_prior(belief: &AgedBelief) -> Option<BeliefPrior> {
    let pose = FieldPose::new(belief.pose.x, belief.pose.y, belief.pose.theta).ok()?;
    let sigma = PoseSigma { x: belief.pose.sigma.x, y: belief.pose.sigma.y, theta: belief.pose.sigma.theta };
    Some(BeliefPrior::new(pose, sigma, belief.age_s))
}

/// The priors of a burst that answers `batch` (oldest first): the penalty placement after a penalty
/// return (then no belief: the robot left the place it was believed at); otherwise the newest belief;
/// the newest request's `own_half`, else own half when we are the goalkeeper; the newest ball.
pub fn priors_for_batch(batch: &[TriggerEvent], config: &PriorsConfig, goalkeeper: bool) -> Priors {
    let penalty_return = batch.iter().any(|trigger| trigger.kind == TriggerKind::PenaltyReturn);
    let newest =
        |pick: &dyn Fn(&TriggerContext) -> bool| batch.iter().rev().map(|t| &t.context).find(|c| pick(c));
    let belief = if penalty_return {
        None
    } else {
        newest(&|c| c.belief.is_some()).and_then(|c| c.belief.as_ref()).and_then(belief_prior)
    };
    let own_half = newest(&|c| c.own_half.is_some()).and_then(|c| c.own_half).unwrap_or(goalkeeper);
    let ball = newest(&|c| c.ball.is_some()).and_then(|c| c.ball).map(|ball| BallPrior {
        own_distance: ball.own.distance,
        own_bearing: ball.own.bearing,
        team: Point2::new(ball.team.x, ball.team.y),
        team_sigma: ball.team.sigma,
        teammates: u32::from(ball.team.teammates),
        flip_probability: config.ball_flip_probability,
    });
    Priors {
        placement: penalty_return.then(PlacementPrior::penalty_return),
        belief,
        own_half: own_half.then(OwnHalfPrior::default),
        ball,
        min_share: config.min_weight_share,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::control::SigmaInput;

    fn pose(x: f64) -> PoseInput {
        PoseInput { x, y: 0.5, theta: 0.1, sigma: SigmaInput { x: 0.2, y: 0.2, theta: 0.1 }, age_s: None }
    }

    fn event(kind: TriggerKind, context: TriggerContext) -> TriggerEvent {
        TriggerEvent { id: 1, kind, reason: None, head_yaw: None, context, at: Instant::now(), t: 0.0 }
    }

    #[test]
    fn the_last_belief_before_the_onset_counts_unless_too_old() {
        let log = BeliefLog::default();
        log.record(pose(-1.0));
        std::thread::sleep(Duration::from_millis(20));
        log.record(pose(-2.0));
        let onset = Instant::now() + BELIEF_MARGIN;
        std::thread::sleep(Duration::from_millis(20));
        log.record(pose(-3.0));
        assert_eq!(log.before(onset, 5.0).map(|b| b.pose.x), Some(-2.0), "not the one after the onset");
        assert!(log.before(onset, 0.1).is_none(), "older than the maximum age");
        assert!(BeliefLog::default().before(onset, 5.0).is_none());
    }

    #[test]
    fn a_batch_s_context_becomes_its_priors() {
        let config = PriorsConfig::default();
        let belief = TriggerContext {
            belief: Some(AgedBelief { pose: pose(-2.0), age_s: 1.0 }),
            ..Default::default()
        };
        let fall = event(TriggerKind::Fall, belief.clone());
        let priors = priors_for_batch(std::slice::from_ref(&fall), &config, false);
        assert!(priors.belief.is_some() && priors.placement.is_none() && priors.own_half.is_none());
        assert_eq!(priors.belief.unwrap().age_s, 1.0);
        let goalkeeper = priors_for_batch(std::slice::from_ref(&fall), &config, true);
        assert!(goalkeeper.own_half.is_some());
        let not_own_half =
            event(TriggerKind::Request, TriggerContext { own_half: Some(false), ..Default::default() });
        assert!(priors_for_batch(&[fall.clone(), not_own_half], &config, true).own_half.is_none());
        let returned = priors_for_batch(
            &[fall, event(TriggerKind::PenaltyReturn, TriggerContext::default())],
            &config,
            false,
        );
        assert!(
            returned.placement.is_some() && returned.belief.is_none(),
            "a penalty return outranks the belief"
        );
        let request = RelocaliseRequest {
            prior: Some(crate::protocol::control::PriorInput {
                pose: PoseInput { age_s: Some(9.0), ..pose(0.0) },
            }),
            ..Default::default()
        };
        let (context, errors) = TriggerContext::of_request(&request, config.belief_max_age_s);
        assert!(context.belief.is_none());
        assert!(errors[0].starts_with("relocalise.prior.pose.age_s: 9 s is older"), "{errors:?}");
    }
}
