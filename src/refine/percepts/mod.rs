//! Line percepts: white field-line points found in a camera frame and projected onto the ground.
//!
//! The way SPL teams do it, on sparse scan lines (each the mean of three neighbouring pixel lines, so
//! carpet texture and chroma noise average out), in two stages:
//! - In the image, with no camera pose ([`detect_in_image`]): the carpet is told by the hue and
//!   saturation learnt from the frame itself, weighted towards its bottom ([`palette`]); the field's
//!   border in each column is where walking up from the bottom stops paying off (a greenish wall or a
//!   crowd above the field is not carpet); a line crossing is a short run brighter than the carpet
//!   right beside it, by a share of that carpet's brightness (less where the sensor clips near white)
//!   and by more than its texture, and grey, with carpet beside it for its width where another bright
//!   run follows ([`scan`]), so sun patches, shadows, backlight, overexposure and blurred lines with the
//!   carpet's tint are judged locally, and sunlit bands between thin shadows are not lines. A crossing
//!   must continue on the neighbouring parallel scan lines (on both sides, or further along one where
//!   a line ends): a painted line does, a ball's patch, a foot or a speck does not; it may be no wider
//!   than its distance below the border allows; and it must line up with the crossings of the
//!   neighbouring scan lines ([`chains`]): sunlit specks of carpet texture and bright blotches
//!   continue in their pixels but not as a line.
//! - On the ground ([`detect`]): a crossing is kept when its width on the ground fits a painted line
//!   (a robot's leg or a ball, standing above the ground, projects far wider) under the camera pose or
//!   a pose a few degrees of pitch away (what a real robot's joint sensors may be off by), and its
//!   centre projects onto the ground. A goal post found in the image is kept when it rises as a
//!   goal's post would over its foot's distance (a robot's leg does not).

mod chains;
mod palette;
mod posts;
mod scan;

use nalgebra::{Point2, Point3, Vector2};
use thiserror::Error;

use super::calibration::CameraCalibration;
use crate::frame::{Frame, rgb_to_yuv};
use crate::geometry::{Camera, CameraIntrinsics, CameraPose, FieldDimensions, FieldPose};
use palette::{Palette, Yuv};
pub use posts::PostSighting;
use scan::Crossing;

/// Scan lines per image width (and the same spacing vertically).
const SCAN_LINES_PER_WIDTH: u32 = 80;
/// Scan spacings from the image's edge, beyond a line's half width, within which a line is not
/// expected to be found (see [`FramePercepts::searched`]).
const EDGE_SCAN_LINES: f64 = 2.0;
/// Widest line crossing in the image, as a share of its width (a line at the robot's feet).
const MAX_CROSSING_SHARE: f64 = 0.2;
/// Pixels of line width allowed per pixel below the carpet's top edge (see
/// [`perspective_width_limit`]): five times what a 5 cm line seen from 0.5 m, horizon at the border,
/// spans across.
const PERSPECTIVE_WIDTH_SLOPE: f64 = 0.5;
/// Line width allowed on top of the perspective share, pixels: what motion blur and defocus add to a
/// line at any distance (and a thin line right at the border).
const BLUR_WIDTH: f64 = 4.0;
/// Least offset, in pixels, at which a crossing must continue beside its scan line.
const MIN_CONTINUATION_OFFSET: usize = 3;
/// Multiples of its width a crossing must continue along one side where the other side ends.
const ONE_SIDED_REACH: usize = 3;
/// Pitch error of the camera pose the ground-width gate tolerates, radians.
const PITCH_TOLERANCE: f64 = 3.0 * std::f64::consts::PI / 180.0;
/// Pitch and roll step of the central differences that give each point's calibration rates, radians.
const CALIBRATION_STEP: f64 = 0.25 * std::f64::consts::PI / 180.0;
/// A line's width on the ground may lie between these multiples of the painted width.
const GROUND_WIDTH_RANGE: (f64, f64) = (0.4, 3.0);
/// Weight of each carpet pixel in the running carpet brightness along a scan line.
const RUNNING_WEIGHT: f32 = 1.0 / 32.0;
/// Scan spacings within which a crossing that lines up with none of its family is kept beside a kept
/// crossing of the other family (see [`chains::near_any`]).
const JUNCTION_REACH: f64 = 1.5;
/// Share of the goal's height a post must be seen to rise above its foot, unless the top of the image
/// cuts it: a robot's leg, as white and upright as a post, rises less before the robot's body widens
/// it. Half, so that a camera pitched a few degrees off (which misjudges the foot's distance, and so
/// the rise expected) still keeps a goal's post.
const MIN_POST_RISE: f64 = 0.5;
/// Rows under the top of the image within which a post's top is cut by it.
const IMAGE_TOP_ROWS: f64 = 8.0;
/// Line points kept per frame at most (evenly thinned beyond).
pub const MAX_POINTS: usize = 400;

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

