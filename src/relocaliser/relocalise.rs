//! One relocalisation: frame → input tensor → network → decoded prediction → hypotheses, timed.

use std::time::Instant;

use thiserror::Error;

use super::decode::{DecodeError, Prediction};
use super::model::{Model, ModelError};
use super::preprocess::{PreprocessError, preprocess};
use crate::frame::Frame;
use crate::geometry::Hypothesis;

/// Why a frame could not be relocalised.
#[derive(Debug, Error)]
pub enum RelocaliseError {
    /// The frame does not fit the model's input.
    #[error(transparent)]
    Preprocess(#[from] PreprocessError),
    /// The network failed.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The network's outputs were unusable.
    #[error(transparent)]
    Decode(#[from] DecodeError),
}

/// Time spent in each stage, milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Timings {
    /// Frame → input tensor.
    pub preprocess_ms: f64,
    /// The network.
    pub inference_ms: f64,
    /// Decoding and unfolding.
    pub decode_ms: f64,
}

/// The result for one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Relocalisation {
    /// The decoded prediction (folded pose, fold probabilities, uncertainty).
    pub prediction: Prediction,
    /// Weighted full-field hypotheses, heaviest first.
    pub hypotheses: Vec<Hypothesis>,
    /// Stage timings.
    pub timings: Timings,
}

/// A model ready to relocalise frames.
#[derive(Debug)]
pub struct Relocaliser {
    model: Model,
}

impl Relocaliser {
    /// Wraps a loaded model.
    pub fn new(model: Model) -> Self {
        Self { model }
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Relocalises from one frame taken with the head turned by `head_yaw` radians.
    pub fn relocalise(&self, frame: &Frame, head_yaw: f64) -> Result<Relocalisation, RelocaliseError> {
        let started = Instant::now();
        let input = preprocess(frame, &self.model.contract().input)?;
        let preprocessed = Instant::now();
        let raw = self.model.run(&input)?;
        let inferred = Instant::now();
        let prediction = Prediction::decode(&raw, self.model.contract().representation, head_yaw)?;
        let hypotheses = prediction.hypotheses();
        let decoded = Instant::now();
        let ms = |from: Instant, to: Instant| (to - from).as_secs_f64() * 1e3;
        Ok(Relocalisation {
            prediction,
            hypotheses,
            timings: Timings {
                preprocess_ms: ms(started, preprocessed),
                inference_ms: ms(preprocessed, inferred),
                decode_ms: ms(inferred, decoded),
            },
        })
    }
}
