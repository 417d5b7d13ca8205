//! The field's painted lines as a distance map: for every cell of a grid over the carpet (and a margin
//! around it), the nearest line primitive and the distance to its centre line. Built once per field;
//! a lookup is two multiplications and an index.

use nalgebra::{Point2, Vector2};

use crate::geometry::FieldModel;

/// Side of one map cell, metres.
pub const CELL_SIZE: f64 = 0.02;
/// How far the map reaches past the carpet's edge, metres (points seen beyond it still find a line).
const MARGIN: f64 = 1.0;

/// One painted centre line: a straight segment or a circle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Primitive {
    /// A straight line between two points.
    Segment {
        /// One end.
        start: Point2<f64>,
        /// The other end.
        end: Point2<f64>,
    },
    /// A circle.
    Circle {
        /// Its centre.
        centre: Point2<f64>,
        /// Radius of its centre line.
        radius: f64,
    },
}

impl Primitive {
    /// Distance from `point` to the centre line and the unit direction in which that distance grows
    /// fastest (its gradient), so that moving `point` by `δ` changes the distance by about `gradient·δ`.
    pub fn residual(&self, point: Point2<f64>) -> (f64, Vector2<f64>) {
        let away = match *self {
            Primitive::Segment { start, end } => {
                let direction = end - start;
                let along = ((point - start).dot(&direction) / direction.norm_squared()).clamp(0.0, 1.0);
                point - (start + direction * along)
            }
            Primitive::Circle { centre, radius } => {
                let radial = point - centre;
                let norm = radial.norm();
                if norm < 1e-9 {
                    return (radius, Vector2::x());
                }
                radial * ((norm - radius) / norm)
            }
        };
        let distance = away.norm();
        if distance < 1e-12 {
            // On the line: the gradient is the normal, pointing either way.
            let normal = match *self {
                Primitive::Segment { start, end } => {
                    let d = (end - start).normalize();
                    Vector2::new(-d.y, d.x)
                }
                Primitive::Circle { centre, .. } => (point - centre).normalize(),
            };
            return (0.0, normal);
        }
        (distance, away / distance)
    }

    /// Points along the centre line, `spacing` metres apart (ends included for segments).
    pub fn samples(&self, spacing: f64) -> Vec<Point2<f64>> {
        match *self {
            Primitive::Segment { start, end } => {
                let count = ((end - start).norm() / spacing).ceil().max(1.0) as usize;
                (0..=count).map(|i| start + (end - start) * (i as f64 / count as f64)).collect()
            }
            Primitive::Circle { centre, radius } => {
                let count = (std::f64::consts::TAU * radius / spacing).ceil().max(8.0) as usize;
                (0..count)
                    .map(|i| {
                        let angle = std::f64::consts::TAU * i as f64 / count as f64;
                        centre + Vector2::new(angle.cos(), angle.sin()) * radius
                    })
                    .collect()
            }
        }
    }
}

/// The distance map of one field.
#[derive(Clone, Debug)]
pub struct LineMap {
    primitives: Vec<Primitive>,
    origin: Point2<f64>,
    columns: usize,
    rows: usize,
    /// Per cell: index of the nearest primitive.
    nearest: Vec<u8>,
    /// Per cell: distance from the cell centre to that primitive, millimetres.
    distance_mm: Vec<u16>,
}

impl LineMap {
    /// Builds the map for `field`: its lines, its centre circle and the arms of its marks.
    pub fn new(field: &FieldModel) -> Self {
        let primitives = field_primitives(field);
        let dimensions = field.dimensions();
        let half_length = dimensions.carpet_half_length() + MARGIN;
        let half_width = dimensions.carpet_half_width() + MARGIN;
        let columns = (2.0 * half_length / CELL_SIZE).ceil() as usize;
        let rows = (2.0 * half_width / CELL_SIZE).ceil() as usize;
        let origin = Point2::new(-half_length, -half_width);
        let mut nearest = Vec::with_capacity(columns * rows);
        let mut distance_mm = Vec::with_capacity(columns * rows);
        for row in 0..rows {
            for column in 0..columns {
                let centre = origin + Vector2::new(column as f64 + 0.5, row as f64 + 0.5) * CELL_SIZE;
                let (index, distance) = primitives
                    .iter()
                    .enumerate()
                    .map(|(index, primitive)| (index, primitive.residual(centre).0))
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .expect("a field has lines");
                nearest.push(index as u8);
                distance_mm.push((distance * 1000.0).round().min(f64::from(u16::MAX)) as u16);
            }
        }
        Self { primitives, origin, columns, rows, nearest, distance_mm }
    }

