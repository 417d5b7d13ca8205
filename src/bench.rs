//! `relocd bench`: per-stage latency medians of one relocalisation on this machine, on the calling
//! thread, for any model: the same stages as `cargo bench --bench relocalise`, but in the shipped
//! binary, so it runs on the robot too.

use std::fmt;
use std::str::FromStr;
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;

use crate::frame::{Frame, YuyvImage};
use crate::geometry::{Camera, CameraIntrinsics, CameraPose, FieldModel};
use crate::pipeline::{self, GlobalSearch, Pipeline, Priors};
use crate::relocaliser::{Backend, Model, Prediction, kernel_isa, preprocess};
use crate::sim::{Randomisation, render};

/// Frames in the fused burst, as the daemon captures by default.
const BURST: usize = 5;
/// Untimed runs of each stage before measuring (caches, tract's lazy state).
const WARM_UP: usize = 3;

/// One stage of a relocalisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// YUYV 640×480 frame → input tensor.
    Preprocess,
    /// The network.
    Inference,
    /// Decoding the outputs and unfolding them into hypotheses.
    Unfold,
    /// Fusing a burst of five predictions.
    Fusion,
    /// Line points of one frame.
    Lines,
    /// Refining one hypothesis against those line points (search, fit and verification).
    Refine,
    /// The global search for places those line points fit: over the whole field and near the heaviest
    /// hypothesis, as the pipeline searches when the lines are unsure.
    Search,
    /// A whole frame: preprocess, inference, unfold.
    Total,
    /// A whole burst of five copies of the frame as the daemon runs it: each frame's network and line
    /// points, fusion, the line fits and, always (its worst case), the global search.
    Burst,
}

impl Stage {
    /// Every stage, in pipeline order.
    pub const ALL: [Stage; 9] = [
        Stage::Preprocess,
        Stage::Inference,
        Stage::Unfold,
        Stage::Fusion,
        Stage::Lines,
        Stage::Refine,
        Stage::Search,
        Stage::Total,
        Stage::Burst,
    ];

    fn name(self) -> &'static str {
        match self {
            Stage::Preprocess => "preprocess",
            Stage::Inference => "inference",
            Stage::Unfold => "unfold",
            Stage::Fusion => "fusion",
            Stage::Lines => "lines",
            Stage::Refine => "refine",
            Stage::Search => "search",
            Stage::Total => "total",
            Stage::Burst => "burst",
        }
    }
}

impl fmt::Display for Stage {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        formatter.write_str(self.name())
    }
}

impl FromStr for Stage {
    type Err = String;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        Stage::ALL.into_iter().find(|stage| stage.name() == name).ok_or_else(|| {
            format!("unknown stage {name:?}: expected preprocess, inference, unfold, fusion, lines, refine, search, total or burst")
        })
    }
}

/// Medians of the stages measured, milliseconds (absent: not measured).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StageMedians {
    /// Frame → input tensor.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preprocess_ms: Option<f64>,
    /// The network.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub inference_ms: Option<f64>,
    /// Decoding and unfolding.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unfold_ms: Option<f64>,
    /// Fusing a burst of five.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fusion_ms: Option<f64>,
    /// Line points of one frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lines_ms: Option<f64>,
    /// Refining one hypothesis against them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refine_ms: Option<f64>,
    /// The global search for places they fit.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub search_ms: Option<f64>,
    /// A whole frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub total_ms: Option<f64>,
    /// A whole burst with the global search.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub burst_ms: Option<f64>,
}

/// What `relocd bench --json` prints.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BenchReport {
    /// The model file, or `<built-in …>`.
    pub model: String,
    /// The inference engine.
    pub backend: Backend,
    /// The instruction sets tract's kernels use here ([`kernel_isa`]).
    pub isa: String,
    /// The CPU, from /proc/cpuinfo where there is one.
    pub cpu: Option<String>,
    /// Timed runs per stage.
    pub iterations: usize,
    /// The frame timed: format and size.
    pub frame: String,
    /// Line points found in the frame under its camera pose: with none, the refine and search stages
    /// have nothing to fit (a frame timed under a camera pose it was not taken from).
    pub line_points: usize,
    /// Frames of line points the refine and search stages fit.
    pub line_frames: usize,
    /// Per-stage medians.
    pub stages: StageMedians,
}

