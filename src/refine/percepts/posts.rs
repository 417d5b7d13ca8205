//! Goal posts in image space: upright bright bars that stand on the carpet and rise above the field's
//! border.
//!
//! Each row (every [`ROW_STEP`]-th) is searched for bars: an edge, another within a post's widest
//! width, and between them grey paint that stands out from both sides, by a share of their brightness
//! or, where they are about as bright, by their colour (a post in front of a grey net or a pastel
//! wall is still seen; a white board it stands against hides it). Bars of neighbouring rows whose centres and widths agree are chained; a chain is a post when it
//! is tall for its width, upright (the camera's roll leans it a little), reaches down to the carpet
//! and rises above the field's border: a field line, even one running away from the camera, lies
//! below the border, and what floats above the field (a window frame, a shirt) does not reach it.

use nalgebra::Point2;

use super::Pixels;
use super::palette::{Palette, Yuv};

/// Rows between the rows searched for bars.
const ROW_STEP: usize = 4;
/// Pixels beyond an edge at which a bar's sides are read (past the edge's blur).
const SIDE_OFFSET: usize = 3;
/// A post's inside is at least this share brighter than each side ...
const CONTRAST_SHARE: f32 = 0.15;
/// ... and at least this many 8-bit levels brighter.
const MIN_STEP: f32 = 16.0;
/// ... or about as bright and this many 8-bit levels of chroma away.
const CHROMA_STEP: f32 = 24.0;
/// Narrowest post, pixels.
const MIN_WIDTH: usize = 3;
/// Widest post as a share of the image width (a post a metre away in the Nao's top camera).
const MAX_WIDTH_SHARE: f64 = 0.12;
/// Most a chain's next bar may move sideways per row (the camera's roll), beyond a pixel of noise.
const MAX_LEAN: f64 = 0.15;
/// A chained bar's width lies within this factor of the previous one's (either way).
const WIDTH_FACTOR: f64 = 1.6;
/// Row steps from a chain's last bar within which its next bar may come: one searched row without
/// the bar (a seam, a blurred edge) does not end the chain.
const MAX_GAP_STEPS: usize = 2;
/// Least bars in a post.
const MIN_BARS: usize = 3;
/// A post is at least this many times as tall as it is wide where seen (a post 0.8 m tall and 0.1 m
/// wide, under its crossbar or cut by the top of the image; a robot is stouter).
const MIN_ASPECT: f64 = 4.5;
/// A post's foot lies at most this many scan spacings above the field's border at its column.
const FOOT_ABOVE_BORDER: f64 = 2.0;
/// A post rises above the field's border at least by its width and by this many pixels.
const MIN_RISE: f64 = 4.0;

/// A goal post seen in the image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PostSighting {
    /// Where it meets the ground (or the goal line under it): its centre column at the bottom of the
    /// bar, pixels.
    pub foot: Point2<f64>,
    /// The highest row it was seen at (the top of the image or of the post).
    pub top: f64,
    /// Its width at the foot, pixels.
    pub width: f64,
}

/// One bar on one row: from its first to past its last bright pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Bar {
    row: usize,
    start: usize,
    end: usize,
}

impl Bar {
    fn centre(&self) -> f64 {
        (self.start + self.end) as f64 / 2.0
    }

    fn width(&self) -> f64 {
        (self.end - self.start) as f64
    }
}

/// The goal posts of a `width` × `height` frame whose carpet is `palette`; `border(u)` is the field's
/// border (the carpet's top) at column `u`, known to a scan spacing of `scan_spacing` pixels.
pub(super) fn find(
    pixels: &Pixels,
    palette: &Palette,
    (width, height): (usize, usize),
    scan_spacing: usize,
    border: impl Fn(f64) -> f64,
) -> Vec<PostSighting> {
    let max_width = ((MAX_WIDTH_SHARE * width as f64) as usize).max(MIN_WIDTH);
    let mut line: Vec<Yuv> = Vec::with_capacity(width);
    let mut open: Vec<Vec<Bar>> = Vec::new();
    let mut chains: Vec<Vec<Bar>> = Vec::new();
    for row in (0..height).step_by(ROW_STEP) {
        pixels.row(row, &mut line);
        let bars = bars_on(&line, palette, max_width, row);
        let mut extended = vec![false; open.len()];
        for bar in bars {
            let continued = open.iter().position(|chain| continues(chain, &bar));
            match continued {
                Some(index) if !extended[index] => {
                    open[index].push(bar);
                    extended[index] = true;
                }
                _ => {
                    open.push(vec![bar]);
                    extended.push(true);
                }
            }
        }
        let (alive, ended): (Vec<_>, Vec<_>) =
            open.into_iter().partition(|chain| row - chain[chain.len() - 1].row <= MAX_GAP_STEPS * ROW_STEP);
        chains.extend(ended);
        open = alive;
    }
    chains.extend(open);
    chains.iter().filter_map(|chain| post_of(chain, scan_spacing as f64, &border)).collect()
}

