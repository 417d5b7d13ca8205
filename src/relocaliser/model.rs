//! Loading and running an ONNX relocaliser with tract. tract stays inside this file.

use std::path::Path;
use std::sync::Arc;

use thiserror::Error;
use tract_onnx::prelude::*;

use super::contract::{CONTRACT_KEY, ContractError, ModelContract};
use super::decode::RawOutput;
use super::preprocess::InputTensor;
use crate::geometry::Representation;

/// The instruction sets tract's kernels may use on this machine, after `TRACT_CPU_ISA`: `x86_64`
/// alone means the generic kernels an Atom without AVX gets; `x86_64,avx,avx2,fma,…` the fast ones;
/// `generic` where tract has no kernels of its own (32-bit x86, the Nao V5).
pub fn kernel_isa() -> String {
    let isa = tract_onnx::tract_core::tract_linalg::isa::native();
    match isa.arch() {
        Some(_) => format!("{isa:?}"),
        None => "generic".into(),
    }
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
    plan: Arc<TypedRunnableModel>,
    /// For each of the contract's required outputs, its index among the graph's outputs.
    output_indices: Vec<usize>,
}

impl Model {
    /// Loads and checks a model file.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        Self::load_as(path, None)
    }

    /// Loads a model file, decoding in `representation` when given (see [`Model::from_bytes_as`]).
    pub fn load_as(path: &Path, representation: Option<Representation>) -> Result<Self, ModelError> {
        let bytes = std::fs::read(path)
            .map_err(|source| ModelError::Read { path: path.display().to_string(), source })?;
        Self::from_bytes_as(&bytes, &path.display().to_string(), representation)
    }

    /// Loads and checks a model from memory; `source_name` names it in errors.
    pub fn from_bytes(bytes: &[u8], source_name: &str) -> Result<Self, ModelError> {
        Self::from_bytes_as(bytes, source_name, None)
    }

    /// Like [`Model::from_bytes`], but decodes the outputs in `representation` instead of the one
    /// the contract names (the graph must then have that representation's outputs).
    pub fn from_bytes_as(
        bytes: &[u8],
        source_name: &str,
        representation: Option<Representation>,
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
        if let Some(representation) = representation {
            contract.representation = representation;
        }

        let model = onnx.model_for_proto_model(&proto).map_err(|error| graph_error(format!("{error:#}")))?;
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

        let shape = contract.input.shape.clone();
        let plan = model
            .with_input_fact(0, f32::fact(&shape).into())
            .and_then(|model| model.into_optimized())
            .and_then(|model| model.into_runnable())
            .map_err(|error| {
                graph_error(format!("cannot build the network for input {shape:?}: {error:#}"))
            })?;
        Ok(Self { contract, plan, output_indices })
    }

    /// The model's contract.
    pub fn contract(&self) -> &ModelContract {
        &self.contract
    }

    /// Runs the network on one input tensor.
    pub fn run(&self, input: &InputTensor) -> Result<RawOutput, ModelError> {
        if input.shape.as_slice() != self.contract.input.shape.as_slice() {
            return Err(ModelError::Inference(format!(
                "input shape {:?} does not match the model's {:?}",
                input.shape, self.contract.input.shape
            )));
        }
        let tensor = tract_ndarray::Array4::from_shape_vec(input.shape, input.data.clone())
            .map_err(|error| ModelError::Inference(error.to_string()))?
            .into_tensor();
        let outputs = self
            .plan
            .run(tvec!(tensor.into()))
            .map_err(|error| ModelError::Inference(format!("{error:#}")))?;
        let names = self.contract.required_outputs();
        let mut values = Vec::with_capacity(names.len());
        for (name, index) in names.iter().zip(&self.output_indices) {
            let view = outputs[*index]
                .to_plain_array_view::<f32>()
                .map_err(|error| ModelError::Inference(format!("output {name}: {error:#}")))?;
            values.push(view.iter().copied().collect::<Vec<f32>>());
        }
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
