//! The coarse stage of the global search: every robot pose on the carpet, on a grid, scored by how far
//! a burst's line points land from the nearest field line.
//!
//! The score is a sum of truncated distances read from a coarse map of the field's lines (4 cm cells, a
//! byte each, padded by the farthest line point's reach so that no lookup needs a bounds check). Grid
//! positions are whole cells apart, so turning the points once per heading gives each point a fixed cell
//! offset, and scoring a position is one add and one byte load per point. Only headings in [0, π) are
//! scored: the field is point-symmetric, so (−x, −y, θ + π) scores what (x, y, θ) does, and callers add
//! that twin themselves. The grid's local minima are the candidates that the fine fit then refines and
//! checks ([`super::LineRefiner::search`]).

use std::ops::Range;

use nalgebra::Point2;

use super::line_map::LineMap;
use super::optimise::Observation;
use crate::geometry::angle::angle_distance;
use crate::geometry::{FieldModel, FieldPose, Symmetry};

/// Cell size of the coarse map, metres.
const CELL: f64 = 0.04;
/// Grid step between scored positions, in cells (0.24 m).
const POSITION_STEP: i32 = 6;
/// Headings scored over [0, π).
const HEADINGS: usize = 60;
/// Distance at which a point stops counting against a pose, metres: the coarse grid's own error (up
/// to 17 cm of position and 1.5° of heading, ~10 cm at 4 m) plus a margin.
const TRUNCATION: f64 = 0.3;
/// Farthest line point the map reaches from a pose on the carpet, metres.
pub const REACH: f64 = 5.0;
/// Points scored, at most (evenly spread over the burst's points).
const MAX_POINTS: usize = 64;
/// Every this many points is a probe, scored first at every pose.
const PROBE_STRIDE: usize = 4;
/// A pose's running sum is compared with its limit after every this many points.
const CHECK_EVERY: usize = 4;
/// A pose is left unscored when its probes lie farther from the lines on average than this many
/// times the largest mean distance a candidate may have.
const PROBE_MARGIN: f64 = 1.5;

/// A grid pose and its score (lower is better; 255 per point means "far from every line").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// The pose on the grid.
    pub pose: FieldPose,
    /// Mean truncated distance of the scored points from the nearest line, metres.
    pub mean_distance: f64,
}

/// Poses near a guess: within `reach` metres of its position along x and y and `turn` radians of its
/// heading, or as near its point-symmetric twin (which scores the same).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Region {
    /// The guess.
    pub centre: FieldPose,
    /// Half the side of the square of positions, metres.
    pub reach: f64,
    /// Largest heading difference, radians.
    pub turn: f64,
}

/// The field's lines as a coarse, padded map of truncated distances.
#[derive(Clone, Debug)]
pub struct SearchMap {
    /// Per cell: distance to the nearest line, truncated and scaled to 0..=255.
    cells: Vec<u8>,
    columns: usize,
    /// Field coordinates of cell (0, 0)'s centre.
    origin: Point2<f64>,
    /// Cell of the first grid position, and the grid's size in positions.
    first: (i32, i32),
    positions: (i32, i32),
}

impl SearchMap {
    /// Builds the map for `field` from its distance map `lines` (once; about 0.25 MB).
    pub fn new(field: &FieldModel, lines: &LineMap) -> Self {
        let dimensions = field.dimensions();
        let (half_length, half_width) = (dimensions.carpet_half_length(), dimensions.carpet_half_width());
        // Grid positions over the carpet, symmetric about the centre spot (so twins score alike).
        let step = f64::from(POSITION_STEP) * CELL;
        let positions = ((half_length / step).floor() as i32, (half_width / step).floor() as i32);
        let pad = ((REACH + CELL) / CELL).ceil() as i32;
        let half_cells = (positions.0 * POSITION_STEP + pad, positions.1 * POSITION_STEP + pad);
        let (columns, rows) = (2 * half_cells.0 + 1, 2 * half_cells.1 + 1);
        let origin = Point2::new(-f64::from(half_cells.0) * CELL, -f64::from(half_cells.1) * CELL);
        let mut cells = Vec::with_capacity((columns * rows) as usize);
        for row in 0..rows {
            for column in 0..columns {
                let centre = origin + nalgebra::Vector2::new(f64::from(column), f64::from(row)) * CELL;
                let distance = lines.residual(centre).0.min(TRUNCATION);
                cells.push((distance / TRUNCATION * 255.0).round() as u8);
            }
        }
        Self {
            cells,
            columns: columns as usize,
            origin,
            first: (half_cells.0 - positions.0 * POSITION_STEP, half_cells.1 - positions.1 * POSITION_STEP),
            positions: (2 * positions.0 + 1, 2 * positions.1 + 1),
        }
    }

