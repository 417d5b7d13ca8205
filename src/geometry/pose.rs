//! Typed poses. A [`FieldPose`] is where a robot stands on the full field; a [`CameraPose`] is where its
//! top camera sits relative to the robot. Folded poses live in [`super::symmetry`] and cannot be mixed
//! with either: converting between them goes through `fold`/`unfold`.

use nalgebra::{Point2, Rotation3, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::angle::normalize_angle;

/// Standard deviations of a pose estimate.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PoseSigma {
    /// Along x, metres.
    pub x: f64,
    /// Along y, metres.
    pub y: f64,
    /// Of the heading, radians.
    pub theta: f64,
}

/// A pose value that cannot be used.
#[derive(Debug, Error, PartialEq)]
pub enum PoseError {
    /// A coordinate is NaN or infinite.
    #[error("{name} must be a finite number, found {value}")]
    NotFinite {
        /// The offending component.
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// A camera parameter outside what a Nao can do.
    #[error("{name} = {value} is out of range: expected {expected}")]
    OutOfRange {
        /// The offending component.
        name: &'static str,
        /// Its value.
        value: f64,
        /// The accepted range, in words.
        expected: &'static str,
    },
}

fn finite(name: &'static str, value: f64) -> Result<f64, PoseError> {
    if value.is_finite() { Ok(value) } else { Err(PoseError::NotFinite { name, value }) }
}

/// The robot's ground pose in the full field frame: position in metres, heading in radians in (−π, π].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawPose", into = "RawPose")]
pub struct FieldPose {
    x: f64,
    y: f64,
    heading: f64,
}

/// The wire form of a pose: `{"x": m, "y": m, "theta": rad}`.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub(crate) struct RawPose {
    pub(crate) x: f64,
    pub(crate) y: f64,
    pub(crate) theta: f64,
}

impl FieldPose {
    /// A pose at (x, y) metres with heading `heading` radians (wrapped into (−π, π]).
    pub fn new(x: f64, y: f64, heading: f64) -> Result<Self, PoseError> {
        Ok(Self {
            x: finite("x", x)?,
            y: finite("y", y)?,
            heading: normalize_angle(finite("theta", heading)?),
        })
    }

    /// Builds a pose from values already known to be finite (e.g. produced by this crate's maths).
    pub(crate) fn from_finite(x: f64, y: f64, heading: f64) -> Self {
        debug_assert!(x.is_finite() && y.is_finite() && heading.is_finite());
        Self { x, y, heading: normalize_angle(heading) }
    }

    /// x in metres (towards the opponent goal).
    pub fn x(&self) -> f64 {
        self.x
    }

    /// y in metres (to the left).
    pub fn y(&self) -> f64 {
        self.y
    }

    /// Heading in radians, counter-clockwise from +x, in (−π, π].
    pub fn heading(&self) -> f64 {
        self.heading
    }

    /// Position on the ground.
    pub fn position(&self) -> Point2<f64> {
        Point2::new(self.x, self.y)
    }

    /// Euclidean distance between the two positions, in metres.
    pub fn distance_to(&self, other: &FieldPose) -> f64 {
        (self.position() - other.position()).norm()
    }

    /// Transforms a point from the robot ground frame into the field frame.
    pub fn robot_to_field(&self, point: Point2<f64>) -> Point2<f64> {
        let (sin, cos) = self.heading.sin_cos();
        Point2::new(self.x + cos * point.x - sin * point.y, self.y + sin * point.x + cos * point.y)
    }

    /// Transforms a point from the field frame into the robot ground frame.
    pub fn field_to_robot(&self, point: Point2<f64>) -> Point2<f64> {
        let (sin, cos) = self.heading.sin_cos();
        let (dx, dy) = (point.x - self.x, point.y - self.y);
        Point2::new(cos * dx + sin * dy, -sin * dx + cos * dy)
    }

    /// Unit vector of the heading.
    pub fn direction(&self) -> Vector2<f64> {
        let (sin, cos) = self.heading.sin_cos();
        Vector2::new(cos, sin)
    }
}

impl TryFrom<RawPose> for FieldPose {
    type Error = PoseError;

    fn try_from(raw: RawPose) -> Result<Self, Self::Error> {
        Self::new(raw.x, raw.y, raw.theta)
    }
}

impl From<FieldPose> for RawPose {
    fn from(pose: FieldPose) -> Self {
        Self { x: pose.x, y: pose.y, theta: pose.heading }
    }
}

