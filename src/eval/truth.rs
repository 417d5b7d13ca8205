//! The lines at the true pose: per burst, whether the verification accepts the robot's true pose as
//! it is, which of its rules it fails, and what the fit that starts there makes of it. A verification
//! that rejects the truth, or a fit that walks away from it, is the percepts' or the rules' fault, not
//! the network's.

use serde::Serialize;

use super::metrics::{FOUND, pose_error};
use crate::geometry::FieldPose;
use crate::refine::{LineCheck, PoseCheck};

/// One burst's check at its true pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TruthEvaluation {
    /// The true pose as given meets the verification's shares.
    pub passes: bool,
    /// Too few of the points lie on a line at the true pose.
    pub points_off_lines: bool,
    /// Too many of the lines the camera should see there were not seen.
    pub lines_unseen: bool,
    /// What the fit from the true pose was called.
    pub fit_check: LineCheck,
    /// The fit from the true pose stands (refined or partial) within 5 cm / 1° of it.
    pub fit_stayed: bool,
}

impl TruthEvaluation {
    /// Scores `check`, made at `truth`.
    pub fn new(truth: &FieldPose, check: &PoseCheck) -> Self {
        let (metres, degrees) = pose_error(&check.fit.pose, truth);
        Self {
            passes: check.passes(),
            points_off_lines: !check.inlier_share_passes(),
            lines_unseen: !check.unseen_share_passes(),
            fit_check: check.fit.evidence.check,
            fit_stayed: check.fit.evidence.check != LineCheck::Contradicted
                && metres <= FOUND.0
                && degrees <= FOUND.1,
        }
    }
}

/// The checks at the true pose over the bursts with enough line points to check.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TruthMetrics {
    /// Bursts checked.
    pub bursts: usize,
    /// Share whose true pose meets the verification's shares.
    pub passes_share: f64,
    /// Share whose points lie off the lines at the true pose more often than the verification allows.
    pub points_off_lines_share: f64,
    /// Share where more lines the camera should see at the true pose went unseen than it allows.
    pub lines_unseen_share: f64,
    /// Share whose fit from the true pose is `refined`.
    pub fit_refined_share: f64,
    /// Share whose fit from the true pose is `partial`.
    pub fit_partial_share: f64,
    /// Share whose fit from the true pose is `contradicted`.
    pub fit_contradicted_share: f64,
    /// Share whose fit from the true pose stands (refined or partial) within 5 cm / 1° of it.
    pub fit_stayed_share: f64,
}

impl TruthMetrics {
    /// Summarises the checks; `None` if there are none.
    pub fn summarise(evaluations: &[TruthEvaluation]) -> Option<Self> {
        if evaluations.is_empty() {
            return None;
        }
        let share = |keep: &dyn Fn(&TruthEvaluation) -> bool| {
            evaluations.iter().filter(|e| keep(e)).count() as f64 / evaluations.len() as f64
        };
        Some(Self {
            bursts: evaluations.len(),
            passes_share: share(&|e| e.passes),
            points_off_lines_share: share(&|e| e.points_off_lines),
            lines_unseen_share: share(&|e| e.lines_unseen),
            fit_refined_share: share(&|e| e.fit_check == LineCheck::Refined),
            fit_partial_share: share(&|e| e.fit_check == LineCheck::Partial),
            fit_contradicted_share: share(&|e| e.fit_check == LineCheck::Contradicted),
            fit_stayed_share: share(&|e| e.fit_stayed),
        })
    }

    /// The shares in one line for people.
    pub fn line(&self) -> String {
        format!(
            "at the true pose ({} bursts): {:.1}% pass ({:.1}% with points off the lines, {:.1}% with \
             lines unseen); the fit from it {:.1}% refined, {:.1}% partial, {:.1}% contradicted, {:.1}% \
             standing within 5 cm / 1°",
            self.bursts,
            100.0 * self.passes_share,
            100.0 * self.points_off_lines_share,
            100.0 * self.lines_unseen_share,
            100.0 * self.fit_refined_share,
            100.0 * self.fit_partial_share,
            100.0 * self.fit_contradicted_share,
            100.0 * self.fit_stayed_share,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::PoseSigma;
    use crate::refine::{LineEvidence, LineFit};

    fn check(
        inlier_share: f64,
        unseen_share: Option<f64>,
        fitted: (f64, f64),
        verdict: LineCheck,
    ) -> PoseCheck {
        let evidence = LineEvidence { check: verdict, points: 40, inlier_share, unseen_share, places: None };
        PoseCheck {
            points: 40,
            inlier_share,
            unseen_share,
            off_lines: Vec::new(),
            unseen: Vec::new(),
            fit: LineFit {
                pose: FieldPose::new(fitted.0, fitted.1, 0.0).unwrap(),
                sigma: PoseSigma { x: 0.01, y: 0.01, theta: 0.01 },
                evidence,
                factor: 1.0,
                camera: None,
                line_information: nalgebra::Matrix3::zeros(),
            },
        }
    }

    #[test]
    fn the_rules_a_true_pose_fails_and_where_its_fit_went_are_counted() {
        let truth = FieldPose::new(1.0, 2.0, 0.0).unwrap();
        let evaluations = [
            TruthEvaluation::new(&truth, &check(1.0, Some(0.0), (1.01, 2.0), LineCheck::Refined)),
            TruthEvaluation::new(&truth, &check(0.9, Some(0.0), (1.2, 2.0), LineCheck::Partial)),
            TruthEvaluation::new(&truth, &check(1.0, Some(0.4), (1.0, 2.0), LineCheck::Contradicted)),
            TruthEvaluation::new(&truth, &check(1.0, None, (1.0, 2.0), LineCheck::Partial)),
        ];
        assert_eq!(evaluations.map(|e| e.passes), [true, false, false, true]);
        let metrics = TruthMetrics::summarise(&evaluations).unwrap();
        assert_eq!(metrics.bursts, 4);
        assert_eq!(metrics.passes_share, 0.5);
        assert_eq!(metrics.points_off_lines_share, 0.25);
        assert_eq!(metrics.lines_unseen_share, 0.25);
        assert_eq!(
            (metrics.fit_refined_share, metrics.fit_partial_share, metrics.fit_contradicted_share),
            (0.25, 0.5, 0.25)
        );
        // The contradicted fit is left at the truth: it does not count as staying there.
        assert_eq!(metrics.fit_stayed_share, 0.5);
        assert!(metrics.line().contains("50.0% pass"));
        assert!(TruthMetrics::summarise(&[]).is_none());
    }
}