/// Times `stages` of relocalising `frame` seen from its camera pose (default: a rendered 640×480 YUYV
/// top-camera frame, with its camera pose) with `model`, `iterations` times each (after a short
/// warm-up), the refine and search stages on `line_frames` copies of the frame's line points (a
/// standing robot's burst); medians in milliseconds.
pub fn run(
    model: Model,
    model_name: String,
    frame: Option<(Frame, CameraPose)>,
    stages: &[Stage],
    iterations: usize,
    line_frames: usize,
) -> anyhow::Result<BenchReport> {
    let (frame, camera_pose) = frame.unwrap_or_else(camera_frame);
    let spec = model.contract().input.clone();
    let input = preprocess(&frame, &spec).context("the benchmark frame does not fit the model")?;
    let raw = model.run(&input)?;
    let representation = model.contract().representation;
    let prediction = Prediction::decode(&raw, representation, 0.0)?;
    let burst = vec![prediction.clone(); BURST];
    let (intrinsics, model_field) = (model.contract().camera, model.contract().field.clone());
    let backend = model.backend();
    let whole = Pipeline::new(model)
        .with_lines(&FieldModel::new(model_field))
        .with_global_search(GlobalSearch::Always);
    let (relocaliser, refiner) = (
        whole.relocaliser().expect("the pipeline has the network"),
        whole.refiner().expect("the pipeline checks lines"),
    );
    let percepts = vec![refiner.percepts(&frame, &intrinsics, &camera_pose)?; line_frames.max(1)];
    let mut heaviest = pipeline::fuse(std::slice::from_ref(&prediction))?.hypotheses;
    heaviest.truncate(1);

    let mut medians = StageMedians::default();
    for &stage in stages {
        let median = match stage {
            Stage::Preprocess => median_ms(iterations, || drop(preprocess(&frame, &spec))),
            Stage::Inference => median_ms(iterations, || drop(relocaliser.model().run(&input))),
            Stage::Unfold => median_ms(iterations, || {
                drop(Prediction::decode(&raw, representation, 0.0).map(|prediction| prediction.hypotheses()))
            }),
            Stage::Fusion => median_ms(iterations, || drop(pipeline::fuse(&burst))),
            Stage::Lines => {
                median_ms(iterations, || drop(refiner.percepts(&frame, &intrinsics, &camera_pose)))
            }
            Stage::Refine => median_ms(iterations, || {
                let _ = pipeline::verify(refiner, &percepts, &mut heaviest.clone(), &[], GlobalSearch::Never);
            }),
            Stage::Search => {
                median_ms(iterations, || drop(pipeline::search_places(refiner, &percepts, heaviest.first())))
            }
            Stage::Total => median_ms(iterations, || drop(relocaliser.relocalise(&frame, 0.0))),
            Stage::Burst => median_ms(iterations, || {
                let mut running = whole.burst();
                for _ in 0..BURST {
                    let _ = running.add(&frame, 0.0, Some(&camera_pose));
                }
                drop(running.finish(&Priors::default()));
            }),
        };
        let slot = match stage {
            Stage::Preprocess => &mut medians.preprocess_ms,
            Stage::Inference => &mut medians.inference_ms,
            Stage::Unfold => &mut medians.unfold_ms,
            Stage::Fusion => &mut medians.fusion_ms,
            Stage::Lines => &mut medians.lines_ms,
            Stage::Refine => &mut medians.refine_ms,
            Stage::Search => &mut medians.search_ms,
            Stage::Total => &mut medians.total_ms,
            Stage::Burst => &mut medians.burst_ms,
        };
        *slot = Some(median);
    }
    let (width, height) = frame.dimensions();
    let format = if matches!(frame, Frame::Yuyv(_)) { "YUYV" } else { "RGB" };
    Ok(BenchReport {
        model: model_name,
        backend,
        isa: kernel_isa(),
        cpu: cpu_name(),
        iterations,
        frame: format!("{format} {width}x{height}"),
        line_points: percepts[0].points.len(),
        line_frames: percepts.len(),
        stages: medians,
    })
}

/// A rendered top-camera frame and its camera pose (the criterion benchmark's frame: seed 4000,
/// frame 0; it shows a penalty-area corner and the goal line).
fn camera_frame() -> (Frame, CameraPose) {
    let field = FieldModel::default();
    let sampled = Randomisation::default().sample(&field, 4000, 0, 1);
    let camera = Camera::new(CameraIntrinsics::nao_top(), &sampled.pose, &sampled.camera);
    let rgb = render(&sampled.scene, &camera, &sampled.settings);
    (Frame::Yuyv(YuyvImage::from_rgb(&rgb).expect("the Nao's frame width is even")), sampled.camera)
}

