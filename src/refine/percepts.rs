//! Line percepts: white field-line points found in a camera frame and projected onto the ground.
//!
//! The way SPL teams do it, on sparse scan lines: the carpet's colour is learnt from the frame itself
//! (the dominant greenish chroma cluster, so exposure and colour temperature do not matter), then every
//! vertical and horizontal scan line is walked for green → bright, unsaturated → green transitions.
//! A run is kept when its width on the ground fits a painted line (a robot's leg or a ball, standing
//! above the ground, projects far wider), it lies below the field border (the top of the carpet in its
//! column), and its centre projects onto the ground within range. The image stage alone
//! ([`detect_in_image`]) needs no camera pose: `relocd inspect` shows it for frames whose pose is
//! unknown.

use nalgebra::Point2;
use thiserror::Error;

use crate::frame::{Frame, rgb_to_yuv};
use crate::geometry::{Camera, CameraIntrinsics, CameraPose, FieldPose};

/// Scan lines per image width (and the same spacing vertically).
const SCAN_LINES_PER_WIDTH: u32 = 80;
/// Pixels between the samples used to learn the frame's colours.
const STATISTICS_STEP: usize = 8;
/// Chroma histogram bin width (U and V, 8-bit levels).
const CHROMA_BIN: f32 = 8.0;
/// Least share of the sampled pixels that must be carpet for the frame to have a carpet at all.
const MIN_CARPET_SHARE: f64 = 0.03;
/// Non-line pixels allowed between a line's edge and the green beside it (anti-aliased edges).
const EDGE_GAP: usize = 2;
/// Consecutive green samples that mark the top of the carpet in a column.
const CARPET_RUN: usize = 4;
/// Line points kept per frame at most (evenly thinned beyond).
const MAX_POINTS: usize = 400;

/// Why a frame could not be searched for lines.
#[derive(Debug, Error, PartialEq)]
pub enum PerceptError {
    /// The frame has no pixels.
    #[error("frame of {width}x{height} has no pixels to search for lines")]
    EmptyFrame {
        /// Its width.
        width: u32,
        /// Its height.
        height: u32,
    },
    /// The camera's field of view cannot project pixels.
    #[error("camera field of view {horizontal}° × {vertical}° is not a usable pinhole (0° to 180° each)")]
    BadFieldOfView {
        /// Horizontal, degrees.
        horizontal: f64,
        /// Vertical, degrees.
        vertical: f64,
    },
}

/// One field-line point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinePoint {
    /// Where it lies on the ground in the robot frame (x forward, y left), metres.
    pub ground: Point2<f64>,
    /// Where it was seen in the image, pixels.
    pub pixel: Point2<f64>,
}

/// Where a painted line crosses a scan line in the image: the edges of its bright run, pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineCrossing {
    /// The run's first edge (its top on a vertical scan line, its left on a horizontal one).
    pub start: Point2<f64>,
    /// The run's other edge.
    pub end: Point2<f64>,
}

impl LineCrossing {
    /// The centre of the crossing: the line point in the image.
    pub fn centre(&self) -> Point2<f64> {
        Point2::from((self.start.coords + self.end.coords) / 2.0)
    }
}

/// What a frame shows before any camera pose is known: its carpet and the line crossings on it.
#[derive(Clone, Debug)]
pub struct ImagePercepts {
    width: u32,
    height: u32,
    scan_spacing: usize,
    /// Share of the sampled pixels that are carpet, in [0, 1].
    pub carpet_share: f64,
    /// Top of the carpet (continuous row) at each vertical scan line; the image height where a column
    /// shows no carpet.
    carpet_top: Vec<f64>,
    /// Whether each grid sample (vertical scan line × every `scan_spacing`-th row, column-major) shows
    /// something that is neither carpet nor line: a robot, a ball, the hall, a deep shadow.
    hidden: Vec<bool>,
    /// The bright runs with carpet on both sides found below the carpet's top, vertical scan lines
    /// first; the ground stage keeps those whose width fits a painted line.
    pub crossings: Vec<LineCrossing>,
}