    /// The grid's local minima over positions and headings in [0, π) (all of them, or those in
    /// `region`), best first, at most `count`, none whose points lie farther than `max_mean_distance`
    /// (metres) from the lines on average. `observations` are robot-frame ground points (farther than
    /// [`REACH`] are left out).
    pub fn candidates(
        &self,
        observations: &[Observation],
        count: usize,
        max_mean_distance: f64,
        region: Option<&Region>,
    ) -> Vec<Candidate> {
        let points: Vec<Point2<f64>> = spread(observations);
        if points.is_empty() {
            return Vec::new();
        }
        // Every PROBE_STRIDE-th point first: a pose whose probes already lie far off the lines is
        // left unscored (u32::MAX), which spares most of the field most of its points.
        let probes = points.len().div_ceil(PROBE_STRIDE);
        let points: Vec<Point2<f64>> = points
            .iter()
            .step_by(PROBE_STRIDE)
            .chain(points.iter().enumerate().filter(|(i, _)| i % PROBE_STRIDE != 0).map(|(_, point)| point))
            .copied()
            .collect();
        let probe_limit =
            (PROBE_MARGIN * max_mean_distance.min(TRUNCATION) / TRUNCATION * 255.0 * probes as f64) as u32;
        // A pose that scores more is never a candidate, and no neighbour of it is kept from being one
        // by it: it is left as soon as its sum is sure to exceed this.
        let Some(score_limit) = score_limit(points.len(), max_mean_distance) else { return Vec::new() };
        let (width, height) = (self.positions.0 as usize, self.positions.1 as usize);
        let layer = width * height;
        let mut scores = vec![u32::MAX; HEADINGS * layer];
        let mut offsets = vec![0isize; points.len()];
        for (heading_index, layer_scores) in scores.chunks_exact_mut(layer).enumerate() {
            let Some((rows, columns)) = self.window(heading_index, region) else { continue };
            let (sin, cos) = heading(heading_index).sin_cos();
            for (offset, point) in offsets.iter_mut().zip(&points) {
                let dx = ((cos * point.x - sin * point.y) / CELL).round() as isize;
                let dy = ((sin * point.x + cos * point.y) / CELL).round() as isize;
                *offset = dy * self.columns as isize + dx;
            }
            let (probe_offsets, rest_offsets) = offsets.split_at(probes);
            for (row, row_scores) in
                layer_scores.chunks_exact_mut(width).enumerate().take(rows.end).skip(rows.start)
            {
                let cell_y = self.first.1 as usize + row * POSITION_STEP as usize;
                for (column, score) in row_scores.iter_mut().enumerate().take(columns.end).skip(columns.start)
                {
                    let cell_x = self.first.0 as usize + column * POSITION_STEP as usize;
                    let base = (cell_y * self.columns + cell_x) as isize;
                    *score = self
                        .sum_within(base, probe_offsets, 0, probe_limit)
                        .and_then(|probed| self.sum_within(base, rest_offsets, probed, score_limit))
                        .unwrap_or(u32::MAX);
                }
            }
        }
        let mut minima: Vec<(u32, usize)> = Vec::new();
        for (index, &score) in scores.iter().enumerate() {
            if score != u32::MAX && is_local_minimum(&scores, index, width, height) {
                minima.push((score, index));
            }
        }
        minima.sort_unstable();
        minima
            .into_iter()
            .take(count)
            .map(|(score, index)| {
                let (heading_index, rest) = (index / layer, index % layer);
                let (row, column) = (rest / width, rest % width);
                let cell = |first: i32, at: usize| first + at as i32 * POSITION_STEP;
                let x = self.origin.x + f64::from(cell(self.first.0, column)) * CELL;
                let y = self.origin.y + f64::from(cell(self.first.1, row)) * CELL;
                Candidate {
                    pose: FieldPose::new(x, y, heading(heading_index)).expect("grid poses are finite"),
                    mean_distance: mean_distance(score, points.len()),
                }
            })
            .collect()
    }

    /// `start` plus the map's cells at `base + offsets`, or `None` once that exceeds `limit` (looked
    /// at every [`CHECK_EVERY`] points). Every offset stays within the padding, so every index is in
    /// the map.
    fn sum_within(&self, base: isize, offsets: &[isize], start: u32, limit: u32) -> Option<u32> {
        let mut sum = start;
        for chunk in offsets.chunks(CHECK_EVERY) {
            sum += chunk.iter().map(|offset| u32::from(self.cells[(base + offset) as usize])).sum::<u32>();
            if sum > limit {
                return None;
            }
        }
        Some(sum)
    }

