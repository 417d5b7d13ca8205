//! relocd: relocalises a Nao robot on the SPL field from one camera image.
//!
//! The library is the pure core (geometry, symmetries, renderer, recording format); the binary
//! `relocd` is the command line on top of it.

pub mod bench;
pub mod client;
pub mod daemon;
pub mod eval;
pub mod frame;
pub mod fuzzing;
pub mod geometry;
pub mod inspect;
pub mod pipeline;
pub mod posture;
pub mod protocol;
pub mod recording;
pub mod refine;
pub mod relocaliser;
pub mod replay;
#[cfg(feature = "report")]
pub mod report;
pub mod sim;
