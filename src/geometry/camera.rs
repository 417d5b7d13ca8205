//! The pinhole camera model: intrinsics from the field of view, extrinsics from a robot pose plus
//! the camera's pose on the robot. Pixel coordinates are continuous: pixel (i, j) covers
//! [i, i+1) × [j, j+1), its centre is (i + 0.5, j + 0.5), u grows to the right and v downwards.

use nalgebra::{Point2, Point3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use super::pose::{CameraPose, FieldPose};

/// Image size and field of view of a pinhole camera with the principal point at the image centre.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraIntrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Horizontal field of view, radians.
    pub horizontal_fov: f64,
    /// Vertical field of view, radians.
    pub vertical_fov: f64,
}

impl CameraIntrinsics {
    /// The Nao top camera: 640×480, 54.7° × 42.5° (B-Human's calibration).
    pub fn nao_top() -> Self {
        Self {
            width: 640,
            height: 480,
            horizontal_fov: 54.7f64.to_radians(),
            vertical_fov: 42.5f64.to_radians(),
        }
    }

    /// These intrinsics with the horizontal and vertical field of view given in degrees, where
    /// given (a robot's calibration); each must lie in (1°, 170°). The error names the axis and
    /// the degrees refused.
    pub fn with_field_of_view(
        self,
        horizontal_deg: Option<f64>,
        vertical_deg: Option<f64>,
    ) -> Result<Self, (&'static str, f64)> {
        let radians = |degrees: Option<f64>, default: f64, axis: &'static str| match degrees {
            None => Ok(default),
            Some(degrees) if degrees > 1.0 && degrees < 170.0 => Ok(degrees.to_radians()),
            Some(degrees) => Err((axis, degrees)),
        };
        Ok(Self {
            horizontal_fov: radians(horizontal_deg, self.horizontal_fov, "horizontal")?,
            vertical_fov: radians(vertical_deg, self.vertical_fov, "vertical")?,
            ..self
        })
    }

    /// The same field of view at another resolution (e.g. the network's input size).
    pub fn with_resolution(self, width: u32, height: u32) -> Self {
        Self { width, height, ..self }
    }

    /// Focal lengths in pixels, (fx, fy).
    pub fn focal_lengths(&self) -> (f64, f64) {
        (
            self.width as f64 / 2.0 / (self.horizontal_fov / 2.0).tan(),
            self.height as f64 / 2.0 / (self.vertical_fov / 2.0).tan(),
        )
    }

    /// The principal point, at the image centre.
    pub fn principal_point(&self) -> Point2<f64> {
        Point2::new(self.width as f64 / 2.0, self.height as f64 / 2.0)
    }
}

impl Default for CameraIntrinsics {
    fn default() -> Self {
        Self::nao_top()
    }
}

/// A placed camera: where it is in the field frame and how it looks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    intrinsics: CameraIntrinsics,
    focal: (f64, f64),
    centre: Point2<f64>,
    /// Rotation from camera axes to field axes.
    rotation: Rotation3<f64>,
    /// Optical centre in the field frame.
    position: Point3<f64>,
}