/// Where the top camera sits relative to the robot's ground frame: height of the optical centre above
/// the ground (m), pitch (rad, positive looks down), roll (rad, positive tilts the image clockwise
/// as seen by the camera, i.e. a right-handed rotation about the optical axis) and head yaw (rad, positive
/// turns left).
///
/// The optical centre is modelled directly above the robot's ground origin.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawCameraPose", into = "RawCameraPose")]
pub struct CameraPose {
    height: f64,
    pitch: f64,
    roll: f64,
    head_yaw: f64,
}

#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
struct RawCameraPose {
    height: f64,
    pitch: f64,
    roll: f64,
    head_yaw: f64,
}

impl CameraPose {
    /// A standing Nao looking straight ahead: 0.5 m high, the top camera's 1.2° tilt, no roll or yaw.
    pub const STANDING: CameraPose =
        CameraPose { height: 0.5, pitch: 1.2 * std::f64::consts::PI / 180.0, roll: 0.0, head_yaw: 0.0 };

    /// A checked camera pose. Height must lie in (0, 5] m, pitch and roll within ±90°, head yaw
    /// within ±180°.
    pub fn new(height: f64, pitch: f64, roll: f64, head_yaw: f64) -> Result<Self, PoseError> {
        use std::f64::consts::{FRAC_PI_2, PI};
        let checked = |name, value: f64, low: f64, high: f64, expected| {
            let value = finite(name, value)?;
            if value <= low || value > high {
                return Err(PoseError::OutOfRange { name, value, expected });
            }
            Ok(value)
        };
        Ok(Self {
            height: checked("height", height, 0.0, 5.0, "0 < height <= 5 m")?,
            pitch: checked("pitch", pitch, -FRAC_PI_2, FRAC_PI_2, "-pi/2 < pitch <= pi/2")?,
            roll: checked("roll", roll, -FRAC_PI_2, FRAC_PI_2, "-pi/2 < roll <= pi/2")?,
            head_yaw: checked("head_yaw", head_yaw, -PI, PI, "-pi < head_yaw <= pi")?,
        })
    }

    /// Height of the optical centre above the ground, metres.
    pub fn height(&self) -> f64 {
        self.height
    }

    /// This pose with a robot's calibration added: `pitch` and `roll` offsets, radians (checked as in
    /// [`CameraPose::new`]).
    pub fn corrected(&self, pitch: f64, roll: f64) -> Result<Self, PoseError> {
        Self::new(self.height, self.pitch + pitch, self.roll + roll, self.head_yaw)
    }

    /// Pitch in radians; positive looks down.
    pub fn pitch(&self) -> f64 {
        self.pitch
    }

    /// Roll about the optical axis in radians.
    pub fn roll(&self) -> f64 {
        self.roll
    }

    /// Head yaw relative to the robot's heading, radians; positive turns left.
    pub fn head_yaw(&self) -> f64 {
        self.head_yaw
    }

    /// The same camera mirrored across the robot's forward axis (roll and yaw change sign): what a
    /// mirrored world looks like through it.
    pub fn mirrored(&self) -> Self {
        Self { roll: -self.roll, head_yaw: -self.head_yaw, ..*self }
    }

    /// This camera as mounted (its pose with the torso upright and the head at zero) on a body at
    /// `body`: torso, head yaw, head pitch and mounting rotate in that order, and the result is read
    /// back as yaw, pitch and roll over the ground. The height stays the mounted one (the neck's few
    /// centimetres of travel are left out).
    pub fn on_body(&self, body: &BodyAngles) -> Result<Self, PoseError> {
        finite("torso_roll", body.torso_roll)?;
        finite("torso_pitch", body.torso_pitch)?;
        finite("head_yaw", body.head_yaw)?;
        finite("head_pitch", body.head_pitch)?;
        let rotation = Rotation3::from_euler_angles(body.torso_roll, body.torso_pitch, 0.0)
            * Rotation3::from_axis_angle(&Vector3::z_axis(), self.head_yaw + body.head_yaw)
            * Rotation3::from_axis_angle(&Vector3::y_axis(), self.pitch + body.head_pitch)
            * Rotation3::from_axis_angle(&Vector3::x_axis(), self.roll);
        let (roll, pitch, yaw) = rotation.euler_angles();
        Self::new(self.height, pitch, roll, yaw)
    }
}

