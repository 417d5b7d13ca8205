//! The optional ONNX Runtime engine (cargo feature `onnxruntime`). `libonnxruntime.so` is loaded when
//! the first model asks for it, never linked and never downloaded: `ORT_DYLIB_PATH` names the file,
//! otherwise the dynamic loader looks for `libonnxruntime.so` on its usual paths. ort stays inside
//! this file.

use std::fmt;
use std::path::PathBuf;
use std::sync::Mutex;

use ort::environment::Environment;
use ort::session::Session;
use ort::session::builder::GraphOptimizationLevel;
use ort::value::Tensor;

use super::preprocess::InputTensor;

/// The library file relocd loads: `ORT_DYLIB_PATH` when set, else `libonnxruntime.so`.
pub fn library() -> PathBuf {
    match std::env::var_os("ORT_DYLIB_PATH") {
        Some(path) if !path.is_empty() => PathBuf::from(path),
        _ => PathBuf::from("libonnxruntime.so"),
    }
}

/// ONNX Runtime allows one environment per process: the first model that needs it starts it.
fn environment() -> Result<Environment, String> {
    static ENVIRONMENT: Mutex<Option<Environment>> = Mutex::new(None);
    let mut slot = ENVIRONMENT.lock().map_err(|_| "an earlier ONNX Runtime start panicked".to_string())?;
    if let Some(environment) = slot.as_ref() {
        return Ok(environment.clone());
    }
    let path = library();
    let environment = ort::init_from(&path)
        .map_err(|error| {
            format!(
                "cannot load ONNX Runtime from {} ({error}); set ORT_DYLIB_PATH to libonnxruntime.so",
                path.display()
            )
        })?
        .with_name("relocd")
        .with_telemetry(false)
        .build()
        .map_err(|error| format!("cannot start ONNX Runtime: {error}"))?;
    *slot = Some(environment.clone());
    Ok(environment)
}

/// One model in an ONNX Runtime session, on the calling thread only (one intra-op thread, sequential).
pub struct OnnxRuntimeSession {
    /// `Session::run` needs `&mut`; relocalisations of one model run one at a time anyway.
    session: Mutex<Session>,
}

impl fmt::Debug for OnnxRuntimeSession {
    fn fmt(&self, formatter: &mut fmt::Formatter) -> fmt::Result {
        formatter.write_str("OnnxRuntimeSession")
    }
}

impl OnnxRuntimeSession {
    /// Loads the library (once per process) and builds a session for the ONNX file in `bytes`.
    pub fn load(bytes: &[u8]) -> Result<Self, String> {
        let environment = environment()?;
        let session = Session::builder(&environment)
            .and_then(|builder| Ok(builder.with_intra_threads(1)?))
            .and_then(|builder| Ok(builder.with_inter_threads(1)?))
            .and_then(|builder| Ok(builder.with_optimization_level(GraphOptimizationLevel::All)?))
            .and_then(|mut builder| builder.commit_from_memory(bytes))
            .map_err(|error| format!("ONNX Runtime cannot build the network: {error}"))?;
        Ok(Self { session: Mutex::new(session) })
    }

    /// Runs the network on `input`, fed as `input_name`, and returns the named outputs in order.
    pub fn run(
        &self,
        input_name: &str,
        input: &InputTensor,
        outputs: &[&str],
    ) -> Result<Vec<Vec<f32>>, String> {
        let tensor = Tensor::from_array((input.shape.map(|size| size as i64), input.data.clone()))
            .map_err(|error| error.to_string())?;
        let mut session = self.session.lock().map_err(|_| "an earlier run panicked".to_string())?;
        let results = session.run(ort::inputs![input_name => tensor]).map_err(|error| error.to_string())?;
        outputs
            .iter()
            .map(|name| {
                let value =
                    results.get(*name).ok_or_else(|| format!("the network has no output {name:?}"))?;
                let (_, values) =
                    value.try_extract_tensor::<f32>().map_err(|error| format!("output {name}: {error}"))?;
                Ok(values.to_vec())
            })
            .collect()
    }
}
