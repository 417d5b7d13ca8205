//! The frame's own carpet colour, learnt from a sparse grid of its pixels.
//!
//! Carpet is told by its hue and saturation, not its brightness: the chroma of a surface scales with
//! the light on it, so the carpet in a sun patch, in a robot's shadow and in a backlit frame keeps its
//! direction in the U/V plane and its chroma per luma. The hue is learnt where the carpet is most
//! likely, near the bottom of the image, so a greenish wall above the field does not decide it.

use crate::frame::yuv_to_rgb_f32;

/// Pixels between the samples used to learn the frame's colours.
const STATISTICS_STEP: usize = 8;
/// Hue histogram bins over the full circle.
const HUE_BINS: usize = 72;
/// Least share of the sampled pixels that must be carpet for the frame to have a carpet at all.
const MIN_CARPET_SHARE: f64 = 0.03;
/// Samples darker than this carry no usable chroma.
const MIN_LUMA: f32 = 8.0;
/// Largest angle between a carpet pixel's chroma and the carpet's hue, radians (about 29°). On the
/// masked real images at most 3% of the carpet's pixels lie further off (the widest spread, 00133's
/// sun and shade), while robots' shells, lit green by the carpet, lie 8–32° off (median by image).
const HUE_TOLERANCE: f32 = 0.5;
/// Largest angle between the histogram's peak and the samples that learn the carpet's hue and
/// saturation, radians.
const LEARNING_HUE_SPREAD: f32 = 0.3;
/// A carpet pixel keeps at least this share of the carpet's chroma per luma.
const GREEN_SATURATION_SHARE: f32 = 0.5;
/// A carpet pixel has at most this many times the carpet's chroma per luma (a robot's green jersey
/// or a painted board has more).
const MAX_GREEN_SATURATION: f32 = 2.0;
/// A line pixel has at most this share of the carpet's chroma per luma (plus sensor noise).
const WHITE_SATURATION_SHARE: f32 = 0.6;
/// Paint seen without its neighbourhood is at least this share brighter than the carpet's median luma
/// (see [`brighter_by`]).
const PAINT_LUMA_SHARE: f32 = 0.3;
/// Of the levels left above a carpet before the sensor's white, the most a brightness share may ask
/// for: on an overexposed carpet the paint saturates too, and the step it can show shrinks.
const HEADROOM_SHARE: f32 = 0.5;
/// The brightest luma the camera records, 8-bit levels.
const SENSOR_WHITE: f32 = 255.0;
/// Chroma every pixel may show from sensor noise alone, 8-bit levels.
const CHROMA_NOISE: f32 = 5.0;

/// One pixel in full-range YUV.
pub(super) type Yuv = (f32, f32, f32);

/// What the frame's carpet looks like.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Palette {
    /// Unit chroma direction of the carpet, (U, V).
    hue: (f32, f32),
    /// The carpet's typical chroma magnitude per luma.
    saturation: f32,
    /// The carpet's median luma.
    green_luma: f32,
}

impl Palette {
    /// Whether a pixel is carpet: the carpet's hue, about its saturation, not black.
    pub(super) fn is_green(&self, (y, u, v): Yuv) -> bool {
        let (cu, cv) = (u - 128.0, v - 128.0);
        let along = cu * self.hue.0 + cv * self.hue.1;
        let magnitude_sq = cu * cu + cv * cv;
        let least = GREEN_SATURATION_SHARE * self.saturation * y;
        let most = MAX_GREEN_SATURATION * self.saturation * y;
        y >= MIN_LUMA
            && along > 0.0
            && along * along >= HUE_TOLERANCE.cos().powi(2) * magnitude_sq
            && magnitude_sq >= least * least
            && magnitude_sq <= most * most
    }

    /// Whether a pixel is grey enough to be white paint (in any light): little chroma for its luma.
    pub(super) fn is_unsaturated(&self, (y, u, v): Yuv) -> bool {
        let most = WHITE_SATURATION_SHARE * self.saturation * y + CHROMA_NOISE;
        (u - 128.0).powi(2) + (v - 128.0).powi(2) <= most * most
    }

