//! Plots of an evaluation a person would rather look at than a table: the location-vs-heading error
//! scatter (as in the thesis' Fig. 3.8) and a field map with true and predicted poses. PNG, drawn with
//! plotters; labels use an embedded DejaVu Sans, so no system font is needed.

use std::path::{Path, PathBuf};
use std::sync::Once;

use image::RgbImage;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::FontStyle;
use thiserror::Error;

use crate::eval::{Evaluation, median};
use crate::geometry::{FieldModel, FieldPose};

/// Font family name the labels use.
const FONT: &str = "sans-serif";
/// At most this many frames are drawn on the field map, so that it stays readable.
const MAP_FRAMES: usize = 120;
/// Length of a heading arrow on the field map, metres.
const ARROW_M: f64 = 0.35;

/// Why a report could not be written.
#[derive(Debug, Error)]
pub enum ReportError {
    /// Nothing to plot.
    #[error("no frames with a true pose to plot")]
    Empty,
    /// The directory or a file could not be written.
    #[error("writing {path}: {source}")]
    Write {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// Drawing failed.
    #[error("drawing {path}: {reason}")]
    Draw {
        /// The plot.
        path: PathBuf,
        /// What plotters said.
        reason: String,
    },
}

/// Writes `errors.png` and `field.png` into `directory` (created if needed); returns their paths.
pub fn write_report(
    directory: &Path,
    evaluations: &[Evaluation],
    field: &FieldModel,
) -> Result<Vec<PathBuf>, ReportError> {
    if evaluations.is_empty() {
        return Err(ReportError::Empty);
    }
    static FONT_REGISTERED: Once = Once::new();
    FONT_REGISTERED.call_once(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular())
            .unwrap_or_else(|_| unreachable!("the embedded DejaVu Sans is a valid font"));
    });
    std::fs::create_dir_all(directory)
        .map_err(|source| ReportError::Write { path: directory.to_path_buf(), source })?;
    let errors = directory.join("errors.png");
    save(&errors, (900, 650), |area| draw_error_scatter(area, evaluations))?;
    let map = directory.join("field.png");
    let dimensions = field.dimensions();
    let aspect = dimensions.carpet_half_width() / dimensions.carpet_half_length();
    save(&map, (1100, (1100.0 * aspect) as u32 + 60), |area| draw_field_map(area, evaluations, field))?;
    Ok(vec![errors, map])
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;
type DrawResult = Result<(), Box<dyn std::error::Error>>;

/// Draws into an RGB buffer with plotters and encodes it as PNG with `image`.
fn save(
    path: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(&Area) -> DrawResult,
) -> Result<(), ReportError> {
    let draw_error = |reason: String| ReportError::Draw { path: path.to_path_buf(), reason };
    let mut pixels = vec![255u8; (width * height * 3) as usize];
    {
        let area = BitMapBackend::with_buffer(&mut pixels, (width, height)).into_drawing_area();
        draw(&area).map_err(|error| draw_error(error.to_string()))?;
        area.present().map_err(|error| draw_error(error.to_string()))?;
    }
    let image = RgbImage::from_raw(width, height, pixels).expect("buffer sized for the image");
    image.save(path).map_err(|error| ReportError::Write {
        path: path.to_path_buf(),
        source: std::io::Error::other(error.to_string()),
    })
}

fn draw_error_scatter(area: &Area, evaluations: &[Evaluation]) -> DrawResult {
    let mut locations: Vec<f64> = evaluations.iter().map(|e| 100.0 * e.best_of_set.0).collect();
    locations.sort_by(f64::total_cmp);
    // Axis to the 98th percentile so that a few wild frames do not squash the rest.
    let x_max = locations[(locations.len() * 98 / 100).min(locations.len() - 1)].max(10.0) * 1.05;
    let mut chart = ChartBuilder::on(area)
        .caption("Best-of-set error per frame", (FONT, 26))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..x_max, 0.0..180.0)?;
    chart
        .configure_mesh()
        .x_desc("location error (cm)")
        .y_desc("heading error (°)")
        .label_style((FONT, 16))
        .axis_desc_style((FONT, 18))
        .draw()?;
    chart.draw_series(evaluations.iter().map(|e| {
        let point = ((100.0 * e.best_of_set.0).min(x_max), e.best_of_set.1);
        Circle::new(point, 2, BLUE.mix(0.35).filled())
    }))?;
    let median_location = median(&locations);
    let headings: Vec<f64> = evaluations.iter().map(|e| e.best_of_set.1).collect();
    let median_heading = median(&headings);
    chart
        .draw_series(LineSeries::new(
            [(median_location, 0.0), (median_location, 180.0)],
            RED.stroke_width(2),
        ))?
        .label(format!("median {median_location:.1} cm / {median_heading:.1}°"))
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED.stroke_width(2)));
    chart.draw_series(LineSeries::new(
        [(0.0, median_heading), (x_max, median_heading)],
        RED.stroke_width(2),
    ))?;
    chart
        .configure_series_labels()
        .label_font((FONT, 16))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

