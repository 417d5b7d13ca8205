//! `relocd inspect`: the line percepts of image files or of a recording, as one JSON line per frame
//! and, on request, overlay pictures. What a team runs first in a new hall.
//!
//! Each frame is searched as line refinement searches it ([`crate::refine::detect`]): the carpet's top
//! edge, the line crossings in the image, and the line points that survive the ground-width gate under
//! the frame's camera pose; and the goal posts standing on the carpet that rise as a goal's would under
//! that pose. With no pose at all (`camera: None`) only the image stage runs (every upright bar found
//! standing on the carpet counts as a post).

use std::fs;
use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage};
use nalgebra::{Point2, Point3};
use serde::Serialize;
use thiserror::Error;

use crate::frame::Frame;
use crate::geometry::{Camera, CameraIntrinsics, CameraPose, FieldModel, FieldPose};
use crate::recording::{Recording, RecordingError};
use crate::refine::line_map::field_primitives;
use crate::refine::{
    ImagePercepts, LineRefiner, PerceptError, PoseCheck, PostSighting, detect, detect_in_image,
};

/// Spacing of the field-line samples drawn under the true pose, metres.
const FIELD_SAMPLE_SPACING: f64 = 0.02;

/// Why a path could not be inspected.
#[derive(Debug, Error)]
pub enum InspectError {
    /// An image file could not be read or decoded.
    #[error("{path}: {reason}")]
    Image {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
    /// A recording could not be read.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// A frame could not be searched.
    #[error("{path}: {source}")]
    Percepts {
        /// The frame.
        path: PathBuf,
        /// Why.
        source: PerceptError,
    },
    /// An overlay could not be written.
    #[error("writing overlay {path}: {reason}")]
    Overlay {
        /// The overlay file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
}

/// How to inspect.
#[derive(Clone, Debug)]
pub struct InspectOptions {
    /// The camera's field of view (its resolution is each frame's own).
    pub intrinsics: CameraIntrinsics,
    /// The camera pose for frames that do not carry one; `None`: image stage only.
    pub camera: Option<CameraPose>,
    /// Use `camera` even where a recording's frame carries its own pose.
    pub override_recorded_camera: bool,
    /// The field whose painted line width gates the points and whose lines are drawn under true poses.
    pub field: FieldModel,
    /// Write an overlay PNG per frame into this directory.
    pub out: Option<PathBuf>,
}

/// A camera pose as printed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CameraReport {
    /// Height above the ground, metres.
    pub height_m: f64,
    /// Pitch, degrees (positive looks down).
    pub pitch_deg: f64,
    /// Roll, degrees.
    pub roll_deg: f64,
}

/// One frame's percepts, one JSON line of `relocd inspect`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Inspection {
    /// The frame's file, as given (for a recording: the directory joined with its record's file).
    pub file: String,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The camera pose the ground stage used; `null`: image stage only.
    pub camera: Option<CameraReport>,
    /// Share of the sampled pixels that are carpet.
    pub carpet_share: f64,
    /// The carpet's top edge, `[u, v]` at each vertical scan line (v = height: no carpet there).
    pub carpet_edge: Vec<[f64; 2]>,
    /// Line crossings found in the image (before the ground-width gate).
    pub crossings: usize,
    /// The line points, `[u, v]` pixel centres of the crossings kept (all crossings without a camera).
    pub line_points: Vec<[f64; 2]>,
    /// The goal posts standing on the carpet, `[u, v, width]`: the centre of each post's foot and its
    /// width there, pixels (with a camera, those that rise as a goal's post would under it).
    pub goal_posts: Vec<[f64; 3]>,
    /// The same points on the ground in the robot frame, `[x, y]` metres (x forward, y left); absent
    /// without a camera.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ground_points: Option<Vec<[f64; 2]>>,
    /// For a recorded frame with a true pose and enough line points: the lines at that pose.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at_truth: Option<TruthInspection>,
}