    /// The grid rows and columns to score at `heading_index`: all of them without a region; with one,
    /// those around its centre or its twin, whichever the heading is near (`None`: neither).
    fn window(&self, heading_index: usize, region: Option<&Region>) -> Option<(Range<usize>, Range<usize>)> {
        let (width, height) = (self.positions.0 as usize, self.positions.1 as usize);
        let Some(region) = region else { return Some((0..height, 0..width)) };
        let twin = Symmetry::PointReflection.apply(&region.centre);
        let grid_heading = heading(heading_index);
        let centre = [region.centre, twin]
            .into_iter()
            .find(|pose| angle_distance(pose.heading(), grid_heading) <= region.turn)?;
        let step = f64::from(POSITION_STEP) * CELL;
        // `first` is the field coordinate of the first grid position along the axis.
        let span = |position: f64, first: f64, count: usize| {
            let low = ((position - region.reach - first) / step).ceil().max(0.0) as usize;
            let high = (((position + region.reach - first) / step).floor() + 1.0).max(0.0) as usize;
            low.min(count)..high.min(count)
        };
        let first = |origin: f64, cell: i32| origin + f64::from(cell) * CELL;
        let rows = span(centre.y(), first(self.origin.y, self.first.1), height);
        Some((rows, span(centre.x(), first(self.origin.x, self.first.0), width)))
    }
}

/// The spacing of the coarse grid: position (metres) and heading (radians).
pub fn grid_spacing() -> (f64, f64) {
    (f64::from(POSITION_STEP) * CELL, std::f64::consts::PI / HEADINGS as f64)
}

fn heading(index: usize) -> f64 {
    index as f64 * std::f64::consts::PI / HEADINGS as f64
}

/// The mean truncated distance (metres) of `points` points that score `score` in all.
fn mean_distance(score: u32, points: usize) -> f64 {
    f64::from(score) / points as f64 / 255.0 * TRUNCATION
}

/// The largest score of `points` (at most [`MAX_POINTS`]) points whose [`mean_distance`] is at most
/// `max_mean_distance` (`None`: not even a perfect score's is).
fn score_limit(points: usize, max_mean_distance: f64) -> Option<u32> {
    let passes = |score: u32| mean_distance(score, points) <= max_mean_distance;
    let most = 255 * points.min(MAX_POINTS) as u32;
    let estimate =
        (max_mean_distance / TRUNCATION * 255.0 * points as f64).clamp(0.0, f64::from(most)) as u32;
    // The estimate is within rounding of the limit: step to it exactly.
    let mut limit = estimate;
    while limit < most && passes(limit + 1) {
        limit += 1;
    }
    while !passes(limit) {
        limit = limit.checked_sub(1)?;
    }
    Some(limit)
}

/// At most [`MAX_POINTS`] of the points within reach, evenly spread over their order.
fn spread(observations: &[Observation]) -> Vec<Point2<f64>> {
    let within: Vec<Point2<f64>> = observations
        .iter()
        .map(|observation| observation.ground)
        .filter(|ground| ground.coords.norm() <= REACH)
        .collect();
    let stride = within.len().div_ceil(MAX_POINTS).max(1);
    within.into_iter().step_by(stride).collect()
}