/// The median of `iterations` timed runs of `work`, milliseconds.
fn median_ms(iterations: usize, mut work: impl FnMut()) -> f64 {
    for _ in 0..WARM_UP {
        work();
    }
    let mut times: Vec<f64> = (0..iterations.max(1))
        .map(|_| {
            let started = Instant::now();
            work();
            started.elapsed().as_secs_f64() * 1000.0
        })
        .collect();
    times.sort_by(f64::total_cmp);
    median(&times)
}

fn median(sorted: &[f64]) -> f64 {
    let middle = sorted.len() / 2;
    if sorted.len() % 2 == 0 { (sorted[middle - 1] + sorted[middle]) / 2.0 } else { sorted[middle] }
}

fn cpu_name() -> Option<String> {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    let line = cpuinfo.lines().find(|line| line.starts_with("model name"))?;
    Some(line.split_once(':')?.1.trim().to_owned())
}

impl fmt::Display for BenchReport {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(formatter, "model   {} ({})", self.model, self.backend)?;
        writeln!(
            formatter,
            "cpu     {} (tract kernels: {})",
            self.cpu.as_deref().unwrap_or("unknown"),
            self.isa
        )?;
        writeln!(formatter, "frame   {}, medians of {} runs, one thread", self.frame, self.iterations)?;
        if self.line_points == 0 {
            writeln!(
                formatter,
                "lines   none under the frame's camera pose: refine and search have nothing to fit \
                 (--camera-height/--camera-pitch/--camera-roll give the pose the frame was taken from)"
            )?;
        } else if self.line_frames > 1 {
            writeln!(
                formatter,
                "lines   {} points; refine and search fit {} copies of the frame's line points",
                self.line_points, self.line_frames
            )?;
        } else {
            writeln!(formatter, "lines   {} points", self.line_points)?;
        }
        let stages = [
            ("preprocess", self.stages.preprocess_ms),
            ("inference", self.stages.inference_ms),
            ("unfold", self.stages.unfold_ms),
            ("fusion (burst of 5)", self.stages.fusion_ms),
            ("lines (one frame)", self.stages.lines_ms),
            ("refine (one hypothesis)", self.stages.refine_ms),
            ("search (when unsure)", self.stages.search_ms),
            ("total (one frame)", self.stages.total_ms),
            ("burst (5, with search)", self.stages.burst_ms),
        ];
        for (name, median) in stages {
            if let Some(median) = median {
                writeln!(formatter, "{name:<24} {median:>10.4} ms")?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians_of_odd_and_even_counts() {
        assert_eq!(median(&[1.0, 2.0, 9.0]), 2.0);
        assert_eq!(median(&[1.0, 2.0, 4.0, 9.0]), 3.0);
    }

    #[test]
    fn stages_parse_by_name() {
        for stage in Stage::ALL {
            assert_eq!(stage.to_string().parse::<Stage>().unwrap(), stage);
        }
        assert!("decode".parse::<Stage>().is_err());
    }

    #[test]
    fn the_report_has_the_requested_stages_only() {
        let model = crate::relocaliser::default_model().unwrap();
        let report = run(model, "built-in".into(), None, &[Stage::Unfold, Stage::Fusion], 2, 3).unwrap();
        let json = serde_json::to_value(&report).unwrap();
        let stages = json["stages"].as_object().unwrap();
        assert_eq!(stages.keys().collect::<Vec<_>>(), ["fusion_ms", "unfold_ms"]);
        assert!(stages.values().all(|value| value.as_f64().unwrap() >= 0.0));
        assert_eq!(json["isa"], kernel_isa());
        assert_eq!(json["line_frames"], 3);
        assert!(json["line_points"].as_u64().unwrap() >= 12, "the benchmark frame shows lines: {json}");
        assert!(report.to_string().contains("3 copies of the frame's line points"), "{report}");
    }

    #[test]
    fn a_frame_without_lines_under_its_camera_says_so() {
        let model = crate::relocaliser::default_model().unwrap();
        let (frame, _) = camera_frame();
        // The benchmark frame seen from a camera looking up: no line fits that pose.
        let looking_up = CameraPose::new(0.5, -0.5, 0.0, 0.0).unwrap();
        let report =
            run(model, "built-in".into(), Some((frame, looking_up)), &[Stage::Search], 1, 1).unwrap();
        assert_eq!(report.line_points, 0);
        assert!(report.to_string().contains("nothing to fit"), "{report}");
    }
}
