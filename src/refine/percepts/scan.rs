//! One scan line at a time: where the carpet ends, and where a painted line crosses it.
//!
//! A crossing is judged against the carpet right beside it, not against the frame: a line in a sun
//! patch, in a robot's shadow or in a backlit frame is brighter than its own neighbouring carpet by a
//! share of that carpet's brightness, whatever the rest of the frame does.

use super::palette::{Palette, Yuv, brighter_by};

/// Carpet pixels on each side of a crossing that give its local reference brightness.
const SIDE_PIXELS: usize = 6;
/// Least carpet pixels in a row on each side of a crossing (a lone greenish pixel is noise). Where
/// the carpet beside a crossing ends at another bright, grey run, it must also span the crossing's
/// width (up to `SIDE_PIXELS`): painted lines lie far apart, while sunlit bands between a window
/// frame's thin shadows are as narrow as the shadows between them.
const MIN_SIDE_PIXELS: usize = 2;
/// A line pixel is at least this share brighter than the carpet beside it (less near the sensor's
/// white, see [`brighter_by`])…
const MIN_CONTRAST_SHARE: f32 = 0.175;
/// …and at least this many 8-bit levels…
const MIN_CONTRAST: f32 = 10.0;
/// …and at least this many times the carpet's texture beside it (a sunlit blade is not paint).
const TEXTURE_CONTRAST: f32 = 3.0;
/// Non-line pixels allowed between a line's bright core and the carpet beside it (blurred edges), or
/// the core's width if that is more.
const EDGE_GAP: usize = 2;
/// Least share of a crossing's core pixels that are bright (a ball's black patches are not).
const MIN_BRIGHT_SHARE: f32 = 0.75;
/// Least carpet score (carpet pixels less others) of a column that has carpet at all.
const MIN_CARPET_SCORE: i64 = 4;

/// A line crossing one scan line: its bright core, [start, end) along the scan, and the brightness a
/// pixel needs to belong to it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Crossing {
    pub(super) start: usize,
    pub(super) end: usize,
    pub(super) threshold: f32,
}

impl Crossing {
    /// The middle of the core along the scan line, pixels.
    pub(super) fn middle(&self) -> f64 {
        (self.start + self.end) as f64 / 2.0
    }

    /// The core's width along the scan line, pixels.
    pub(super) fn width(&self) -> f64 {
        (self.end - self.start) as f64
    }
}

/// The crossings of one scan line of `pixels` (in order along it; `green` says which are carpet), each
/// at most `max_width` pixels wide, with carpet on both sides.
pub(super) fn crossings(
    pixels: &[Yuv],
    green: &[bool],
    palette: &Palette,
    max_width: usize,
) -> Vec<Crossing> {
    let mut found = Vec::new();
    let mut index = 0;
    while index < pixels.len() {
        if green[index] {
            index += 1;
            continue;
        }
        let start = index;
        while index < pixels.len() && !green[index] {
            index += 1;
        }
        let end = index;
        if start == 0 || end == pixels.len() || end - start > max_width + 2 * EDGE_GAP {
            continue;
        }
        let (Some(before), Some(after)) = (
            carpet_beside(pixels, green, palette, (start.saturating_sub(SIDE_PIXELS)..start).rev()),
            carpet_beside(pixels, green, palette, end..(end + SIDE_PIXELS).min(pixels.len())),
        ) else {
            continue;
        };
        let least = (end - start).min(SIDE_PIXELS);
        if [&before, &after].iter().any(|side| side.against_paint && side.pixels < least) {
            continue;
        }
        let reference = before.luma.max(after.luma);
        let texture = TEXTURE_CONTRAST * before.roughness.max(after.roughness);
        let threshold = threshold(reference).max(reference + texture);
        let bright = |pixel: Yuv| is_bright(pixel, threshold, palette);
        let Some(first) = (start..end).find(|&i| bright(pixels[i])) else { continue };
        let last = (start..end).rev().find(|&i| bright(pixels[i])).expect("a bright pixel exists");
        let core = first..last + 1;
        let bright_count = core.clone().filter(|&i| bright(pixels[i])).count();
        let ramp = EDGE_GAP.max(core.len());
        if first - start > ramp
            || end - 1 - last > ramp
            || core.len() > max_width
            || (bright_count as f32) < MIN_BRIGHT_SHARE * core.len() as f32
        {
            continue;
        }
        found.push(Crossing { start: core.start, end: core.end, threshold });
    }
    found
}

