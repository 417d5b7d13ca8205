//! The field's symmetries and the four output representations of the thesis (chapter 3).
//!
//! A representation folds a full-field pose into a canonical region and remembers, one bit per
//! generator, which symmetries it applied. Unfolding a (predicted) folded pose with the network's
//! probability for each bit gives the weighted full-field hypotheses.
//!
//! | representation | generators (bit order)      | canonical region                 | hypotheses |
//! |----------------|-----------------------------|----------------------------------|------------|
//! | `full`         | none                        | the whole field                  | 1          |
//! | `half-point`   | point reflection            | own half, x ≤ 0                  | 2          |
//! | `half-line`    | long-axis mirror            | left half, y ≥ 0                 | 2          |
//! | `quarter`      | long-axis, short-axis mirror| own left quarter, x ≤ 0 and y ≥ 0| 4          |
//!
//! **On a symmetry line.** A mirror fixes the points of its line, so a pose exactly on it (y = 0 for
//! the long-axis mirror, x = 0 for the short-axis one) is canonical and folds to itself with bit 0.
//! The point reflection fixes no pose (it turns the heading by π), so its canonical region is
//! half-open: x < 0; on x = 0 the side y > 0; at the centre spot headings in (−π/2, π/2].
//!
//! The thesis cuts the point-symmetric half at y = 0 (Algorithm 1); relocd cuts at x = 0 instead: the
//! cut through the field is 6 m long instead of 9 m, so fewer poses lie near it, and the poses a
//! penalised robot returns to (own half, by the touchlines) are canonical and far from the cut.

use std::f64::consts::{FRAC_PI_2, PI};
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::angle::normalize_angle;
use super::pose::{FieldPose, PoseError};

/// Why a folded prediction could not be unfolded.
#[derive(Debug, Error, PartialEq)]
pub enum SymmetryError {
    /// The number of fold probabilities does not match the representation.
    #[error("representation {representation} has {expected} fold bit(s), got {found} probabilities")]
    WrongBitCount {
        /// The representation.
        representation: Representation,
        /// Its number of fold bits.
        expected: usize,
        /// The number given.
        found: usize,
    },
    /// A probability is NaN or outside [0, 1].
    #[error("fold probability {index} is {value}: expected a number in [0, 1]")]
    BadProbability {
        /// Which bit.
        index: usize,
        /// The value given.
        value: f64,
    },
    /// A representation name that is not one of the four.
    #[error("unknown representation {0:?}: expected full, half-point, half-line or quarter")]
    UnknownRepresentation(String),
}

/// One element of the field's symmetry group, acting on full-field poses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Symmetry {
    /// Leaves the pose as it is.
    Identity,
    /// Point reflection through the centre spot: (x, y, θ) → (−x, −y, θ + π). The image seen from
    /// both poses is the same.
    PointReflection,
    /// Mirror across the long axis (y = 0): (x, y, θ) → (x, −y, −θ). The image is mirrored
    /// horizontally.
    MirrorLongAxis,
    /// Mirror across the centre line (x = 0): (x, y, θ) → (−x, y, π − θ). The image is mirrored
    /// horizontally.
    MirrorShortAxis,
}

impl Symmetry {
    /// The group elements of the field: the identity, the two mirrors and their product.
    pub const ALL: [Symmetry; 4] =
        [Symmetry::Identity, Symmetry::PointReflection, Symmetry::MirrorLongAxis, Symmetry::MirrorShortAxis];

    /// Applies the symmetry to a full-field pose.
    pub fn apply(self, pose: &FieldPose) -> FieldPose {
        let (x, y, heading) = self.apply_raw(pose.x(), pose.y(), pose.heading());
        FieldPose::from_finite(x, y, heading)
    }

    fn apply_raw(self, x: f64, y: f64, heading: f64) -> (f64, f64, f64) {
        match self {
            Symmetry::Identity => (x, y, heading),
            Symmetry::PointReflection => (-x, -y, normalize_angle(heading + PI)),
            Symmetry::MirrorLongAxis => (x, -y, normalize_angle(-heading)),
            Symmetry::MirrorShortAxis => (-x, y, normalize_angle(PI - heading)),
        }
    }

    /// Whether the symmetry maps the camera image to its horizontal mirror image.
    pub fn mirrors_image(self) -> bool {
        matches!(self, Symmetry::MirrorLongAxis | Symmetry::MirrorShortAxis)
    }

    /// Whether (x, y, θ) lies on the side this generator leaves alone (see the module docs).
    fn keeps(self, x: f64, y: f64, heading: f64) -> bool {
        match self {
            Symmetry::Identity => true,
            Symmetry::PointReflection => {
                x < 0.0
                    || (x == 0.0 && y > 0.0)
                    || (x == 0.0 && y == 0.0 && heading > -FRAC_PI_2 && heading <= FRAC_PI_2)
            }
            Symmetry::MirrorLongAxis => y >= 0.0,
            Symmetry::MirrorShortAxis => x <= 0.0,
        }
    }
}

