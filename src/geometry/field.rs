//! The field model: the SPL field as data (dimensions) and as geometry (painted lines, circle, marks,
//! goals) in the field frame.

use std::path::Path;

use nalgebra::{Point2, Vector2};
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// The default field, embedded: the SPL field of the 2025 rules.
pub const SPL_2025_TOML: &str = include_str!("spl_2025.toml");

/// Why a field description was rejected.
#[derive(Debug, Error)]
pub enum FieldError {
    /// The file could not be read.
    #[error("cannot read field file {path}: {error}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error (in the message, so not also a source to print twice).
        error: std::io::Error,
    },
    /// The file is not valid TOML/JSON for a field, or has unknown or missing keys.
    #[error("field file {path} is not a valid field description: {reason}")]
    Parse {
        /// The file.
        path: String,
        /// The parser's message.
        reason: String,
    },
    /// A dimension is not positive or does not fit with the others.
    #[error("field dimension {key} = {value} m is invalid: {reason}")]
    Invalid {
        /// The offending key.
        key: &'static str,
        /// Its value.
        value: f64,
        /// What it must satisfy.
        reason: String,
    },
}

/// The numbers that define a field (metres, to line centres), as in the rule book.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FieldDimensions {
    /// Distance between the two goal lines.
    pub field_length: f64,
    /// Distance between the two touchlines.
    pub field_width: f64,
    /// Width of every painted line.
    pub line_width: f64,
    /// Diameter of the centre circle.
    pub centre_circle_diameter: f64,
    /// Depth of the penalty area, from the goal line.
    pub penalty_area_length: f64,
    /// Width of the penalty area.
    pub penalty_area_width: f64,
    /// Depth of the goal area, from the goal line.
    pub goal_area_length: f64,
    /// Width of the goal area.
    pub goal_area_width: f64,
    /// Distance of the penalty marks from the goal lines.
    pub penalty_mark_distance: f64,
    /// Arm length of the penalty-mark and centre-mark crosses.
    pub mark_size: f64,
    /// Carpet outside the outer lines.
    pub border_strip_width: f64,
    /// Clear width between the goal posts.
    pub goal_inner_width: f64,
    /// Depth of the goal behind the goal line.
    pub goal_depth: f64,
    /// Height of the goal (top of the crossbar).
    pub goal_height: f64,
    /// Diameter of the posts and the crossbar.
    pub goal_post_diameter: f64,
}

impl FieldDimensions {
    /// The SPL field of the 2025 rules.
    pub fn spl_2025() -> Self {
        Self::from_toml(SPL_2025_TOML).expect("the embedded field description is valid")
    }

    /// Parses and validates a TOML field description.
    pub fn from_toml(text: &str) -> Result<Self, FieldError> {
        let dimensions: Self = toml::from_str(text)
            .map_err(|error| FieldError::Parse { path: "<toml>".into(), reason: error.to_string() })?;
        dimensions.validate()?;
        Ok(dimensions)
    }

    /// Loads a field description from a `.toml` or `.json` file and validates it.
    pub fn load(path: &Path) -> Result<Self, FieldError> {
        let name = path.display().to_string();
        let text =
            std::fs::read_to_string(path).map_err(|error| FieldError::Read { path: name.clone(), error })?;
        let parsed: Result<Self, String> =
            if path.extension().is_some_and(|extension| extension.eq_ignore_ascii_case("json")) {
                serde_json::from_str(&text).map_err(|error| error.to_string())
            } else {
                toml::from_str(&text).map_err(|error| error.to_string())
            };
        let dimensions = parsed.map_err(|reason| FieldError::Parse { path: name, reason })?;
        dimensions.validate()?;
        Ok(dimensions)
    }

