//! The camera's calibration error, learnt over bursts. A robot's camera pitch and roll are off by an
//! offset that stays with the robot (joint offsets, a head that sits a little askew) plus a part that
//! changes from one stance to the next (joint play, the torso's tilt as the IMU sees it). Every line
//! fit estimates the whole error within its prior ([`super::optimise`]); the bursts whose lines fix it
//! teach a [`CalibrationTracker`] the lasting part, so later fits start from it and hold to it more
//! tightly. A fit whose correction is left loose trades pitch for distance and roll for heading.

use nalgebra::{Matrix2, Vector2};

/// Spread of the whole calibration error before anything is learnt, radians.
const INITIAL_SIGMA: f64 = 1.0 * std::f64::consts::PI / 180.0;
/// Least spread of the part of the error that changes from burst to burst, radians: joint play and
/// the torso tilt of a standing Nao (an assumption; rendered frames have none). Where the
/// measurements scatter more than their own σ explains, the tracker takes the larger spread.
const MIN_STANCE_SIGMA: f64 = 0.3 * std::f64::consts::PI / 180.0;
/// Median absolute deviation of a normal distribution per standard deviation.
const MAD_PER_SIGMA: f64 = 0.674_489_75;
/// Measurements looser than this (radians, either axis) teach nothing.
const MAX_MEASUREMENT_SIGMA: f64 = 0.5 * std::f64::consts::PI / 180.0;
/// The recent measurements the tracker keeps: older ones fall out (a head knocked in a fall).
const WINDOW: usize = 16;
/// Fewest measurements that must agree before anything is learnt: one wrong fit teaches nothing.
const MIN_AGREEING: usize = 3;
/// Measurements within this many σ (their own and the stance's) of the median agree.
const AGREE_SIGMAS: f64 = 3.0;

/// A camera's pitch and roll correction (radians, added to its pose; positive pitch looks further
/// down) and how well it is known: what a burst adds to every camera pose, and the spread each fit
/// may correct it by.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraCalibration {
    /// (pitch, roll) added to every camera pose, radians.
    pub correction: Vector2<f64>,
    /// Standard deviation of the remaining error in (pitch, roll), radians.
    pub sigma: Vector2<f64>,
}

impl Default for CameraCalibration {
    /// Nothing learnt: no correction, a degree of error either way.
    fn default() -> Self {
        Self { correction: Vector2::zeros(), sigma: Vector2::repeat(INITIAL_SIGMA) }
    }
}

/// What the lines of one burst say about the camera's (pitch, roll) correction, radians, on their own
/// (without the prior the fit held it to).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraMeasurement {
    /// The correction, radians.
    pub correction: Vector2<f64>,
    /// Its covariance, radians².
    pub covariance: Matrix2<f64>,
}

impl CameraMeasurement {
    /// The measurement that `information` (the lines' information about the correction) and a fit
    /// at `fitted`, held to `prior` by independent standard deviations, imply: the fit's correction
    /// with the prior's pull taken out. `None` where the lines leave the correction looser than
    /// [`MAX_MEASUREMENT_SIGMA`].
    pub fn from_fit(
        fitted: Vector2<f64>,
        information: &Matrix2<f64>,
        prior: &CameraCalibration,
    ) -> Option<Self> {
        let covariance = information.try_inverse()?;
        let loose =
            covariance.diagonal().iter().any(|v| !v.is_finite() || *v > MAX_MEASUREMENT_SIGMA.powi(2));
        if loose || covariance.diagonal().iter().any(|v| *v <= 0.0) {
            return None;
        }
        // At the fit, the lines' pull balances the prior's: information · (measured − fitted) equals
        // the prior's information · (fitted − prior).
        let prior_pull = (fitted - prior.correction).component_div(&prior.sigma.component_mul(&prior.sigma));
        Some(Self { correction: fitted + covariance * prior_pull, covariance })
    }
}

/// Learns the lasting part of a camera's calibration error from the bursts' measurements: the
/// information-weighted mean of the recent measurements that agree with their median, once at
/// least [`MIN_AGREEING`] do, and the spread of the part that changes from stance to stance; and
/// gives the calibration each burst's fits start from.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CalibrationTracker {
    /// The last [`WINDOW`] measurements, oldest first.
    recent: Vec<CameraMeasurement>,
    /// What the recent measurements agree on.
    learnt: Option<Consensus>,
}

/// The offset the recent measurements agree on.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Consensus {
    /// The lasting (pitch, roll) offset, radians.
    offset: Vector2<f64>,
    /// Its covariance, radians².
    covariance: Matrix2<f64>,
    /// Standard deviation of the stance's part in (pitch, roll), radians.
    stance: Vector2<f64>,
    /// How many measurements agree on it.
    agreeing: usize,
}

