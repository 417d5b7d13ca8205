//! Crossings that line up: a painted line crosses neighbouring parallel scan lines at positions that
//! follow it, a speck of sunlit carpet texture or a bright blotch does not.
//!
//! A crossing is kept when it belongs to a straight piece of three: crossings on three neighbouring
//! scan lines of one family whose centres step along the scan by about the same amount (a line at a
//! slant, or a gently curved one, over two scan spacings); or when it lies next to an end of such a
//! piece (a corner, where the line's step turns); or, in the image, near a kept crossing of the other
//! family (a short line seen at a grazing angle where it meets a longer one).

/// Steepest step of a piece's centres between neighbouring scan lines, in scan spacings: a line
/// steeper than this is crossed more often by the other family of scan lines.
const MAX_SLOPE: f64 = 2.0;
/// Largest difference, in pixels, between a piece's two steps beyond what its crossings' widths allow
/// (a curved line, pixel rounding).
const STEP_TOLERANCE: f64 = 6.0;

/// A crossing on one scan line: which scan line (its index among its family's) and the crossing's
/// centre and width along it, pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Placed {
    pub(super) scan_line: usize,
    pub(super) centre: f64,
    pub(super) width: f64,
}

/// Which of `crossings` (one family of scan lines, `spacing` pixels apart) belong to a straight piece
/// of three.
pub(super) fn in_straight_pieces(crossings: &[Placed], spacing: f64) -> Vec<bool> {
    let mut by_line: Vec<Vec<usize>> = Vec::new();
    for (index, crossing) in crossings.iter().enumerate() {
        if by_line.len() <= crossing.scan_line {
            by_line.resize(crossing.scan_line + 1, Vec::new());
        }
        by_line[crossing.scan_line].push(index);
    }
    let reach = MAX_SLOPE * spacing;
    let on_line = |line: Option<usize>| -> &[usize] {
        line.and_then(|line| by_line.get(line)).map_or(&[], Vec::as_slice)
    };
    let mut kept = vec![false; crossings.len()];
    for (middle, crossing) in crossings.iter().enumerate() {
        let before = on_line(crossing.scan_line.checked_sub(1));
        let after = on_line(Some(crossing.scan_line + 1));
        for &first in before {
            let step_in = crossing.centre - crossings[first].centre;
            if step_in.abs() > reach + crossing.width.max(crossings[first].width) / 2.0 {
                continue;
            }
            for &last in after {
                let step_out = crossings[last].centre - crossing.centre;
                let widths = crossings[first].width.max(crossing.width).max(crossings[last].width);
                if (step_out - step_in).abs() <= STEP_TOLERANCE + widths / 2.0 {
                    kept[first] = true;
                    kept[middle] = true;
                    kept[last] = true;
                }
            }
        }
    }
    // A piece's ends reach one scan line further: the crossing at a corner or where the line leaves
    // the image, whose step turns with the line.
    let in_piece = kept.clone();
    for (index, crossing) in crossings.iter().enumerate() {
        let beside = [crossing.scan_line.checked_sub(1), Some(crossing.scan_line + 1)];
        kept[index] |= beside.into_iter().flat_map(on_line).any(|&neighbour| {
            in_piece[neighbour]
                && (crossings[neighbour].centre - crossing.centre).abs()
                    <= reach + crossing.width.max(crossings[neighbour].width) / 2.0
        });
    }
    kept
}

/// Which of `unkept` crossings (centres in the image, pixels) lie within about `reach` pixels of one of
/// the `kept` centres, in an image of `width` × `height` pixels.
pub(super) fn near_any(
    unkept: &[(f64, f64)],
    kept: &[(f64, f64)],
    reach: f64,
    (width, height): (u32, u32),
) -> Vec<bool> {
    let cell = reach.max(1.0);
    let columns = (f64::from(width) / cell).ceil() as usize + 1;
    let rows = (f64::from(height) / cell).ceil() as usize + 1;
    let cell_of = |(u, v): (f64, f64)| {
        ((u / cell).max(0.0) as usize).min(columns - 1)
            + columns * ((v / cell).max(0.0) as usize).min(rows - 1)
    };
    let mut occupied = vec![Vec::new(); columns * rows];
    for &centre in kept {
        occupied[cell_of(centre)].push(centre);
    }
    unkept
        .iter()
        .map(|&(u, v)| {
            let (column, row) = (cell_of((u, v)) % columns, cell_of((u, v)) / columns);
            (row.saturating_sub(1)..(row + 2).min(rows)).any(|row| {
                (column.saturating_sub(1)..(column + 2).min(columns)).any(|column| {
                    occupied[column + columns * row].iter().any(|&(ku, kv)| (ku - u).hypot(kv - v) <= reach)
                })
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn near_any_finds_kept_centres_within_reach_only() {
        let kept = [(100.0, 100.0), (630.0, 470.0)];
        let unkept = [(110.0, 105.0), (130.0, 100.0), (639.0, 479.0), (0.0, 0.0)];
        assert_eq!(near_any(&unkept, &kept, 16.0, (640, 480)), vec![true, false, true, false]);
    }

    fn placed(scan_line: usize, centre: f64) -> Placed {
        Placed { scan_line, centre, width: 4.0 }
    }

    #[test]
    fn a_slanted_line_is_kept_end_to_end() {
        let line: Vec<Placed> = (3..9).map(|i| placed(i, 100.0 + 9.0 * i as f64)).collect();
        assert!(in_straight_pieces(&line, 8.0).iter().all(|&kept| kept));
    }

    #[test]
    fn pairs_scattered_specks_and_zigzags_are_dropped() {
        let specks = [placed(2, 50.0), placed(3, 52.0), placed(5, 200.0), placed(6, 140.0), placed(7, 190.0)];
        assert_eq!(in_straight_pieces(&specks, 8.0), vec![false; 5]);
    }

    #[test]
    fn a_line_among_specks_keeps_only_the_line_and_its_corner() {
        let mut crossings = vec![placed(4, 300.0), placed(5, 310.0), placed(6, 320.0), placed(7, 312.0)];
        crossings.extend([placed(5, 100.0), placed(6, 40.0), placed(8, 340.0)]);
        assert_eq!(in_straight_pieces(&crossings, 8.0), vec![true, true, true, true, false, false, false]);
    }
}