/// The brightness a line pixel reaches beside carpet of luma `carpet`.
pub(super) fn threshold(carpet: f32) -> f32 {
    brighter_by(carpet, MIN_CONTRAST_SHARE).max(carpet + MIN_CONTRAST)
}

/// Whether a pixel belongs to a line whose pixels must reach `threshold`: bright and grey.
pub(super) fn is_bright(pixel: Yuv, threshold: f32, palette: &Palette) -> bool {
    pixel.0 >= threshold && palette.is_unsaturated(pixel)
}

/// The carpet beside a crossing.
struct Side {
    /// Mean luma.
    luma: f32,
    /// Mean luma step between neighbouring pixels: the carpet's texture there.
    roughness: f32,
    /// How many carpet pixels in a row it has (at most `SIDE_PIXELS`).
    pixels: usize,
    /// Whether those end at a paint-like pixel (another bright, grey run) within `SIDE_PIXELS`.
    against_paint: bool,
}

/// The carpet pixels met first along `side` (up to `SIDE_PIXELS` of them, contiguous); `None` when
/// fewer than `MIN_SIDE_PIXELS` carpet pixels border the run there.
fn carpet_beside(
    pixels: &[Yuv],
    green: &[bool],
    palette: &Palette,
    side: impl Iterator<Item = usize>,
) -> Option<Side> {
    let (mut sum, mut steps, mut count, mut last) = (0.0, 0.0, 0usize, None);
    let mut against_paint = false;
    for index in side {
        if !green[index] {
            against_paint = palette.looks_like_paint(pixels[index]);
            break;
        }
        let luma = pixels[index].0;
        sum += luma;
        steps += last.map_or(0.0, |last: f32| (luma - last).abs());
        last = Some(luma);
        count += 1;
    }
    (count >= MIN_SIDE_PIXELS).then(|| Side {
        luma: sum / count as f32,
        roughness: steps / (count - 1).max(1) as f32,
        pixels: count,
        against_paint,
    })
}

