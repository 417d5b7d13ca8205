//! What the renderer draws: the field, its colours and lighting, and what stands on it.

use nalgebra::{Point2, Vector3};

use super::colour::{Linear, hsv_to_linear};
use crate::geometry::FieldModel;

/// What lies beyond the carpet.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Surroundings {
    /// Everything off the carpet is black, as in the thesis: the field's symmetry holds exactly.
    #[default]
    Black,
    /// A hall whose walls are covered with random coloured panels (fixed by the seed) and a grey floor:
    /// it breaks the symmetry, as real halls do.
    Asymmetric {
        /// Chooses the panels.
        seed: u64,
    },
}

/// Light falling on the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lighting {
    /// Colour and intensity of the light, linear RGB (1 = a white surface is just not clipped).
    pub colour: Linear,
    /// Unit vector pointing towards the main light.
    pub direction: Vector3<f64>,
    /// Fraction of the light that arrives diffusely from all around, in [0, 1].
    pub ambient: f64,
    /// A second lamp, if any.
    pub second: Option<SecondLight>,
}

/// A second lamp: it takes a share of the direct light (and casts its own shadows).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SecondLight {
    /// Unit vector pointing towards it.
    pub direction: Vector3<f64>,
    /// Its share of the direct (non-ambient) light, in [0, 1].
    pub share: f64,
}

impl Lighting {
    /// Shading factor of a surface with unit normal `normal` that every light reaches.
    pub fn shade(&self, normal: &Vector3<f64>) -> Linear {
        self.shade_lit(normal, [true, true])
    }

    /// Shading factor of a surface with unit normal `normal` that the main and the second light reach
    /// or not (`lit`); the ambient share always arrives.
    pub fn shade_lit(&self, normal: &Vector3<f64>, lit: [bool; 2]) -> Linear {
        let facing =
            |direction: &Vector3<f64>, lit: bool| if lit { normal.dot(direction).max(0.0) } else { 0.0 };
        let direct = match self.second {
            None => facing(&self.direction, lit[0]),
            Some(second) => {
                (1.0 - second.share) * facing(&self.direction, lit[0])
                    + second.share * facing(&second.direction, lit[1])
            }
        };
        let factor = self.ambient + (1.0 - self.ambient) * direct;
        self.colour.map(|channel| channel * factor)
    }
}

impl Default for Lighting {
    /// White light from straight above, as in a hall with ceiling lamps.
    fn default() -> Self {
        Self { colour: [0.95; 3], direction: Vector3::z(), ambient: 0.6, second: None }
    }
}

/// Another robot: an upright body (legs, jersey-coloured torso, head) standing at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Robot {
    /// Where it stands, field frame.
    pub position: Point2<f64>,
    /// Jersey colour, linear RGB.
    pub jersey: Linear,
}

/// Body dimensions of the robots drawn (a Nao is about 0.57 m tall).
pub(crate) mod body {
    /// Top of the legs.
    pub const LEGS_TOP: f64 = 0.30;
    /// Radius of the leg cylinder.
    pub const LEGS_RADIUS: f64 = 0.08;
    /// Top of the torso.
    pub const TORSO_TOP: f64 = 0.46;
    /// Radius of the torso cylinder.
    pub const TORSO_RADIUS: f64 = 0.10;
    /// Height of the head's centre.
    pub const HEAD_CENTRE: f64 = 0.51;
    /// Radius of the head.
    pub const HEAD_RADIUS: f64 = 0.075;
}

/// Carpet texture and wear: procedural value noise that darkens and lightens the carpet in patches and
/// wears the paint of the lines through to the carpet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wear {
    /// Chooses the pattern.
    pub seed: u64,
    /// Relative change of the carpet's albedo at the noise's extremes, e.g. 0.2 for ±20%.
    pub carpet: f64,
    /// Largest share of a line's paint worn through to the carpet, in [0, 1].
    pub paint: f64,
}

/// Radius of the SPL ball.
pub const BALL_RADIUS: f64 = 0.05;

/// Everything the renderer needs besides the camera.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// The field geometry.
    pub field: FieldModel,
    /// Carpet albedo, linear RGB.
    pub carpet: Linear,
    /// Line paint albedo, linear RGB.
    pub paint: Linear,
    /// Albedo of goals and robot bodies, linear RGB.
    pub white: Linear,
    /// Whether goals have nets.
    pub nets: bool,
    /// The light.
    pub lighting: Lighting,
    /// Other robots on or beside the field.
    pub robots: Vec<Robot>,
    /// The ball, if on the carpet.
    pub ball: Option<Point2<f64>>,
    /// What lies beyond the carpet.
    pub surroundings: Surroundings,
    /// Whether robots, the ball and the goal posts cast shadows of the main light onto the carpet.
    pub shadows: bool,
    /// Carpet texture and line wear, if any.
    pub wear: Option<Wear>,
}

impl Scene {
    /// The plain scene: default field and light, a mid-green carpet, no nets, robots or ball, black
    /// surroundings, no shadows or wear. Symmetric under the field's point symmetry.
    pub fn plain(field: FieldModel) -> Self {
        Self {
            field,
            carpet: hsv_to_linear(115.0, 0.65, 0.45),
            paint: [0.85; 3],
            white: [0.8; 3],
            nets: false,
            lighting: Lighting::default(),
            robots: Vec::new(),
            ball: None,
            surroundings: Surroundings::Black,
            shadows: false,
            wear: None,
        }
    }
}

impl Default for Scene {
    fn default() -> Self {
        Self::plain(FieldModel::default())
    }
}