fn draw_field_map(area: &Area, evaluations: &[Evaluation], field: &FieldModel) -> DrawResult {
    let dimensions = field.dimensions();
    let (half_length, half_width) = (dimensions.carpet_half_length(), dimensions.carpet_half_width());
    area.fill(&RGBColor(40, 120, 50))?;
    let mut chart = ChartBuilder::on(area)
        .caption("Truth (white) and closest hypothesis (red)", (FONT, 24).into_font().color(&WHITE))
        .margin(10)
        .build_cartesian_2d(-half_length..half_length, -half_width..half_width)?;
    let paint = WHITE.stroke_width(2);
    for line in &field.lines {
        chart
            .draw_series(LineSeries::new([(line.start.x, line.start.y), (line.end.x, line.end.y)], paint))?;
    }
    for circle in &field.circles {
        let points = (0..=72).map(|step| {
            let angle = f64::from(step) / 72.0 * std::f64::consts::TAU;
            (circle.centre.x + circle.radius * angle.cos(), circle.centre.y + circle.radius * angle.sin())
        });
        chart.draw_series(LineSeries::new(points, paint))?;
    }
    let step = evaluations.len().div_ceil(MAP_FRAMES);
    for evaluation in evaluations.iter().step_by(step) {
        let (truth, closest) = (&evaluation.truth, &evaluation.closest);
        let error = [(truth.x(), truth.y()), (closest.x(), closest.y())];
        chart.draw_series(LineSeries::new(error, YELLOW.mix(0.8)))?;
        draw_pose(&mut chart, truth, WHITE)?;
        draw_pose(&mut chart, closest, RED)?;
    }
    Ok(())
}

fn draw_pose(
    chart: &mut ChartContext<BitMapBackend, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    pose: &FieldPose,
    colour: RGBColor,
) -> DrawResult {
    let tip = (pose.x() + ARROW_M * pose.heading().cos(), pose.y() + ARROW_M * pose.heading().sin());
    chart.draw_series(LineSeries::new([(pose.x(), pose.y()), tip], colour.stroke_width(2)))?;
    chart.draw_series(std::iter::once(Circle::new((pose.x(), pose.y()), 4, colour.filled())))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::Sample;
    use crate::geometry::Representation;
    use crate::relocaliser::{Prediction, RawOutput};

    fn evaluation(index: usize) -> Evaluation {
        let truth = FieldPose::new(-3.0 + index as f64 * 0.3, 1.0, 0.2 * index as f64).unwrap();
        let raw = RawOutput {
            position: [truth.x() as f32 + 0.1, truth.y() as f32],
            heading: [1.0, 0.0],
            fold_probabilities: vec![0.3],
            position_sigma: 0.2,
            heading_kappa: 50.0,
        };
        let prediction = Prediction::decode(&raw, Representation::HalfPoint, 0.0).unwrap();
        Sample { truth, head_yaw: 0.0, prediction }.evaluate()
    }

    #[test]
    fn writes_both_plots_as_png() {
        let dir = tempfile::tempdir().unwrap();
        let evaluations: Vec<Evaluation> = (0..20).map(evaluation).collect();
        let written = write_report(&dir.path().join("report"), &evaluations, &FieldModel::default()).unwrap();
        assert_eq!(written.len(), 2);
        for path in written {
            let image = image::open(&path).unwrap().into_rgb8();
            assert!(image.width() >= 900, "{}", path.display());
            // Something was drawn: not a single flat colour.
            let first = image.get_pixel(0, 0);
            assert!(image.pixels().any(|pixel| pixel != first), "{} is blank", path.display());
        }
    }

    #[test]
    fn nothing_to_plot_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        assert!(matches!(write_report(dir.path(), &[], &FieldModel::default()), Err(ReportError::Empty)));
    }
}