    /// Whether a pixel could be white paint in the frame's light: grey and clearly brighter than the
    /// carpet's median (a grey robot or a wall in the same light is not).
    pub(super) fn looks_like_paint(&self, pixel: Yuv) -> bool {
        self.is_unsaturated(pixel) && pixel.0 >= brighter_by(self.green_luma, PAINT_LUMA_SHARE)
    }

    /// Learns the carpet from a sparse grid of `pixel(x, y)` over a `width` × `height` frame; `None`
    /// when no greenish hue covers enough of it. Also returns the share of the samples that are carpet.
    pub(super) fn learn(
        width: usize,
        height: usize,
        pixel: impl Fn(usize, usize) -> Yuv,
    ) -> Option<(Self, f64)> {
        let samples: Vec<(usize, Yuv)> = (STATISTICS_STEP / 2..height)
            .step_by(STATISTICS_STEP)
            .flat_map(|y| (STATISTICS_STEP / 2..width).step_by(STATISTICS_STEP).map(move |x| (x, y)))
            .map(|(x, y)| (y, pixel(x, y)))
            .collect();
        if samples.is_empty() {
            return None;
        }
        let hue_of = |(_, u, v): Yuv| (v - 128.0).atan2(u - 128.0);
        let bin_of = |hue: f32| {
            let turn = (hue / std::f32::consts::TAU).rem_euclid(1.0);
            ((turn * HUE_BINS as f32) as usize).min(HUE_BINS - 1)
        };
        // Greenish, with some chroma: the candidates, weighted towards the bottom of the image.
        let greenish: Vec<(usize, Yuv, f32)> = samples
            .iter()
            .filter(|&&(_, yuv)| is_greenish(yuv))
            .map(|&(row, yuv)| (row, yuv, hue_of(yuv)))
            .collect();
        let mut histogram = [0.0f32; HUE_BINS];
        for &(row, _, hue) in &greenish {
            let depth = row as f32 / height as f32;
            histogram[bin_of(hue)] += 1.0 + 4.0 * depth * depth;
        }
        let smoothed = |bin: usize| {
            histogram[(bin + HUE_BINS - 1) % HUE_BINS] + histogram[bin] + histogram[(bin + 1) % HUE_BINS]
        };
        let peak = (0..HUE_BINS).max_by(|&a, &b| smoothed(a).total_cmp(&smoothed(b)))?;
        let peak_hue = (peak as f32 + 0.5) / HUE_BINS as f32 * std::f32::consts::TAU;
        let members: Vec<Yuv> = greenish
            .iter()
            .filter(|&&(_, _, hue)| angle_between(hue, peak_hue) <= LEARNING_HUE_SPREAD)
            .map(|&(_, yuv, _)| yuv)
            .collect();
        if (members.len() as f64) < MIN_CARPET_SHARE * samples.len() as f64 {
            return None;
        }
        let (sum_u, sum_v) =
            members.iter().fold((0.0, 0.0), |(su, sv), &(_, u, v)| (su + (u - 128.0), sv + (v - 128.0)));
        let norm = sum_u.hypot(sum_v).max(f32::EPSILON);
        let mut saturations: Vec<f32> =
            members.iter().map(|&(y, u, v)| (u - 128.0).hypot(v - 128.0) / y).collect();
        saturations.sort_by(f32::total_cmp);
        let mut lumas: Vec<f32> = members.iter().map(|member| member.0).collect();
        lumas.sort_by(f32::total_cmp);
        let palette = Self {
            hue: (sum_u / norm, sum_v / norm),
            saturation: saturations[saturations.len() / 2],
            green_luma: lumas[lumas.len() / 2],
        };
        let carpet = samples.iter().filter(|&&(_, yuv)| palette.is_green(yuv)).count();
        Some((palette, carpet as f64 / samples.len() as f64))
    }
}