/// The lines at a frame's true pose (see [`PoseCheck`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TruthInspection {
    /// Whether the true pose as recorded meets the verification's shares.
    pub passes: bool,
    /// Share of the line points on a line there.
    pub inlier_share: f64,
    /// Share of the lines expected there that were not seen; `null` when too few were expected.
    pub unseen_share: Option<f64>,
    /// The line points on no line there, `[u, v]`.
    pub off_lines: Vec<[f64; 2]>,
    /// Where the expected lines no point was found near lie in the image, `[u, v]`.
    pub unseen: Vec<[f64; 2]>,
}

impl TruthInspection {
    fn new(check: &PoseCheck) -> Self {
        let pixels = |list: &[(usize, Point2<f64>)]| {
            list.iter().map(|(_, pixel)| [rounded(pixel.x, 2), rounded(pixel.y, 2)]).collect()
        };
        Self {
            passes: check.passes(),
            inlier_share: rounded(check.inlier_share, 4),
            unseen_share: check.unseen_share.map(|share| rounded(share, 4)),
            off_lines: pixels(&check.off_lines),
            unseen: pixels(&check.unseen),
        }
    }
}

/// Inspects every path (image files or recording directories, in order), handing each frame's
/// result to `emit` as soon as it is ready.
pub fn inspect(
    paths: &[PathBuf],
    options: &InspectOptions,
    mut emit: impl FnMut(Inspection),
) -> Result<(), InspectError> {
    if let Some(out) = &options.out {
        fs::create_dir_all(out)
            .map_err(|error| InspectError::Overlay { path: out.clone(), reason: error.to_string() })?;
    }
    // The field's lines, checked under true poses (its distance map is built once, when first needed).
    let refiner = std::cell::OnceCell::new();
    let refiner = || refiner.get_or_init(|| LineRefiner::new(&options.field));
    // The field's painted lines as points, drawn under true poses.
    let field_lines: Vec<Point2<f64>> = field_primitives(&options.field)
        .iter()
        .flat_map(|primitive| primitive.samples(FIELD_SAMPLE_SPACING))
        .collect();
    for path in paths {
        if Recording::is_at(path) {
            let recording = Recording::open(path)?;
            for record in recording.records() {
                let frame = recording.load_frame(record)?;
                let camera = match (options.override_recorded_camera, record.camera) {
                    (false, Some(recorded)) => Some(recorded),
                    _ => options.camera,
                };
                let truth = record.pose.zip(camera);
                let file = path.join(&record.file);
                let truth = truth.map(|(pose, camera)| (pose, camera, refiner()));
                emit(inspect_frame(&file, &frame, camera, truth, &field_lines, options)?);
            }
        } else {
            let image = image::open(path)
                .map_err(|error| InspectError::Image { path: path.clone(), reason: error.to_string() })?;
            let frame = Frame::Rgb(image.into_rgb8());
            emit(inspect_frame(path, &frame, options.camera, None, &field_lines, options)?);
        }
    }
    Ok(())
}