    /// The description as TOML, the format `load` reads.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("field dimensions serialise")
    }

    /// Half the carpet's length: the largest |x| on the carpet.
    pub fn carpet_half_length(&self) -> f64 {
        self.field_length / 2.0 + self.border_strip_width
    }

    /// Half the carpet's width: the largest |y| on the carpet.
    pub fn carpet_half_width(&self) -> f64 {
        self.field_width / 2.0 + self.border_strip_width
    }

    /// Checks every dimension is positive and that the parts fit inside each other.
    pub fn validate(&self) -> Result<(), FieldError> {
        let invalid =
            |key, value, reason: &str| Err(FieldError::Invalid { key, value, reason: reason.to_string() });
        let positive = [
            ("field_length", self.field_length),
            ("field_width", self.field_width),
            ("line_width", self.line_width),
            ("centre_circle_diameter", self.centre_circle_diameter),
            ("penalty_area_length", self.penalty_area_length),
            ("penalty_area_width", self.penalty_area_width),
            ("goal_area_length", self.goal_area_length),
            ("goal_area_width", self.goal_area_width),
            ("penalty_mark_distance", self.penalty_mark_distance),
            ("mark_size", self.mark_size),
            ("goal_inner_width", self.goal_inner_width),
            ("goal_depth", self.goal_depth),
            ("goal_height", self.goal_height),
            ("goal_post_diameter", self.goal_post_diameter),
        ];
        for (key, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return invalid(key, value, "must be a positive number of metres");
            }
        }
        if !(self.border_strip_width.is_finite() && self.border_strip_width >= 0.0) {
            return invalid("border_strip_width", self.border_strip_width, "must be >= 0");
        }
        let half_length = self.field_length / 2.0;
        if self.penalty_area_length >= half_length {
            return invalid(
                "penalty_area_length",
                self.penalty_area_length,
                "must be shorter than half the field_length",
            );
        }
        if self.penalty_area_width >= self.field_width {
            return invalid(
                "penalty_area_width",
                self.penalty_area_width,
                "must be narrower than field_width",
            );
        }
        if self.goal_area_length >= self.penalty_area_length {
            return invalid(
                "goal_area_length",
                self.goal_area_length,
                "must be shorter than penalty_area_length",
            );
        }
        if self.goal_area_width >= self.penalty_area_width {
            return invalid(
                "goal_area_width",
                self.goal_area_width,
                "must be narrower than penalty_area_width",
            );
        }
        if self.penalty_mark_distance >= half_length {
            return invalid(
                "penalty_mark_distance",
                self.penalty_mark_distance,
                "must be less than half the field_length",
            );
        }
        if self.centre_circle_diameter >= self.field_width.min(self.field_length) {
            return invalid(
                "centre_circle_diameter",
                self.centre_circle_diameter,
                "must fit inside the field",
            );
        }
        if self.goal_inner_width + 2.0 * self.goal_post_diameter >= self.field_width {
            return invalid(
                "goal_inner_width",
                self.goal_inner_width,
                "the goal must fit between the touchlines",
            );
        }
        if self.line_width >= self.mark_size.min(self.goal_area_length) {
            return invalid(
                "line_width",
                self.line_width,
                "must be thinner than the marks and the goal area",
            );
        }
        Ok(())
    }
}

impl Default for FieldDimensions {
    fn default() -> Self {
        Self::spl_2025()
    }
}

/// A painted straight line, given by the end points of its centre line. It is drawn `line_width`
/// wide with square caps (extended by half the width past each end) so that corners close.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineSegment {
    /// One end of the centre line.
    pub start: Point2<f64>,
    /// The other end of the centre line.
    pub end: Point2<f64>,
}

impl LineSegment {
    fn new(start: (f64, f64), end: (f64, f64)) -> Self {
        Self { start: Point2::new(start.0, start.1), end: Point2::new(end.0, end.1) }
    }

    /// Distance from `point` to the centre line segment.
    pub fn distance_to(&self, point: Point2<f64>) -> f64 {
        let direction = self.end - self.start;
        let along = ((point - self.start).dot(&direction) / direction.norm_squared()).clamp(0.0, 1.0);
        (point - (self.start + direction * along)).norm()
    }