impl CalibrationTracker {
    /// The calibration the next burst's fits start from: the learnt offset, with its uncertainty and
    /// the stance's; the default where nothing is learnt yet.
    pub fn calibration(&self) -> CameraCalibration {
        match &self.learnt {
            Some(learnt) => CameraCalibration {
                correction: learnt.offset,
                sigma: (learnt.covariance.diagonal() + learnt.stance.component_mul(&learnt.stance))
                    .map(f64::sqrt),
            },
            None => CameraCalibration::default(),
        }
    }

    /// How many of the recent measurements agree on the learnt offset (0: nothing learnt).
    pub fn learnt(&self) -> usize {
        self.learnt.map_or(0, |learnt| learnt.agreeing)
    }

    /// Takes one burst's measurement (one that is not finite or looser than
    /// [`MAX_MEASUREMENT_SIGMA`] is left out) and learns again from the recent ones.
    pub fn learn(&mut self, measured: &CameraMeasurement) {
        let finite = measured.correction.iter().chain(measured.covariance.iter()).all(|v| v.is_finite());
        if !finite
            || measured.covariance.diagonal().iter().any(|&v| v <= 0.0 || v > MAX_MEASUREMENT_SIGMA.powi(2))
        {
            return;
        }
        if self.recent.len() == WINDOW {
            self.recent.remove(0);
        }
        self.recent.push(*measured);
        self.learnt = self.consensus();
    }

    /// The information-weighted mean of the recent measurements within [`AGREE_SIGMAS`] of their
    /// median (their own σ and the stance's), with its covariance, where at least [`MIN_AGREEING`]
    /// agree. The stance's spread is what the measurements scatter about their median beyond their
    /// own σ (by their median absolute deviation), at least [`MIN_STANCE_SIGMA`].
    fn consensus(&self) -> Option<Consensus> {
        let median = |values: &mut Vec<f64>| {
            values.sort_by(f64::total_cmp);
            values[values.len() / 2]
        };
        let axis_median =
            |value: &dyn Fn(&CameraMeasurement) -> f64| median(&mut self.recent.iter().map(value).collect());
        let centre = Vector2::new(axis_median(&|m| m.correction.x), axis_median(&|m| m.correction.y));
        let stance = Vector2::from_fn(|axis, _| {
            let deviation = axis_median(&|m| (m.correction[axis] - centre[axis]).abs()) / MAD_PER_SIGMA;
            let own = axis_median(&|m| m.covariance[(axis, axis)]);
            (deviation * deviation - own).max(MIN_STANCE_SIGMA * MIN_STANCE_SIGMA).sqrt()
        });
        let stance_covariance = Matrix2::from_diagonal(&stance.component_mul(&stance));
        let (mut information, mut weighted, mut agreeing) = (Matrix2::zeros(), Vector2::zeros(), 0);
        for measured in &self.recent {
            let Some(inverse) = (measured.covariance + stance_covariance).try_inverse() else { continue };
            let off = measured.correction - centre;
            if off.dot(&(inverse * off)) <= AGREE_SIGMAS * AGREE_SIGMAS {
                information += inverse;
                weighted += inverse * measured.correction;
                agreeing += 1;
            }
        }
        let covariance = information.try_inverse().filter(|_| agreeing >= MIN_AGREEING)?;
        Some(Consensus { offset: covariance * weighted, covariance, stance, agreeing })
    }
}