/// `luma` raised by `share` of itself, or by `HEADROOM_SHARE` of the levels left below the sensor's
/// white where that is less.
pub(super) fn brighter_by(luma: f32, share: f32) -> f32 {
    luma + (share * luma).min(HEADROOM_SHARE * (SENSOR_WHITE - luma))
}

/// Green above red and blue, bright enough and coloured enough to carry a hue.
fn is_greenish((y, u, v): Yuv) -> bool {
    let [r, g, b] = yuv_to_rgb_f32(128.0, u, v);
    y >= MIN_LUMA && g >= 0.9 * r.max(b) && (u - 128.0).hypot(v - 128.0) >= CHROMA_NOISE
}

/// The absolute difference of two angles, in [0, π].
fn angle_between(a: f32, b: f32) -> f32 {
    let difference = (a - b).rem_euclid(std::f32::consts::TAU);
    difference.min(std::f32::consts::TAU - difference)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::rgb_to_yuv;

    fn learn_rgb(pixel: impl Fn(usize, usize) -> [u8; 3]) -> Option<(Palette, f64)> {
        Palette::learn(640, 480, |x, y| {
            let [r, g, b] = pixel(x, y);
            rgb_to_yuv(r, g, b)
        })
    }

    #[test]
    fn carpet_in_sun_and_shadow_is_carpet_and_paint_is_not() {
        let (palette, share) = learn_rgb(|_, _| [60, 130, 50]).unwrap();
        assert!(share > 0.99);
        let green = |rgb: [u8; 3]| palette.is_green(rgb_to_yuv(rgb[0], rgb[1], rgb[2]));
        let white = |rgb: [u8; 3]| palette.is_unsaturated(rgb_to_yuv(rgb[0], rgb[1], rgb[2]));
        assert!(green([120, 250, 100]), "sunlit carpet");
        assert!(green([15, 33, 12]), "carpet in deep shadow");
        assert!(!green([230, 235, 230]) && white([230, 235, 230]), "white paint");
        assert!(!green([40, 45, 40]) && white([40, 45, 40]), "paint in shadow");
        assert!(!green([120, 130, 120]), "a grey wall with a green tint");
        assert!(!green([200, 40, 30]) && !white([200, 40, 30]), "a red wall");
    }

    #[test]
    fn a_shell_lit_green_by_the_carpet_is_not_carpet() {
        // A pixel with the carpet's chroma per luma, its hue turned from the carpet's: carpet in sun
        // or shade drifts by up to ~20°; a robot's white shell lit by the carpet is ~30° off.
        let carpet = rgb_to_yuv(60, 130, 50);
        let (palette, _) = Palette::learn(640, 480, |_, _| carpet).unwrap();
        let turned = |degrees: f32| {
            let (sin, cos) = degrees.to_radians().sin_cos();
            let (u, v) = (carpet.1 - 128.0, carpet.2 - 128.0);
            (carpet.0, 128.0 + u * cos - v * sin, 128.0 + u * sin + v * cos)
        };
        for degrees in [-20.0, 20.0] {
            assert!(palette.is_green(turned(degrees)), "{degrees}°");
        }
        for degrees in [-31.0, 31.0] {
            assert!(!palette.is_green(turned(degrees)), "{degrees}°");
        }
    }

    #[test]
    fn the_bottom_of_the_image_decides_the_carpet() {
        // A larger greenish-grey wall above a smaller carpet: the carpet's hue wins.
        let (palette, _) = learn_rgb(|_, y| if y < 300 { [90, 120, 110] } else { [60, 130, 50] }).unwrap();
        assert!(palette.is_green(rgb_to_yuv(60, 130, 50)));
        assert!(!palette.is_green(rgb_to_yuv(90, 120, 110)));
    }

    #[test]
    fn a_frame_without_green_has_no_carpet() {
        assert!(learn_rgb(|x, _| if x < 320 { [200, 40, 30] } else { [30, 30, 30] }).is_none());
        assert!(learn_rgb(|_, _| [0, 0, 0]).is_none());
    }
}
