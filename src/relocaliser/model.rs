//! Loading and running an ONNX relocaliser: with tract (built in), or with ONNX Runtime (cargo feature
//! `onnxruntime`). tract stays inside this file and its one op of relocd's own, [`max_pool`].

mod max_pool;

use std::fmt;
use std::path::Path;
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use thiserror::Error;
use tract_onnx::prelude::*;

use super::contract::{CONTRACT_KEY, ContractError, ModelContract};
use super::decode::RawOutput;
use super::preprocess::InputTensor;
use crate::geometry::Representation;

/// The instruction sets tract's kernels may use on this machine, after `TRACT_CPU_ISA`:
/// `x86_64,sse4.1` means the SSE kernels an Atom without AVX gets (the patched tract-linalg in
/// `vendor/`), `x86_64` alone the generic ones; `x86_64,sse4.1,avx,avx2,fma,…` the fast ones;
/// `generic` where tract has no kernels of its own (32-bit x86, the Nao V5).
pub fn kernel_isa() -> String {
    let isa = tract_onnx::tract_core::tract_linalg::isa::native();
    match isa.arch() {
        Some(_) => format!("{isa:?}"),
        None => "generic".into(),
    }
}

/// The inference engine that runs a model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// tract: pure Rust, no library needed; the static robot build's engine.
    #[default]
    Tract,
    /// ONNX Runtime, loaded from `libonnxruntime.so` at run time (needs the `onnxruntime` feature).
    Onnxruntime,
}

impl fmt::Display for Backend {
    fn fmt(&self, formatter: &mut fmt::Formatter) -> fmt::Result {
        formatter.write_str(match self {
            Backend::Tract => "tract",
            Backend::Onnxruntime => "onnxruntime",
        })
    }
}

/// How to load a model.
#[derive(Clone, Copy, Debug, Default)]
pub struct LoadOptions {
    /// The engine that runs it.
    pub backend: Backend,
    /// Decode the outputs in this representation instead of the contract's (the graph must then have
    /// that representation's outputs).
    pub representation: Option<Representation>,
}

/// A model file that cannot be used, or a run that failed.
#[derive(Debug, Error)]
pub enum ModelError {
    /// The file could not be read.
    #[error("cannot read model {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The bytes are not an ONNX model.
    #[error("model {source_name} is not an ONNX file (empty, truncated or corrupt?): {reason}")]
    NotOnnx {
        /// Where the bytes came from.
        source_name: String,
        /// The decoder's message.
        reason: String,
    },
    /// The contract in the metadata is missing or invalid.
    #[error("model {source_name}: {error}")]
    Contract {
        /// Where the bytes came from.
        source_name: String,
        /// What is wrong.
        error: ContractError,
    },
    /// The chosen engine is not available.
    #[error("model {source_name}: {reason}")]
    Backend {
        /// Where the bytes came from.
        source_name: String,
        /// Why the engine cannot be used.
        reason: String,
    },
    /// The graph does not match its contract (names, shapes) or tract cannot build it.
    #[error("model {source_name}: {reason}")]
    Graph {
        /// Where the bytes came from.
        source_name: String,
        /// What is wrong.
        reason: String,
    },
    /// Running the network failed.
    #[error("inference failed: {0}")]
    Inference(String),
}

/// A loaded, optimised model with its contract; cheap to run many times.
#[derive(Debug)]
pub struct Model {
    contract: ModelContract,
    engine: Engine,
}

/// The network, ready to run in the chosen engine.
#[derive(Debug)]
enum Engine {
    Tract {
        plan: Arc<TypedRunnableModel>,
        /// For each of the contract's required outputs, its index among the graph's outputs.
        output_indices: Vec<usize>,
    },
    #[cfg(feature = "onnxruntime")]
    Onnxruntime(super::onnxruntime::OnnxRuntimeSession),
}