/// The body angles that turn the camera, as LoLA reports them, radians: torso roll and pitch over the
/// ground from the IMU (positive pitch leans forward), head yaw (positive turns left) and head pitch
/// (positive looks down) from the joints.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BodyAngles {
    /// Torso roll about the forward axis (right-handed: positive lowers the right shoulder).
    pub torso_roll: f64,
    /// Torso pitch; positive leans forward.
    pub torso_pitch: f64,
    /// HeadYaw joint; positive turns left.
    pub head_yaw: f64,
    /// HeadPitch joint; positive looks down.
    pub head_pitch: f64,
}

/// How the camera sits on the robot: its pose with the torso upright and the head at zero, and the
/// head yaw to assume when neither the sensors nor a trigger give one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraMounting {
    /// The camera's pose with the torso upright and the head at zero (its yaw is ignored).
    pub mounted: CameraPose,
    /// Head yaw assumed when nothing says otherwise, radians (positive: left).
    pub head_yaw: f64,
}

impl CameraMounting {
    /// The camera's pose on a body at `body` (the sensed torso and head angles; an upright body with
    /// the assumed head yaw when there are none); `head_yaw`, a trigger's, replaces the head yaw
    /// either way.
    pub fn pose_on(&self, body: Option<BodyAngles>, head_yaw: Option<f64>) -> Result<CameraPose, PoseError> {
        let body = body.unwrap_or(BodyAngles { head_yaw: self.head_yaw, ..BodyAngles::default() });
        let mounted = CameraPose { head_yaw: 0.0, ..self.mounted };
        mounted.on_body(&BodyAngles { head_yaw: head_yaw.unwrap_or(body.head_yaw), ..body })
    }
}

impl Default for CameraPose {
    fn default() -> Self {
        Self::STANDING
    }
}

impl TryFrom<RawCameraPose> for CameraPose {
    type Error = PoseError;

    fn try_from(raw: RawCameraPose) -> Result<Self, Self::Error> {
        Self::new(raw.height, raw.pitch, raw.roll, raw.head_yaw)
    }
}

