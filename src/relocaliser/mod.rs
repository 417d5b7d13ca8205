//! The relocaliser: the model contract, preprocessing a camera frame into the network's input, running
//! the network with tract, and decoding its outputs into weighted full-field hypotheses.

pub mod contract;
pub mod decode;
pub mod fusion;
pub mod model;
pub mod pipeline;
pub mod preprocess;
pub mod prior;

pub use contract::{ContractError, InputSpec, ModelContract};
pub use decode::{DecodeError, Prediction, RawOutput};
pub use fusion::{BurstEstimate, FusedHypothesis, FusionError, PoseSigma, fuse};
pub use model::{Model, ModelError, kernel_isa};
pub use pipeline::{Relocalisation, RelocaliseError, Relocaliser, Timings};
pub use preprocess::{InputTensor, PreprocessError, preprocess};
pub use prior::PlacementPrior;

/// File name of the default model in `models/`: the SqueezeNet half-point net with int8 weights and
/// fp32 activations, the form tract runs fastest on both its AVX2 and its generic (Atom) kernels
/// (BENCHMARKS.md, "Model forms").
pub const DEFAULT_MODEL_NAME: &str = "squeezenet-half-point.w8.onnx";

/// The default model, built into the binary so that relocd runs with no files beside it.
pub const DEFAULT_MODEL: &[u8] = include_bytes!("../../models/squeezenet-half-point.w8.onnx");

/// Loads the built-in default model.
pub fn default_model() -> Result<Model, ModelError> {
    Model::from_bytes(DEFAULT_MODEL, &format!("<built-in {DEFAULT_MODEL_NAME}>"))
}