/// Whether `bar` continues `chain` upright: the next rows down, about the same centre and width.
fn continues(chain: &[Bar], bar: &Bar) -> bool {
    let last = chain[chain.len() - 1];
    let rows = (bar.row - last.row) as f64;
    let ratio = bar.width() / last.width();
    bar.row > last.row
        && (bar.centre() - last.centre()).abs() <= 1.0 + MAX_LEAN * rows
        && (1.0 / WIDTH_FACTOR..=WIDTH_FACTOR).contains(&ratio)
}

/// The post a chain of bars shows, if it is one.
fn post_of(chain: &[Bar], scan_spacing: f64, border: &impl Fn(f64) -> f64) -> Option<PostSighting> {
    let (first, last) = (chain[0], chain[chain.len() - 1]);
    let mut widths: Vec<f64> = chain.iter().map(Bar::width).collect();
    widths.sort_by(f64::total_cmp);
    let width = widths[widths.len() / 2];
    let (top, bottom) = (first.row as f64, (last.row + 1) as f64);
    let tall = bottom - top >= MIN_ASPECT * width;
    let upright = (last.centre() - first.centre()).abs() <= 1.0 + MAX_LEAN * (bottom - top);
    let stands = bottom >= border(last.centre()) - FOOT_ABOVE_BORDER * scan_spacing;
    let rises = top <= border(first.centre()) - width.max(MIN_RISE);
    (chain.len() >= MIN_BARS && tall && upright && stands && rises).then_some(PostSighting {
        foot: Point2::new(last.centre(), bottom),
        top,
        width: last.width(),
    })
}

/// The bars on one row of pixels (`line`, at `row`): an edge, then another at most `max_width`
/// later, grey paint between them that stands out from both sides and is nowhere darker than half way
/// to them (a blurred edge pixel may be either).
fn bars_on(line: &[Yuv], palette: &Palette, max_width: usize, row: usize) -> Vec<Bar> {
    let mut bars = Vec::new();
    let mut start = SIDE_OFFSET + 1;
    while start + SIDE_OFFSET + 1 < line.len() {
        let bar = stands_out(line[start], line[start - SIDE_OFFSET])
            .then(|| {
                let last = (start + max_width + 1).min(line.len() - SIDE_OFFSET - 1);
                (start + 1..last).find(|&end| stands_out(line[end - 1], line[end - 1 + SIDE_OFFSET]))
            })
            .flatten()
            .filter(|&end| is_bar(&line[start - SIDE_OFFSET - 1..end + SIDE_OFFSET + 1], palette));
        match bar {
            Some(end) => {
                bars.push(Bar { row, start, end });
                start = end;
            }
            None => start += 1,
        }
    }
    bars
}

/// Whether a pixel of paint stands out from one beside it: clearly brighter, or about as bright and
/// clearly coloured where the paint is grey (a white post before a pastel wall).
fn stands_out(paint: Yuv, side: Yuv) -> bool {
    let brighter = paint.0 >= (side.0 * (1.0 + CONTRAST_SHARE)).max(side.0 + MIN_STEP);
    let (du, dv) = (paint.1 - side.1, paint.2 - side.2);
    brighter || (paint.0 + MIN_STEP >= side.0 && du * du + dv * dv >= CHROMA_STEP * CHROMA_STEP)
}