/// Whether no neighbour (over position and heading, the heading not wrapping) scores lower, and no
/// earlier neighbour scores the same (so a plateau yields one minimum).
fn is_local_minimum(scores: &[u32], index: usize, width: usize, height: usize) -> bool {
    let layer = width * height;
    let (heading, rest) = (index / layer, index % layer);
    let (row, column) = (rest / width, rest % width);
    let score = scores[index];
    let headings = scores.len() / layer;
    for dh in -1i64..=1 {
        for dr in -1i64..=1 {
            for dc in -1i64..=1 {
                let (h, r, c) = (heading as i64 + dh, row as i64 + dr, column as i64 + dc);
                if (dh, dr, dc) == (0, 0, 0)
                    || !(0..headings as i64).contains(&h)
                    || !(0..height as i64).contains(&r)
                    || !(0..width as i64).contains(&c)
                {
                    continue;
                }
                let neighbour = (h as usize) * layer + (r as usize) * width + c as usize;
                if scores[neighbour] < score || (scores[neighbour] == score && neighbour < index) {
                    return false;
                }
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::refine::optimise::observe_lines;

    /// Robot-frame points on the model's lines as seen from `truth` (ahead, within 3.5 m).
    fn observe(field: &FieldModel, truth: &FieldPose) -> Vec<Observation> {
        observe_lines(field, truth, |ground| {
            ground.x > 0.3 && ground.coords.norm() < 3.5 && ground.y.abs() < 0.8 * ground.x
        })
    }

    #[test]
    fn the_truth_or_its_twin_is_among_the_best_candidates() {
        let field = FieldModel::default();
        let search = SearchMap::new(&field, &LineMap::new(&field));
        for truth in [
            FieldPose::new(-3.3, -1.4, -2.4).unwrap(),
            FieldPose::new(1.13, 0.4, 0.7).unwrap(),
            FieldPose::new(-0.5, 2.9, -1.2).unwrap(),
        ] {
            let observations = observe(&field, &truth);
            assert!(observations.len() > 20, "{}", observations.len());
            let candidates = search.candidates(&observations, 10, 0.12, None);
            let twin = Symmetry::PointReflection.apply(&truth);
            let (step, turn) = grid_spacing();
            let found = candidates.iter().any(|candidate| {
                [truth, twin].iter().any(|pose| {
                    candidate.pose.distance_to(pose) <= step
                        && angle_distance(candidate.pose.heading(), pose.heading()) <= turn
                })
            });
            assert!(found, "{truth:?} not in {candidates:?}");
        }
    }

    #[test]
    fn a_region_keeps_its_candidates_near_its_centre_or_twin_and_still_finds_the_truth() {
        let field = FieldModel::default();
        let search = SearchMap::new(&field, &LineMap::new(&field));
        let truth = FieldPose::new(-2.1, 1.7, 2.6).unwrap();
        let observations = observe(&field, &truth);
        let centre = FieldPose::new(-1.6, 2.2, 2.3).unwrap();
        let region = Region { centre, reach: 0.8, turn: 0.5 };
        let candidates = search.candidates(&observations, 10, 0.12, Some(&region));
        assert!(!candidates.is_empty());
        let (step, turn) = grid_spacing();
        let twin = Symmetry::PointReflection.apply(&centre);
        for candidate in &candidates {
            let inside = [centre, twin].iter().any(|pose| {
                (candidate.pose.x() - pose.x()).abs() <= region.reach
                    && (candidate.pose.y() - pose.y()).abs() <= region.reach
                    && angle_distance(candidate.pose.heading(), pose.heading()) <= region.turn
            });
            assert!(inside, "{candidate:?} outside {region:?}");
        }
        let near = |pose: &FieldPose| {
            candidates.iter().any(|c| {
                c.pose.distance_to(pose) <= step && angle_distance(c.pose.heading(), pose.heading()) <= turn
            })
        };
        assert!(near(&truth) || near(&Symmetry::PointReflection.apply(&truth)), "{candidates:?}");
        let elsewhere = Region { centre: FieldPose::new(3.0, -2.5, 0.0).unwrap(), ..region };
        let far = search.candidates(&observations, 10, 0.12, Some(&elsewhere));
        assert!(far.iter().all(|c| c.pose.distance_to(&truth) > 1.0), "{far:?}");
    }

    #[test]
    fn no_points_no_candidates() {
        let field = FieldModel::default();
        let search = SearchMap::new(&field, &LineMap::new(&field));
        assert!(search.candidates(&[], 10, 0.12, None).is_empty());
        let far = [Observation {
            ground: Point2::new(9.0, 0.0),
            sigma: 0.02,
            weight: 1.0,
            calibration_rates: [nalgebra::Vector2::zeros(); 2],
        }];
        assert!(search.candidates(&far, 10, 0.12, None).is_empty(), "points beyond reach are left out");
    }

    #[test]
    fn the_score_limit_is_the_largest_score_a_candidate_may_have() {
        for points in [1, 13, 64] {
            for max_mean_distance in [0.0, 0.05, 0.12, 0.2999, 0.3, 1.0] {
                let limit = score_limit(points, max_mean_distance).expect("a perfect score passes");
                assert!(mean_distance(limit, points) <= max_mean_distance);
                let most = 255 * points as u32;
                assert!(limit == most || mean_distance(limit + 1, points) > max_mean_distance);
            }
        }
        assert_eq!(score_limit(64, -0.01), None);
        assert_eq!(score_limit(64, f64::NAN), None);
    }

    #[test]
    fn a_sum_is_left_once_it_exceeds_its_limit() {
        let field = FieldModel::default();
        let search = SearchMap::new(&field, &LineMap::new(&field));
        // Far from every line (beyond the carpet): every cell reads the truncation, 255.
        let base = (search.columns * (search.first.1 as usize) + 2) as isize;
        let offsets = [0isize; 8];
        assert_eq!(search.sum_within(base, &offsets, 10, 10 + 8 * 255), Some(10 + 8 * 255));
        assert_eq!(search.sum_within(base, &offsets, 10, 10 + 8 * 255 - 1), None);
    }

    #[test]
    fn grid_positions_are_symmetric_about_the_centre_spot() {
        let field = FieldModel::default();
        let search = SearchMap::new(&field, &LineMap::new(&field));
        let first_x = search.origin.x + f64::from(search.first.0) * CELL;
        let last_x = first_x + f64::from((search.positions.0 - 1) * POSITION_STEP) * CELL;
        assert!((first_x + last_x).abs() < 1e-9, "{first_x} .. {last_x}");
        assert!(last_x <= field.dimensions().carpet_half_length());
    }
}