impl Camera {
    /// The camera of a robot standing at `robot` with its camera at `camera_pose`.
    pub fn new(intrinsics: CameraIntrinsics, robot: &FieldPose, camera_pose: &CameraPose) -> Self {
        let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), robot.heading() + camera_pose.head_yaw());
        let pitch = Rotation3::from_axis_angle(&Vector3::y_axis(), camera_pose.pitch());
        let roll = Rotation3::from_axis_angle(&Vector3::x_axis(), camera_pose.roll());
        Self {
            intrinsics,
            focal: intrinsics.focal_lengths(),
            centre: intrinsics.principal_point(),
            rotation: yaw * pitch * roll,
            position: Point3::new(robot.x(), robot.y(), camera_pose.height()),
        }
    }

    /// The intrinsics.
    pub fn intrinsics(&self) -> &CameraIntrinsics {
        &self.intrinsics
    }

    /// Optical centre in the field frame.
    pub fn position(&self) -> Point3<f64> {
        self.position
    }

    /// Direction (not normalised; its camera-frame x component is 1) in the field frame of the ray
    /// through the continuous pixel coordinate (u, v).
    pub fn ray_direction(&self, u: f64, v: f64) -> Vector3<f64> {
        let in_camera =
            Vector3::new(1.0, -(u - self.centre.x) / self.focal.0, -(v - self.centre.y) / self.focal.1);
        self.rotation * in_camera
    }

    /// Pixel coordinate of a field-frame point, or `None` if it is behind the camera.
    pub fn project(&self, point: &Point3<f64>) -> Option<Point2<f64>> {
        let in_camera = self.rotation.inverse() * (point - self.position);
        if in_camera.x <= 1e-9 {
            return None;
        }
        Some(Point2::new(
            self.centre.x - self.focal.0 * in_camera.y / in_camera.x,
            self.centre.y - self.focal.1 * in_camera.z / in_camera.x,
        ))
    }

    /// Where the ray through pixel (u, v) meets the ground, or `None` if it points above the horizon.
    pub fn ground_point(&self, u: f64, v: f64) -> Option<Point2<f64>> {
        let direction = self.ray_direction(u, v);
        if direction.z >= -1e-12 {
            return None;
        }
        let distance = -self.position.z / direction.z;
        Some(Point2::new(self.position.x + distance * direction.x, self.position.y + distance * direction.y))
    }

    /// Whether a pixel coordinate lies inside the image.
    pub fn contains(&self, pixel: &Point2<f64>) -> bool {
        (0.0..self.intrinsics.width as f64).contains(&pixel.x)
            && (0.0..self.intrinsics.height as f64).contains(&pixel.y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;
    use std::f64::consts::FRAC_PI_2;

    fn camera(x: f64, y: f64, heading: f64, pitch: f64, roll: f64, yaw: f64) -> Camera {
        Camera::new(
            CameraIntrinsics::nao_top(),
            &FieldPose::new(x, y, heading).unwrap(),
            &CameraPose::new(0.5, pitch, roll, yaw).unwrap(),
        )
    }

    #[test]
    fn focal_length_matches_the_field_of_view() {
        let (fx, fy) = CameraIntrinsics::nao_top().focal_lengths();
        assert_abs_diff_eq!(fx, 618.7, epsilon = 0.1);
        assert_abs_diff_eq!(fy, 617.1, epsilon = 0.1);
    }

    #[test]
    fn optical_axis_hits_the_image_centre() {
        let camera = camera(1.0, 2.0, FRAC_PI_2, 0.0, 0.0, 0.0);
        let ahead = Point3::new(1.0, 5.0, 0.5);
        assert_abs_diff_eq!(camera.project(&ahead).unwrap(), Point2::new(320.0, 240.0), epsilon = 1e-9);
        assert!(camera.project(&Point3::new(1.0, -5.0, 0.5)).is_none());
    }

    #[test]
    fn left_is_left_and_down_is_down() {
        let camera = camera(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let left = camera.project(&Point3::new(5.0, 1.0, 0.5)).unwrap();
        let low = camera.project(&Point3::new(5.0, 0.0, 0.0)).unwrap();
        assert!(left.x < 320.0 && (left.y - 240.0).abs() < 1e-9);
        assert!(low.y > 240.0 && (low.x - 320.0).abs() < 1e-9);
    }

    #[test]
    fn pitch_moves_the_horizon_up() {
        let level = camera(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let pitched = camera(0.0, 0.0, 0.0, 0.2, 0.0, 0.0);
        let far = Point3::new(1000.0, 0.0, 0.0);
        assert!(pitched.project(&far).unwrap().y < level.project(&far).unwrap().y);
    }

    #[test]
    fn ground_point_inverts_projection() {
        let camera = camera(-2.0, 1.0, 0.7, 0.25, 0.05, -0.3);
        for (u, v) in [(10.0, 400.0), (320.0, 300.0), (600.5, 470.25)] {
            let ground = camera.ground_point(u, v).unwrap();
            let back = camera.project(&Point3::new(ground.x, ground.y, 0.0)).unwrap();
            assert_abs_diff_eq!(back, Point2::new(u, v), epsilon = 1e-6);
        }
        assert!(camera.ground_point(320.0, 0.0).is_none());
    }

    #[test]
    fn head_yaw_adds_to_the_robot_heading() {
        let turned_head = camera(0.0, 0.0, 0.3, 0.1, 0.0, 0.4);
        let turned_body = camera(0.0, 0.0, 0.7, 0.1, 0.0, 0.0);
        let point = Point3::new(3.0, 2.0, 0.0);
        assert_abs_diff_eq!(
            turned_head.project(&point).unwrap(),
            turned_body.project(&point).unwrap(),
            epsilon = 1e-9
        );
    }
}
