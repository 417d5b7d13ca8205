//! The model contract: what an ONNX file promises about its input and outputs, read from its
//! `metadata_props` key `relocd.contract` (a JSON document) and checked before the model is used.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::geometry::{CameraIntrinsics, CameraPose, FieldDimensions, Representation};

/// The metadata key holding the contract.
pub const CONTRACT_KEY: &str = "relocd.contract";
/// The contract version this build reads.
pub const CONTRACT_VERSION: u32 = 1;

/// A contract that is missing or says something relocd cannot work with.
#[derive(Debug, Error, PartialEq)]
pub enum ContractError {
    /// The file has no `relocd.contract` metadata.
    #[error(
        "the model has no \"{CONTRACT_KEY}\" metadata: it was not exported for relocd (see models/README.md)"
    )]
    Missing,
    /// The contract is not valid JSON or lacks a key.
    #[error("the model's contract is not valid: {0}")]
    Malformed(String),
    /// A contract field has a value relocd cannot use.
    #[error("the model's contract field {field} is {found}: expected {expected}")]
    Invalid {
        /// The field, as a JSON path.
        field: &'static str,
        /// What it holds.
        found: String,
        /// What would be accepted.
        expected: String,
    },
}

/// How a frame becomes the input tensor.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InputSpec {
    /// Name of the graph input.
    pub name: String,
    /// Shape, `[1, 3, height, width]`.
    pub shape: Vec<usize>,
    /// Memory layout; only `NCHW` is supported.
    pub layout: String,
    /// Channel order; only `RGB` is supported.
    pub colour: String,
    /// Factor applied to 8-bit values first (usually 1/255).
    pub scale: f32,
    /// Per-channel mean subtracted after scaling.
    pub mean: [f32; 3],
    /// Per-channel standard deviation divided by after subtracting the mean.
    pub std: [f32; 3],
}

impl InputSpec {
    /// (width, height) of the input image.
    pub fn image_size(&self) -> (usize, usize) {
        (self.shape[3], self.shape[2])
    }
}

/// Everything the ONNX file promises, as read from its metadata.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelContract {
    /// Contract format version.
    pub contract_version: u32,
    /// A name for this model and version, reported with every result.
    pub model_id: String,
    /// The output representation.
    pub representation: Representation,
    /// The input tensor.
    pub input: InputSpec,
    /// Output names and their meaning.
    pub outputs: BTreeMap<String, String>,
    /// The field the model was trained on.
    pub field: FieldDimensions,
    /// The camera the training frames were rendered with.
    pub camera: CameraIntrinsics,
    /// How the model was trained (data seeds and sizes, architecture, quantisation); informative.
    #[serde(default)]
    pub training: serde_json::Value,
}

/// The camera poses a model's training frames were rendered with (`training.camera_range` in its
/// contract, written by `models/export.py` from v3 on). A frame from outside it is one the network has
/// not learnt to read.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
pub struct CameraRange {
    /// Lowest and highest camera height, metres.
    pub height_m: [f64; 2],
    /// Least and most pitch, degrees, positive looking down.
    pub pitch_deg_down: [f64; 2],
    /// Largest roll either way, degrees.
    pub max_roll_deg: f64,
}

impl CameraRange {
    /// What about `pose` lies outside the range, in words; `None` when it lies within.
    pub fn outside(&self, pose: &CameraPose) -> Option<String> {
        let (height, pitch, roll) = (pose.height(), pose.pitch().to_degrees(), pose.roll().to_degrees());
        let mut reasons = Vec::new();
        if !(self.height_m[0]..=self.height_m[1]).contains(&height) {
            reasons.push(format!(
                "height {height:.2} m not in {:.2}-{:.2} m",
                self.height_m[0], self.height_m[1]
            ));
        }
        if !(self.pitch_deg_down[0]..=self.pitch_deg_down[1]).contains(&pitch) {
            reasons.push(format!(
                "pitch {pitch:.1}° not in {:.1}° to {:.1}° (down)",
                self.pitch_deg_down[0], self.pitch_deg_down[1]
            ));
        }
        if roll.abs() > self.max_roll_deg {
            reasons.push(format!("roll {roll:.1}° beyond ±{:.1}°", self.max_roll_deg));
        }
        (!reasons.is_empty()).then(|| reasons.join(", "))
    }
}