/// One frame: its percepts (checked at the true pose, with its camera pose and the refiner, where it
/// has one), and its overlay where asked for.
fn inspect_frame(
    file: &Path,
    frame: &Frame,
    camera: Option<CameraPose>,
    truth: Option<(FieldPose, CameraPose, &LineRefiner)>,
    field_lines: &[Point2<f64>],
    options: &InspectOptions,
) -> Result<Inspection, InspectError> {
    let failed = |source| InspectError::Percepts { path: file.to_path_buf(), source };
    let (width, height) = frame.dimensions();
    let (image, points, posts, ground, at_truth) = match camera {
        Some(pose) => {
            let percepts =
                detect(frame, &options.intrinsics, &pose, options.field.dimensions()).map_err(failed)?;
            let pixels: Vec<Point2<f64>> = percepts.points.iter().map(|point| point.pixel).collect();
            let ground: Vec<[f64; 2]> =
                percepts.points.iter().map(|point| [point.ground.x, point.ground.y]).collect();
            let at_truth =
                truth.and_then(|(pose, _, refiner)| refiner.check_at(std::slice::from_ref(&percepts), &pose));
            let posts = percepts.posts.iter().map(|post| post.sighting).collect();
            (percepts.image().clone(), pixels, posts, Some(ground), at_truth)
        }
        None => {
            let image = detect_in_image(frame).map_err(failed)?;
            let pixels = image.crossings.iter().map(|crossing| crossing.centre()).collect();
            let posts = image.goal_posts(frame);
            (image, pixels, posts, None, None)
        }
    };
    if let Some(out) = &options.out {
        let name =
            file.file_name().map_or_else(|| "frame".into(), |name| name.to_string_lossy().into_owned());
        let path = out.join(format!("{name}.inspect.png"));
        let truth = truth.map(|(pose, camera, _)| (pose, camera));
        let mut overlay =
            draw_overlay(frame, &image, &points, truth, at_truth.as_ref(), field_lines, options);
        draw_posts(&mut overlay, &posts);
        overlay.save(&path).map_err(|error| InspectError::Overlay { path, reason: error.to_string() })?;
    }
    let round = |value: f64| rounded(value, 2);
    Ok(Inspection {
        file: file.display().to_string(),
        width,
        height,
        camera: camera.map(|pose| CameraReport {
            height_m: pose.height(),
            pitch_deg: round(pose.pitch().to_degrees()),
            roll_deg: round(pose.roll().to_degrees()),
        }),
        carpet_share: round(image.carpet_share),
        carpet_edge: image.carpet_edge().map(|(u, v)| [round(u), round(v)]).collect(),
        crossings: image.crossings.len(),
        line_points: points.iter().map(|point| [round(point.x), round(point.y)]).collect(),
        goal_posts: posts
            .iter()
            .map(|post| [round(post.foot.x), round(post.foot.y), round(post.width)])
            .collect(),
        ground_points: ground
            .map(|ground| ground.iter().map(|[x, y]| [rounded(*x, 3), rounded(*y, 3)]).collect()),
        at_truth: at_truth.as_ref().map(TruthInspection::new),
    })
}

/// Frames each goal post in green from its top to its foot, with a tick at the foot.
fn draw_posts(canvas: &mut RgbImage, posts: &[PostSighting]) {
    const GREEN: [u8; 3] = [0, 255, 60];
    for post in posts {
        let half = post.width / 2.0 + 1.0;
        let mut v = post.top;
        while v <= post.foot.y {
            put(canvas, post.foot.x - half, v, GREEN);
            put(canvas, post.foot.x + half, v, GREEN);
            v += 1.0;
        }
        for d in -4..=4 {
            put(canvas, post.foot.x + f64::from(d), post.foot.y, GREEN);
        }
    }
}

/// Paints the pixel at (`x`, `y`) in `colour` where it lies inside `canvas`.
fn put(canvas: &mut RgbImage, x: f64, y: f64, colour: [u8; 3]) {
    let (width, height) = canvas.dimensions();
    if x >= 0.0 && y >= 0.0 && (x as u32) < width && (y as u32) < height {
        canvas.put_pixel(x as u32, y as u32, Rgb(colour));
    }
}

/// `value` rounded to `decimals` decimal places, for printing.
fn rounded(value: f64, decimals: i32) -> f64 {
    let factor = 10f64.powi(decimals);
    (value * factor).round() / factor
}

