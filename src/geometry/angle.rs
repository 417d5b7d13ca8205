//! Angle helpers.

use std::f64::consts::{PI, TAU};

/// Wraps an angle in radians into (−π, π].
///
/// Non-finite input is returned unchanged so that callers can reject it with a clear error.
pub fn normalize_angle(angle: f64) -> f64 {
    if !angle.is_finite() {
        return angle;
    }
    let wrapped = angle.rem_euclid(TAU); // [0, 2π)
    if wrapped > PI { wrapped - TAU } else { wrapped }
}

/// Absolute difference of two angles, in [0, π].
pub fn angle_distance(a: f64, b: f64) -> f64 {
    normalize_angle(a - b).abs()
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;
    use proptest::prelude::*;

    #[test]
    fn wraps_into_half_open_interval() {
        assert_abs_diff_eq!(normalize_angle(PI), PI);
        assert_abs_diff_eq!(normalize_angle(-PI), PI);
        assert_abs_diff_eq!(normalize_angle(3.0 * PI), PI, epsilon = 1e-12);
        assert_abs_diff_eq!(normalize_angle(-0.5), -0.5);
        assert_abs_diff_eq!(normalize_angle(TAU + 0.25), 0.25, epsilon = 1e-12);
    }

    #[test]
    fn distance_goes_the_short_way_round() {
        assert_abs_diff_eq!(angle_distance(PI - 0.1, -PI + 0.1), 0.2, epsilon = 1e-12);
        assert_abs_diff_eq!(angle_distance(0.3, -0.3), 0.6, epsilon = 1e-12);
    }

    proptest! {
        #[test]
        fn normalized_angles_stay_in_range(angle in -100.0f64..100.0) {
            let wrapped = normalize_angle(angle);
            prop_assert!(wrapped > -PI && wrapped <= PI);
            prop_assert!(angle_distance(wrapped, angle) < 1e-9);
        }
    }
}