    /// The primitives, in the order the map indexes them.
    pub fn primitives(&self) -> &[Primitive] {
        &self.primitives
    }

    fn cell(&self, point: Point2<f64>) -> usize {
        let offset = (point - self.origin) / CELL_SIZE;
        let column = (offset.x.max(0.0) as usize).min(self.columns - 1);
        let row = (offset.y.max(0.0) as usize).min(self.rows - 1);
        row * self.columns + column
    }

    /// Distance from `point` to the nearest line, to the map's resolution (a cell's centre value, so
    /// within `CELL_SIZE / √2` of the exact distance; points off the map read its edge).
    pub fn distance(&self, point: Point2<f64>) -> f64 {
        f64::from(self.distance_mm[self.cell(point)]) / 1000.0
    }

    /// The line primitive nearest `point` (per the map's cell).
    pub fn nearest(&self, point: Point2<f64>) -> &Primitive {
        &self.primitives[usize::from(self.nearest[self.cell(point)])]
    }

    /// Exact distance to, and gradient of, the nearest primitive (as the map associates it).
    pub fn residual(&self, point: Point2<f64>) -> (f64, Vector2<f64>) {
        self.nearest(point).residual(point)
    }
}

/// Every painted centre line of `field` as primitives: lines, circles, and both arms of every mark
/// (what [`LineMap::new`] builds its map of, without building it).
pub fn field_primitives(field: &FieldModel) -> Vec<Primitive> {
    let segments = field.lines.iter().map(|line| Primitive::Segment { start: line.start, end: line.end });
    let circles =
        field.circles.iter().map(|circle| Primitive::Circle { centre: circle.centre, radius: circle.radius });
    let arms = field.marks.iter().flat_map(|mark| {
        [Vector2::x(), Vector2::y()].map(|axis| Primitive::Segment {
            start: mark.centre - axis * (mark.size / 2.0),
            end: mark.centre + axis * (mark.size / 2.0),
        })
    });
    segments.chain(circles).chain(arms).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;

    #[test]
    fn map_agrees_with_the_field_model() {
        let field = FieldModel::default();
        let map = LineMap::new(&field);
        for (x, y) in [(0.0, 0.0), (1.23, 0.5), (-4.4, 2.9), (3.7, -1.1), (-0.3, 0.71), (5.5, 3.9)] {
            let point = Point2::new(x, y);
            let exact = field.distance_to_nearest_line(point);
            assert_abs_diff_eq!(map.distance(point), exact, epsilon = CELL_SIZE);
            assert_abs_diff_eq!(map.residual(point).0, exact, epsilon = CELL_SIZE);
        }
        // Off the map, the edge cell's line still gives the exact distance.
        assert_abs_diff_eq!(map.residual(Point2::new(-7.0, 0.0)).0, 2.5, epsilon = 1e-12);
    }

    #[test]
    fn gradient_points_away_from_the_line() {
        let segment = Primitive::Segment { start: Point2::new(0.0, 0.0), end: Point2::new(2.0, 0.0) };
        let (distance, gradient) = segment.residual(Point2::new(1.0, -0.3));
        assert_abs_diff_eq!(distance, 0.3, epsilon = 1e-12);
        assert_abs_diff_eq!(gradient, Vector2::new(0.0, -1.0), epsilon = 1e-12);
        let circle = Primitive::Circle { centre: Point2::origin(), radius: 0.75 };
        let (distance, gradient) = circle.residual(Point2::new(0.0, 0.5));
        assert_abs_diff_eq!(distance, 0.25, epsilon = 1e-12);
        assert_abs_diff_eq!(gradient, Vector2::new(0.0, -1.0), epsilon = 1e-12);
    }

    #[test]
    fn samples_cover_the_primitive() {
        let segment = Primitive::Segment { start: Point2::new(0.0, 0.0), end: Point2::new(1.0, 0.0) };
        let samples = segment.samples(0.1);
        assert_eq!(samples.len(), 11);
        assert_abs_diff_eq!(samples[10], Point2::new(1.0, 0.0), epsilon = 1e-12);
        let circle = Primitive::Circle { centre: Point2::origin(), radius: 0.75 };
        assert!(circle.samples(0.1).iter().all(|p| (p.coords.norm() - 0.75).abs() < 1e-12));
    }
}