impl ImagePercepts {
    /// The frame's size, (width, height) in pixels.
    pub fn dimensions(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Pixels between neighbouring scan lines.
    pub fn scan_spacing(&self) -> usize {
        self.scan_spacing
    }

    /// The carpet's top edge: (column centre, top row) at each vertical scan line, the image height
    /// where the column shows no carpet.
    pub fn carpet_edge(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        let spacing = self.scan_spacing as f64;
        let centre = move |index: usize| (self.scan_spacing / 2) as f64 + index as f64 * spacing + 0.5;
        self.carpet_top.iter().enumerate().map(move |(index, &top)| (centre(index), top))
    }
}

/// The line points of one frame, with what is needed to tell where lines should have been seen.
#[derive(Clone, Debug)]
pub struct FramePercepts {
    /// The line points found.
    pub points: Vec<LinePoint>,
    /// Share of the sampled pixels that are carpet, in [0, 1].
    pub carpet_share: f64,
    camera: Camera,
    camera_height: f64,
    image: ImagePercepts,
}

impl FramePercepts {
    /// The camera of a robot standing at the robot-frame origin: projects robot-frame ground points.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Height of the camera above the ground, metres.
    pub fn camera_height(&self) -> f64 {
        self.camera_height
    }

    /// Pixels between neighbouring scan lines.
    pub fn scan_spacing(&self) -> usize {
        self.image.scan_spacing
    }

    /// The image-space percepts the points were taken from.
    pub fn image(&self) -> &ImagePercepts {
        &self.image
    }

    /// Whether a line at `pixel` would have been searched for: inside the image, away from its edges,
    /// on the carpet (below the field border of its column) and not hidden by anything standing on it.
    pub fn searched(&self, pixel: &Point2<f64>) -> bool {
        let intrinsics = self.camera.intrinsics();
        let image = &self.image;
        let margin = image.scan_spacing as f64;
        if !(pixel.x >= margin
            && pixel.x < intrinsics.width as f64 - margin
            && pixel.y >= margin
            && pixel.y < intrinsics.height as f64 - margin)
        {
            return false;
        }
        let column = (pixel.x / image.scan_spacing as f64 - 0.5).max(0.0);
        let left = (column.floor() as usize).min(image.carpet_top.len() - 1);
        let right = (left + 1).min(image.carpet_top.len() - 1);
        pixel.y > image.carpet_top[left].max(image.carpet_top[right]) + margin && !image.hidden_at(pixel)
    }
}

impl ImagePercepts {
    /// Whether the grid sample nearest to `pixel` shows neither carpet nor line.
    fn hidden_at(&self, pixel: &Point2<f64>) -> bool {
        let rows = self.hidden.len() / self.carpet_top.len();
        let nearest = |value: f64, count: usize| {
            ((value / self.scan_spacing as f64 - 0.5).round().max(0.0) as usize).min(count.saturating_sub(1))
        };
        let (column, row) = (nearest(pixel.x, self.carpet_top.len()), nearest(pixel.y, rows));
        self.hidden.get(column * rows + row).copied().unwrap_or(true)
    }
}

/// How a sample looks against the frame's carpet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Class {
    Green,
    Bright,
    Other,
}

/// The frame's own colour statistics: its carpet cluster and what counts as line white.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Palette {
    green_u: f32,
    green_v: f32,
    green_radius: f32,
    green_luma: f32,
    white_luma: f32,
    /// Largest chroma magnitude per luma a white pixel may have.
    white_saturation: f32,
}

impl Palette {
    fn classify(&self, (y, u, v): (f32, f32, f32)) -> Class {
        if y >= self.white_luma {
            let saturation = (u - 128.0).hypot(v - 128.0) / y.max(1.0);
            if saturation <= self.white_saturation {
                return Class::Bright;
            }
        }
        let chroma = (u - self.green_u).hypot(v - self.green_v);
        if chroma <= self.green_radius && y >= 0.3 * self.green_luma && y < self.white_luma {
            Class::Green
        } else {
            Class::Other
        }
    }
}

/// Pixel access in YUV for either frame format.
struct Pixels<'a> {
    frame: &'a Frame,
    width: usize,
}

