//! Colour helpers: linear RGB ↔ sRGB, colour temperature, HSV.

/// Linear RGB, each channel nominally in [0, 1] (brighter values clip at the sensor).
pub type Linear = [f64; 3];

/// sRGB-encoded value in [0, 1] → linear.
pub fn srgb_to_linear(value: f64) -> f64 {
    if value <= 0.04045 { value / 12.92 } else { ((value + 0.055) / 1.055).powf(2.4) }
}

/// Linear value → sRGB-encoded value in [0, 1] (clipped).
pub fn linear_to_srgb(value: f64) -> f64 {
    let value = value.clamp(0.0, 1.0);
    if value <= 0.003_130_8 { value * 12.92 } else { 1.055 * value.powf(1.0 / 2.4) - 0.055 }
}

/// An sRGB colour given by hue (degrees), saturation and value, as linear RGB.
pub fn hsv_to_linear(hue: f64, saturation: f64, value: f64) -> Linear {
    let sector = hue.rem_euclid(360.0) / 60.0;
    let chroma = value * saturation;
    let second = chroma * (1.0 - (sector % 2.0 - 1.0).abs());
    let (r, g, b) = match sector as u32 {
        0 => (chroma, second, 0.0),
        1 => (second, chroma, 0.0),
        2 => (0.0, chroma, second),
        3 => (0.0, second, chroma),
        4 => (second, 0.0, chroma),
        _ => (chroma, 0.0, second),
    };
    let offset = value - chroma;
    [r + offset, g + offset, b + offset].map(srgb_to_linear)
}

/// Relative linear RGB of a black body at `kelvin` (Tanner Helland's fit), normalised so the
/// brightest channel is 1.
pub fn colour_temperature(kelvin: f64) -> Linear {
    let t = kelvin.clamp(1000.0, 40000.0) / 100.0;
    let red = if t <= 66.0 { 255.0 } else { 329.698_727_446 * (t - 60.0).powf(-0.133_204_759_2) };
    let green = if t <= 66.0 {
        99.470_802_586_1 * t.ln() - 161.119_568_166_1
    } else {
        288.122_169_528_3 * (t - 60.0).powf(-0.075_514_849_2)
    };
    let blue = if t >= 66.0 {
        255.0
    } else if t <= 19.0 {
        0.0
    } else {
        138.517_731_223_1 * (t - 10.0).ln() - 305.044_792_730_7
    };
    let srgb = [red, green, blue].map(|channel| srgb_to_linear((channel / 255.0).clamp(0.0, 1.0)));
    let brightest = srgb.iter().cloned().fold(f64::MIN, f64::max);
    srgb.map(|channel| channel / brightest)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;

    #[test]
    fn srgb_round_trips() {
        for value in [0.0, 0.002, 0.2, 0.5, 1.0] {
            assert_abs_diff_eq!(linear_to_srgb(srgb_to_linear(value)), value, epsilon = 1e-12);
        }
    }

    #[test]
    fn warm_light_is_red_and_cold_light_is_blue() {
        let warm = colour_temperature(3000.0);
        let cold = colour_temperature(9000.0);
        assert!(warm[0] > warm[2] && cold[2] > cold[0]);
        let daylight = colour_temperature(6600.0);
        assert!(daylight.iter().all(|channel| *channel > 0.9));
    }

    #[test]
    fn hsv_green_is_green() {
        let green = hsv_to_linear(120.0, 0.8, 0.5);
        assert!(green[1] > green[0] && green[1] > green[2]);
        assert_abs_diff_eq!(hsv_to_linear(0.0, 0.0, 1.0)[0], 1.0, epsilon = 1e-12);
    }
}
