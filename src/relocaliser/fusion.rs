//! Burst fusion: the predictions of several frames of the same standing robot become one weighted,
//! mutually symmetric hypothesis set with a spread estimate per hypothesis.
//!
//! Averaging in a fixed folded field would fail at the fold boundary: two frames of a robot standing on
//! the cut fold to opposite ends of the canonical region. So the frames are *aligned* first: a reference
//! pose is chosen (the heaviest hypothesis of the frame the others agree with most), each frame's
//! hypothesis nearest the reference marks its aligned class, and class `c` of the fused set averages
//! class `c ⊕ aligned` of every frame. Frames are weighted by their own predicted precision and by how
//! well they agree with the others (a Cauchy weight of their distance from the mean), so one frame of
//! carpet or a passing leg does not drag the result.

use thiserror::Error;

use super::decode::Prediction;
use crate::geometry::angle::angle_distance;
use crate::geometry::{FieldPose, Hypothesis, PoseSigma, Representation};

/// Metres a radian of heading difference counts as when frames are compared.
const METRES_PER_RADIAN: f64 = 1.0;
/// Distance (pose units as above) at which a frame's agreement weight has halved.
const AGREEMENT_SCALE: f64 = 0.5;
/// A frame closer than this to the fused pose counts as agreeing.
const AGREEING_DISTANCE: f64 = 2.0 * AGREEMENT_SCALE;

/// Why a burst could not be fused.
#[derive(Debug, Error, PartialEq)]
pub enum FusionError {
    /// No frames.
    #[error("a burst needs at least one frame")]
    Empty,
    /// The predictions come from models with different representations.
    #[error("a burst mixes {0} and {1} predictions")]
    MixedRepresentations(Representation, Representation),
}

/// One fused full-field hypothesis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FusedHypothesis {
    /// The robot's pose.
    pub pose: FieldPose,
    /// Its probability; the set's weights sum to 1.
    pub weight: f64,
    /// Spread: the burst's scatter combined with the frames' own predicted uncertainty.
    pub sigma: PoseSigma,
}

/// The fused result of one burst.
#[derive(Clone, Debug, PartialEq)]
pub struct BurstEstimate {
    /// Hypotheses, heaviest first.
    pub hypotheses: Vec<FusedHypothesis>,
    /// Frames fused.
    pub frames: usize,
    /// Frames within a metre (heading counted as a metre per radian) of the fused pose.
    pub agreeing: usize,
}

/// One frame's hypotheses indexed by fold class, with its precision.
struct FrameHypotheses {
    by_class: Vec<Hypothesis>,
    precision: f64,
    position_sigma: f64,
    heading_sigma: f64,
}

fn pose_distance(a: &FieldPose, b: &FieldPose) -> f64 {
    a.distance_to(b) + METRES_PER_RADIAN * angle_distance(a.heading(), b.heading())
}

impl FrameHypotheses {
    fn new(prediction: &Prediction) -> Self {
        let mut by_class = prediction.hypotheses();
        by_class.sort_by_key(|hypothesis| hypothesis.class.0);
        let position_sigma = prediction.position_sigma.max(1e-3);
        Self {
            by_class,
            precision: 1.0 / (position_sigma * position_sigma),
            position_sigma,
            heading_sigma: prediction.heading_sigma.max(1e-3),
        }
    }

    fn heaviest(&self) -> &Hypothesis {
        self.by_class.iter().max_by(|a, b| a.weight.total_cmp(&b.weight)).expect("at least one class")
    }