impl Pixels<'_> {
    fn yuv(&self, x: usize, y: usize) -> (f32, f32, f32) {
        match self.frame {
            Frame::Rgb(image) => {
                let offset = (y * self.width + x) * 3;
                let raw = &image.as_raw()[offset..offset + 3];
                rgb_to_yuv(raw[0], raw[1], raw[2])
            }
            Frame::Yuyv(image) => {
                let pair = (y * self.width + (x & !1)) * 2;
                let bytes = &image.as_bytes()[pair..pair + 4];
                let luma = if x & 1 == 0 { bytes[0] } else { bytes[2] };
                (f32::from(luma), f32::from(bytes[1]), f32::from(bytes[3]))
            }
        }
    }
}

/// Finds the field-line points of `frame`, taken by a camera with `intrinsics` (any resolution: the
/// field of view is what counts) at `camera_pose` on the robot: the image stage
/// ([`detect_in_image`]), then the crossings whose width on the ground fits a painted line.
pub fn detect(
    frame: &Frame,
    intrinsics: &CameraIntrinsics,
    camera_pose: &CameraPose,
    line_width: f64,
) -> Result<FramePercepts, PerceptError> {
    let (width, height) = frame.dimensions();
    let fov_ok = |angle: f64| angle.is_finite() && angle > 0.0 && angle < std::f64::consts::PI;
    if width > 0 && height > 0 && (!fov_ok(intrinsics.horizontal_fov) || !fov_ok(intrinsics.vertical_fov)) {
        return Err(PerceptError::BadFieldOfView {
            horizontal: intrinsics.horizontal_fov.to_degrees(),
            vertical: intrinsics.vertical_fov.to_degrees(),
        });
    }
    let image = detect_in_image(frame)?;
    let origin = FieldPose::new(0.0, 0.0, 0.0).expect("the origin is finite");
    let camera = Camera::new(intrinsics.with_resolution(width, height), &origin, camera_pose);
    let mut points: Vec<LinePoint> =
        image.crossings.iter().filter_map(|crossing| line_point(&camera, crossing, line_width)).collect();
    if points.len() > MAX_POINTS {
        let stride = points.len() as f64 / MAX_POINTS as f64;
        points = (0..MAX_POINTS).map(|i| points[(i as f64 * stride) as usize]).collect();
    }
    Ok(FramePercepts {
        points,
        carpet_share: image.carpet_share,
        camera,
        camera_height: camera_pose.height(),
        image,
    })
}

/// Finds the carpet and the line crossings of `frame` in image space, with no camera pose: the
/// bright runs with carpet on both sides below the carpet's top, before the ground-width gate.
pub fn detect_in_image(frame: &Frame) -> Result<ImagePercepts, PerceptError> {
    let (width, height) = frame.dimensions();
    if width == 0 || height == 0 {
        return Err(PerceptError::EmptyFrame { width, height });
    }
    let pixels = Pixels { frame, width: width as usize };
    let scan_spacing = (width / SCAN_LINES_PER_WIDTH).max(1) as usize;
    let mut image = ImagePercepts {
        width,
        height,
        scan_spacing,
        carpet_share: 0.0,
        carpet_top: vec![height as f64],
        hidden: Vec::new(),
        crossings: Vec::new(),
    };
    let Some((palette, carpet_share)) = learn_palette(&pixels, width as usize, height as usize) else {
        return Ok(image);
    };
    image.carpet_share = carpet_share;
    let (width, height) = (width as usize, height as usize);
    let columns: Vec<usize> = (scan_spacing / 2..width).step_by(scan_spacing).collect();
    let rows: Vec<usize> = (scan_spacing / 2..height).step_by(scan_spacing).collect();
    image.carpet_top = Vec::with_capacity(columns.len());
    image.hidden = Vec::with_capacity(columns.len() * rows.len());
    let mut classes = Vec::with_capacity(width.max(height));
    for &column in &columns {
        classes.clear();
        classes.extend((0..height).map(|row| palette.classify(pixels.yuv(column, row))));
        let top = carpet_start(&classes).map_or(height as f64, |row| row as f64);
        image.carpet_top.push(top);
        image.hidden.extend(rows.iter().map(|&row| classes[row] == Class::Other));
        let u = column as f64 + 0.5;
        for (start, end) in line_runs(&classes) {
            let crossing =
                LineCrossing { start: Point2::new(u, start as f64), end: Point2::new(u, end as f64) };
            if crossing.centre().y > top {
                image.crossings.push(crossing);
            }
        }
    }
    for &row in &rows {
        classes.clear();
        classes.extend((0..width).map(|column| palette.classify(pixels.yuv(column, row))));
        let v = row as f64 + 0.5;
        for (start, end) in line_runs(&classes) {
            let middle = (start + end) as f64 / 2.0;
            let index = ((middle / scan_spacing as f64) as usize).min(image.carpet_top.len() - 1);
            let next = (index + 1).min(image.carpet_top.len() - 1);
            let top = image.carpet_top[index].max(image.carpet_top[next]);
            let crossing =
                LineCrossing { start: Point2::new(start as f64, v), end: Point2::new(end as f64, v) };
            if crossing.centre().y > top {
                image.crossings.push(crossing);
            }
        }
    }
    Ok(image)
}

