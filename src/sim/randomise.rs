//! Randomised frames for training and testing: a pose uniformly over the carpet, a jittered camera,
//! and a randomised scene (light, carpet tone, robots, ball, sensor noise). Deterministic: the same
//! seed and frame index always give the same frame, whatever the thread count.

use std::f64::consts::{FRAC_PI_2, PI};
use std::ops::RangeInclusive;

use nalgebra::{Point2, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::colour::{colour_temperature, hsv_to_linear};
use super::render::RenderSettings;
use super::scene::{Lighting, Robot, Scene, SecondLight, Surroundings, Wear};
use super::trace::mix_bits;
use crate::geometry::{CameraPose, FieldModel, FieldPose};

/// SPL jersey colours, as (hue°, saturation, value) in sRGB.
const JERSEY_COLOURS: [(f64, f64, f64); 10] = [
    (220.0, 0.8, 0.7), // blue
    (0.0, 0.85, 0.75), // red
    (55.0, 0.9, 0.9),  // yellow
    (0.0, 0.0, 0.12),  // black
    (0.0, 0.0, 0.95),  // white
    (120.0, 0.8, 0.5), // green
    (28.0, 0.9, 0.9),  // orange
    (285.0, 0.6, 0.6), // purple
    (25.0, 0.6, 0.35), // brown
    (0.0, 0.0, 0.5),   // grey
];

/// The ranges frames are drawn from. Angles in radians, lengths in metres.
#[derive(Clone, Debug, PartialEq)]
pub struct Randomisation {
    /// Camera height above the ground.
    pub camera_height: RangeInclusive<f64>,
    /// Camera pitch (positive looks down).
    pub camera_pitch: RangeInclusive<f64>,
    /// Camera roll.
    pub camera_roll: RangeInclusive<f64>,
    /// Largest |head yaw|; 0 keeps the camera looking along the robot's heading.
    pub max_head_yaw: f64,
    /// Light intensity factor.
    pub light_intensity: RangeInclusive<f64>,
    /// Colour temperature of the light, kelvin.
    pub colour_temperature: RangeInclusive<f64>,
    /// How much of the light's colour cast the camera's white balance leaves (0 = perfect balance).
    pub white_balance_error: RangeInclusive<f64>,
    /// Fraction of diffuse light.
    pub ambient: RangeInclusive<f64>,
    /// Largest tilt of the main light from vertical.
    pub max_light_tilt: f64,
    /// Hue of the carpet, degrees.
    pub carpet_hue: RangeInclusive<f64>,
    /// Saturation of the carpet.
    pub carpet_saturation: RangeInclusive<f64>,
    /// Brightness (HSV value) of the carpet.
    pub carpet_value: RangeInclusive<f64>,
    /// Most other robots on the carpet (uniform from 0).
    pub max_robots: usize,
    /// Probability that the ball is on the carpet.
    pub ball_probability: f64,
    /// Probability that the goals have nets.
    pub net_probability: f64,
    /// Sensor noise standard deviation, 8-bit levels.
    pub noise_sigma: RangeInclusive<f64>,
    /// Black or asymmetric surroundings (the asymmetric hall gets a per-frame seed).
    pub asymmetric_surroundings: bool,
    /// Poses where the rules put a robot back after a penalty (x = −3.2 ± 0.5 m, |y| = 3.35–3.65 m,
    /// facing the field ± 15°) instead of uniform over the carpet.
    pub penalty_return: bool,
    /// What real halls add ([`HallRealism`]); drawn after everything else, so frames without it stay
    /// exactly as they were.
    pub hall_realism: bool,
}

/// What real halls show that the plain randomisation does not: shadows of a second lamp as well as the
/// first, a worn and textured carpet, motion blur, exposure and white-balance errors beyond the light's own, robots standing at the
/// border, and the cluttered asymmetric hall.
pub struct HallRealism;

impl HallRealism {
    /// Relative carpet albedo change of the texture, range.
    const CARPET_TEXTURE: RangeInclusive<f64> = 0.05..=0.35;
    /// Share of paint worn through, range.
    const PAINT_WEAR: RangeInclusive<f64> = 0.0..=0.6;
    /// Probability that a frame is blurred, and the longest blur as a share of the image width (6 px
    /// of 640).
    const MOTION_BLUR: (f64, f64) = (0.5, 6.0 / 640.0);
    /// Exposure error factor on top of the light's intensity.
    const EXPOSURE: RangeInclusive<f64> = 0.6..=1.5;
    /// Per-channel white-balance error factor.
    const CHANNEL_GAIN: RangeInclusive<f64> = 0.88..=1.12;
    /// Probability of a second lamp, its tilt from vertical (radians) and its share of the direct light.
    const SECOND_LIGHT: (f64, RangeInclusive<f64>, RangeInclusive<f64>) = (0.7, 0.17..=0.87, 0.2..=0.5);
    /// Most robots standing on the border strip.
    const BORDER_ROBOTS: usize = 3;

    fn apply(field: &FieldModel, rng: &mut ChaCha8Rng, frame: &mut SampledFrame) {
        let scene = &mut frame.scene;
        scene.shadows = true;
        scene.wear = Some(Wear {
            seed: rng.random(),
            carpet: rng.random_range(Self::CARPET_TEXTURE),
            paint: rng.random_range(Self::PAINT_WEAR),
        });
        if rng.random_bool(Self::SECOND_LIGHT.0) {
            let tilt = rng.random_range(Self::SECOND_LIGHT.1.clone());
            let azimuth = rng.random_range(-PI..PI);
            scene.lighting.second = Some(SecondLight {
                direction: Vector3::new(tilt.sin() * azimuth.cos(), tilt.sin() * azimuth.sin(), tilt.cos()),
                share: rng.random_range(Self::SECOND_LIGHT.2.clone()),
            });
        }
        let exposure = rng.random_range(Self::EXPOSURE);
        for channel in &mut scene.lighting.colour {
            *channel *= exposure * rng.random_range(Self::CHANNEL_GAIN);
        }
        let dimensions = field.dimensions();
        let (half_length, half_width) = (dimensions.field_length / 2.0, dimensions.field_width / 2.0);
        for _ in 0..rng.random_range(0..=Self::BORDER_ROBOTS) {
            let along_touchline = rng.random_bool(0.7);
            let outward = rng.random_range(0.1..=dimensions.border_strip_width);
            let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let position = if along_touchline {
                Point2::new(rng.random_range(-half_length..=half_length), side * (half_width + outward))
            } else {
                Point2::new(side * (half_length + outward), rng.random_range(-half_width..=half_width))
            };
            if (position - frame.pose.position()).norm() > 0.35 {
                let (hue, saturation, value) = JERSEY_COLOURS[rng.random_range(0..JERSEY_COLOURS.len())];
                scene.robots.push(Robot { position, jersey: hsv_to_linear(hue, saturation, value) });
            }
        }
        if scene.surroundings == Surroundings::Black {
            scene.surroundings = Surroundings::Asymmetric { seed: rng.random() };
        }
        if rng.random_bool(Self::MOTION_BLUR.0) {
            let length = rng.random_range(0.0..=Self::MOTION_BLUR.1);
            let direction = rng.random_range(-PI..PI);
            frame.settings.motion_blur = [length * direction.cos(), length * direction.sin()];
        }
    }
}

impl Default for Randomisation {
    fn default() -> Self {
        Self {
            camera_height: 0.45..=0.53,
            camera_pitch: 0.0..=20f64.to_radians(),
            camera_roll: -3f64.to_radians()..=3f64.to_radians(),
            max_head_yaw: 0.0,
            light_intensity: 0.55..=1.3,
            colour_temperature: 3000.0..=8000.0,
            white_balance_error: 0.0..=0.5,
            ambient: 0.45..=0.85,
            max_light_tilt: 35f64.to_radians(),
            carpet_hue: 85.0..=150.0,
            carpet_saturation: 0.35..=0.85,
            carpet_value: 0.25..=0.6,
            max_robots: 6,
            ball_probability: 0.7,
            net_probability: 0.5,
            noise_sigma: 0.5..=5.0,
            asymmetric_surroundings: false,
            penalty_return: false,
            hall_realism: false,
        }
    }
}

/// One randomised frame, ready to render.
#[derive(Clone, Debug, PartialEq)]
pub struct SampledFrame {
    /// The robot's true pose.
    pub pose: FieldPose,
    /// Its camera.
    pub camera: CameraPose,
    /// The scene around it.
    pub scene: Scene,
    /// Sensor settings (noise, chroma subsampling) for this frame.
    pub settings: RenderSettings,
}

impl Randomisation {
    /// Draws frame `index` of the sequence `seed`.
    pub fn sample(&self, field: &FieldModel, seed: u64, index: u64, supersample: u32) -> SampledFrame {
        let mut rng = ChaCha8Rng::seed_from_u64(mix_bits(seed) ^ mix_bits(index.wrapping_add(0x5eed)));
        let dimensions = field.dimensions();
        let (half_length, half_width) = (dimensions.carpet_half_length(), dimensions.carpet_half_width());
        let (u, v, w) = (
            rng.random_range(-half_length..=half_length),
            rng.random_range(-half_width..=half_width),
            rng.random_range(-PI..PI),
        );
        let pose = if self.penalty_return {
            // The same draws, mapped onto the placement beside either touchline in the own half.
            let side = if v < 0.0 { -1.0 } else { 1.0 };
            FieldPose::new(
                -3.2 + 0.5 * u / half_length,
                side * (3.35 + 0.3 * v.abs() / half_width),
                -side * FRAC_PI_2 + 15f64.to_radians() * w / PI,
            )
        } else {
            FieldPose::new(u, v, w)
        }
        .expect("sampled pose is finite");
        let head_yaw = self.draw_head_yaw(&mut rng);
        let camera = CameraPose::new(
            rng.random_range(self.camera_height.clone()),
            rng.random_range(self.camera_pitch.clone()),
            rng.random_range(self.camera_roll.clone()),
            head_yaw,
        )
        .expect("randomisation ranges give a valid camera pose");

        let intensity = rng.random_range(self.light_intensity.clone());
        let cast = colour_temperature(rng.random_range(self.colour_temperature.clone()));
        let balance_error = rng.random_range(self.white_balance_error.clone());
        let tint = cast.map(|channel| 1.0 + balance_error * (channel - 1.0));
        let tilt = rng.random_range(0.0..=self.max_light_tilt);
        let azimuth = rng.random_range(-PI..PI);
        let lighting = Lighting {
            colour: tint.map(|channel| channel * intensity),
            direction: Vector3::new(tilt.sin() * azimuth.cos(), tilt.sin() * azimuth.sin(), tilt.cos()),
            ambient: rng.random_range(self.ambient.clone()),
            second: None,
        };
        let carpet = hsv_to_linear(
            rng.random_range(self.carpet_hue.clone()),
            rng.random_range(self.carpet_saturation.clone()),
            rng.random_range(self.carpet_value.clone()),
        );
        let paint_level = rng.random_range(0.7..=0.95);
        let white_level = rng.random_range(0.6..=0.9);

        let robot_count = rng.random_range(0..=self.max_robots);
        let mut robots = Vec::with_capacity(robot_count);
        while robots.len() < robot_count {
            let position = Point2::new(
                rng.random_range(-half_length..=half_length),
                rng.random_range(-half_width..=half_width),
            );
            // Keep other robots out of our own body.
            if (position - pose.position()).norm() > 0.35 {
                let (hue, saturation, value) = JERSEY_COLOURS[rng.random_range(0..JERSEY_COLOURS.len())];
                robots.push(Robot { position, jersey: hsv_to_linear(hue, saturation, value) });
            }
        }
        let ball = rng.random_bool(self.ball_probability).then(|| {
            Point2::new(
                rng.random_range(-half_length..=half_length),
                rng.random_range(-half_width..=half_width),
            )
        });
        let surroundings = if self.asymmetric_surroundings {
            Surroundings::Asymmetric { seed: rng.random() }
        } else {
            Surroundings::Black
        };
        let scene = Scene {
            field: field.clone(),
            carpet,
            paint: [paint_level; 3],
            white: [white_level; 3],
            nets: rng.random_bool(self.net_probability),
            lighting,
            robots,
            ball,
            surroundings,
            shadows: false,
            wear: None,
        };
        let settings = RenderSettings {
            supersample,
            noise_sigma: rng.random_range(self.noise_sigma.clone()),
            noise_seed: rng.random(),
            chroma_subsampling: true,
            motion_blur: [0.0; 2],
        };
        let mut frame = SampledFrame { pose, camera, scene, settings };
        if self.hall_realism {
            HallRealism::apply(field, &mut rng, &mut frame);
        }
        frame
    }

    /// A head yaw uniform in ±`max_head_yaw`, or 0 (drawing nothing) when the head does not turn.
    fn draw_head_yaw(&self, rng: &mut ChaCha8Rng) -> f64 {
        if self.max_head_yaw > 0.0 { rng.random_range(-self.max_head_yaw..=self.max_head_yaw) } else { 0.0 }
    }

    /// Draws frame `frame` of burst `burst` of the sequence `seed`: a robot standing still, so the pose
    /// and scene of frame 0 (which equals `sample(field, seed, burst, …)`) with the camera swaying by up
    /// to a degree in pitch and roll, a fresh head yaw where the head may turn, and fresh sensor noise.
    pub fn sample_in_burst(
        &self,
        field: &FieldModel,
        seed: u64,
        burst: u64,
        frame: u64,
        supersample: u32,
    ) -> SampledFrame {
        let still = self.sample(field, seed, burst, supersample);
        if frame == 0 {
            return still;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(
            mix_bits(seed ^ 0xb0257) ^ mix_bits(burst.wrapping_add(0x5eed)) ^ mix_bits(frame),
        );
        let sway = 1.0f64.to_radians();
        let limit = 89.9f64.to_radians();
        let swayed =
            |angle: f64, rng: &mut ChaCha8Rng| (angle + rng.random_range(-sway..=sway)).clamp(-limit, limit);
        let head_yaw = self.draw_head_yaw(&mut rng);
        let camera = CameraPose::new(
            still.camera.height(),
            swayed(still.camera.pitch(), &mut rng),
            swayed(still.camera.roll(), &mut rng),
            head_yaw,
        )
        .expect("a degree of sway keeps the camera pose valid");
        let settings = RenderSettings { noise_seed: rng.random(), ..still.settings };
        SampledFrame { camera, settings, ..still }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampling_is_deterministic_and_varies_by_index() {
        let field = FieldModel::default();
        let randomisation = Randomisation::default();
        let first = randomisation.sample(&field, 1, 0, 2);
        assert_eq!(first, randomisation.sample(&field, 1, 0, 2));
        assert_ne!(first.pose, randomisation.sample(&field, 1, 1, 2).pose);
        assert_ne!(first.pose, randomisation.sample(&field, 2, 0, 2).pose);
    }

    #[test]
    fn a_burst_keeps_pose_and_scene_and_varies_the_camera() {
        let field = FieldModel::default();
        let randomisation = Randomisation { max_head_yaw: 0.5, ..Randomisation::default() };
        let first = randomisation.sample_in_burst(&field, 3, 7, 0, 1);
        assert_eq!(first, randomisation.sample(&field, 3, 7, 1));
        let later = randomisation.sample_in_burst(&field, 3, 7, 2, 1);
        assert_eq!((later.pose, &later.scene), (first.pose, &first.scene));
        assert_ne!(later.camera, first.camera);
        assert!((later.camera.pitch() - first.camera.pitch()).abs() <= 1f64.to_radians() + 1e-12);
        assert_ne!(later.settings.noise_seed, first.settings.noise_seed);
        assert_eq!(later, randomisation.sample_in_burst(&field, 3, 7, 2, 1));
    }

    #[test]
    fn penalty_return_poses_stand_beside_a_touchline_facing_the_field() {
        let field = FieldModel::default();
        let randomisation = Randomisation { penalty_return: true, ..Randomisation::default() };
        let mut sides = [0, 0];
        for index in 0..100 {
            let pose = randomisation.sample(&field, 4, index, 1).pose;
            assert!((-3.7..=-2.7).contains(&pose.x()), "{pose:?}");
            assert!(
                (3.35..=3.65).contains(&pose.y().abs()) && field.is_on_carpet(pose.position()),
                "{pose:?}"
            );
            let facing = -pose.y().signum() * FRAC_PI_2;
            assert!((pose.heading() - facing).abs() <= 15f64.to_radians() + 1e-9, "{pose:?}");
            sides[usize::from(pose.y() > 0.0)] += 1;
        }
        assert!(sides[0] > 20 && sides[1] > 20, "both touchlines: {sides:?}");
    }

    #[test]
    fn samples_stay_within_their_ranges() {
        let field = FieldModel::default();
        let randomisation = Randomisation::default();
        for index in 0..200 {
            let frame = randomisation.sample(&field, 9, index, 1);
            assert!(field.is_on_carpet(frame.pose.position()));
            assert!(randomisation.camera_height.contains(&frame.camera.height()));
            assert!(randomisation.camera_pitch.contains(&frame.camera.pitch()));
            assert!(randomisation.camera_roll.contains(&frame.camera.roll()));
            assert!(frame.scene.robots.len() <= randomisation.max_robots);
            for robot in &frame.scene.robots {
                assert!(field.is_on_carpet(robot.position));
                assert!((robot.position - frame.pose.position()).norm() > 0.35);
            }
        }
    }

    /// The range a real Nao's top camera covers (issue 18: crouched walk to standing, head pitch plus
    /// torso): 0.38–0.55 m, 10° up to 25° down, rolled ±5°. Frames looking up stay valid and render.
    #[test]
    fn the_real_robot_camera_range_is_sampled_and_renders() {
        use crate::geometry::{Camera, CameraIntrinsics};
        use crate::sim::render::render;

        let field = FieldModel::default();
        let randomisation = Randomisation {
            camera_height: 0.38..=0.55,
            camera_pitch: -10f64.to_radians()..=25f64.to_radians(),
            camera_roll: -5f64.to_radians()..=5f64.to_radians(),
            hall_realism: true,
            ..Randomisation::default()
        };
        let (mut up, mut beyond_old_roll) = (0, 0);
        for index in 0..300 {
            let frame = randomisation.sample(&field, 11, index, 1);
            assert!(randomisation.camera_height.contains(&frame.camera.height()));
            assert!(randomisation.camera_pitch.contains(&frame.camera.pitch()));
            assert!(randomisation.camera_roll.contains(&frame.camera.roll()));
            up += usize::from(frame.camera.pitch() < 0.0);
            beyond_old_roll += usize::from(frame.camera.roll().abs() > 3f64.to_radians());
        }
        // 10 of 35 degrees look up, 2 of 5 degrees of roll lie beyond the old ±3°.
        assert!((60..=115).contains(&up), "{up} of 300 frames look up");
        assert!((80..=160).contains(&beyond_old_roll), "{beyond_old_roll} of 300 frames rolled beyond 3°");

        let looking_up = (0..300)
            .map(|index| randomisation.sample(&field, 11, index, 1))
            .find(|frame| frame.camera.pitch() < -8f64.to_radians())
            .expect("some frame looks up by more than 8°");
        let intrinsics = CameraIntrinsics::nao_top().with_resolution(40, 30);
        let camera = Camera::new(intrinsics, &looking_up.pose, &looking_up.camera);
        let image = render(&looking_up.scene, &camera, &looking_up.settings);
        assert_eq!((image.width(), image.height()), (40, 30));
    }
}
