//! Priors for evaluation (`relocd replay --prior SPEC`): fixed ones, and ones drawn around a recording's
//! true pose to simulate each case the daemon meets: a right belief from before a fall, a belief that
//! is wrong by a flip, a team ball with noise. Draws come from a seeded generator, so a replay repeats.

use std::f64::consts::PI;
use std::str::FromStr;

use nalgebra::{Point2, Vector2};
use rand::{Rng, RngExt};

use super::{BallPrior, BeliefPrior, OwnHalfPrior, PlacementPrior, Priors};
use crate::geometry::{FieldPose, PoseSigma, Symmetry, normalize_angle};

/// The chance that one teammate's ball is flipped, used by the daemon's default and the simulation.
pub const DEFAULT_BALL_FLIP_PROBABILITY: f64 = 0.2;
/// Nearest and farthest own ball in the simulation, metres, within ±60° of the heading.
const OWN_BALL_RANGE: (f64, f64) = (0.5, 4.0);

/// One `--prior` of `relocd replay`.
#[derive(Clone, Debug, PartialEq)]
pub enum PriorSpec {
    /// `penalty-return`: the SPL placement after a penalty.
    PenaltyReturn,
    /// `own-half`: the robot is on its own half.
    OwnHalf,
    /// `belief:X,Y,THETA_DEG[,SIGMA_M[,SIGMA_DEG]]`: a fixed belief (default σ 0.5 m, 15°).
    Belief(BeliefPrior),
    /// `belief-near:ERR_M,ERR_DEG`: a belief drawn within ERR_M and ±ERR_DEG of the truth, claiming σ
    /// of half those errors; `belief-flipped:ERR_M,ERR_DEG` is its point reflection (a belief wrong by
    /// a flip).
    BeliefNear {
        /// Largest position error, metres.
        error_m: f64,
        /// Largest heading error, radians.
        error_rad: f64,
        /// Give the flipped twin of the drawn belief.
        flipped: bool,
    },
    /// `ball:NOISE_M[,TEAMMATES]`: a ball 0.5–4 m ahead of the true pose (±60°), seen by the robot
    /// with 5% / 2° noise, and a team ball within NOISE_M of it from TEAMMATES (default 1) teammates;
    /// `ball-flipped:…` gives the team ball's point reflection (the teammates are flipped).
    Ball {
        /// Largest team ball error, metres.
        noise_m: f64,
        /// Teammates agreeing on the team ball.
        teammates: u32,
        /// The team ball is the point reflection.
        flipped: bool,
    },
}

impl PriorSpec {
    /// Whether it needs the recording's true pose.
    pub fn needs_truth(&self) -> bool {
        matches!(self, PriorSpec::BeliefNear { .. } | PriorSpec::Ball { .. })
    }
}

fn numbers(text: &str, spec: &str, least: usize, most: usize) -> Result<Vec<f64>, String> {
    let values: Vec<f64> = text
        .split(',')
        .map(|value| value.trim().parse::<f64>().map_err(|_| format!("{spec}: `{value}` is not a number")))
        .collect::<Result<_, _>>()?;
    if values.len() < least || values.len() > most {
        return Err(format!("{spec}: expected {least} to {most} comma-separated numbers"));
    }
    if let Some(bad) = values.iter().find(|value| !value.is_finite()) {
        return Err(format!("{spec}: {bad} is not finite"));
    }
    Ok(values)
}