/// Learns the carpet's chroma cluster and the line white from a sparse grid of the frame's pixels;
/// `None` when no greenish cluster covers enough of the frame. Also returns the carpet's share.
fn learn_palette(pixels: &Pixels, width: usize, height: usize) -> Option<(Palette, f64)> {
    const BINS: usize = (256.0 / CHROMA_BIN) as usize;
    let samples: Vec<(f32, f32, f32)> = (STATISTICS_STEP / 2..height)
        .step_by(STATISTICS_STEP)
        .flat_map(|y| (STATISTICS_STEP / 2..width).step_by(STATISTICS_STEP).map(move |x| (x, y)))
        .map(|(x, y)| pixels.yuv(x, y))
        .collect();
    if samples.is_empty() {
        return None;
    }
    let bin = |value: f32| ((value / CHROMA_BIN) as usize).min(BINS - 1);
    let mut histogram = vec![0usize; BINS * BINS];
    for &(y, u, v) in &samples {
        if y >= 16.0 {
            histogram[bin(u) * BINS + bin(v)] += 1;
        }
    }
    let greenish = |u: f32, v: f32| {
        let [r, g, b] = crate::frame::yuv_to_rgb_f32(128.0, u, v);
        g >= 0.9 * r.max(b)
    };
    let (peak, _) = histogram
        .iter()
        .enumerate()
        .filter(|(index, _)| {
            let centre = |i: usize| (i as f32 + 0.5) * CHROMA_BIN;
            greenish(centre(index / BINS), centre(index % BINS))
        })
        .max_by_key(|(_, count)| **count)?;
    let (peak_u, peak_v) = ((peak / BINS) as f32 + 0.5, (peak % BINS) as f32 + 0.5);
    let (peak_u, peak_v) = (peak_u * CHROMA_BIN, peak_v * CHROMA_BIN);
    let near: Vec<&(f32, f32, f32)> = samples
        .iter()
        .filter(|(y, u, v)| *y >= 16.0 && (u - peak_u).hypot(v - peak_v) <= 1.5 * CHROMA_BIN)
        .collect();
    if (near.len() as f64) < MIN_CARPET_SHARE * samples.len() as f64 {
        return None;
    }
    let count = near.len() as f32;
    let green_u = near.iter().map(|s| s.1).sum::<f32>() / count;
    let green_v = near.iter().map(|s| s.2).sum::<f32>() / count;
    let spread =
        (near.iter().map(|s| (s.1 - green_u).powi(2) + (s.2 - green_v).powi(2)).sum::<f32>() / count).sqrt();
    let mut lumas: Vec<f32> = near.iter().map(|s| s.0).collect();
    lumas.sort_by(f32::total_cmp);
    let green_luma = lumas[lumas.len() / 2];
    let upper_luma = lumas[lumas.len() * 9 / 10];
    let green_saturation = (green_u - 128.0).hypot(green_v - 128.0) / green_luma.max(1.0);
    let palette = Palette {
        green_u,
        green_v,
        green_radius: (3.0 * spread).clamp(8.0, 24.0),
        green_luma,
        white_luma: upper_luma.max(green_luma + 0.3 * green_luma.max(60.0)).min(250.0),
        white_saturation: (0.6 * green_saturation).max(0.08),
    };
    let carpet = samples.iter().filter(|s| palette.classify(**s) == Class::Green).count();
    Some((palette, carpet as f64 / samples.len() as f64))
}

