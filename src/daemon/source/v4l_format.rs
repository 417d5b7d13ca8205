//! The pure half of V4L2 capture: which devices to try, how long to back off, whether the driver
//! agreed to the format relocd asked for, and how a driver buffer becomes a YUYV frame. Tested on
//! every build; the `v4l` feature adds the device I/O that uses it.

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::frame::YuyvImage;

/// The udev link of the Nao's top camera.
pub const TOP_CAMERA: &str = "/dev/video-top";
/// Tried when the top camera's link is missing (a system without the Nao's udev rules).
pub const FALLBACK_DEVICE: &str = "/dev/video0";
/// The only pixel format relocd takes.
pub const YUYV: [u8; 4] = *b"YUYV";

/// Devices to try, in order: the configured one, then the fallback when the configured one is the
/// top camera's default link.
pub fn candidate_devices(configured: &Path) -> Vec<PathBuf> {
    let mut devices = vec![configured.to_path_buf()];
    if configured == Path::new(TOP_CAMERA) {
        devices.push(PathBuf::from(FALLBACK_DEVICE));
    }
    devices
}

/// Wait before the `attempt`-th retry (from 0) to open a failing device: 100 ms doubling to 2 s.
pub fn backoff(attempt: u32) -> Duration {
    Duration::from_millis(100u64.saturating_mul(1 << attempt.min(5))).min(Duration::from_secs(2))
}

/// The format a driver settled on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Negotiated {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Pixel format code.
    pub fourcc: [u8; 4],
    /// Bytes per row (at least width × 2 for YUYV).
    pub stride: u32,
}

/// Checks that the driver gave the YUYV size asked for; drivers silently pick the nearest they have.
pub fn check_format(width: u32, height: u32, negotiated: &Negotiated) -> Result<(), String> {
    if negotiated.fourcc != YUYV {
        return Err(format!(
            "the driver offers {} instead of YUYV",
            String::from_utf8_lossy(&negotiated.fourcc).escape_debug()
        ));
    }
    if (negotiated.width, negotiated.height) != (width, height) {
        return Err(format!(
            "the driver offers {}×{} instead of {width}×{height} (set camera.width/height to a mode it has)",
            negotiated.width, negotiated.height
        ));
    }
    if negotiated.stride < width * 2 {
        return Err(format!(
            "the driver reports {} bytes per row, less than {}",
            negotiated.stride,
            width * 2
        ));
    }
    Ok(())
}

/// Copies a driver buffer (`used` bytes valid, rows `stride` bytes apart) into a packed frame.
pub fn frame_from_buffer(buffer: &[u8], used: usize, format: &Negotiated) -> Result<YuyvImage, String> {
    let (row, stride, rows) = (format.width as usize * 2, format.stride as usize, format.height as usize);
    let needed = stride * rows.saturating_sub(1) + row;
    let valid = &buffer[..used.min(buffer.len())];
    if valid.len() < needed {
        return Err(format!(
            "truncated frame: {} bytes, a {}×{} frame needs {needed}",
            valid.len(),
            format.width,
            format.height
        ));
    }
    let data = if stride == row {
        valid[..row * rows].to_vec()
    } else {
        valid.chunks(stride).take(rows).flat_map(|line| &line[..row]).copied().collect()
    };
    YuyvImage::new(format.width, format.height, data).map_err(|error| error.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    const VGA: Negotiated = Negotiated { width: 640, height: 480, fourcc: YUYV, stride: 1280 };

    #[test]
    fn the_top_camera_falls_back_to_video0_and_others_do_not() {
        assert_eq!(
            candidate_devices(Path::new(TOP_CAMERA)),
            [PathBuf::from(TOP_CAMERA), PathBuf::from(FALLBACK_DEVICE)]
        );
        assert_eq!(candidate_devices(Path::new("/dev/video-bottom")), [PathBuf::from("/dev/video-bottom")]);
    }

    #[test]
    fn backoff_doubles_up_to_two_seconds() {
        let waits: Vec<u64> = (0..8).map(|attempt| backoff(attempt).as_millis() as u64).collect();
        assert_eq!(waits, [100, 200, 400, 800, 1600, 2000, 2000, 2000]);
    }

    #[test]
    fn a_format_the_driver_changed_is_refused_with_the_reason() {
        assert!(check_format(640, 480, &VGA).is_ok());
        let mjpeg = Negotiated { fourcc: *b"MJPG", ..VGA };
        assert!(check_format(640, 480, &mjpeg).unwrap_err().contains("MJPG"));
        let smaller = Negotiated { width: 320, height: 240, stride: 640, ..VGA };
        assert!(check_format(640, 480, &smaller).unwrap_err().contains("320×240"));
        let short_rows = Negotiated { stride: 1000, ..VGA };
        assert!(check_format(640, 480, &short_rows).unwrap_err().contains("bytes per row"));
    }

    #[test]
    fn buffers_become_packed_frames_and_truncated_ones_are_errors() {
        let format = Negotiated { width: 4, height: 2, fourcc: YUYV, stride: 8 };
        let buffer: Vec<u8> = (0..16).collect();
        assert_eq!(frame_from_buffer(&buffer, 16, &format).unwrap().as_bytes(), &buffer[..]);

        let padded = Negotiated { stride: 12, ..format };
        let buffer: Vec<u8> = (0..24).collect();
        let frame = frame_from_buffer(&buffer, 20, &padded).unwrap();
        assert_eq!(frame.as_bytes(), [(0..8).collect::<Vec<u8>>(), (12..20).collect()].concat());

        assert!(frame_from_buffer(&buffer, 10, &format).unwrap_err().contains("truncated"));
    }
}