impl From<CameraPose> for RawCameraPose {
    fn from(pose: CameraPose) -> Self {
        Self { height: pose.height, pitch: pose.pitch, roll: pose.roll, head_yaw: pose.head_yaw }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;
    use std::f64::consts::{FRAC_PI_2, PI};

    #[test]
    fn a_mounted_camera_takes_the_sensed_or_the_triggered_head_yaw() {
        let mounted = CameraPose::new(0.5, 2f64.to_radians(), 0.0, 0.0).unwrap();
        let camera = CameraMounting { mounted, head_yaw: 30f64.to_radians() };
        let assumed = camera.pose_on(None, None).unwrap();
        assert_abs_diff_eq!(assumed.head_yaw(), 30f64.to_radians(), epsilon = 1e-12);
        assert_abs_diff_eq!(assumed.pitch(), 2f64.to_radians(), epsilon = 1e-12);
        let body = BodyAngles { head_yaw: 0.5, head_pitch: 0.2, ..BodyAngles::default() };
        let sensed = camera.pose_on(Some(body), None).unwrap();
        assert_abs_diff_eq!(sensed.head_yaw(), 0.5, epsilon = 1e-12);
        assert_abs_diff_eq!(sensed.pitch(), 2f64.to_radians() + 0.2, epsilon = 1e-12);
        let requested = camera.pose_on(Some(body), Some(-0.25)).unwrap();
        assert_abs_diff_eq!(requested.head_yaw(), -0.25, epsilon = 1e-12);
        assert_eq!(requested.pitch(), sensed.pitch());
        assert!(camera.pose_on(Some(BodyAngles { torso_roll: f64::NAN, ..body }), None).is_err());
    }

    #[test]
    fn a_camera_on_an_upright_body_adds_the_head_angles() {
        let mounted = CameraPose::STANDING;
        let body = BodyAngles { head_yaw: 0.4, head_pitch: 0.3, ..BodyAngles::default() };
        let pose = mounted.on_body(&body).unwrap();
        assert_abs_diff_eq!(pose.pitch(), mounted.pitch() + 0.3, epsilon = 1e-12);
        assert_abs_diff_eq!(pose.head_yaw(), 0.4, epsilon = 1e-12);
        assert_abs_diff_eq!(pose.roll(), 0.0, epsilon = 1e-12);
        assert_eq!(pose.height(), mounted.height());
        assert_eq!(mounted.on_body(&BodyAngles::default()).unwrap(), mounted);
    }

    #[test]
    fn a_leaning_torso_tilts_the_camera_by_where_the_head_looks() {
        let mounted = CameraPose::new(0.5, 0.0, 0.0, 0.0).unwrap();
        let lean = BodyAngles { torso_pitch: 0.1, ..BodyAngles::default() };
        // Looking ahead, a forward lean is a downward look ...
        let ahead = mounted.on_body(&lean).unwrap();
        assert_abs_diff_eq!(
            Vector2::new(ahead.pitch(), ahead.roll()),
            Vector2::new(0.1, 0.0),
            epsilon = 1e-12
        );
        // ... looking to the left, it is a roll: the camera's left side, towards the robot's back, rises.
        let left = mounted.on_body(&BodyAngles { head_yaw: FRAC_PI_2, ..lean }).unwrap();
        assert_abs_diff_eq!(left.pitch(), 0.0, epsilon = 1e-12);
        assert_abs_diff_eq!(left.roll(), 0.1, epsilon = 1e-12);
        assert_abs_diff_eq!(left.head_yaw(), FRAC_PI_2, epsilon = 1e-12);
        // A torso rolled to the right rolls a camera looking ahead alike.
        let rolled = mounted.on_body(&BodyAngles { torso_roll: 0.05, ..BodyAngles::default() }).unwrap();
        assert_abs_diff_eq!(
            Vector2::new(rolled.pitch(), rolled.roll()),
            Vector2::new(0.0, 0.05),
            epsilon = 1e-12
        );
    }

    #[test]
    fn broken_body_angles_are_errors() {
        let nan = BodyAngles { head_pitch: f64::NAN, ..BodyAngles::default() };
        let error = CameraPose::STANDING.on_body(&nan).unwrap_err().to_string();
        assert!(error.contains("head_pitch"), "{error}");
        // Lying face down, the camera looks past the vertical: no ground-plane camera pose.
        let lying = BodyAngles { torso_pitch: 1.6, ..BodyAngles::default() };
        assert!(matches!(CameraPose::STANDING.on_body(&lying), Err(PoseError::OutOfRange { .. })));
    }

    #[test]
    fn field_pose_normalises_heading() {
        let pose = FieldPose::new(1.0, 2.0, 3.0 * PI).unwrap();
        assert_abs_diff_eq!(pose.heading(), PI, epsilon = 1e-12);
    }

    #[test]
    fn field_pose_rejects_nan() {
        assert_eq!(
            FieldPose::new(f64::NAN, 0.0, 0.0).unwrap_err().to_string(),
            "x must be a finite number, found NaN"
        );
    }

    #[test]
    fn field_pose_reads_and_writes_the_wire_form() {
        let pose: FieldPose = serde_json::from_str(r#"{"x": 1.5, "y": -2.0, "theta": 7.0}"#).unwrap();
        assert_abs_diff_eq!(pose.heading(), 7.0 - 2.0 * PI, epsilon = 1e-12);
        let json = serde_json::to_string(&pose).unwrap();
        assert!(json.starts_with(r#"{"x":1.5,"y":-2.0,"theta":0.71"#), "{json}");
        assert!(serde_json::from_str::<FieldPose>(r#"{"x": 1.5, "y": -2.0}"#).is_err());
    }

    #[test]
    fn robot_to_field_rotates_then_translates() {
        let pose = FieldPose::new(1.0, 1.0, FRAC_PI_2).unwrap();
        let point = pose.robot_to_field(Point2::new(2.0, 0.0));
        assert_abs_diff_eq!(point, Point2::new(1.0, 3.0), epsilon = 1e-12);
    }

    #[test]
    fn camera_pose_rejects_impossible_values() {
        assert!(CameraPose::new(0.5, 0.1, 0.0, 0.0).is_ok());
        let error = CameraPose::new(0.5, 2.0, 0.0, 0.0).unwrap_err();
        assert_eq!(error.to_string(), "pitch = 2 is out of range: expected -pi/2 < pitch <= pi/2");
        assert!(CameraPose::new(0.0, 0.0, 0.0, 0.0).is_err());
        assert!(CameraPose::new(0.5, f64::NAN, 0.0, 0.0).is_err());
    }

    #[test]
    fn camera_pose_reads_the_recording_form() {
        let camera: CameraPose =
            serde_json::from_str(r#"{"height": 0.5, "pitch": 0.1, "roll": 0.0, "head_yaw": -0.2}"#).unwrap();
        assert_abs_diff_eq!(camera.head_yaw(), -0.2);
        assert!(
            serde_json::from_str::<CameraPose>(r#"{"height": -1, "pitch": 0, "roll": 0, "head_yaw": 0}"#)
                .is_err()
        );
    }
}