impl Model {
    /// Loads and checks a model file for tract.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        Self::load_with(path, LoadOptions::default())
    }

    /// Loads and checks a model file with `options`.
    pub fn load_with(path: &Path, options: LoadOptions) -> Result<Self, ModelError> {
        let bytes = std::fs::read(path)
            .map_err(|source| ModelError::Read { path: path.display().to_string(), source })?;
        Self::from_bytes_with(&bytes, &path.display().to_string(), options)
    }

    /// Loads and checks a model from memory for tract; `source_name` names it in errors.
    pub fn from_bytes(bytes: &[u8], source_name: &str) -> Result<Self, ModelError> {
        Self::from_bytes_with(bytes, source_name, LoadOptions::default())
    }

    /// Loads and checks a model from memory with `options`. The contract and the graph's inputs and
    /// outputs are checked the same way whichever engine runs it.
    pub fn from_bytes_with(
        bytes: &[u8],
        source_name: &str,
        options: LoadOptions,
    ) -> Result<Self, ModelError> {
        let source_name = source_name.to_string();
        let graph_error = |reason: String| ModelError::Graph { source_name: source_name.clone(), reason };
        if bytes.is_empty() {
            return Err(ModelError::NotOnnx { source_name, reason: "the file is empty".into() });
        }
        let onnx = tract_onnx::onnx();
        let proto = onnx.proto_model_for_read(&mut &bytes[..]).map_err(|error| ModelError::NotOnnx {
            source_name: source_name.clone(),
            reason: format!("{error:#}"),
        })?;
        if proto.graph.is_none() {
            return Err(ModelError::NotOnnx { source_name, reason: "it holds no graph".into() });
        }
        let contract_text = proto
            .metadata_props
            .iter()
            .find(|entry| entry.key == CONTRACT_KEY)
            .map(|entry| entry.value.clone())
            .ok_or_else(|| ModelError::Contract {
                source_name: source_name.clone(),
                error: ContractError::Missing,
            })?;
        let mut contract = ModelContract::from_json(&contract_text)
            .map_err(|error| ModelError::Contract { source_name: source_name.clone(), error })?;
        if let Some(representation) = options.representation {
            contract.representation = representation;
        }

        let model = without_panics(|| onnx.model_for_proto_model(&proto))
            .map_err(|error| graph_error(format!("{error:#}")))?;
        // The decoded protobuf holds a copy of every weight: free it before tract optimises the graph,
        // which is where loading peaks.
        drop(proto);
        let inputs = model.input_outlets().map_err(|error| graph_error(format!("{error:#}")))?;
        let input_names: Vec<&str> =
            inputs.iter().map(|outlet| model.node(outlet.node).name.as_str()).collect();
        if input_names != [contract.input.name.as_str()] {
            return Err(graph_error(format!(
                "the graph's inputs are {input_names:?}, the contract names one input {:?}",
                contract.input.name
            )));
        }
        let outputs = model.output_outlets().map_err(|error| graph_error(format!("{error:#}")))?;
        let output_names: Vec<String> = outputs
            .iter()
            .map(|outlet| model.outlet_label(*outlet).unwrap_or(&model.node(outlet.node).name).to_string())
            .collect();
        let output_indices = contract
            .required_outputs()
            .into_iter()
            .map(|name| {
                output_names.iter().position(|found| found == name).ok_or_else(|| {
                    graph_error(format!("the graph has no output {name:?} (it has {output_names:?})"))
                })
            })
            .collect::<Result<Vec<_>, _>>()?;

        let engine = match options.backend {
            Backend::Tract => {
                let shape = contract.input.shape.clone();
                let plan = without_panics(|| {
                    model
                        .with_input_fact(0, f32::fact(&shape).into())
                        .and_then(|model| model.into_optimized())
                        .and_then(max_pool::pool_in_two_passes)
                        .and_then(|model| model.into_runnable())
                })
                .map_err(|error| {
                    graph_error(format!("cannot build the network for input {shape:?}: {error:#}"))
                })?;
                Engine::Tract { plan, output_indices }
            }
            #[cfg(feature = "onnxruntime")]
            Backend::Onnxruntime => Engine::Onnxruntime(
                super::onnxruntime::OnnxRuntimeSession::load(bytes)
                    .map_err(|reason| ModelError::Backend { source_name: source_name.clone(), reason })?,
            ),
            #[cfg(not(feature = "onnxruntime"))]
            Backend::Onnxruntime => {
                return Err(ModelError::Backend {
                    source_name,
                    reason: "this relocd was built without ONNX Runtime (cargo build --features onnxruntime)"
                        .into(),
                });
            }
        };
        Ok(Self { contract, engine })
    }

    /// The model's contract.
    pub fn contract(&self) -> &ModelContract {
        &self.contract
    }

    /// The engine that runs it.
    pub fn backend(&self) -> Backend {
        match self.engine {
            Engine::Tract { .. } => Backend::Tract,
            #[cfg(feature = "onnxruntime")]
            Engine::Onnxruntime(_) => Backend::Onnxruntime,
        }
    }

    /// Runs the network on one input tensor.
    pub fn run(&self, input: &InputTensor) -> Result<RawOutput, ModelError> {
        if input.shape.as_slice() != self.contract.input.shape.as_slice() {
            return Err(ModelError::Inference(format!(
                "input shape {:?} does not match the model's {:?}",
                input.shape, self.contract.input.shape
            )));
        }
        let names = self.contract.required_outputs();
        let values = match &self.engine {
            Engine::Tract { plan, output_indices } => run_tract(plan, output_indices, input, &names)?,
            #[cfg(feature = "onnxruntime")]
            Engine::Onnxruntime(session) => {
                session.run(&self.contract.input.name, input, &names).map_err(ModelError::Inference)?
            }
        };
        let take = |index: usize, length: usize| -> Result<Vec<f32>, ModelError> {
            let found = &values[index];
            if found.len() == length {
                Ok(found.clone())
            } else {
                Err(ModelError::Inference(format!(
                    "output {} has {} values, expected {length}",
                    names[index],
                    found.len()
                )))
            }
        };
        let bits = self.contract.representation.fold_bits();
        let offset = usize::from(bits > 0);
        let position = take(0, 2)?;
        let heading = take(1, 2)?;
        Ok(RawOutput {
            position: [position[0], position[1]],
            heading: [heading[0], heading[1]],
            fold_probabilities: if bits > 0 { take(2, bits)? } else { Vec::new() },
            position_sigma: take(2 + offset, 1)?[0],
            heading_kappa: take(3 + offset, 1)?[0],
        })
    }
}

