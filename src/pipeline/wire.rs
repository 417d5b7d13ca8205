//! The wire types of [`crate::protocol::message`], built from pipeline results.

use super::Hypothesis;
use super::priors::AppliedPrior;
use crate::protocol::message;
use crate::refine::{LineCheck, LineEvidence};

impl From<LineCheck> for message::LineCheck {
    fn from(check: LineCheck) -> Self {
        match check {
            LineCheck::Refined => Self::Refined,
            LineCheck::Partial => Self::Partial,
            LineCheck::Unrefined => Self::Unrefined,
            LineCheck::Contradicted => Self::Contradicted,
            LineCheck::Ambiguous => Self::Ambiguous,
        }
    }
}

impl From<LineEvidence> for message::LineEvidence {
    fn from(evidence: LineEvidence) -> Self {
        Self {
            check: evidence.check.into(),
            points: evidence.points,
            inlier_share: evidence.inlier_share,
            unseen_share: evidence.unseen_share,
            places: evidence.places,
        }
    }
}

impl From<&Hypothesis> for message::Hypothesis {
    fn from(hypothesis: &Hypothesis) -> Self {
        Self {
            x: hypothesis.pose.x(),
            y: hypothesis.pose.y(),
            theta: hypothesis.pose.heading(),
            weight: hypothesis.weight,
            sigma: [hypothesis.sigma.x, hypothesis.sigma.y, hypothesis.sigma.theta],
            lines: hypothesis.lines.map(Into::into),
        }
    }
}

impl From<&AppliedPrior> for message::AppliedPrior {
    fn from(applied: &AppliedPrior) -> Self {
        Self { name: applied.kind.name().into(), factors: applied.factors.clone() }
    }
}