/// The first index from which `CARPET_RUN` samples in a row are green: the field border's row.
fn carpet_start(classes: &[Class]) -> Option<usize> {
    let mut run = 0;
    for (index, class) in classes.iter().enumerate() {
        run = if *class == Class::Green { run + 1 } else { 0 };
        if run == CARPET_RUN {
            return Some(index + 1 - CARPET_RUN);
        }
    }
    None
}

/// Runs of bright samples with green on both sides (within `EDGE_GAP`), as [start, end) indices.
fn line_runs(classes: &[Class]) -> Vec<(usize, usize)> {
    let mut runs = Vec::new();
    let mut last_green: Option<usize> = None;
    let mut index = 0;
    while index < classes.len() {
        match classes[index] {
            Class::Green => {
                last_green = Some(index);
                index += 1;
            }
            Class::Other => index += 1,
            Class::Bright => {
                let start = index;
                while index < classes.len() && classes[index] == Class::Bright {
                    index += 1;
                }
                let green_before = last_green.is_some_and(|green| green + EDGE_GAP + 1 >= start);
                let green_after =
                    classes[index..classes.len().min(index + EDGE_GAP + 1)].contains(&Class::Green);
                if green_before && green_after {
                    runs.push((start, index));
                }
            }
        }
    }
    runs
}

/// The line point of a crossing, if its width on the ground fits a painted line of `line_width`.
fn line_point(camera: &Camera, crossing: &LineCrossing, line_width: f64) -> Option<LinePoint> {
    let (start, end, centre) = (crossing.start, crossing.end, crossing.centre());
    let (from, to, ground) = (
        camera.ground_point(start.x, start.y)?,
        camera.ground_point(end.x, end.y)?,
        camera.ground_point(centre.x, centre.y)?,
    );
    let ground_width = (to - from).norm();
    let fits = ground_width >= 0.4 * line_width && ground_width <= 3.0 * line_width;
    fits.then_some(LinePoint { ground, pixel: centre })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_need_green_on_both_sides() {
        use Class::{Bright as B, Green as G, Other as O};
        assert_eq!(line_runs(&[G, G, B, B, G]), vec![(2, 4)]);
        assert_eq!(line_runs(&[G, O, B, B, O, G]), vec![(2, 4)]);
        assert_eq!(line_runs(&[O, O, O, B, B, G]), vec![]);
        assert_eq!(line_runs(&[G, B, B, O, O, O, G]), vec![]);
        assert_eq!(line_runs(&[G, B, G, B, G]), vec![(1, 2), (3, 4)]);
    }

    #[test]
    fn what_stands_on_the_carpet_hides_the_lines_behind_it() {
        use image::{Rgb, RgbImage};
        // Carpet to the top of the image, a grey robot standing in its lower middle.
        let frame = Frame::Rgb(RgbImage::from_fn(640, 480, |x, y| {
            let robot = (280..360).contains(&x) && (300..420).contains(&y);
            Rgb(if robot { [128, 128, 128] } else { [60, 130, 50] })
        }));
        let camera = CameraPose::new(0.5, 0.3, 0.0, 0.0).unwrap();
        let percepts = detect(&frame, &CameraIntrinsics::nao_top(), &camera, 0.05).unwrap();
        assert!(percepts.points.is_empty());
        assert!(percepts.searched(&Point2::new(100.0, 360.0)), "open carpet");
        assert!(!percepts.searched(&Point2::new(320.0, 360.0)), "behind the robot");
        assert!(!percepts.searched(&Point2::new(320.0, 2.0)), "at the image edge");
    }

    #[test]
    fn carpet_starts_at_the_first_green_run() {
        use Class::{Bright as B, Green as G, Other as O};
        assert_eq!(carpet_start(&[O, G, O, G, G, G, G, B]), Some(3));
        assert_eq!(carpet_start(&[O, G, G, G, O]), None);
    }
}
