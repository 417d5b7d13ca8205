//! Loading ONNX models: the contract is checked, broken files give clear errors, and the committed
//! models match onnxruntime's outputs (the parity fixtures written at export time) in tract, and in the
//! ONNX Runtime backend when the `onnxruntime` feature is on.

use std::path::{Path, PathBuf};

use image::RgbImage;
use relocd::frame::Frame;
use relocd::geometry::{Representation, Symmetry};
use relocd::relocaliser::{Backend, LoadOptions, Model, Relocaliser, default_model, preprocess};

fn models() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models")
}

fn tiny(name: &str) -> PathBuf {
    models().join("fixtures/tiny").join(name)
}

fn load_error(path: &Path) -> String {
    Model::load(path).unwrap_err().to_string()
}

#[test]
fn a_valid_model_loads_and_unfolds_into_symmetric_hypotheses() {
    let model = Model::load(&tiny("valid.onnx")).unwrap();
    assert_eq!(model.contract().representation, Representation::HalfPoint);
    assert_eq!(model.contract().input.image_size(), (160, 120));
    let relocaliser = Relocaliser::new(model);
    let frame =
        Frame::Rgb(RgbImage::from_fn(640, 480, |x, y| image::Rgb([(x % 256) as u8, (y % 256) as u8, 90])));
    let result = relocaliser.relocalise(&frame, 0.0).unwrap();
    assert_eq!(result.hypotheses.len(), 2);
    let total: f64 = result.hypotheses.iter().map(|h| h.weight).sum();
    assert!((total - 1.0).abs() < 1e-9);
    let twin = Symmetry::PointReflection.apply(&result.hypotheses[0].pose);
    assert!(twin.distance_to(&result.hypotheses[1].pose) < 1e-9);
}

#[test]
fn broken_models_name_what_is_wrong() {
    let cases = [
        ("no-contract.onnx", "has no \"relocd.contract\" metadata"),
        ("unknown-representation.onnx", "unknown variant `half-diagonal`"),
        ("wrong-input-shape.onnx", "cannot build the network for input [1, 3, 240, 320]"),
        ("missing-output.onnx", "the graph has no output \"heading_kappa\""),
    ];
    for (name, expected) in cases {
        let error = load_error(&tiny(name));
        assert!(error.contains(expected), "{name}: {error}");
    }
}

#[test]
fn truncated_corrupt_and_foreign_files_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(tiny("valid.onnx")).unwrap();
    let truncated = dir.path().join("truncated.onnx");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    assert!(load_error(&truncated).contains("is not an ONNX file"), "{}", load_error(&truncated));

    let image = dir.path().join("picture.onnx");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/images/render-black-seed1-frame0.jpg"),
        &image,
    )
    .unwrap();
    assert!(load_error(&image).contains("is not an ONNX file"), "{}", load_error(&image));

    let empty = dir.path().join("empty.onnx");
    std::fs::write(&empty, b"").unwrap();
    assert!(load_error(&empty).ends_with("the file is empty"));
}

/// Found by fuzzing (fuzz/corpus/model/): a graph output that no node produces made tract panic.
#[test]
fn a_graph_output_without_a_producer_is_an_error_not_a_panic() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus/model/graph-output-without-producer.onnx");
    let error = load_error(&path);
    assert!(error.contains("tract cannot read this graph"), "{error}");
}

#[test]
fn wrong_size_frames_give_a_clear_error() {
    let relocaliser = Relocaliser::new(Model::load(&tiny("valid.onnx")).unwrap());
    let error = relocaliser.relocalise(&Frame::Rgb(RgbImage::new(500, 400)), 0.0).unwrap_err().to_string();
    assert!(error.contains("a 500x400 frame cannot be reduced"), "{error}");
}

#[test]
fn the_built_in_default_model_loads() {
    let model = default_model().unwrap();
    assert_eq!(model.contract().representation, Representation::HalfPoint);
}

