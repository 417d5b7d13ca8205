//! The robot is on its own half (x < 0): the goalkeeper, or a robot its team knows to be there.

use crate::geometry::FieldPose;

/// A soft step across the centre line: a pose at x has likelihood 1 / (1 + e^(x / scale)), so the
/// rule says little about poses near the line, where a half-field network's error spans both halves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OwnHalfPrior {
    /// Width of the step, metres.
    pub scale: f64,
}

impl Default for OwnHalfPrior {
    /// A step 0.25 m wide: 2% at 1 m into the opponent half, 50% on the centre line.
    fn default() -> Self {
        Self { scale: 0.25 }
    }
}

impl OwnHalfPrior {
    /// The likelihood of a pose, up to a constant.
    pub fn likelihood(&self, pose: &FieldPose) -> f64 {
        1.0 / (1.0 + (pose.x() / self.scale).exp())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn own_half_poses_are_likely_the_centre_line_is_a_coin_flip() {
        let prior = OwnHalfPrior::default();
        let at = |x: f64| prior.likelihood(&FieldPose::new(x, 0.0, 0.0).unwrap());
        assert!(at(-3.0) > 0.99);
        assert!((at(0.0) - 0.5).abs() < 1e-12);
        assert!(at(1.0) < 0.02);
    }
}