/// Where a painted line crosses a scan line in the image: the edges of its bright core, pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineCrossing {
    /// The core's first edge (its top on a vertical scan line, its left on a horizontal one).
    pub start: Point2<f64>,
    /// The core's other edge.
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
    /// something that is neither carpet nor line: a robot, a ball, the hall.
    hidden: Vec<bool>,
    /// The line crossings found on the carpet, vertical scan lines first.
    pub crossings: Vec<LineCrossing>,
    /// The carpet's colours; `None` where the frame has no carpet.
    palette: Option<Palette>,
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

    /// The carpet's top at column `u`: the lower of the two scan lines around it.
    fn carpet_top_at(&self, u: f64) -> f64 {
        let column = (u / self.scan_spacing as f64 - 0.5).max(0.0);
        let left = (column.floor() as usize).min(self.carpet_top.len() - 1);
        let right = (left + 1).min(self.carpet_top.len() - 1);
        self.carpet_top[left].max(self.carpet_top[right])
    }

    /// The lower of the carpet's tops a scan spacing beyond either end of a run from column `from` to
    /// column `to`: a row crossing there is a line only below it, with carpet beyond it on both sides.
    fn carpet_top_beside(&self, from: f64, to: f64) -> f64 {
        let spacing = self.scan_spacing as f64;
        self.carpet_top_at(from - spacing).max(self.carpet_top_at(to + spacing))
    }

    /// The goal posts standing on this carpet in `frame` (the frame these percepts were found in):
    /// upright bright bars from the carpet up past the field's border.
    pub fn goal_posts(&self, frame: &Frame) -> Vec<PostSighting> {
        let (width, height) = frame.dimensions();
        let Some(palette) = self.palette.filter(|_| (width, height) == (self.width, self.height)) else {
            return Vec::new();
        };
        let pixels = Pixels { frame, width: width as usize };
        let size = (width as usize, height as usize);
        posts::find(&pixels, &palette, size, self.scan_spacing, |u| self.carpet_top_at(u))
    }

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

/// One field-line point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinePoint {
    /// Where it lies on the ground in the robot frame (x forward, y left), metres.
    pub ground: Point2<f64>,
    /// Where it was seen in the image, pixels.
    pub pixel: Point2<f64>,
    /// How `ground` moves per radian of camera pitch and per radian of roll (a calibration error).
    pub calibration_rates: [Vector2<f64>; 2],
}

/// A goal post standing on the ground.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PostPoint {
    /// Where its foot lies on the ground in the robot frame (x forward, y left), metres: its bearing
    /// is as good as the foot's column, its distance only as good as the foot's row.
    pub ground: Point2<f64>,
    /// Where it was seen in the image.
    pub sighting: PostSighting,
    /// How `ground` moves per radian of camera pitch and per radian of roll (a calibration error).
    pub calibration_rates: [Vector2<f64>; 2],
}

impl PostPoint {
    /// Its direction from the robot, radians (counter-clockwise from straight ahead).
    pub fn bearing(&self) -> f64 {
        self.ground.y.atan2(self.ground.x)
    }

    /// How its bearing moves per radian of camera pitch and per radian of roll: its foot's
    /// [`PostPoint::calibration_rates`] across the line of sight, over the distance.
    pub fn bearing_rates(&self) -> Vector2<f64> {
        let squared = self.ground.coords.norm_squared();
        let [pitch, roll] = self.calibration_rates.map(|rate| self.ground.coords.perp(&rate) / squared);
        Vector2::new(pitch, roll)
    }
}

/// The line points of one frame, with what is needed to tell where lines should have been seen.
#[derive(Clone, Debug)]
pub struct FramePercepts {
    /// The line points found.
    pub points: Vec<LinePoint>,
    /// The goal posts found.
    pub posts: Vec<PostPoint>,
    intrinsics: CameraIntrinsics,
    camera_pose: CameraPose,
    /// How far off the camera pose may be in (pitch, roll), radians.
    camera_sigma: Vector2<f64>,
    image: ImagePercepts,
}

impl FramePercepts {
    /// Height of the camera above the ground, metres.
    pub fn camera_height(&self) -> f64 {
        self.camera_pose.height()
    }

    /// The frame as seen with a camera pose known to `sigma` in (pitch, roll), radians (by default a
    /// degree, [`CameraCalibration::default`]): how far a line fit may correct it.
    pub fn with_camera_sigma(mut self, sigma: Vector2<f64>) -> Self {
        self.camera_sigma = sigma;
        self
    }

    /// How far off the camera pose may be in (pitch, roll), radians.
    pub fn camera_sigma(&self) -> Vector2<f64> {
        self.camera_sigma
    }

    /// The frame's camera (of a robot standing at the robot-frame origin: it projects robot-frame
    /// ground points) with `pitch` and `roll` (radians) added to its pose, as a calibration
    /// correction puts it; `None` where that pose is impossible.
    pub fn corrected_camera(&self, pitch: f64, roll: f64) -> Option<Camera> {
        robot_camera(self.intrinsics, &self.camera_pose, pitch, roll)
    }

    /// Pixels between neighbouring scan lines.
    pub fn scan_spacing(&self) -> usize {
        self.image.scan_spacing
    }

    /// The image-space percepts the points were taken from.
    pub fn image(&self) -> &ImagePercepts {
        &self.image
    }

