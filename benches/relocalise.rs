//! Per-stage latency of one relocalisation on the calling thread: YUYV 640×480 → input tensor,
//! inference of the built-in int8 model and of every committed model in `models/`, decoding and
//! unfolding, fusing a burst of five frames, line points and refining one hypothesis against them,
//! and the whole pipeline. `relocd bench` times the same
//! stages in the shipped binary.

use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use relocd::frame::{Frame, YuyvImage};
use relocd::geometry::{Camera, CameraIntrinsics, CameraPose, FieldModel};
use relocd::pipeline;
use relocd::refine::LineRefiner;
use relocd::relocaliser::{Model, Prediction, Relocaliser, default_model, preprocess};
use relocd::sim::{Randomisation, render};

fn camera_frame() -> (Frame, CameraPose) {
    let field = FieldModel::default();
    let sampled = Randomisation::default().sample(&field, 4000, 0, 1);
    let camera = Camera::new(CameraIntrinsics::nao_top(), &sampled.pose, &sampled.camera);
    let frame =
        Frame::Yuyv(YuyvImage::from_rgb(&render(&sampled.scene, &camera, &sampled.settings)).unwrap());
    (frame, sampled.camera)
}

/// Every ONNX model in `models/`, by file name.
fn committed_models() -> Vec<(String, Model)> {
    let directory = Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    let mut files: Vec<_> = std::fs::read_dir(&directory)
        .expect("models/ exists")
        .filter_map(|entry| entry.ok().map(|entry| entry.path()))
        .filter(|path| path.extension().is_some_and(|extension| extension == "onnx"))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|path| {
            let name = path.file_stem().unwrap().to_string_lossy().into_owned();
            (name, Model::load(&path).unwrap_or_else(|error| panic!("{}: {error}", path.display())))
        })
        .collect()
}

fn stages(criterion: &mut Criterion) {
    let (frame, camera_pose) = camera_frame();
    let model = default_model().unwrap();
    let input = preprocess(&frame, &model.contract().input).unwrap();
    let raw = model.run(&input).unwrap();
    let representation = model.contract().representation;

    let mut group = criterion.benchmark_group("relocalise");
    group.bench_function("preprocess_yuyv_640x480", |b| {
        b.iter(|| preprocess(&frame, &model.contract().input))
    });
    group.bench_function("inference_int8_default", |b| b.iter(|| model.run(&input)));
    for (name, committed) in committed_models() {
        match preprocess(&frame, &committed.contract().input) {
            Ok(input) => {
                group.bench_function(format!("inference/{name}"), |b| b.iter(|| committed.run(&input)));
            }
            Err(error) => eprintln!("skipping {name}: {error}"),
        }
    }
    group.bench_function("decode_and_unfold", |b| {
        b.iter(|| Prediction::decode(&raw, representation, 0.0).map(|prediction| prediction.hypotheses()))
    });
    let prediction = Prediction::decode(&raw, representation, 0.0).unwrap();
    let burst = vec![prediction; 5];
    group.bench_function("fuse_burst_of_5", |b| b.iter(|| pipeline::fuse(&burst)));
    let refiner = LineRefiner::new(&FieldModel::default());
    let intrinsics = CameraIntrinsics::nao_top();
    group.bench_function("line_points_yuyv_640x480", |b| {
        b.iter(|| refiner.percepts(&frame, &intrinsics, &camera_pose))
    });
    let percepts = refiner.percepts(&frame, &intrinsics, &camera_pose).unwrap();
    let mut one = pipeline::fuse(&burst[..1]).unwrap().hypotheses;
    one.truncate(1);
    group.bench_function("refine_one_hypothesis", |b| {
        b.iter(|| {
            pipeline::verify(
                &refiner,
                std::slice::from_ref(&percepts),
                &mut one.clone(),
                &[],
                pipeline::GlobalSearch::Never,
            )
        })
    });
    let relocaliser = Relocaliser::new(model);
    group.bench_function("whole_frame", |b| b.iter(|| relocaliser.relocalise(&frame, 0.0)));
    group.finish();
}

// No HTML plots: the figures that matter are the medians printed, and criterion's plotting would meet
// the `ab_glyph` font backend that relocd's own plots enable in plotters, with no font registered.
criterion_group! {
    name = benches;
    config = Criterion::default().without_plots();
    targets = stages
}
criterion_main!(benches);