/// The top of the carpet in one image column (`pixels` from top to bottom), as SPL teams find the
/// field boundary: walking up from the bottom, every carpet pixel scores one and every other pixel
/// loses one (paint-like pixels neither score nor lose); the carpet ends where the score peaks. A
/// line, a ball or a robot standing on the carpet costs less than the carpet above it brings back; a
/// wall, a crowd or a greenish hall above the field does not bring it back. `None` when the column
/// shows no carpet.
pub(super) fn carpet_top(pixels: &[Yuv], green: &[bool], palette: &Palette) -> Option<usize> {
    let (mut score, mut best, mut top) = (0i64, MIN_CARPET_SCORE - 1, None);
    for row in (0..green.len()).rev() {
        score += if green[row] {
            1
        } else if palette.looks_like_paint(pixels[row]) {
            0
        } else {
            -1
        };
        if score > best {
            best = score;
            top = Some(row);
        }
    }
    top
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::rgb_to_yuv;

    const CARPET: [u8; 3] = [60, 130, 50];
    const PAINT: [u8; 3] = [230, 235, 230];

    fn palette() -> Palette {
        palette_of(CARPET)
    }

    /// The palette learnt from a frame all of `carpet`.
    fn palette_of([r, g, b]: [u8; 3]) -> Palette {
        Palette::learn(64, 64, |_, _| rgb_to_yuv(r, g, b)).unwrap().0
    }

    fn line(colours: &[[u8; 3]]) -> (Vec<Yuv>, Vec<bool>) {
        line_on(&palette(), colours)
    }

    /// The pixels of `colours` and which of them are carpet under `palette`.
    fn line_on(palette: &Palette, colours: &[[u8; 3]]) -> (Vec<Yuv>, Vec<bool>) {
        let pixels: Vec<Yuv> = colours.iter().map(|c| rgb_to_yuv(c[0], c[1], c[2])).collect();
        let green = pixels.iter().map(|&p| palette.is_green(p)).collect();
        (pixels, green)
    }

    fn scaled(colour: [u8; 3], factor: f32) -> [u8; 3] {
        colour.map(|c| (c as f32 * factor).round().min(255.0) as u8)
    }

    #[test]
    fn a_line_is_found_against_its_own_carpet_in_sun_and_shadow() {
        for light in [0.25, 1.0, 1.6] {
            let mut colours = vec![scaled(CARPET, light); 20];
            colours[8..11].fill(scaled(PAINT, light * 0.7));
            let (pixels, green) = line(&colours);
            let found = crossings(&pixels, &green, &palette(), 10);
            assert_eq!(found.len(), 1, "light {light}");
            assert_eq!((found[0].start, found[0].end), (8, 11));
        }
    }

    #[test]
    fn a_line_is_found_on_an_overexposed_carpet() {
        // The carpet near the sensor's white: the paint clips at 255 and can show only ~35 levels more
        // than it, less than the share of the carpet's brightness asked for elsewhere; a pale carpet
        // speck still is no line.
        let carpet = [195, 238, 190];
        let palette = palette_of(carpet);
        for (paint, lines) in [([250, 255, 250], 1), ([205, 245, 203], 0)] {
            let mut colours = [carpet; 20];
            colours[8..11].fill(paint);
            let (pixels, green) = line_on(&palette, &colours);
            assert_eq!(crossings(&pixels, &green, &palette, 10).len(), lines, "{paint:?}");
        }
    }

    #[test]
    fn wide_dark_and_open_ended_runs_are_not_lines() {
        let palette = palette();
        let mut wide = vec![CARPET; 40];
        wide[5..30].fill(PAINT);
        let mut dark = vec![CARPET; 20];
        dark[8..11].fill([20, 20, 20]);
        let mut edge = vec![CARPET; 20];
        edge[15..].fill(PAINT);
        let mut ball = vec![CARPET; 20];
        ball[5..15].fill(PAINT);
        ball[8..12].fill([20, 20, 20]);
        for (name, colours) in [("wide", wide), ("dark", dark), ("open", edge), ("patched", ball)] {
            let (pixels, green) = line(&colours);
            assert!(crossings(&pixels, &green, &palette, 10).is_empty(), "{name}");
        }
    }

    #[test]
    fn sunlit_stripes_between_thin_shadows_are_not_lines() {
        // Carpet striped by a window frame's shadows: 8-pixel bright bands between 3-pixel strips of
        // shadowed carpet. A painted line of that width just below the field's border has as little
        // carpet above it, but against a wall, not against another bright band.
        let band = [scaled(PAINT, 0.9); 8];
        let mut stripes = vec![CARPET; 10];
        for _ in 0..3 {
            stripes.extend(band);
            stripes.extend([CARPET; 3]);
        }
        stripes.extend([CARPET; 7]);
        let mut below_the_border = vec![[40, 40, 45]; 10];
        below_the_border.extend([CARPET; 3]);
        below_the_border.extend(band);
        below_the_border.extend([CARPET; 10]);
        let palette = palette();
        let (pixels, green) = line(&stripes);
        assert!(crossings(&pixels, &green, &palette, 10).is_empty());
        let (pixels, green) = line(&below_the_border);
        assert_eq!(crossings(&pixels, &green, &palette, 10).len(), 1);
    }

    #[test]
    fn the_carpet_ends_below_the_wall_not_at_a_line() {
        // Top to bottom: a wall, carpet, a thick line, carpet, the robot's own feet.
        let mut colours = vec![[120, 130, 120]; 100];
        colours.extend(vec![CARPET; 200]);
        colours[180..230].fill(PAINT);
        colours.extend(vec![PAINT; 20]);
        let (pixels, green) = line(&colours);
        let palette = palette();
        assert_eq!(carpet_top(&pixels, &green, &palette), Some(100));
        assert_eq!(carpet_top(&pixels[..100], &green[..100], &palette), None);
    }
}