/// Which of a representation's generators folding applied: bit i is generator i.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct FoldClass(pub u8);

impl FoldClass {
    /// Whether generator `index` was applied.
    pub fn bit(self, index: usize) -> bool {
        self.0 & (1 << index) != 0
    }
}

/// The output representation a network was trained for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Representation {
    /// The full field, no folding.
    Full,
    /// Half field by the point symmetry (thesis Algorithm 1).
    HalfPoint,
    /// Half field by the long-axis mirror (thesis Algorithm 2).
    HalfLine,
    /// Quarter field by both mirrors.
    Quarter,
}

impl Representation {
    /// All four representations.
    pub const ALL: [Representation; 4] =
        [Representation::Full, Representation::HalfPoint, Representation::HalfLine, Representation::Quarter];

    /// The generators, one per fold bit, in bit order.
    pub fn generators(self) -> &'static [Symmetry] {
        match self {
            Representation::Full => &[],
            Representation::HalfPoint => &[Symmetry::PointReflection],
            Representation::HalfLine => &[Symmetry::MirrorLongAxis],
            Representation::Quarter => &[Symmetry::MirrorLongAxis, Symmetry::MirrorShortAxis],
        }
    }

    /// Number of fold bits the network predicts.
    pub fn fold_bits(self) -> usize {
        self.generators().len()
    }

    /// Number of full-field hypotheses one folded pose unfolds to.
    pub fn hypothesis_count(self) -> usize {
        1 << self.fold_bits()
    }

    /// The representation's name as written in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Representation::Full => "full",
            Representation::HalfPoint => "half-point",
            Representation::HalfLine => "half-line",
            Representation::Quarter => "quarter",
        }
    }

    /// Folds a full-field pose into the canonical region.
    pub fn fold(self, pose: &FieldPose) -> (FoldedPose, FoldClass) {
        let (mut x, mut y, mut heading) = (pose.x(), pose.y(), pose.heading());
        let mut class = 0u8;
        for (index, generator) in self.generators().iter().enumerate() {
            if !generator.keeps(x, y, heading) {
                (x, y, heading) = generator.apply_raw(x, y, heading);
                class |= 1 << index;
            }
        }
        (FoldedPose { representation: self, x, y, heading }, FoldClass(class))
    }

    /// Whether a pose lies in the canonical region (folding leaves it unchanged).
    pub fn is_canonical(self, pose: &FieldPose) -> bool {
        self.generators().iter().all(|generator| generator.keeps(pose.x(), pose.y(), pose.heading()))
    }
}

impl fmt::Display for Representation {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        formatter.write_str(self.name())
    }
}

impl FromStr for Representation {
    type Err = SymmetryError;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|representation| representation.name() == name)
            .ok_or_else(|| SymmetryError::UnknownRepresentation(name.to_string()))
    }
}

/// A pose in a representation's folded field, as the network predicts it. It need not lie exactly
/// inside the canonical region (a prediction can overshoot the cut); unfolding works all the same.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FoldedPose {
    representation: Representation,
    x: f64,
    y: f64,
    heading: f64,
}

/// One full-field pose hypothesis with its weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hypothesis {
    /// The pose on the full field.
    pub pose: FieldPose,
    /// Probability of this hypothesis; a set's weights sum to 1.
    pub weight: f64,
    /// Which fold class it unfolds.
    pub class: FoldClass,
}

impl FoldedPose {
    /// A folded pose predicted for `representation`; the heading is wrapped into (−π, π].
    pub fn new(representation: Representation, x: f64, y: f64, heading: f64) -> Result<Self, PoseError> {
        let pose = FieldPose::new(x, y, heading)?;
        Ok(Self { representation, x: pose.x(), y: pose.y(), heading: pose.heading() })
    }

    /// The representation whose folded field this pose lives in.
    pub fn representation(&self) -> Representation {
        self.representation
    }

    /// x in the folded field, metres.
    pub fn x(&self) -> f64 {
        self.x
    }

    /// y in the folded field, metres.
    pub fn y(&self) -> f64 {
        self.y
    }

    /// Heading in the folded field, radians in (−π, π].
    pub fn heading(&self) -> f64 {
        self.heading
    }

