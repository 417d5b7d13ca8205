//! Network outputs → a folded pose with fold probabilities and uncertainty → weighted full-field
//! hypotheses.
//!
//! The network sees the camera, so it predicts the ground pose of the camera (its heading includes the
//! head yaw). Unfolding happens on that pose, giving the symmetric camera poses the image could come
//! from; the measured head yaw is then taken off each of them to give the robot's pose.

use thiserror::Error;

use crate::geometry::{FieldPose, FoldedPose, Hypothesis, Representation};

/// Outputs that cannot be a prediction (NaN, a zero heading vector, wrong sizes).
#[derive(Debug, Error, PartialEq)]
pub enum DecodeError {
    /// An output holds NaN or infinity.
    #[error("model output {name} is not finite: {values:?}")]
    NotFinite {
        /// The output.
        name: &'static str,
        /// Its values.
        values: Vec<f32>,
    },
    /// The heading vector has no direction.
    #[error("model output heading {0:?} has no direction")]
    NoHeading([f32; 2]),
    /// Wrong number of fold probabilities for the representation.
    #[error("model gave {found} fold probabilities, {representation} needs {expected}")]
    FoldCount {
        /// The representation.
        representation: Representation,
        /// What it needs.
        expected: usize,
        /// What came.
        found: usize,
    },
}

/// The network's outputs for one frame, as named in the contract.
#[derive(Clone, Debug, PartialEq)]
pub struct RawOutput {
    /// Folded (x, y), metres.
    pub position: [f32; 2],
    /// Folded heading as (cos, sin).
    pub heading: [f32; 2],
    /// Probability that each fold bit is set (empty for `full`).
    pub fold_probabilities: Vec<f32>,
    /// Predicted standard deviation of the position, metres.
    pub position_sigma: f32,
    /// Predicted von Mises concentration of the heading.
    pub heading_kappa: f32,
}

/// One frame's decoded prediction.
#[derive(Clone, Debug, PartialEq)]
pub struct Prediction {
    /// The camera's ground pose in the folded field.
    pub folded: FoldedPose,
    /// Probability of each fold bit, in [0, 1].
    pub fold_probabilities: Vec<f64>,
    /// Standard deviation of the position, metres.
    pub position_sigma: f64,
    /// Standard deviation of the heading, radians (from the concentration, at most π).
    pub heading_sigma: f64,
    /// Head yaw taken off the hypotheses' headings, radians.
    pub head_yaw: f64,
}

impl Prediction {
    /// Checks and decodes raw outputs of a `representation` model, for a camera turned by `head_yaw`.
    pub fn decode(
        raw: &RawOutput,
        representation: Representation,
        head_yaw: f64,
    ) -> Result<Self, DecodeError> {
        let finite = |name, values: &[f32]| {
            if values.iter().all(|value| value.is_finite()) {
                Ok(())
            } else {
                Err(DecodeError::NotFinite { name, values: values.to_vec() })
            }
        };
        finite("position", &raw.position)?;
        finite("heading", &raw.heading)?;
        finite("fold_probabilities", &raw.fold_probabilities)?;
        finite("position_sigma", &[raw.position_sigma])?;
        finite("heading_kappa", &[raw.heading_kappa])?;
        let expected = representation.fold_bits();
        if raw.fold_probabilities.len() != expected {
            return Err(DecodeError::FoldCount {
                representation,
                expected,
                found: raw.fold_probabilities.len(),
            });
        }
        let [cos, sin] = raw.heading.map(f64::from);
        if cos.hypot(sin) < 1e-6 {
            return Err(DecodeError::NoHeading(raw.heading));
        }
        let folded =
            FoldedPose::new(representation, raw.position[0].into(), raw.position[1].into(), sin.atan2(cos))
                .expect("finite values checked above");
        let kappa = f64::from(raw.heading_kappa).max(1e-6);
        Ok(Self {
            folded,
            fold_probabilities: raw
                .fold_probabilities
                .iter()
                .map(|p| f64::from(*p).clamp(0.0, 1.0))
                .collect(),
            position_sigma: f64::from(raw.position_sigma).abs(),
            heading_sigma: (1.0 / kappa.sqrt()).min(std::f64::consts::PI),
            head_yaw,
        })
    }

    /// The weighted full-field robot poses, heaviest first; weights sum to 1.
    pub fn hypotheses(&self) -> Vec<Hypothesis> {
        let mut hypotheses =
            self.folded.unfold(&self.fold_probabilities).expect("probability count checked in decode");
        for hypothesis in &mut hypotheses {
            let pose = hypothesis.pose;
            hypothesis.pose = FieldPose::new(pose.x(), pose.y(), pose.heading() - self.head_yaw)
                .expect("unfolded poses are finite");
        }
        hypotheses.sort_by(|a, b| b.weight.total_cmp(&a.weight));
        hypotheses
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn raw(probabilities: Vec<f32>) -> RawOutput {
        RawOutput {
            position: [-2.0, 1.0],
            heading: [0.0, 2.0],
            fold_probabilities: probabilities,
            position_sigma: 0.3,
            heading_kappa: 100.0,
        }
    }

    #[test]
    fn half_point_output_unfolds_into_two_symmetric_poses() {
        let prediction = Prediction::decode(&raw(vec![0.8]), Representation::HalfPoint, 0.0).unwrap();
        assert!((prediction.folded.heading() - PI / 2.0).abs() < 1e-9);
        assert!((prediction.heading_sigma - 0.1).abs() < 1e-9);
        let hypotheses = prediction.hypotheses();
        assert_eq!(hypotheses.len(), 2);
        assert!((hypotheses[0].weight - 0.8).abs() < 1e-6);
        assert_eq!((hypotheses[0].pose.x(), hypotheses[0].pose.y()), (2.0, -1.0));
        assert!((hypotheses[0].pose.heading() + PI / 2.0).abs() < 1e-9);
        assert_eq!((hypotheses[1].pose.x(), hypotheses[1].pose.y()), (-2.0, 1.0));
    }

    #[test]
    fn head_yaw_is_taken_off_every_hypothesis() {
        let prediction = Prediction::decode(&raw(vec![0.5]), Representation::HalfLine, 0.3).unwrap();
        let hypotheses = prediction.hypotheses();
        let mut headings: Vec<f64> = hypotheses.iter().map(|h| h.pose.heading()).collect();
        headings.sort_by(f64::total_cmp);
        assert!((headings[0] - (-PI / 2.0 - 0.3)).abs() < 1e-9, "{headings:?}");
        assert!((headings[1] - (PI / 2.0 - 0.3)).abs() < 1e-9, "{headings:?}");
    }

    #[test]
    fn broken_outputs_are_rejected() {
        let mut nan = raw(vec![0.5]);
        nan.position[1] = f32::NAN;
        assert!(matches!(
            Prediction::decode(&nan, Representation::HalfPoint, 0.0),
            Err(DecodeError::NotFinite { name: "position", .. })
        ));
        let mut flat = raw(vec![0.5]);
        flat.heading = [0.0, 0.0];
        assert_eq!(
            Prediction::decode(&flat, Representation::HalfPoint, 0.0).unwrap_err(),
            DecodeError::NoHeading([0.0, 0.0])
        );
        assert!(matches!(
            Prediction::decode(&raw(vec![0.5]), Representation::Quarter, 0.0),
            Err(DecodeError::FoldCount { expected: 2, found: 1, .. })
        ));
    }
}