    /// Whether a line at `pixel`, `line_width` pixels wide there, would have been searched for: on the
    /// carpet (below the field border of its column and of the columns a line's width and a scan
    /// spacing to either side, as a row crossing needs: a line beside a goal post's foot is not
    /// found), not hidden by anything standing on it, and far enough inside the image for the scan
    /// lines to find it. A crossing needs carpet beyond the line on its scan line and two
    /// neighbouring scan lines to line up with, so a line within half its width and
    /// [`EDGE_SCAN_LINES`] scan spacings of the image's edge is often not found.
    pub fn searched(&self, pixel: &Point2<f64>, line_width: f64) -> bool {
        let (width, height) = self.image.dimensions();
        let spacing = self.image.scan_spacing as f64;
        let margin = EDGE_SCAN_LINES * spacing + line_width / 2.0;
        if !(pixel.x >= margin
            && pixel.x < width as f64 - margin
            && pixel.y >= margin
            && pixel.y < height as f64 - margin)
        {
            return false;
        }
        let half_width = line_width / 2.0;
        let carpet_top = self
            .image
            .carpet_top_at(pixel.x)
            .max(self.image.carpet_top_beside(pixel.x - half_width, pixel.x + half_width));
        pixel.y > carpet_top + spacing && !self.image.hidden_at(pixel)
    }
}

/// Pixel access in YUV for either frame format.
struct Pixels<'a> {
    frame: &'a Frame,
    width: usize,
}

impl Pixels<'_> {
    fn yuv(&self, x: usize, y: usize) -> Yuv {
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

    /// The whole scan line of [`Self::smoothed`] pixels at `across` (a column for
    /// [`Axis::Vertical`], a row otherwise), `length` pixels along it and `limit` across, into `line`.
    /// A YUYV frame is read a row at a time rather than pixel by pixel: the same sums, in integers
    /// (exact, as they are in floats).
    fn scan_line(&self, axis: Axis, across: usize, (length, limit): (usize, usize), line: &mut Vec<Yuv>) {
        line.clear();
        let Frame::Yuyv(image) = self.frame else {
            line.extend((0..length).map(|along| self.smoothed(axis, across, along, limit)));
            return;
        };
        let (bytes, stride) = (image.as_bytes(), 2 * self.width);
        let neighbours = [across.saturating_sub(1), across, (across + 1).min(limit - 1)];
        let mean = |a: u8, b: u8, c: u8| f32::from(u16::from(a) + u16::from(b) + u16::from(c)) / 3.0;
        match axis {
            // Three pixels side by side in every row: a pixel's luma is byte 2x, its pair's U and V
            // follow the pair's first luma.
            Axis::Vertical => {
                let [a, b, c] = neighbours;
                let [pa, pb, pc] = neighbours.map(|x| (x & !1) * 2);
                line.extend(bytes.chunks_exact(stride).take(length).map(|row| {
                    (
                        mean(row[2 * a], row[2 * b], row[2 * c]),
                        mean(row[pa + 1], row[pb + 1], row[pc + 1]),
                        mean(row[pa + 3], row[pb + 3], row[pc + 3]),
                    )
                }));
            }
            // Three rows, a pixel pair (four bytes) at a time.
            Axis::Horizontal => {
                let [above, row, below] =
                    neighbours.map(|y| bytes[y * stride..(y + 1) * stride].chunks_exact(4));
                let pairs = above.zip(row).zip(below).flat_map(|((a, b), c)| {
                    let (u, v) = (mean(a[1], b[1], c[1]), mean(a[3], b[3], c[3]));
                    [(mean(a[0], b[0], c[0]), u, v), (mean(a[2], b[2], c[2]), u, v)]
                });
                line.extend(pairs.take(length));
            }
        }
    }

    /// Row `y`'s pixels, into `line`; a YUYV frame a pixel pair (four bytes) at a time.
    fn row(&self, y: usize, line: &mut Vec<Yuv>) {
        line.clear();
        let Frame::Yuyv(image) = self.frame else {
            line.extend((0..self.width).map(|x| self.yuv(x, y)));
            return;
        };
        let stride = 2 * self.width;
        let pairs = image.as_bytes()[y * stride..(y + 1) * stride].chunks_exact(4).flat_map(|pair| {
            let (u, v) = (f32::from(pair[1]), f32::from(pair[3]));
            [(f32::from(pair[0]), u, v), (f32::from(pair[2]), u, v)]
        });
        line.extend(pairs.take(self.width));
    }

    /// The mean of three pixels across a scan line at `along` on the scan line at `across`: carpet
    /// texture and chroma noise average out, a line crossing the scan does not.
    fn smoothed(&self, axis: Axis, across: usize, along: usize, limit: usize) -> Yuv {
        let sample = |offset: usize| match axis {
            Axis::Vertical => self.yuv(offset, along),
            Axis::Horizontal => self.yuv(along, offset),
        };
        let (a, b, c) =
            (sample(across.saturating_sub(1)), sample(across), sample((across + 1).min(limit - 1)));
        ((a.0 + b.0 + c.0) / 3.0, (a.1 + b.1 + c.1) / 3.0, (a.2 + b.2 + c.2) / 3.0)
    }
}