/// Whether `pixels`, a bar with [`SIDE_OFFSET`] + 1 pixels of its surroundings on either side, is
/// grey paint standing out from the outermost pixel of each side (an edge's blur is not its side).
fn is_bar(pixels: &[Yuv], palette: &Palette) -> bool {
    let reach = SIDE_OFFSET + 1;
    let inside = &pixels[reach..pixels.len() - reach];
    if inside.len() < MIN_WIDTH {
        return false;
    }
    let (left, right) = (pixels[0], pixels[pixels.len() - 1]);
    let mut sorted = inside.to_vec();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let middle = sorted[sorted.len() / 2];
    let side = left.0.max(right.0).min(middle.0);
    stands_out(middle, left)
        && stands_out(middle, right)
        && sorted[0].0 >= (middle.0 + side) / 2.0
        && inside.iter().all(|&pixel| palette.is_unsaturated(pixel))
        && palette.looks_like_paint(middle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Frame;
    use crate::refine::detect_in_image;
    use image::{Rgb, RgbImage};

    const CARPET: [u8; 3] = [60, 130, 50];
    const PAINT: [u8; 3] = [230, 232, 230];
    const HALL: [u8; 3] = [40, 40, 45];

    /// A 640×480 frame: carpet below row 200, the hall above it, and `paint(x, y)` white.
    fn frame(paint: impl Fn(u32, u32) -> bool) -> Frame {
        Frame::Rgb(RgbImage::from_fn(640, 480, |x, y| {
            Rgb(if paint(x, y) {
                PAINT
            } else if y >= 200 {
                CARPET
            } else {
                HALL
            })
        }))
    }

    fn posts_of(frame: &Frame) -> Vec<PostSighting> {
        detect_in_image(frame).unwrap().goal_posts(frame)
    }

    #[test]
    fn a_post_standing_on_the_carpet_is_found_at_its_foot() {
        // A post 12 px wide from row 60 down to row 230, its foot 30 px below the field's border.
        let frame = frame(|x, y| (300..312).contains(&x) && (60..230).contains(&y));
        let posts = posts_of(&frame);
        assert_eq!(posts.len(), 1, "{posts:?}");
        let post = posts[0];
        assert!((post.foot.x - 306.0).abs() <= 1.0, "{post:?}");
        assert!((post.foot.y - 230.0).abs() <= 2.0, "{post:?}");
        assert!((post.width - 12.0).abs() <= 2.0 && post.top <= 62.0, "{post:?}");
    }

    #[test]
    fn a_post_before_a_grey_net_is_found_and_a_white_board_hides_it() {
        let net = |x: u32, y: u32| (312..400).contains(&x) && (60..200).contains(&y);
        let in_front_of_net = Frame::Rgb(RgbImage::from_fn(640, 480, |x, y| {
            let post = (300..312).contains(&x) && (60..230).contains(&y);
            Rgb(if post {
                PAINT
            } else if net(x, y) {
                [160, 160, 165]
            } else if y >= 200 {
                CARPET
            } else {
                HALL
            })
        }));
        assert_eq!(posts_of(&in_front_of_net).len(), 1);
        let board =
            frame(|x, y| ((300..312).contains(&x) && (60..230).contains(&y)) || (60..200).contains(&y));
        assert!(posts_of(&board).is_empty());
    }

    #[test]
    fn lines_robots_and_what_floats_above_the_field_are_not_posts() {
        // A steep field line running up to just below the border.
        let line = frame(|x, y| y >= 215 && (x as f64 - 320.0 - 0.05 * (y as f64 - 215.0)).abs() < 5.0);
        assert!(posts_of(&line).is_empty(), "a line");
        // A stout white robot on the carpet, rising above the border.
        let robot = frame(|x, y| (300..340).contains(&x) && (150..260).contains(&y));
        assert!(posts_of(&robot).is_empty(), "a robot");
        // A white pole in the hall that ends well above the field.
        let pole = frame(|x, y| (300..310).contains(&x) && (20..150).contains(&y));
        assert!(posts_of(&pole).is_empty(), "a pole above the field");
        // A frame with no carpet has no posts.
        let hall = Frame::Rgb(RgbImage::from_fn(640, 480, |x, _| {
            Rgb(if (300..310).contains(&x) { PAINT } else { HALL })
        }));
        assert!(posts_of(&hall).is_empty(), "no carpet");
    }
}