    /// Whether `point` is on the painted line of width `width` (square caps).
    pub fn covers(&self, point: Point2<f64>, width: f64) -> bool {
        // The paint reaches at most width/√2 beyond the segment on either axis: a point outside the
        // segment's box grown by the width is off it, without the root and division below.
        let (low, high) = (self.start.coords.inf(&self.end.coords), self.start.coords.sup(&self.end.coords));
        if point.x < low.x - width
            || point.x > high.x + width
            || point.y < low.y - width
            || point.y > high.y + width
        {
            return false;
        }
        let direction = self.end - self.start;
        let length = direction.norm();
        let unit = direction / length;
        let offset = point - self.start;
        let along = offset.dot(&unit);
        let across = offset.perp(&unit);
        across.abs() <= width / 2.0 && along >= -width / 2.0 && along <= length + width / 2.0
    }
}

/// A painted circle, given by the radius of its centre line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Circle {
    /// Centre of the circle.
    pub centre: Point2<f64>,
    /// Radius to the middle of the painted line.
    pub radius: f64,
}

impl Circle {
    /// Distance from `point` to the circle's centre line.
    pub fn distance_to(&self, point: Point2<f64>) -> f64 {
        ((point - self.centre).norm() - self.radius).abs()
    }

    /// Whether `point` is on the painted circle of line width `width`.
    pub fn covers(&self, point: Point2<f64>, width: f64) -> bool {
        // Outside the circle's box grown by the width, without the root.
        let reach = self.radius + width;
        if (point.x - self.centre.x).abs() > reach || (point.y - self.centre.y).abs() > reach {
            return false;
        }
        self.distance_to(point) <= width / 2.0
    }
}

/// A painted cross (penalty marks, centre mark): two arms of `size` length and line width, aligned
/// with the field axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mark {
    /// Centre of the cross.
    pub centre: Point2<f64>,
    /// Length of each arm.
    pub size: f64,
}

impl Mark {
    /// Whether `point` is on the painted cross of line width `width`.
    pub fn covers(&self, point: Point2<f64>, width: f64) -> bool {
        let offset = point - self.centre;
        let (along, across) = (offset.x.abs(), offset.y.abs());
        let half_arm = self.size / 2.0;
        (along <= half_arm && across <= width / 2.0) || (across <= half_arm && along <= width / 2.0)
    }
}

/// One goal: two posts and a crossbar, the net behind them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Goal {
    /// The post centres (the post nearer +y first).
    pub posts: [Point2<f64>; 2],
    /// Radius of posts and crossbar.
    pub post_radius: f64,
    /// Height of the top of the crossbar.
    pub height: f64,
    /// x of the net's back plane.
    pub back_x: f64,
}

/// The field as geometry in the field frame: what is painted and what stands on it.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldModel {
    dimensions: FieldDimensions,
    /// Straight painted lines: boundary, centre line, penalty and goal areas.
    pub lines: Vec<LineSegment>,
    /// The centre circle.
    pub circles: Vec<Circle>,
    /// The penalty marks and the centre mark.
    pub marks: Vec<Mark>,
    /// The own goal (x < 0) and the opponent goal (x > 0).
    pub goals: [Goal; 2],
}

impl FieldModel {
    /// Builds the geometry from validated dimensions.
    pub fn new(dimensions: FieldDimensions) -> Self {
        let d = &dimensions;
        let (hl, hw) = (d.field_length / 2.0, d.field_width / 2.0);
        let mut lines = vec![
            LineSegment::new((-hl, hw), (hl, hw)),
            LineSegment::new((-hl, -hw), (hl, -hw)),
            LineSegment::new((-hl, -hw), (-hl, hw)),
            LineSegment::new((hl, -hw), (hl, hw)),
            LineSegment::new((0.0, -hw), (0.0, hw)),
        ];
        for side in [-1.0, 1.0] {
            for (length, width) in
                [(d.penalty_area_length, d.penalty_area_width), (d.goal_area_length, d.goal_area_width)]
            {
                let front = side * (hl - length);
                let half = width / 2.0;
                lines.push(LineSegment::new((front, -half), (front, half)));
                lines.push(LineSegment::new((front, half), (side * hl, half)));
                lines.push(LineSegment::new((front, -half), (side * hl, -half)));
            }
        }
        let marks = [-1.0, 0.0, 1.0]
            .into_iter()
            .map(|side| Mark {
                centre: Point2::new(side * (hl - d.penalty_mark_distance), 0.0),
                size: d.mark_size,
            })
            .collect();
        let post_radius = d.goal_post_diameter / 2.0;
        // The posts' field-side faces are flush with the field-side edge of the goal line.
        let post_x = hl - d.line_width / 2.0 + post_radius;
        let post_y = d.goal_inner_width / 2.0 + post_radius;
        let goal = |side: f64| Goal {
            posts: [Point2::new(side * post_x, post_y), Point2::new(side * post_x, -post_y)],
            post_radius,
            height: d.goal_height,
            back_x: side * (hl + d.goal_depth),
        };
        Self {
            circles: vec![Circle { centre: Point2::origin(), radius: d.centre_circle_diameter / 2.0 }],
            lines,
            marks,
            goals: [goal(-1.0), goal(1.0)],
            dimensions,
        }
    }