/// The direction of a family of scan lines.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Axis {
    /// Columns, walked top to bottom.
    Vertical,
    /// Rows, walked left to right.
    Horizontal,
}

/// Finds the carpet and the line crossings of `frame` in image space, with no camera pose.
pub fn detect_in_image(frame: &Frame) -> Result<ImagePercepts, PerceptError> {
    let (width, height) = frame.dimensions();
    if width == 0 || height == 0 {
        return Err(PerceptError::EmptyFrame { width, height });
    }
    let scan_spacing = (width / SCAN_LINES_PER_WIDTH).max(1) as usize;
    let pixels = Pixels { frame, width: width as usize };
    let (width_px, height_px) = (width as usize, height as usize);
    let Some((palette, carpet_share)) = Palette::learn(width_px, height_px, |x, y| pixels.yuv(x, y)) else {
        return Ok(ImagePercepts {
            width,
            height,
            scan_spacing,
            carpet_share: 0.0,
            carpet_top: vec![height as f64],
            hidden: Vec::new(),
            crossings: Vec::new(),
            palette: None,
        });
    };
    let max_width = ((MAX_CROSSING_SHARE * width as f64) as usize).max(1);
    let columns: Vec<usize> = (scan_spacing / 2..width_px).step_by(scan_spacing).collect();
    let rows: Vec<usize> = (scan_spacing / 2..height_px).step_by(scan_spacing).collect();
    let mut image = ImagePercepts {
        width,
        height,
        scan_spacing,
        carpet_share,
        carpet_top: Vec::with_capacity(columns.len()),
        hidden: Vec::with_capacity(columns.len() * rows.len()),
        crossings: Vec::new(),
        palette: Some(palette),
    };
    let mut line: Vec<Yuv> = Vec::with_capacity(width_px.max(height_px));
    let mut green: Vec<bool> = Vec::with_capacity(width_px.max(height_px));
    let mut vertical: Vec<(usize, Crossing)> = Vec::new();
    let mut tops = Vec::with_capacity(columns.len());
    for (index, &column) in columns.iter().enumerate() {
        pixels.scan_line(Axis::Vertical, column, (height_px, width_px), &mut line);
        classify(&line, &palette, &mut green);
        tops.push(scan::carpet_top(&line, &green, &palette).unwrap_or(height_px));
        image.hidden.extend(rows.iter().map(|&row| !green[row] && !palette.looks_like_paint(line[row])));
        vertical.extend(scan::crossings(&line, &green, &palette, max_width).into_iter().map(|c| (index, c)));
    }
    // One column's spike (a post, a leg) is not the field's border: the median of three is.
    image.carpet_top = (0..tops.len())
        .map(|i| {
            let mut three = [tops[i.saturating_sub(1)], tops[i], tops[(i + 1).min(tops.len() - 1)]];
            three.sort_unstable();
            three[1] as f64
        })
        .collect();
    let mut found: Vec<(Axis, usize, Crossing)> = vertical
        .into_iter()
        .filter(|&(index, crossing)| crossing.start as f64 > image.carpet_top[index])
        .map(|(index, crossing)| (Axis::Vertical, columns[index], crossing))
        .collect();
    for &row in &rows {
        pixels.scan_line(Axis::Horizontal, row, (width_px, height_px), &mut line);
        classify(&line, &palette, &mut green);
        for crossing in scan::crossings(&line, &green, &palette, max_width) {
            // The carpet on both sides reaches above the crossing (a wide line along a column cuts
            // that column's carpet short, not its neighbours').
            let top = image.carpet_top_beside(crossing.start as f64, crossing.end as f64);
            if row as f64 + 0.5 > top {
                found.push((Axis::Horizontal, row, crossing));
            }
        }
    }
    found.retain(|found| {
        let (column, row) = centre_pixel(found);
        found.2.width() <= perspective_width_limit(row - image.carpet_top_at(column))
    });
    found.retain(|&(axis, position, crossing)| {
        continues(&pixels, &palette, axis, position, crossing, (width_px, height_px))
    });
    let lined_up = lined_up(&found, scan_spacing, (width, height));
    image.crossings = found
        .into_iter()
        .zip(lined_up)
        .filter_map(|(found, lined_up)| lined_up.then_some(found))
        .map(|(axis, position, crossing)| {
            let across = position as f64 + 0.5;
            let (start, end) = (crossing.start as f64, crossing.end as f64);
            match axis {
                Axis::Vertical => {
                    LineCrossing { start: Point2::new(across, start), end: Point2::new(across, end) }
                }
                Axis::Horizontal => {
                    LineCrossing { start: Point2::new(start, across), end: Point2::new(end, across) }
                }
            }
        })
        .collect();
    Ok(image)
}

/// The centre of a crossing `found` on the scan line at `position` across `axis`: (column, row), pixels.
fn centre_pixel(&(axis, position, crossing): &(Axis, usize, Crossing)) -> (f64, f64) {
    let across = position as f64 + 0.5;
    match axis {
        Axis::Vertical => (across, crossing.middle()),
        Axis::Horizontal => (crossing.middle(), across),
    }
}