impl FromStr for PriorSpec {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let (name, arguments) = text.split_once(':').unwrap_or((text, ""));
        let non_negative = |values: &[f64], spec: &str| match values.iter().find(|value| **value < 0.0) {
            Some(bad) => Err(format!("{spec}: {bad} is negative")),
            None => Ok(()),
        };
        match name {
            "penalty-return" => Ok(PriorSpec::PenaltyReturn),
            "own-half" => Ok(PriorSpec::OwnHalf),
            "belief" => {
                let v = numbers(arguments, "belief:X,Y,THETA_DEG[,SIGMA_M[,SIGMA_DEG]]", 3, 5)?;
                non_negative(&v[3..], "belief σ")?;
                let pose =
                    FieldPose::new(v[0], v[1], v[2].to_radians()).map_err(|error| error.to_string())?;
                let (sigma_m, sigma_deg) =
                    (v.get(3).copied().unwrap_or(0.5), v.get(4).copied().unwrap_or(15.0));
                let sigma = PoseSigma { x: sigma_m, y: sigma_m, theta: sigma_deg.to_radians() };
                Ok(PriorSpec::Belief(BeliefPrior::new(pose, sigma, 0.0)))
            }
            "belief-near" | "belief-flipped" => {
                let v = numbers(arguments, &format!("{name}:ERR_M,ERR_DEG"), 2, 2)?;
                non_negative(&v, name)?;
                Ok(PriorSpec::BeliefNear {
                    error_m: v[0],
                    error_rad: v[1].to_radians(),
                    flipped: name == "belief-flipped",
                })
            }
            "ball" | "ball-flipped" => {
                let v = numbers(arguments, &format!("{name}:NOISE_M[,TEAMMATES]"), 1, 2)?;
                non_negative(&v, name)?;
                let teammates = v.get(1).copied().unwrap_or(1.0);
                if teammates < 1.0 || teammates.fract() != 0.0 {
                    return Err(format!("{name}: TEAMMATES must be a whole number ≥ 1, found {teammates}"));
                }
                Ok(PriorSpec::Ball {
                    noise_m: v[0],
                    teammates: teammates as u32,
                    flipped: name == "ball-flipped",
                })
            }
            _ => Err(format!(
                "unknown prior `{name}`: expected penalty-return, own-half, belief:X,Y,THETA_DEG[,SIGMA_M[,SIGMA_DEG]], \
                 belief-near:ERR_M,ERR_DEG, belief-flipped:ERR_M,ERR_DEG, ball:NOISE_M[,TEAMMATES] or \
                 ball-flipped:NOISE_M[,TEAMMATES]"
            )),
        }
    }
}

/// A point uniformly within `radius` of the origin.
fn in_disc(rng: &mut impl Rng, radius: f64) -> Vector2<f64> {
    let (r, angle) = (radius * rng.random::<f64>().sqrt(), rng.random_range(-PI..PI));
    Vector2::new(r * angle.cos(), r * angle.sin())
}

/// A sample of a standard normal (Box–Muller).
pub(crate) fn normal(rng: &mut impl Rng) -> f64 {
    let u = 1.0 - rng.random::<f64>();
    (-2.0 * u.ln()).sqrt() * (2.0 * PI * rng.random::<f64>()).cos()
}