/// The outputs every model has, whatever its representation.
pub const BASE_OUTPUTS: [&str; 4] = ["position", "heading", "position_sigma", "heading_kappa"];
/// The output that carries the fold-bit probabilities (absent for `full`).
pub const FOLD_OUTPUT: &str = "fold_probabilities";

impl ModelContract {
    /// Parses and checks a contract document.
    pub fn from_json(text: &str) -> Result<Self, ContractError> {
        let contract: Self =
            serde_json::from_str(text).map_err(|error| ContractError::Malformed(error.to_string()))?;
        contract.validate()?;
        Ok(contract)
    }

    /// The camera poses the training frames covered, where the contract says (models from v3 on).
    pub fn camera_range(&self) -> Option<CameraRange> {
        serde_json::from_value(self.training.get("camera_range")?.clone()).ok()
    }

    /// The output names this contract's representation needs, in the order relocd reads them.
    pub fn required_outputs(&self) -> Vec<&'static str> {
        let mut names = BASE_OUTPUTS.to_vec();
        if self.representation.fold_bits() > 0 {
            names.insert(2, FOLD_OUTPUT);
        }
        names
    }

    fn validate(&self) -> Result<(), ContractError> {
        let invalid = |field, found: String, expected: &str| {
            Err(ContractError::Invalid { field, found, expected: expected.to_string() })
        };
        if self.contract_version != CONTRACT_VERSION {
            return invalid(
                "contract_version",
                self.contract_version.to_string(),
                &format!("{CONTRACT_VERSION} (re-export the model for this relocd)"),
            );
        }
        let shape = &self.input.shape;
        if shape.len() != 4 || shape[0] != 1 || shape[1] != 3 || shape[2] == 0 || shape[3] == 0 {
            return invalid("input.shape", format!("{shape:?}"), "[1, 3, height, width]");
        }
        if self.input.layout != "NCHW" {
            return invalid("input.layout", format!("{:?}", self.input.layout), "\"NCHW\"");
        }
        if self.input.colour != "RGB" {
            return invalid("input.colour", format!("{:?}", self.input.colour), "\"RGB\"");
        }
        if !(self.input.scale.is_finite() && self.input.scale > 0.0) {
            return invalid("input.scale", self.input.scale.to_string(), "a positive number");
        }
        if self.input.std.iter().any(|std| !(std.is_finite() && *std > 0.0))
            || self.input.mean.iter().any(|m| !m.is_finite())
        {
            return invalid(
                "input.std",
                format!("{:?} (mean {:?})", self.input.std, self.input.mean),
                "finite, std > 0",
            );
        }
        for name in self.required_outputs() {
            if !self.outputs.contains_key(name) {
                return invalid(
                    "outputs",
                    format!("{:?}", self.outputs.keys().collect::<Vec<_>>()),
                    &format!(
                        "an entry for \"{name}\" ({} needs {:?})",
                        self.representation,
                        self.required_outputs()
                    ),
                );
            }
        }
        self.field.validate().map_err(|error| ContractError::Invalid {
            field: "field",
            found: error.to_string(),
            expected: "a valid field description".into(),
        })?;
        Ok(())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A valid contract document for tests.
    pub(crate) fn sample_json(representation: &str) -> serde_json::Value {
        let mut outputs = serde_json::json!({
            "position": "m", "heading": "unit", "position_sigma": "m", "heading_kappa": "1"
        });
        if representation != "full" {
            outputs["fold_probabilities"] = "p".into();
        }
        serde_json::json!({
            "contract_version": 1,
            "model_id": "test",
            "representation": representation,
            "input": {"name": "image", "shape": [1, 3, 120, 160], "layout": "NCHW", "colour": "RGB",
                      "scale": 1.0 / 255.0, "mean": [0.5, 0.5, 0.5], "std": [0.25, 0.25, 0.25]},
            "outputs": outputs,
            "field": FieldDimensions::spl_2025(),
            "camera": CameraIntrinsics::nao_top(),
        })
    }

    fn parse(document: &serde_json::Value) -> Result<ModelContract, ContractError> {
        ModelContract::from_json(&document.to_string())
    }

    #[test]
    fn accepts_a_complete_contract() {
        let contract = parse(&sample_json("half-point")).unwrap();
        assert_eq!(contract.representation, Representation::HalfPoint);
        assert_eq!(contract.input.image_size(), (160, 120));
        assert_eq!(
            contract.required_outputs(),
            ["position", "heading", "fold_probabilities", "position_sigma", "heading_kappa"]
        );
        assert_eq!(parse(&sample_json("full")).unwrap().required_outputs().len(), 4);
    }

    #[test]
    fn names_the_wrong_field() {
        let mut unknown = sample_json("half-point");
        unknown["representation"] = "half-diagonal".into();
        assert!(parse(&unknown).unwrap_err().to_string().contains("unknown variant `half-diagonal`"));

        let mut shape = sample_json("half-point");
        shape["input"]["shape"] = serde_json::json!([1, 120, 160, 3]);
        assert_eq!(
            parse(&shape).unwrap_err().to_string(),
            "the model's contract field input.shape is [1, 120, 160, 3]: expected [1, 3, height, width]"
        );

        let mut missing = sample_json("quarter");
        missing["outputs"].as_object_mut().unwrap().remove("fold_probabilities");
        let error = parse(&missing).unwrap_err().to_string();
        assert!(error.contains("field outputs") && error.contains("\"fold_probabilities\""), "{error}");

        let mut version = sample_json("full");
        version["contract_version"] = 7.into();
        assert!(parse(&version).unwrap_err().to_string().contains("contract_version is 7"));

        let mut std = sample_json("full");
        std["input"]["std"] = serde_json::json!([0.25, 0.0, 0.25]);
        assert!(parse(&std).unwrap_err().to_string().contains("input.std"));

        assert!(matches!(ModelContract::from_json("{"), Err(ContractError::Malformed(_))));
    }

    #[test]
    fn the_training_camera_range_is_read_and_says_what_lies_outside_it() {
        let mut document = sample_json("half-point");
        assert_eq!(ModelContract::from_json(&document.to_string()).unwrap().camera_range(), None);
        document["training"] = serde_json::json!({
            "camera_range": {"height_m": [0.38, 0.55], "pitch_deg_down": [-10.0, 25.0], "max_roll_deg": 5.0}
        });
        let range = ModelContract::from_json(&document.to_string()).unwrap().camera_range().unwrap();
        let pose = |height: f64, pitch: f64, roll: f64| {
            CameraPose::new(height, pitch.to_radians(), roll.to_radians(), 0.0).unwrap()
        };
        assert_eq!(range.outside(&pose(0.5, 10.0, 2.0)), None);
        let low_and_up = range.outside(&pose(0.3, -15.0, 0.0)).unwrap();
        assert!(low_and_up.contains("height 0.30 m") && low_and_up.contains("pitch -15.0°"), "{low_and_up}");
        assert!(range.outside(&pose(0.5, 0.0, -6.0)).unwrap().contains("roll -6.0°"));
        document["training"]["camera_range"] = serde_json::json!({"height_m": "tall"});
        assert_eq!(
            ModelContract::from_json(&document.to_string()).unwrap().camera_range(),
            None,
            "malformed"
        );
    }
}