/// Which of the crossings `found` (vertical scan lines first, then horizontal ones) belong to a
/// straight piece of three within their family, or lie beside a kept crossing of the other family
/// (see [`chains`]).
fn lined_up(found: &[(Axis, usize, Crossing)], scan_spacing: usize, dimensions: (u32, u32)) -> Vec<bool> {
    let placed = |&(_, position, crossing): &(Axis, usize, Crossing)| chains::Placed {
        scan_line: position / scan_spacing,
        centre: crossing.middle(),
        width: crossing.width(),
    };
    let vertical = found.iter().take_while(|&&(axis, ..)| axis == Axis::Vertical).count();
    let (columns, rows) = found.split_at(vertical);
    let family = |crossings: &[(Axis, usize, Crossing)]| {
        chains::in_straight_pieces(&crossings.iter().map(placed).collect::<Vec<_>>(), scan_spacing as f64)
    };
    let mut in_pieces = family(columns);
    in_pieces.extend(family(rows));
    let centres: Vec<(f64, f64)> = found.iter().map(centre_pixel).collect();
    let reach = JUNCTION_REACH * scan_spacing as f64;
    let mut kept = in_pieces.clone();
    for (own, other) in [(0..vertical, vertical..found.len()), (vertical..found.len(), 0..vertical)] {
        let unkept: Vec<usize> = own.filter(|&i| !in_pieces[i]).collect();
        let beside: Vec<(f64, f64)> = other.filter(|&i| in_pieces[i]).map(|i| centres[i]).collect();
        let unkept_centres: Vec<(f64, f64)> = unkept.iter().map(|&i| centres[i]).collect();
        for (index, near) in
            unkept.into_iter().zip(chains::near_any(&unkept_centres, &beside, reach, dimensions))
        {
            kept[index] |= near;
        }
    }
    kept
}

/// The widest a line crossing may be `below` pixels under the carpet's top edge: a line's width in the
/// image grows with its distance below the horizon, which lies at or above the field's border, so
/// a wide bright band just below the border (a sun patch, a board's reflection) is not paint; blur
/// widens every line by about the same few pixels.
fn perspective_width_limit(below: f64) -> f64 {
    PERSPECTIVE_WIDTH_SLOPE * below.max(0.0) + BLUR_WIDTH
}

/// The running mean luma of the carpet pixels (`green`) of `line` met before each pixel, walking it in
/// `order`; NaN before the first.
fn running_carpet_luma(line: &[Yuv], green: &[bool], order: impl Iterator<Item = usize>) -> Vec<f32> {
    let mut means = vec![f32::NAN; line.len()];
    let mut mean = f32::NAN;
    for index in order {
        means[index] = mean;
        if green[index] {
            let luma = line[index].0;
            mean = if mean.is_nan() { luma } else { mean + RUNNING_WEIGHT * (luma - mean) };
        }
    }
    means
}

/// Which pixels of a scan line are carpet, into `green`. A pixel of the carpet's hue that is clearly
/// brighter and greyer than the carpet on both sides of it (a running mean from each end) is a blurred
/// line with the carpet's tint, not carpet; a lone carpet pixel between two others is chroma noise
/// inside a line.
fn classify(line: &[Yuv], palette: &Palette, green: &mut Vec<bool>) {
    green.clear();
    green.extend(line.iter().map(|&pixel| palette.is_green(pixel)));
    let from_start = running_carpet_luma(line, green, 0..line.len());
    let from_end = running_carpet_luma(line, green, (0..line.len()).rev());
    for index in 0..line.len() {
        let carpet = from_start[index].max(from_end[index]);
        if green[index]
            && carpet.is_finite()
            && scan::is_bright(line[index], scan::threshold(carpet), palette)
        {
            green[index] = false;
        }
    }
    for index in 1..green.len().saturating_sub(1) {
        if green[index] && !green[index - 1] && !green[index + 1] {
            green[index] = false;
        }
    }
}

/// Whether a crossing at `position` across `axis` has bright pixels on the parallel scan lines its own
/// width (at least `MIN_CONTINUATION_OFFSET`) away on both sides, or further along one side,
/// within a window that a straight or curved line at a slant reaches: a painted line continues, a
/// blob ends.
fn continues(
    pixels: &Pixels,
    palette: &Palette,
    axis: Axis,
    position: usize,
    crossing: Crossing,
    (width, height): (usize, usize),
) -> bool {
    let offset = (crossing.end - crossing.start).max(MIN_CONTINUATION_OFFSET);
    let (across_limit, along_limit) = match axis {
        Axis::Vertical => (width, height),
        Axis::Horizontal => (height, width),
    };
    let window = crossing.start.saturating_sub(2 * offset)..(crossing.end + 2 * offset).min(along_limit);
    let bright_on = |across: usize| {
        window.clone().any(|along| {
            scan::is_bright(pixels.smoothed(axis, across, along, across_limit), crossing.threshold, palette)
        })
    };
    // Both sides at once its width; or, where a line ends (a corner, a T, the image's edge), one side
    // at every multiple of its width up to `ONE_SIDED_REACH` (further than a ball's patch reaches).
    let side = |distance: usize, towards_start: bool| {
        let across = if towards_start { position.checked_sub(distance) } else { Some(position + distance) };
        across.filter(|&across| across < across_limit).is_some_and(bright_on)
    };
    let reaches =
        |towards_start: bool| (2..=ONE_SIDED_REACH).all(|times| side(times * offset, towards_start));
    let (before, after) = (side(offset, true), side(offset, false));
    (before && (after || reaches(true))) || (after && reaches(false))
}