/// The priors `specs` give a burst whose true pose is `truth` (drawn with `rng`; specs that need the
/// truth are left out without it), with the floor `min_share`.
pub fn priors_for(
    specs: &[PriorSpec],
    truth: Option<&FieldPose>,
    min_share: f64,
    rng: &mut impl Rng,
) -> Priors {
    let mut priors = Priors { min_share, ..Priors::default() };
    for spec in specs {
        match (spec, truth) {
            (PriorSpec::PenaltyReturn, _) => priors.placement = Some(PlacementPrior::penalty_return()),
            (PriorSpec::OwnHalf, _) => priors.own_half = Some(OwnHalfPrior::default()),
            (PriorSpec::Belief(belief), _) => priors.belief = Some(*belief),
            (PriorSpec::BeliefNear { error_m, error_rad, flipped }, Some(truth)) => {
                let position = truth.position() + in_disc(rng, *error_m);
                let heading = normalize_angle(truth.heading() + rng.random_range(-1.0..=1.0) * error_rad);
                let near = FieldPose::new(position.x, position.y, heading).expect("finite belief");
                let pose = if *flipped { Symmetry::PointReflection.apply(&near) } else { near };
                let sigma = PoseSigma {
                    x: (error_m / 2.0).max(0.1),
                    y: (error_m / 2.0).max(0.1),
                    theta: (error_rad / 2.0).max(5f64.to_radians()),
                };
                priors.belief = Some(BeliefPrior::new(pose, sigma, 0.0));
            }
            (PriorSpec::Ball { noise_m, teammates, flipped }, Some(truth)) => {
                let distance = rng.random_range(OWN_BALL_RANGE.0..OWN_BALL_RANGE.1);
                let bearing = rng.random_range(-PI / 3.0..PI / 3.0);
                let ball =
                    truth.robot_to_field(Point2::new(distance * bearing.cos(), distance * bearing.sin()));
                let team = ball + in_disc(rng, *noise_m);
                priors.ball = Some(BallPrior {
                    own_distance: distance * (1.0 + 0.05 * normal(rng)).max(0.0),
                    own_bearing: normalize_angle(bearing + 2f64.to_radians() * normal(rng)),
                    team: if *flipped { Point2::from(-team.coords) } else { team },
                    team_sigma: (noise_m / 2.0).max(0.05),
                    teammates: *teammates,
                    flip_probability: DEFAULT_BALL_FLIP_PROBABILITY,
                });
            }
            (PriorSpec::BeliefNear { .. } | PriorSpec::Ball { .. }, None) => {}
        }
    }
    priors
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;

    #[test]
    fn specs_parse_and_bad_ones_say_why() {
        assert_eq!("penalty-return".parse(), Ok(PriorSpec::PenaltyReturn));
        assert!(
            matches!("belief:-2,1,90".parse(), Ok(PriorSpec::Belief(b)) if (b.sigma.x - 0.5).abs() < 1e-12)
        );
        assert!(matches!(
            "belief-flipped:1,30".parse(),
            Ok(PriorSpec::BeliefNear { flipped: true, error_m: 1.0, .. })
        ));
        assert!(matches!("ball:0.5,3".parse(), Ok(PriorSpec::Ball { teammates: 3, flipped: false, .. })));
        assert!("belief:1,2".parse::<PriorSpec>().unwrap_err().contains("3 to 5"));
        assert!("belief:1,2,3,-1".parse::<PriorSpec>().unwrap_err().contains("negative"));
        assert!("ball:nan".parse::<PriorSpec>().unwrap_err().contains("not finite"));
        assert!("ball:0.5,0".parse::<PriorSpec>().unwrap_err().contains("TEAMMATES"));
        assert!("ghost".parse::<PriorSpec>().unwrap_err().contains("unknown prior `ghost`"));
    }

    #[test]
    fn drawn_priors_lie_where_the_spec_says() {
        let truth = FieldPose::new(-1.0, 2.0, 0.4).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..100 {
            let specs = ["belief-near:1,30".parse().unwrap(), "ball:0.5".parse().unwrap()];
            let priors = priors_for(&specs, Some(&truth), 0.1, &mut rng);
            let belief = priors.belief.unwrap();
            assert!(belief.pose.distance_to(&truth) <= 1.0 + 1e-9);
            assert!(
                crate::geometry::angle::angle_distance(belief.pose.heading(), truth.heading())
                    <= std::f64::consts::FRAC_PI_6 + 1e-9
            );
            let ball = priors.ball.unwrap();
            assert!((1..=1).contains(&ball.teammates) && ball.team_sigma > 0.0);
            let flipped = priors_for(&["belief-flipped:0,0".parse().unwrap()], Some(&truth), 0.1, &mut rng);
            assert!(
                flipped.belief.unwrap().pose.distance_to(&Symmetry::PointReflection.apply(&truth)) < 1e-9
            );
        }
        assert!(priors_for(&["ball:0.5".parse().unwrap()], None, 0.1, &mut rng).is_empty());
    }
}