/// tract's outputs on the parity frames equal onnxruntime's, within the fixture's tolerance.
#[test]
fn committed_models_match_onnxruntime() {
    check_parity(Backend::Tract, None);
}

/// The ONNX Runtime backend reproduces the fixture (written by onnxruntime's Python API) to float
/// precision: it checks the wiring (input name, output order, shapes), not the arithmetic. Only the
/// float forms (fp32, w8) are compared: onnxruntime picks its integer kernels by CPU (AVX2's
/// saturating u8×s8 pairs, AVX-512 VNNI), so its int8 outputs on this machine differ from the
/// fixture machine's by more than the fixture's tolerance (0.033 in a heading, measured here).
#[cfg(feature = "onnxruntime")]
#[test]
fn the_onnxruntime_backend_matches_the_parity_fixtures() {
    check_parity(Backend::Onnxruntime, Some(1e-5));
}

/// Runs the forms of every model with a parity fixture through `backend` and compares with the
/// fixture's outputs: only the float forms, within `float_forms_at`, if given; else every form,
/// within the fixture's tolerance for it.
fn check_parity(backend: Backend, float_forms_at: Option<f64>) {
    let parity = models().join("fixtures/parity");
    let mut checked = 0;
    for entry in std::fs::read_dir(&parity).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|extension| extension != "json") {
            continue;
        }
        let name = path.file_stem().unwrap().to_str().unwrap().to_string();
        let fixture: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        // Every form of the model with onnxruntime outputs in the fixture: fp32, int8 (QDQ), w8, qop.
        for kind in fixture["frames"][0]["outputs"].as_object().unwrap().keys() {
            let model_path = models().join(format!("{name}.{kind}.onnx"));
            assert!(model_path.exists(), "{name}.json has outputs for a missing {model_path:?}");
            let integer_arithmetic = matches!(kind.as_str(), "int8" | "qop");
            let tolerance = match float_forms_at {
                Some(_) if integer_arithmetic => continue,
                Some(tolerance) => tolerance,
                None => fixture["tolerance"][kind.as_str()].as_f64().unwrap(),
            };
            let model = Model::load_with(&model_path, LoadOptions { backend, representation: None }).unwrap();
            for frame in fixture["frames"].as_array().unwrap() {
                let image = image::open(parity.join(frame["file"].as_str().unwrap())).unwrap().into_rgb8();
                let input = preprocess(&Frame::Rgb(image), &model.contract().input).unwrap();
                let raw = model.run(&input).unwrap();
                let expected = &frame["outputs"][kind.as_str()];
                let found: [(&str, Vec<f32>); 5] = [
                    ("position", raw.position.to_vec()),
                    ("heading", raw.heading.to_vec()),
                    ("fold_probabilities", raw.fold_probabilities.clone()),
                    ("position_sigma", vec![raw.position_sigma]),
                    ("heading_kappa", vec![raw.heading_kappa]),
                ];
                for (output, values) in found {
                    let Some(reference) = expected[output].as_array() else { continue };
                    assert_eq!(reference.len(), values.len(), "{name}.{kind} {output}");
                    for (value, reference) in values.iter().zip(reference) {
                        let reference = reference.as_f64().unwrap();
                        let scale = reference.abs().max(1.0);
                        assert!(
                            (f64::from(*value) - reference).abs() <= tolerance * scale,
                            "{name}.{kind} {output} on {}: {backend} {value}, onnxruntime {reference}",
                            frame["file"]
                        );
                    }
                }
            }
            checked += 1;
        }
    }
    assert!(checked >= 1, "no parity fixture checked");
}

#[test]
fn the_built_in_model_says_which_cameras_it_was_trained_for() {
    let model = default_model().unwrap();
    let range = model.contract().camera_range().expect("the v3 contract carries its camera range");
    assert_eq!(range.height_m, [0.38, 0.55]);
    assert_eq!(range.pitch_deg_down, [-10.0, 25.0]);
    let standing = relocd::geometry::CameraPose::STANDING;
    assert_eq!(range.outside(&standing), None, "a standing Nao is inside");
}