    /// The dimensions this model was built from.
    pub fn dimensions(&self) -> &FieldDimensions {
        &self.dimensions
    }

    /// The centres of all four goal posts.
    pub fn goal_posts(&self) -> impl Iterator<Item = Point2<f64>> + '_ {
        self.goals.iter().flat_map(|goal| goal.posts)
    }

    /// Whether a ground point is covered by white paint.
    pub fn is_painted(&self, point: Point2<f64>) -> bool {
        let width = self.dimensions.line_width;
        self.lines.iter().any(|line| line.covers(point, width))
            || self.circles.iter().any(|circle| circle.covers(point, width))
            || self.marks.iter().any(|mark| mark.covers(point, width))
    }

    /// Distance from a ground point to the nearest painted centre line (lines, circle, mark arms).
    pub fn distance_to_nearest_line(&self, point: Point2<f64>) -> f64 {
        let arm = |mark: &Mark, axis: Vector2<f64>| LineSegment {
            start: mark.centre - axis * (mark.size / 2.0),
            end: mark.centre + axis * (mark.size / 2.0),
        };
        let lines = self.lines.iter().map(|line| line.distance_to(point));
        let circles = self.circles.iter().map(|circle| circle.distance_to(point));
        let marks = self.marks.iter().flat_map(|mark| {
            [arm(mark, Vector2::x()).distance_to(point), arm(mark, Vector2::y()).distance_to(point)]
        });
        lines.chain(circles).chain(marks).fold(f64::INFINITY, f64::min)
    }

    /// Whether a ground point is on the carpet (field plus border strip).
    pub fn is_on_carpet(&self, point: Point2<f64>) -> bool {
        point.x.abs() <= self.dimensions.carpet_half_length()
            && point.y.abs() <= self.dimensions.carpet_half_width()
    }
}