    /// The fold class whose pose lies nearest `reference`, and that distance.
    fn nearest(&self, reference: &FieldPose) -> (u8, f64) {
        self.by_class
            .iter()
            .map(|hypothesis| (hypothesis.class.0, pose_distance(&hypothesis.pose, reference)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("at least one class")
    }
}

/// Fuses the predictions of a burst of frames of one standing robot (any head yaws).
pub fn fuse(predictions: &[Prediction]) -> Result<BurstEstimate, FusionError> {
    let first = predictions.first().ok_or(FusionError::Empty)?.folded.representation();
    if let Some(other) =
        predictions.iter().map(|p| p.folded.representation()).find(|&representation| representation != first)
    {
        return Err(FusionError::MixedRepresentations(first, other));
    }
    let frames: Vec<FrameHypotheses> = predictions.iter().map(FrameHypotheses::new).collect();

    // The reference: the heaviest hypothesis of the frame whose pose the others agree with most.
    let disagreement = |reference: &FieldPose| -> f64 {
        frames.iter().map(|frame| frame.nearest(reference).1.min(2.0 * AGREEING_DISTANCE)).sum()
    };
    let reference = frames
        .iter()
        .map(|frame| frame.heaviest().pose)
        .min_by(|a, b| disagreement(a).total_cmp(&disagreement(b)))
        .expect("at least one frame");
    let aligned: Vec<u8> = frames.iter().map(|frame| frame.nearest(&reference).0).collect();

    // Two rounds of agreement weighting around the current estimate of the aligned class.
    let mut centre = reference;
    let mut weights = vec![0.0; frames.len()];
    for _ in 0..2 {
        for ((weight, frame), &class) in weights.iter_mut().zip(&frames).zip(&aligned) {
            let distance = pose_distance(&frame.by_class[usize::from(class)].pose, &centre);
            *weight = frame.precision / (1.0 + (distance / AGREEMENT_SCALE).powi(2));
        }
        centre = weighted_mean(&frames, &aligned, 0, &weights).0;
    }
    let agreeing = frames
        .iter()
        .zip(&aligned)
        .filter(|(frame, class)| {
            pose_distance(&frame.by_class[usize::from(**class)].pose, &centre) < AGREEING_DISTANCE
        })
        .count();

    let mut hypotheses: Vec<FusedHypothesis> = (0..first.hypothesis_count() as u8)
        .map(|class| {
            let (pose, sigma) = weighted_mean(&frames, &aligned, class, &weights);
            let weight = frames
                .iter()
                .zip(&aligned)
                .zip(&weights)
                .map(|((frame, aligned), w)| w * frame.by_class[usize::from(class ^ aligned)].weight)
                .sum::<f64>()
                / weights.iter().sum::<f64>();
            FusedHypothesis { pose, weight, sigma }
        })
        .collect();
    hypotheses.sort_by(|a, b| b.weight.total_cmp(&a.weight));
    Ok(BurstEstimate { hypotheses, frames: frames.len(), agreeing })
}

/// Weighted mean of class `class ⊕ aligned[j]` over the frames, with its spread: the weighted scatter
/// combined with the frames' weighted mean predicted σ (frames of one standing robot are not independent
/// views, so their own uncertainty does not shrink with their number).
fn weighted_mean(
    frames: &[FrameHypotheses],
    aligned: &[u8],
    class: u8,
    weights: &[f64],
) -> (FieldPose, PoseSigma) {
    let total: f64 = weights.iter().sum();
    let poses: Vec<(&FieldPose, f64, &FrameHypotheses)> = frames
        .iter()
        .zip(aligned)
        .zip(weights)
        .map(|((frame, aligned), w)| (&frame.by_class[usize::from(class ^ aligned)].pose, w / total, frame))
        .collect();
    let mean = |value: &dyn Fn(&FieldPose, &FrameHypotheses) -> f64| -> f64 {
        poses.iter().map(|(pose, w, frame)| w * value(pose, frame)).sum()
    };
    let (x, y) = (mean(&|pose, _| pose.x()), mean(&|pose, _| pose.y()));
    let (sin, cos) = (mean(&|pose, _| pose.heading().sin()), mean(&|pose, _| pose.heading().cos()));
    let heading = sin.atan2(cos);
    let scatter_x = mean(&|pose, _| (pose.x() - x).powi(2));
    let scatter_y = mean(&|pose, _| (pose.y() - y).powi(2));
    let scatter_theta = mean(&|pose, _| angle_distance(pose.heading(), heading).powi(2));
    let position_sigma = mean(&|_, frame| frame.position_sigma);
    let heading_sigma = mean(&|_, frame| frame.heading_sigma);
    (
        FieldPose::new(x, y, heading).expect("means of finite poses are finite"),
        PoseSigma {
            x: (scatter_x + position_sigma * position_sigma).sqrt(),
            y: (scatter_y + position_sigma * position_sigma).sqrt(),
            theta: (scatter_theta + heading_sigma * heading_sigma).sqrt(),
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::FoldedPose;
    use crate::relocaliser::decode::Prediction;
    use approx::assert_abs_diff_eq;
    use proptest::prelude::*;

    fn prediction(
        representation: Representation,
        truth: FieldPose,
        bits: Vec<f64>,
        sigma: f64,
    ) -> Prediction {
        let (folded, _) = representation.fold(&truth);
        Prediction {
            folded: FoldedPose::new(representation, folded.x(), folded.y(), folded.heading()).unwrap(),
            fold_probabilities: bits,
            position_sigma: sigma,
            heading_sigma: 0.05,
            head_yaw: 0.0,
        }
    }

    #[test]
    fn one_frame_fuses_to_its_own_hypotheses() {
        let truth = FieldPose::new(-2.0, 1.0, 0.5).unwrap();
        let single = prediction(Representation::HalfPoint, truth, vec![0.3], 0.2);
        let fused = fuse(std::slice::from_ref(&single)).unwrap();
        let expected = single.hypotheses();
        assert_eq!(fused.frames, 1);
        assert_eq!(fused.agreeing, 1);
        for (fused, expected) in fused.hypotheses.iter().zip(&expected) {
            assert_abs_diff_eq!(fused.weight, expected.weight, epsilon = 1e-12);
            assert!(fused.pose.distance_to(&expected.pose) < 1e-9);
            assert_abs_diff_eq!(fused.sigma.x, 0.2, epsilon = 1e-9);
            assert_abs_diff_eq!(fused.sigma.theta, 0.05, epsilon = 1e-9);
        }
    }

    #[test]
    fn frames_on_both_sides_of_the_cut_average_to_the_cut() {
        // A robot on the centre line: half-point folding sends the two frames to opposite ends.
        let left =
            prediction(Representation::HalfPoint, FieldPose::new(-0.05, 2.0, 0.0).unwrap(), vec![0.5], 0.1);
        let right =
            prediction(Representation::HalfPoint, FieldPose::new(0.05, 2.0, 0.0).unwrap(), vec![0.5], 0.1);
        assert!((left.folded.y() - right.folded.y()).abs() > 3.9, "the frames fold apart");
        let fused = fuse(&[left, right]).unwrap();
        assert_eq!(fused.agreeing, 2);
        let nearest =
            fused.hypotheses.iter().min_by(|a, b| a.pose.y().total_cmp(&b.pose.y()).reverse()).unwrap();
        // Agreement weights favour the reference frame a little; the mean stays on the cut.
        assert_abs_diff_eq!(nearest.pose.x(), 0.0, epsilon = 1e-3);
        assert_abs_diff_eq!(nearest.pose.y(), 2.0, epsilon = 1e-9);
        assert_abs_diff_eq!(nearest.sigma.x, (0.05f64.powi(2) + 0.01).sqrt(), epsilon = 1e-3);
    }

    #[test]
    fn an_outlier_frame_barely_moves_the_result() {
        let truth = FieldPose::new(-3.0, -1.0, 1.0).unwrap();
        let mut burst = vec![prediction(Representation::HalfPoint, truth, vec![0.2], 0.2); 4];
        burst.push(prediction(
            Representation::HalfPoint,
            FieldPose::new(-1.0, 2.5, -2.0).unwrap(),
            vec![0.2],
            0.2,
        ));
        let fused = fuse(&burst).unwrap();
        assert_eq!(fused.agreeing, 4);
        let best = fused.hypotheses.iter().map(|h| h.pose.distance_to(&truth)).fold(f64::INFINITY, f64::min);
        assert!(best < 0.1, "outlier pulled the mean {best} m away");
    }

    #[test]
    fn bad_bursts_are_rejected() {
        assert_eq!(fuse(&[]).unwrap_err(), FusionError::Empty);
        let pose = FieldPose::new(-1.0, 1.0, 0.0).unwrap();
        let burst = [
            prediction(Representation::HalfPoint, pose, vec![0.5], 0.1),
            prediction(Representation::Full, pose, vec![], 0.1),
        ];
        assert_eq!(
            fuse(&burst).unwrap_err(),
            FusionError::MixedRepresentations(Representation::HalfPoint, Representation::Full)
        );
    }

    fn any_representation() -> impl Strategy<Value = Representation> {
        prop::sample::select(Representation::ALL.to_vec())
    }

    proptest! {
        #[test]
        fn fused_sets_are_symmetric_and_weights_sum_to_one(
            representation in any_representation(),
            x in -4.5f64..4.5, y in -3.0f64..3.0, heading in -3.1f64..3.1,
            jitter in prop::collection::vec((-0.2f64..0.2, -0.2f64..0.2, -0.2f64..0.2, 0.0f64..1.0, 0.0f64..1.0), 1..6),
        ) {
            let burst: Vec<Prediction> = jitter
                .iter()
                .map(|(dx, dy, dt, p, q)| {
                    let pose = FieldPose::new(x + dx, y + dy, heading + dt).unwrap();
                    let bits = [*p, *q][..representation.fold_bits()].to_vec();
                    prediction(representation, pose, bits, 0.3)
                })
                .collect();
            let fused = fuse(&burst).unwrap();
            prop_assert_eq!(fused.hypotheses.len(), representation.hypothesis_count());
            prop_assert!((fused.hypotheses.iter().map(|h| h.weight).sum::<f64>() - 1.0).abs() < 1e-9);
            prop_assert!(fused.hypotheses.windows(2).all(|pair| pair[0].weight >= pair[1].weight));
            // Every fused hypothesis is a symmetry image of the heaviest one.
            let heaviest = fused.hypotheses[0].pose;
            for hypothesis in &fused.hypotheses {
                let imaged = crate::geometry::Symmetry::ALL.iter().any(|s| {
                    let image = s.apply(&heaviest);
                    image.distance_to(&hypothesis.pose) < 1e-6
                        && angle_distance(image.heading(), hypothesis.pose.heading()) < 1e-6
                });
                prop_assert!(imaged);
            }
            // The truth (centre of the jitter) is within the jitter of some hypothesis.
            let truth = FieldPose::new(x, y, heading).unwrap();
            let best = fused.hypotheses.iter().map(|h| h.pose.distance_to(&truth)).fold(f64::INFINITY, f64::min);
            prop_assert!(best < 0.3, "{}", best);
        }
    }
}