    /// The full-field pose of one fold class: undoes the class's generators in reverse order.
    pub fn unfold_class(&self, class: FoldClass) -> FieldPose {
        let (mut x, mut y, mut heading) = (self.x, self.y, self.heading);
        for (index, generator) in self.representation.generators().iter().enumerate().rev() {
            if class.bit(index) {
                (x, y, heading) = generator.apply_raw(x, y, heading);
            }
        }
        FieldPose::from_finite(x, y, heading)
    }

    /// Unfolds into all full-field hypotheses, weighted by the network's probability that each fold
    /// bit is set (independent bits). The weights sum to 1.
    pub fn unfold(&self, bit_probabilities: &[f64]) -> Result<Vec<Hypothesis>, SymmetryError> {
        let bits = self.representation.fold_bits();
        if bit_probabilities.len() != bits {
            return Err(SymmetryError::WrongBitCount {
                representation: self.representation,
                expected: bits,
                found: bit_probabilities.len(),
            });
        }
        if let Some((index, &value)) =
            bit_probabilities.iter().enumerate().find(|(_, value)| !(0.0..=1.0).contains(*value))
        {
            return Err(SymmetryError::BadProbability { index, value });
        }
        Ok((0..self.representation.hypothesis_count())
            .map(|class| {
                let class = FoldClass(class as u8);
                let weight = bit_probabilities
                    .iter()
                    .enumerate()
                    .map(|(index, &p)| if class.bit(index) { p } else { 1.0 - p })
                    .product();
                Hypothesis { pose: self.unfold_class(class), weight, class }
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::angle::angle_distance;
    use approx::assert_abs_diff_eq;
    use proptest::prelude::*;

    const TOLERANCE: f64 = 1e-9;

    fn same_pose(a: &FieldPose, b: &FieldPose) -> bool {
        a.distance_to(b) < TOLERANCE && angle_distance(a.heading(), b.heading()) < TOLERANCE
    }

    fn pose(x: f64, y: f64, heading: f64) -> FieldPose {
        FieldPose::new(x, y, heading).unwrap()
    }

    fn any_pose() -> impl Strategy<Value = FieldPose> {
        (-5.2f64..5.2, -3.7f64..3.7, -PI..PI).prop_map(|(x, y, heading)| pose(x, y, heading))
    }

    fn any_representation() -> impl Strategy<Value = Representation> {
        proptest::sample::select(Representation::ALL.to_vec())
    }

    fn probabilities(count: usize) -> impl Strategy<Value = Vec<f64>> {
        proptest::collection::vec(0.0f64..=1.0, count)
    }

    #[test]
    fn half_point_folds_the_opponent_half_through_the_centre() {
        let (folded, class) = Representation::HalfPoint.fold(&pose(3.0, 1.0, 0.5));
        assert_eq!(class, FoldClass(1));
        assert_eq!((folded.x(), folded.y()), (-3.0, -1.0));
        assert_abs_diff_eq!(folded.heading(), 0.5 - PI, epsilon = 1e-12);
        assert_eq!(Representation::HalfPoint.fold(&pose(-3.0, -1.0, 0.5)).1, FoldClass(0));
    }

    #[test]
    fn half_line_mirrors_the_right_half() {
        let (folded, class) = Representation::HalfLine.fold(&pose(3.0, -1.0, 0.5));
        assert_eq!(class, FoldClass(1));
        assert_eq!((folded.x(), folded.y(), folded.heading()), (3.0, 1.0, -0.5));
    }

    #[test]
    fn quarter_sets_one_bit_per_mirror() {
        let (folded, class) = Representation::Quarter.fold(&pose(2.0, -1.0, 0.25));
        assert_eq!(class, FoldClass(0b11));
        assert_eq!((folded.x(), folded.y()), (-2.0, 1.0));
        assert_abs_diff_eq!(folded.heading(), 0.25 - PI, epsilon = 1e-12);
    }

    #[test]
    fn poses_on_a_mirror_line_are_canonical() {
        let on_long_axis = pose(2.0, 0.0, -1.0);
        assert_eq!(Representation::HalfLine.fold(&on_long_axis).1, FoldClass(0));
        let on_centre_line = pose(0.0, -1.0, 1.0);
        assert_eq!(Representation::Quarter.fold(&on_centre_line).1, FoldClass(0b01));
    }

    #[test]
    fn point_cut_is_half_open() {
        assert_eq!(Representation::HalfPoint.fold(&pose(0.0, 1.0, 2.0)).1, FoldClass(0));
        assert_eq!(Representation::HalfPoint.fold(&pose(0.0, -1.0, 2.0)).1, FoldClass(1));
        assert_eq!(Representation::HalfPoint.fold(&pose(0.0, 0.0, 0.3)).1, FoldClass(0));
        let (folded, class) = Representation::HalfPoint.fold(&pose(0.0, 0.0, 2.0));
        assert_eq!(class, FoldClass(1));
        assert_abs_diff_eq!(folded.heading(), 2.0 - PI, epsilon = 1e-12);
    }

    #[test]
    fn unfold_rejects_bad_probabilities() {
        let folded = FoldedPose::new(Representation::Quarter, -1.0, 1.0, 0.0).unwrap();
        assert_eq!(
            folded.unfold(&[0.5]).unwrap_err().to_string(),
            "representation quarter has 2 fold bit(s), got 1 probabilities"
        );
        assert!(matches!(
            folded.unfold(&[0.5, f64::NAN]),
            Err(SymmetryError::BadProbability { index: 1, .. })
        ));
        assert!(folded.unfold(&[1.5, 0.0]).is_err());
    }

    #[test]
    fn unfold_weights_follow_the_bit_probabilities() {
        let folded = FoldedPose::new(Representation::Quarter, -1.0, 1.0, 0.0).unwrap();
        let hypotheses = folded.unfold(&[0.2, 0.9]).unwrap();
        let weights: Vec<f64> = hypotheses.iter().map(|h| h.weight).collect();
        for (weight, expected) in weights.iter().zip([0.8 * 0.1, 0.2 * 0.1, 0.8 * 0.9, 0.2 * 0.9]) {
            assert_abs_diff_eq!(*weight, expected, epsilon = 1e-12);
        }
        assert!(same_pose(&hypotheses[3].pose, &pose(1.0, -1.0, PI)));
    }

    #[test]
    fn representation_names_round_trip() {
        for representation in Representation::ALL {
            assert_eq!(representation.name().parse::<Representation>().unwrap(), representation);
            let json = serde_json::to_string(&representation).unwrap();
            assert_eq!(json, format!("\"{}\"", representation.name()));
        }
        assert!("half".parse::<Representation>().unwrap_err().to_string().contains("half-point"));
    }

    proptest! {
        #[test]
        fn unfolding_a_fold_contains_the_pose(
            original in any_pose(), representation in any_representation(), seed in probabilities(2),
        ) {
            let (folded, class) = representation.fold(&original);
            let hypotheses = folded.unfold(&seed[..representation.fold_bits()]).unwrap();
            prop_assert_eq!(hypotheses.len(), representation.hypothesis_count());
            let matching = hypotheses.iter().find(|h| h.class == class).unwrap();
            prop_assert!(same_pose(&matching.pose, &original), "{:?} vs {:?}", matching.pose, original);
        }

        #[test]
        fn hypotheses_are_images_of_each_other(
            original in any_pose(), representation in any_representation(), seed in probabilities(2),
        ) {
            let (folded, _) = representation.fold(&original);
            let hypotheses = folded.unfold(&seed[..representation.fold_bits()]).unwrap();
            for a in &hypotheses {
                for b in &hypotheses {
                    let related = Symmetry::ALL.iter().any(|g| same_pose(&g.apply(&a.pose), &b.pose));
                    prop_assert!(related, "{:?} and {:?} are not symmetric", a.pose, b.pose);
                }
            }
        }

        #[test]
        fn folding_is_idempotent_and_canonical(original in any_pose(), representation in any_representation()) {
            let (folded, _) = representation.fold(&original);
            let canonical = folded.unfold_class(FoldClass(0));
            prop_assert!(representation.is_canonical(&canonical));
            let (again, class) = representation.fold(&canonical);
            prop_assert_eq!(class, FoldClass(0));
            prop_assert_eq!(again, folded);
        }

        #[test]
        fn headings_stay_normalised_and_weights_sum_to_one(
            original in any_pose(), representation in any_representation(), seed in probabilities(2),
        ) {
            let (folded, _) = representation.fold(&original);
            prop_assert!(folded.heading() > -PI && folded.heading() <= PI);
            let hypotheses = folded.unfold(&seed[..representation.fold_bits()]).unwrap();
            let total: f64 = hypotheses.iter().map(|h| h.weight).sum();
            prop_assert!((total - 1.0).abs() < 1e-12);
            for hypothesis in &hypotheses {
                prop_assert!(hypothesis.weight >= 0.0);
                prop_assert!(hypothesis.pose.heading() > -PI && hypothesis.pose.heading() <= PI);
            }
        }

        #[test]
        fn symmetric_poses_fold_to_the_same_canonical_pose(original in any_pose(), representation in any_representation()) {
            let (folded, _) = representation.fold(&original);
            for generator in representation.generators() {
                let (image_folded, _) = representation.fold(&generator.apply(&original));
                let a = folded.unfold_class(FoldClass(0));
                let b = image_folded.unfold_class(FoldClass(0));
                prop_assert!(same_pose(&a, &b), "{:?} vs {:?}", a, b);
            }
        }
    }
}