/// Runs `build` (tract reading or optimising a graph), turning a panic into an error: tract trusts
/// some graph invariants that a corrupt file breaks (found by fuzzing: a graph output that no node
/// produces), and a bad model must never take the daemon down.
fn without_panics<T>(build: impl FnOnce() -> TractResult<T>) -> TractResult<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(build)).unwrap_or_else(|panic| {
        let message = panic
            .downcast_ref::<&str>()
            .map(|text| text.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "no message".into());
        Err(anyhow::anyhow!("tract cannot read this graph (it panicked: {message})"))
    })
}

/// Runs tract's plan and returns the outputs at `output_indices`, flattened.
fn run_tract(
    plan: &Arc<TypedRunnableModel>,
    output_indices: &[usize],
    input: &InputTensor,
    names: &[&str],
) -> Result<Vec<Vec<f32>>, ModelError> {
    let tensor = tract_ndarray::Array4::from_shape_vec(input.shape, input.data.clone())
        .map_err(|error| ModelError::Inference(error.to_string()))?
        .into_tensor();
    let outputs =
        plan.run(tvec!(tensor.into())).map_err(|error| ModelError::Inference(format!("{error:#}")))?;
    names
        .iter()
        .zip(output_indices)
        .map(|(name, index)| {
            let view = outputs[*index]
                .to_plain_array_view::<f32>()
                .map_err(|error| ModelError::Inference(format!("output {name}: {error:#}")))?;
            Ok(view.iter().copied().collect())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn error_of(bytes: &[u8]) -> String {
        Model::from_bytes(bytes, "test.onnx").unwrap_err().to_string()
    }

    #[test]
    fn empty_and_garbage_files_are_not_onnx() {
        assert_eq!(
            error_of(b""),
            "model test.onnx is not an ONNX file (empty, truncated or corrupt?): the file is empty"
        );
        assert!(error_of(b"\xff\xff\xff\xff garbage").starts_with("model test.onnx is not an ONNX file"));
    }

    #[test]
    fn a_missing_file_names_the_path() {
        let error = Model::load(Path::new("/nonexistent/model.onnx")).unwrap_err().to_string();
        assert!(error.starts_with("cannot read model /nonexistent/model.onnx"), "{error}");
    }
}