/// Finds the field-line points and goal posts of `frame`, taken by a camera with `intrinsics` (any
/// resolution: the field of view is what counts) at `camera_pose` on the robot, on a field of
/// `dimensions` (its line width and goal height).
pub fn detect(
    frame: &Frame,
    intrinsics: &CameraIntrinsics,
    camera_pose: &CameraPose,
    dimensions: &FieldDimensions,
) -> Result<FramePercepts, PerceptError> {
    let line_width = dimensions.line_width;
    let (width, height) = frame.dimensions();
    let fov_ok = |angle: f64| angle.is_finite() && angle > 0.0 && angle < std::f64::consts::PI;
    if width > 0 && height > 0 && (!fov_ok(intrinsics.horizontal_fov) || !fov_ok(intrinsics.vertical_fov)) {
        return Err(PerceptError::BadFieldOfView {
            horizontal: intrinsics.horizontal_fov.to_degrees(),
            vertical: intrinsics.vertical_fov.to_degrees(),
        });
    }
    let image = detect_in_image(frame)?;
    let intrinsics = intrinsics.with_resolution(width, height);
    let turned = |pitch: f64, roll: f64| robot_camera(intrinsics, camera_pose, pitch, roll);
    let camera = turned(0.0, 0.0).expect("the frame's own camera pose is valid");
    // The same camera a little more and a little less pitched, for the width gate.
    let tilted: Vec<Camera> =
        [-PITCH_TOLERANCE, PITCH_TOLERANCE].iter().filter_map(|&delta| turned(delta, 0.0)).collect();
    // The camera turned a little each way in pitch and in roll, for each point's calibration rates.
    let step = CALIBRATION_STEP;
    let turns = [(turned(step, 0.0), turned(-step, 0.0)), (turned(0.0, step), turned(0.0, -step))];
    // How the ground point under `pixel` moves per radian of pitch and of roll; a pixel a turned camera
    // cannot place (near the horizon) gets no rate: no correction moves it.
    let calibration_rates = |pixel: &Point2<f64>| {
        turns.each_ref().map(|(more, less)| {
            let moved = |camera: &Option<Camera>| camera.as_ref()?.ground_point(pixel.x, pixel.y);
            match (moved(more), moved(less)) {
                (Some(more), Some(less)) => (more - less) / (2.0 * step),
                _ => Vector2::zeros(),
            }
        })
    };
    let mut points: Vec<LinePoint> = image
        .crossings
        .iter()
        .filter_map(|crossing| {
            let centre = crossing.centre();
            let ground = camera.ground_point(centre.x, centre.y)?;
            let fits = std::iter::once(&camera)
                .chain(&tilted)
                .any(|camera| ground_width_fits(camera, crossing, line_width));
            fits.then(|| LinePoint { ground, pixel: centre, calibration_rates: calibration_rates(&centre) })
        })
        .collect();
    if points.len() > MAX_POINTS {
        let stride = points.len() as f64 / MAX_POINTS as f64;
        points = (0..MAX_POINTS).map(|i| points[(i as f64 * stride) as usize]).collect();
    }
    let posts = image
        .goal_posts(frame)
        .into_iter()
        .filter_map(|sighting| {
            let ground = camera.ground_point(sighting.foot.x, sighting.foot.y)?;
            rises_as_a_post(&camera, &ground, &sighting, dimensions.goal_height).then(|| PostPoint {
                ground,
                sighting,
                calibration_rates: calibration_rates(&sighting.foot),
            })
        })
        .collect();
    let camera_sigma = CameraCalibration::default().sigma;
    Ok(FramePercepts { points, posts, intrinsics, camera_pose: *camera_pose, camera_sigma, image })
}

/// The camera of a robot standing at the robot-frame origin, at `pose` turned by `pitch` and `roll`
/// radians; `None` where that pose is impossible.
fn robot_camera(intrinsics: CameraIntrinsics, pose: &CameraPose, pitch: f64, roll: f64) -> Option<Camera> {
    let origin = FieldPose::new(0.0, 0.0, 0.0).expect("the origin is finite");
    Some(Camera::new(intrinsics, &origin, &pose.corrected(pitch, roll).ok()?))
}

/// Whether a post seen at `sighting`, its foot at `ground`, rises in the image as a goal `goal_height`
/// tall would (at least [`MIN_POST_RISE`] of it) or up to the top of the image.
fn rises_as_a_post(camera: &Camera, ground: &Point2<f64>, sighting: &PostSighting, goal_height: f64) -> bool {
    let risen = camera.project(&Point3::new(ground.x, ground.y, MIN_POST_RISE * goal_height));
    sighting.top <= risen.map_or(IMAGE_TOP_ROWS, |pixel| pixel.y.max(IMAGE_TOP_ROWS))
}