impl std::fmt::Display for CalibrationTracker {
    /// E.g. `pitch +0.68°, roll -0.41° (σ 0.12°, 0.10°; stance σ 0.30°, 0.30°; 9 of the last 12 bursts agree)`.
    fn fmt(&self, formatter: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Some(learnt) = &self.learnt else {
            return write!(formatter, "nothing learnt ({} measurements)", self.recent.len());
        };
        let sigma = learnt.covariance.diagonal().map(|variance| variance.max(0.0).sqrt().to_degrees());
        write!(
            formatter,
            "pitch {:+.2}°, roll {:+.2}° (σ {:.2}°, {:.2}°; stance σ {:.2}°, {:.2}°; {} of the last {} bursts agree)",
            learnt.offset.x.to_degrees(),
            learnt.offset.y.to_degrees(),
            sigma.x,
            sigma.y,
            learnt.stance.x.to_degrees(),
            learnt.stance.y.to_degrees(),
            learnt.agreeing,
            self.recent.len()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn degrees(pitch: f64, roll: f64) -> Vector2<f64> {
        Vector2::new(pitch.to_radians(), roll.to_radians())
    }

    fn measurement(pitch: f64, roll: f64, sigma_degrees: f64) -> CameraMeasurement {
        CameraMeasurement {
            correction: degrees(pitch, roll),
            covariance: Matrix2::from_diagonal_element(sigma_degrees.to_radians().powi(2)),
        }
    }

    #[test]
    fn learns_a_lasting_offset_and_narrows_the_prior() {
        let mut tracker = CalibrationTracker::default();
        let before = tracker.calibration();
        assert_eq!(before, CameraCalibration::default());
        // Measurements scattered about (0.7°, −0.4°) by a stance error.
        let scatter = [0.2, -0.3, 0.1, -0.1, 0.25, -0.2, 0.0, 0.15, -0.25, 0.05];
        for (index, scatter) in scatter.iter().enumerate() {
            tracker.learn(&measurement(0.7 + scatter, -0.4 - scatter, 0.3));
            let learnt = if index + 1 >= MIN_AGREEING { index + 1 } else { 0 };
            assert_eq!(tracker.learnt(), learnt, "burst {index}");
        }
        let learnt = tracker.calibration();
        assert!((learnt.correction - degrees(0.7, -0.4)).amax() < 0.1_f64.to_radians(), "{learnt:?}");
        assert!(learnt.sigma.x < 0.5 * before.sigma.x);
        // Never tighter than the stance's own error: this scatter is what the measurements' σ explains.
        assert!(learnt.sigma.x > MIN_STANCE_SIGMA);
        assert!(tracker.to_string().contains("stance σ 0.30°, 0.30°"), "{tracker}");
        assert!(tracker.to_string().ends_with("10 of the last 10 bursts agree)"), "{tracker}");
    }

    #[test]
    fn a_stance_that_moves_the_camera_more_widens_the_prior() {
        let mut tracker = CalibrationTracker::default();
        // Sharp measurements (σ 0.1°) scattered about (0.7°, −0.4°) by about 0.6° from stance to stance.
        let scatter =
            [-0.9, 0.6, -0.45, 0.3, -0.2, 0.75, 0.0, -0.6, 0.1, 0.2, -0.3, 0.45, -0.1, 0.9, -0.75, 0.05];
        for (index, scatter) in scatter.iter().enumerate() {
            tracker.learn(&measurement(0.7 + scatter, -0.4 - scatter, 0.1));
            assert!(tracker.learnt() > 0 || index + 1 < MIN_AGREEING, "burst {index}: {tracker}");
        }
        let learnt = tracker.calibration();
        assert!((learnt.correction - degrees(0.7, -0.4)).amax() < 0.2_f64.to_radians(), "{tracker}");
        for sigma in learnt.sigma.iter() {
            assert!((0.45..0.8).contains(&sigma.to_degrees()), "{tracker}");
        }
        assert_eq!(tracker.learnt(), WINDOW, "{tracker}");
    }

    #[test]
    fn a_wrong_fit_teaches_nothing_and_is_outvoted() {
        let mut tracker = CalibrationTracker::default();
        tracker.learn(&measurement(-2.5, 2.0, 0.2));
        assert_eq!(tracker.calibration(), CameraCalibration::default(), "one burst alone");
        for _ in 0..4 {
            tracker.learn(&measurement(0.5, 0.0, 0.2));
        }
        assert_eq!(tracker.learnt(), 4);
        assert!((tracker.calibration().correction - degrees(0.5, 0.0)).amax() < 1e-9);
        // Not a number, or too loose to tell: left out.
        let not_a_number =
            CameraMeasurement { correction: Vector2::new(f64::NAN, 0.0), ..measurement(0.0, 0.0, 0.2) };
        tracker.learn(&not_a_number);
        tracker.learn(&measurement(3.0, 0.0, 1.0));
        assert_eq!(tracker.learnt(), 4);
        assert!(tracker.to_string().contains("4 of the last 5 bursts agree"), "{tracker}");
    }

    #[test]
    fn old_measurements_fall_out() {
        let mut tracker = CalibrationTracker::default();
        for _ in 0..WINDOW {
            tracker.learn(&measurement(0.5, 0.0, 0.2));
        }
        // The head was knocked: from now on the error is another.
        for _ in 0..WINDOW {
            tracker.learn(&measurement(-0.3, 0.2, 0.2));
        }
        assert!((tracker.calibration().correction - degrees(-0.3, 0.2)).amax() < 1e-9);
        assert_eq!(tracker.learnt(), WINDOW);
    }

    #[test]
    fn a_measurement_takes_the_prior_pull_out_of_a_fit() {
        // Lines alone say 1°; a prior at 0 with σ 1° and lines of σ 0.5° put the fit at 0.8°.
        let prior = CameraCalibration { correction: Vector2::zeros(), sigma: degrees(1.0, 1.0) };
        let information = Matrix2::from_diagonal_element(1.0 / 0.5_f64.to_radians().powi(2));
        let measured = CameraMeasurement::from_fit(degrees(0.8, 0.0), &information, &prior).unwrap();
        assert!((measured.correction - degrees(1.0, 0.0)).amax() < 1e-9, "{measured:?}");
        // Lines that hardly fix the correction measure nothing.
        let loose = Matrix2::from_diagonal_element(1.0 / 2.0_f64.to_radians().powi(2));
        assert!(CameraMeasurement::from_fit(degrees(0.1, 0.0), &loose, &prior).is_none());
        assert!(CameraMeasurement::from_fit(degrees(0.1, 0.0), &Matrix2::zeros(), &prior).is_none());
    }
}
