//! The built-in renderer: what the Nao top camera sees from a pose on the field, by casting rays
//! against the field model, and the randomisation that makes labelled training and test frames.

mod colour;
pub mod dataset;
pub mod randomise;
mod render;
pub mod scene;
mod trace;

pub use dataset::{DatasetSpec, render_dataset};
pub use randomise::{HallRealism, Randomisation, SampledFrame};
pub use render::{RenderSettings, render};
pub use scene::{Lighting, Robot, Scene, SecondLight, Surroundings, Wear};
