//! Pure geometry: angles, typed poses, the field model, the four symmetries and the camera model.
//!
//! Frames used throughout relocd (metres and radians everywhere inside):
//! - **field**: origin at the centre spot, +x towards the opponent goal, +y to the left, z up,
//!   headings counter-clockwise from +x;
//! - **robot ground**: origin on the ground below the camera, +x forward, +y left, z up;
//! - **camera**: optical centre, +x along the optical axis, +y left, +z up (so image u grows
//!   towards −y and image v towards −z).

pub mod angle;
pub mod camera;
pub mod field;
pub mod pose;
pub mod symmetry;

pub use angle::normalize_angle;
pub use camera::{Camera, CameraIntrinsics};
pub use field::{FieldDimensions, FieldError, FieldModel};
pub use pose::{BodyAngles, CameraMounting, CameraPose, FieldPose, PoseError, PoseSigma};
pub use symmetry::{FoldClass, FoldedPose, Hypothesis, Representation, Symmetry, SymmetryError};