/// Whether a crossing's width on the ground under `camera` fits a painted line of `line_width`.
fn ground_width_fits(camera: &Camera, crossing: &LineCrossing, line_width: f64) -> bool {
    let (Some(from), Some(to)) = (
        camera.ground_point(crossing.start.x, crossing.start.y),
        camera.ground_point(crossing.end.x, crossing.end.y),
    ) else {
        return false;
    };
    let ground_width = (to - from).norm();
    (GROUND_WIDTH_RANGE.0 * line_width..=GROUND_WIDTH_RANGE.1 * line_width).contains(&ground_width)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;
    use image::{Rgb, RgbImage};

    #[test]
    fn a_yuyv_scan_line_or_row_is_its_pixels_read_one_by_one() {
        let (width, height) = (10usize, 6usize);
        let data: Vec<u8> = (0..width * height * 2).map(|i| (i * 37 % 251) as u8).collect();
        let frame = Frame::Yuyv(crate::frame::YuyvImage::new(width as u32, height as u32, data).unwrap());
        let pixels = Pixels { frame: &frame, width };
        let mut line = Vec::new();
        for (axis, length, limit) in [(Axis::Vertical, height, width), (Axis::Horizontal, width, height)] {
            for across in 0..limit {
                pixels.scan_line(axis, across, (length, limit), &mut line);
                let one_by_one: Vec<Yuv> =
                    (0..length).map(|along| pixels.smoothed(axis, across, along, limit)).collect();
                assert_eq!(line, one_by_one, "{axis:?} {across}");
            }
        }
        for y in 0..height {
            pixels.row(y, &mut line);
            let one_by_one: Vec<Yuv> = (0..width).map(|x| pixels.yuv(x, y)).collect();
            assert_eq!(line, one_by_one, "row {y}");
        }
    }

    #[test]
    fn what_stands_on_the_carpet_hides_the_lines_behind_it() {
        // Carpet to the top of the image, a grey robot standing in its lower middle.
        let frame = Frame::Rgb(RgbImage::from_fn(640, 480, |x, y| {
            let robot = (280..360).contains(&x) && (300..420).contains(&y);
            Rgb(if robot { [128, 128, 128] } else { [60, 130, 50] })
        }));
        let camera = CameraPose::new(0.5, 0.3, 0.0, 0.0).unwrap();
        let percepts =
            detect(&frame, &CameraIntrinsics::nao_top(), &camera, &FieldDimensions::default()).unwrap();
        assert!(percepts.points.is_empty());
        assert!(percepts.searched(&Point2::new(100.0, 360.0), 10.0), "open carpet");
        assert!(!percepts.searched(&Point2::new(320.0, 360.0), 10.0), "behind the robot");
        assert!(!percepts.searched(&Point2::new(320.0, 2.0), 10.0), "at the image edge");
        assert!(percepts.searched(&Point2::new(30.0, 360.0), 10.0), "a thin line near the edge");
        assert!(!percepts.searched(&Point2::new(30.0, 360.0), 30.0), "a wide line near the edge");
    }

    #[test]
    fn a_line_beside_a_post_is_not_expected() {
        // Carpet to the top of the image, a grey post standing on it from the top down to row 300: a
        // row crossing needs carpet beyond the line on both sides, so beside the post none is found.
        let frame = Frame::Rgb(RgbImage::from_fn(640, 480, |x, y| {
            let post = (300..320).contains(&x) && y < 300;
            Rgb(if post { [200, 200, 200] } else { [60, 130, 50] })
        }));
        let camera = CameraPose::new(0.5, 0.3, 0.0, 0.0).unwrap();
        let percepts =
            detect(&frame, &CameraIntrinsics::nao_top(), &camera, &FieldDimensions::default()).unwrap();
        assert!(!percepts.searched(&Point2::new(326.0, 200.0), 6.0), "right beside the post");
        assert!(!percepts.searched(&Point2::new(292.0, 200.0), 6.0), "on its other side");
        assert!(percepts.searched(&Point2::new(400.0, 200.0), 6.0), "clear of the post");
        assert!(percepts.searched(&Point2::new(326.0, 360.0), 6.0), "below its foot");
    }

    /// Carpet below row 200 and the hall above it, with an upright white bar 10 px wide standing 30 px
    /// into the carpet at each (left column, top row).
    fn standing_bars(bars: &[(u32, u32)]) -> Frame {
        let bars = bars.to_vec();
        Frame::Rgb(RgbImage::from_fn(640, 480, move |x, y| {
            let paint =
                bars.iter().any(|&(left, top)| (left..left + 10).contains(&x) && (top..230).contains(&y));
            Rgb(if paint {
                [230, 232, 230]
            } else if y >= 200 {
                [60, 130, 50]
            } else {
                [40, 40, 45]
            })
        }))
    }

    #[test]
    fn a_post_rises_as_a_goal_s_post_would_under_the_camera() {
        // Two bars, each found in the image: a post up to row 60, a robot's leg up to row 170.
        let kept = |frame: &Frame, camera: &CameraPose, dimensions: &FieldDimensions| -> Vec<f64> {
            let percepts = detect(frame, &CameraIntrinsics::nao_top(), camera, dimensions).unwrap();
            assert_eq!(percepts.image().goal_posts(frame).len(), 2, "both stand in the image");
            // Each kept post by the bar it stands for (its left edge).
            percepts.posts.iter().map(|post| (post.sighting.foot.x / 50.0).floor() * 50.0).collect()
        };
        // 3.1 m away under this camera, half a goal's height rises to about row 151.
        let camera = CameraPose::new(0.5, 10.0_f64.to_radians(), 0.0, 0.0).unwrap();
        let frame = standing_bars(&[(300, 60), (450, 170)]);
        assert_eq!(kept(&frame, &camera, &FieldDimensions::default()), vec![300.0]);
        // Looking down at a goal 1.2 m tall 1.1 m away, half its height is above the image: a post
        // must reach the image's top.
        let camera = CameraPose::new(0.5, 25.0_f64.to_radians(), 0.0, 0.0).unwrap();
        let tall = FieldDimensions { goal_height: 1.2, ..FieldDimensions::default() };
        let frame = standing_bars(&[(300, 0), (450, 20)]);
        assert_eq!(kept(&frame, &camera, &tall), vec![300.0]);
    }

    #[test]
    fn a_post_s_bearing_rates_are_how_its_bearing_turns_with_the_camera() {
        // A post off to the side: the camera's pitch and roll turn its bearing.
        let frame = standing_bars(&[(520, 20)]);
        let bearing = |pitch: f64, roll: f64| {
            let camera = CameraPose::new(0.5, (10.0 + pitch).to_radians(), roll.to_radians(), 0.0).unwrap();
            let percepts = detect(&frame, &CameraIntrinsics::nao_top(), &camera, &FieldDimensions::default());
            let posts = percepts.unwrap().posts;
            assert_eq!(posts.len(), 1);
            (posts[0].bearing(), posts[0].bearing_rates())
        };
        let (straight, rates) = bearing(0.0, 0.0);
        assert!(rates.x.abs() > 0.02 && rates.y.abs() > 0.02, "{rates:?}");
        for (pitch, roll) in [(0.5, 0.0), (0.0, 0.5), (-0.3, -0.4)] {
            let expected = straight + rates.dot(&Vector2::new(pitch, roll)) * 1.0_f64.to_radians();
            assert_abs_diff_eq!(bearing(pitch, roll).0, expected, epsilon = 2e-5);
        }
    }

    #[test]
    fn a_painted_line_continues_and_a_ball_does_not() {
        // A slanted line on carpet and a white disc (a ball's patch) of about its width elsewhere.
        let frame = Frame::Rgb(RgbImage::from_fn(640, 480, |x, y| {
            let (x, y) = (x as f64, y as f64);
            let line = (y - 200.0 - 0.5 * x).abs() < 6.0;
            let ball = (x - 500.0).hypot(y - 150.0) < 10.0;
            Rgb(if line || ball { [230, 235, 230] } else { [60, 130, 50] })
        }));
        assert_crossings_on_line(&frame, (200.0, 0.5), 8.0, 30);
    }

    /// Asserts that `frame` has more than `least` crossings, each within `tolerance` pixels (in v) of
    /// the line v = offset + slope · u.
    fn assert_crossings_on_line(frame: &Frame, (offset, slope): (f64, f64), tolerance: f64, least: usize) {
        let image = detect_in_image(frame).unwrap();
        assert!(image.crossings.len() > least, "{} crossings", image.crossings.len());
        for crossing in &image.crossings {
            let centre = crossing.centre();
            assert!(
                (centre.y - offset - slope * centre.x).abs() < tolerance,
                "{centre:?} is not on the line"
            );
        }
    }

    #[test]
    fn a_blurred_line_with_the_carpets_tint_is_a_line_and_a_sun_patch_is_not() {
        // Carpet with a broad sunlit band across the top half and, below it, a blurred line whose
        // pixels keep some of the carpet's green.
        let frame = Frame::Rgb(RgbImage::from_fn(640, 480, |x, y| {
            let (x, y) = (x as f64, y as f64);
            let sun = (60.0..180.0).contains(&(y - 0.2 * x));
            let distance = (y - 330.0 - 0.3 * x).abs();
            Rgb(if distance < 4.0 {
                [150, 195, 140]
            } else if sun {
                [110, 235, 95]
            } else {
                [60, 130, 50]
            })
        }));
        assert_crossings_on_line(&frame, (330.0, 0.3), 6.0, 40);
    }

    #[test]
    fn a_blurred_line_near_the_border_may_be_a_little_wider_than_perspective_allows() {
        // 00122's motion-blurred line, 24 px tall 40 px under the border, is paint; a band as wide
        // right at the border is not.
        assert!(perspective_width_limit(40.0) >= 24.0);
        assert!(perspective_width_limit(0.0) < 24.0);
        assert_eq!(perspective_width_limit(-5.0), perspective_width_limit(0.0));
    }

    #[test]
    fn an_empty_frame_is_refused() {
        let frame = Frame::Rgb(RgbImage::new(0, 0));
        assert_eq!(detect_in_image(&frame).unwrap_err(), PerceptError::EmptyFrame { width: 0, height: 0 });
    }
}