/// The frame with its percepts drawn on it: the carpet's top edge (yellow), crossings the ground
/// gate dropped (red), line points (magenta crosses), `field_lines` under the true pose (cyan) and,
/// from the check there, the lines expected but unseen (orange squares) and the points on no line
/// (blue squares).
fn draw_overlay(
    frame: &Frame,
    image: &ImagePercepts,
    points: &[Point2<f64>],
    truth: Option<(FieldPose, CameraPose)>,
    at_truth: Option<&PoseCheck>,
    field_lines: &[Point2<f64>],
    options: &InspectOptions,
) -> RgbImage {
    let mut canvas = frame.to_rgb();
    let (width, height) = canvas.dimensions();
    if let Some((pose, camera_pose)) = truth {
        let camera = Camera::new(options.intrinsics.with_resolution(width, height), &pose, &camera_pose);
        for sample in field_lines {
            if let Some(pixel) = camera.project(&Point3::new(sample.x, sample.y, 0.0)) {
                put(&mut canvas, pixel.x, pixel.y, [0, 230, 255]);
            }
        }
    }
    let edge: Vec<(f64, f64)> = image.carpet_edge().collect();
    for pair in edge.windows(2) {
        let ((u0, v0), (u1, v1)) = (pair[0], pair[1]);
        let steps = (u1 - u0).abs().max((v1 - v0).abs()).ceil().max(1.0) as usize;
        for step in 0..=steps {
            let t = step as f64 / steps as f64;
            put(&mut canvas, u0 + t * (u1 - u0), v0 + t * (v1 - v0), [255, 230, 0]);
        }
    }
    for crossing in &image.crossings {
        let centre = crossing.centre();
        if !points.iter().any(|point| (point - centre).norm() < 1e-9) {
            put(&mut canvas, centre.x, centre.y, [255, 0, 0]);
            put(&mut canvas, centre.x + 1.0, centre.y, [255, 0, 0]);
        }
    }
    for point in points {
        for d in -3..=3 {
            let d = f64::from(d);
            put(&mut canvas, point.x + d, point.y, [255, 0, 255]);
            put(&mut canvas, point.x, point.y + d, [255, 0, 255]);
        }
    }
    if let Some(check) = at_truth {
        let marked = [(&check.unseen, [255, 140, 0]), (&check.off_lines, [40, 90, 255])];
        for (pixels, colour) in marked {
            for (_, pixel) in pixels.iter() {
                for d in -4..=4 {
                    let d = f64::from(d);
                    for (dx, dy) in [(d, -4.0), (d, 4.0), (-4.0, d), (4.0, d)] {
                        put(&mut canvas, pixel.x + dx, pixel.y + dy, colour);
                    }
                }
            }
        }
    }
    canvas
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options(camera: Option<CameraPose>, out: Option<PathBuf>) -> InspectOptions {
        InspectOptions {
            intrinsics: CameraIntrinsics::nao_top(),
            camera,
            override_recorded_camera: false,
            field: FieldModel::new(crate::geometry::FieldDimensions::spl_2025()),
            out,
        }
    }

    #[test]
    fn a_missing_or_broken_image_is_named() {
        let directory = tempfile::tempdir().unwrap();
        let broken = directory.path().join("broken.png");
        fs::write(&broken, b"not a png").unwrap();
        for path in [directory.path().join("missing.png"), broken] {
            let error = inspect(std::slice::from_ref(&path), &options(None, None), |_| {}).unwrap_err();
            assert!(error.to_string().contains(&path.display().to_string()), "{error}");
        }
    }

    #[test]
    fn an_image_gives_one_line_and_an_overlay() {
        let directory = tempfile::tempdir().unwrap();
        let path = directory.path().join("carpet.png");
        RgbImage::from_fn(64, 48, |_, y| {
            Rgb(if (30..33).contains(&y) { [230, 230, 230] } else { [60, 130, 50] })
        })
        .save(&path)
        .unwrap();
        let out = directory.path().join("overlays");
        let mut lines = Vec::new();
        let camera = CameraPose::new(0.5, 0.3, 0.0, 0.0).unwrap();
        inspect(std::slice::from_ref(&path), &options(Some(camera), Some(out.clone())), |line| {
            lines.push(line)
        })
        .unwrap();
        assert_eq!(lines.len(), 1);
        assert_eq!((lines[0].width, lines[0].height), (64, 48));
        assert_eq!(lines[0].file, path.display().to_string());
        assert!(lines[0].carpet_edge.iter().all(|[_, v]| *v == 0.0), "{:?}", lines[0].carpet_edge);
        assert!(out.join("carpet.png.inspect.png").is_file());
    }
}
