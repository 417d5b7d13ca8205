//! The relocaliser: the model contract, preprocessing a camera frame into the network's input, running
//! the network (tract, or ONNX Runtime with the `onnxruntime` feature), and decoding its outputs into
//! weighted full-field hypotheses.

pub mod contract;
pub mod decode;
pub mod fusion;
pub mod model;
#[cfg(feature = "onnxruntime")]
pub mod onnxruntime;
pub mod preprocess;
pub mod relocalise;

use std::path::Path;

pub use contract::{ContractError, InputSpec, ModelContract};
pub use decode::{DecodeError, Prediction, RawOutput};
pub use fusion::{BurstEstimate, FusedHypothesis, FusionError, fuse};
pub use model::{Backend, LoadOptions, Model, ModelError, kernel_isa};
pub use preprocess::{InputTensor, PreprocessError, preprocess};
pub use relocalise::{Relocalisation, RelocaliseError, Relocaliser, Timings};

/// A model built into the binary, so that relocd runs with no files beside it.
#[derive(Clone, Copy, Debug)]
pub struct BuiltInModel {
    /// Its file name in `models/`.
    pub name: &'static str,
    /// The ONNX file.
    pub bytes: &'static [u8],
}

/// tract's built-in model: the SqueezeNet half-point net with int8 weights and fp32 activations, the
/// form tract runs fastest on both its AVX2 and its generic (Atom) kernels (models/README.md, "Forms").
pub const DEFAULT_MODEL: BuiltInModel = BuiltInModel {
    name: "squeezenet-half-point.w8.onnx",
    bytes: include_bytes!("../../models/squeezenet-half-point.w8.onnx"),
};

/// The same network in the form ONNX Runtime runs fastest: int8 QDQ.
#[cfg(feature = "onnxruntime")]
const ONNXRUNTIME_DEFAULT_MODEL: BuiltInModel = BuiltInModel {
    name: "squeezenet-half-point.int8.onnx",
    bytes: include_bytes!("../../models/squeezenet-half-point.int8.onnx"),
};

/// The built-in model for `backend`: the same network, in the form that engine runs fastest.
pub fn built_in_model(backend: Backend) -> BuiltInModel {
    match backend {
        #[cfg(feature = "onnxruntime")]
        Backend::Onnxruntime => ONNXRUNTIME_DEFAULT_MODEL,
        _ => DEFAULT_MODEL,
    }
}

/// Loads tract's built-in model.
pub fn default_model() -> Result<Model, ModelError> {
    load_model(None, LoadOptions::default()).map(|(model, _)| model)
}

/// Loads the model file at `path`, or the built-in model for `options.backend` when there is none;
/// returns it with the name to report (the path, or `<built-in NAME>`).
pub fn load_model(path: Option<&Path>, options: LoadOptions) -> Result<(Model, String), ModelError> {
    match path {
        Some(path) => Ok((Model::load_with(path, options)?, path.display().to_string())),
        None => {
            let built_in = built_in_model(options.backend);
            let name = format!("<built-in {}>", built_in.name);
            Ok((Model::from_bytes_with(built_in.bytes, &name, options)?, name))
        }
    }
}