impl Default for FieldModel {
    fn default() -> Self {
        Self::new(FieldDimensions::spl_2025())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;

    #[test]
    fn embedded_field_matches_the_rules() {
        let field = FieldModel::default();
        let d = field.dimensions();
        assert_eq!((d.field_length, d.field_width), (9.0, 6.0));
        assert_eq!(d.carpet_half_length(), 5.2);
        assert_eq!(field.marks[0].centre, Point2::new(-3.2, 0.0));
        assert_eq!(field.marks[2].centre, Point2::new(3.2, 0.0));
        assert_abs_diff_eq!(field.goals[1].posts[0], Point2::new(4.525, 0.8), epsilon = 1e-12);
        assert_eq!(field.lines.len(), 5 + 2 * 2 * 3);
    }

    #[test]
    fn paint_covers_lines_marks_and_circle_but_not_carpet() {
        let field = FieldModel::default();
        for painted in [
            (0.0, 0.0),
            (0.0, 2.0),
            (4.5, 1.0),
            (4.52, 3.02),
            (2.85, 2.02),
            (0.75, 0.0),
            (-3.2, 0.04),
            (0.0, -0.75),
        ] {
            assert!(field.is_painted(Point2::new(painted.0, painted.1)), "{painted:?}");
        }
        for carpet in [(1.0, 1.0), (-3.2, 0.1), (4.56, 0.0), (0.8, 0.0), (2.8, 0.5), (0.04, 0.3)] {
            assert!(!field.is_painted(Point2::new(carpet.0, carpet.1)), "{carpet:?}");
        }
    }

    #[test]
    fn covering_ends_where_the_paint_ends_for_slanted_lines_and_circles() {
        // The box checks in front of `covers` must never decide: the painted rectangle's corners and
        // the circle's outer edge reach the boxes' corners diagonally.
        let width = 0.05;
        let slanted = LineSegment { start: Point2::new(0.3, -0.2), end: Point2::new(1.1, 0.4) };
        let circle = Circle { centre: Point2::new(-0.5, 0.2), radius: 0.75 };
        let on_rectangle = |point: Point2<f64>| {
            let unit = (slanted.end - slanted.start).normalize();
            let offset = point - slanted.start;
            let (along, across) = (offset.dot(&unit), offset.perp(&unit));
            across.abs() <= width / 2.0
                && along >= -width / 2.0
                && along <= (slanted.end - slanted.start).norm() + width / 2.0
        };
        let (mut on_line, mut on_circle) = (0, 0);
        for i in -400..=400 {
            for j in -400..=400 {
                let point = Point2::new(f64::from(i) * 0.004, f64::from(j) * 0.004);
                assert_eq!(slanted.covers(point, width), on_rectangle(point), "{point}");
                let on_ring = ((point - circle.centre).norm() - circle.radius).abs() <= width / 2.0;
                assert_eq!(circle.covers(point, width), on_ring, "{point}");
                on_line += usize::from(on_rectangle(point));
                on_circle += usize::from(on_ring);
            }
        }
        assert!(on_line > 1000 && on_circle > 1000, "{on_line} {on_circle}");
    }

    #[test]
    fn distance_to_nearest_line_is_zero_on_a_line() {
        let field = FieldModel::default();
        assert_abs_diff_eq!(field.distance_to_nearest_line(Point2::new(2.0, 3.0)), 0.0);
        assert_abs_diff_eq!(field.distance_to_nearest_line(Point2::new(2.0, 2.7)), 0.3, epsilon = 1e-12);
        // The centre mark's arm ends 5 cm from the centre spot.
        assert_abs_diff_eq!(field.distance_to_nearest_line(Point2::new(0.3, 0.0)), 0.25, epsilon = 1e-12);
    }

    #[test]
    fn field_round_trips_through_toml() {
        let dimensions = FieldDimensions::spl_2025();
        assert_eq!(FieldDimensions::from_toml(&dimensions.to_toml()).unwrap(), dimensions);
    }

    #[test]
    fn loads_json_and_toml_files() {
        let dir = tempfile::tempdir().unwrap();
        let json = dir.path().join("small.json");
        let mut small = FieldDimensions::spl_2025();
        small.field_length = 7.5;
        std::fs::write(&json, serde_json::to_string(&small).unwrap()).unwrap();
        assert_eq!(FieldDimensions::load(&json).unwrap().field_length, 7.5);
        let toml_path = dir.path().join("small.toml");
        std::fs::write(&toml_path, small.to_toml()).unwrap();
        assert_eq!(FieldDimensions::load(&toml_path).unwrap(), small);
    }

    #[test]
    fn bad_field_files_name_the_problem() {
        let unknown = SPL_2025_TOML.replace("field_length", "field_lenght");
        let error = FieldDimensions::from_toml(&unknown).unwrap_err().to_string();
        assert!(error.contains("field_lenght"), "{error}");

        let negative = SPL_2025_TOML.replace("line_width = 0.05", "line_width = -0.05");
        let error = FieldDimensions::from_toml(&negative).unwrap_err().to_string();
        assert_eq!(
            error,
            "field dimension line_width = -0.05 m is invalid: must be a positive number of metres"
        );

        let too_deep = SPL_2025_TOML.replace("penalty_area_length = 1.65", "penalty_area_length = 5.0");
        assert!(
            FieldDimensions::from_toml(&too_deep).unwrap_err().to_string().contains("penalty_area_length")
        );

        let missing = FieldDimensions::load(Path::new("/nonexistent/field.toml")).unwrap_err();
        assert!(missing.to_string().starts_with("cannot read field file /nonexistent/field.toml"));
    }
}
