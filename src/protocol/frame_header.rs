//! Forwarded frames: a team process that already streams the top camera sends each frame to relocd's
//! Unix stream socket as a fixed 48-byte little-endian header followed by the YUYV bytes.
//!
//! ```text
//! offset size  field
//!  0      4    magic "RLF1"
//!  4      2    version (1), u16
//!  6      2    format (1 = YUYV 4:2:2), u16
//!  8      4    width, pixels, u32 (even)
//! 12      4    height, pixels, u32
//! 16      4    payload bytes that follow, u32 (= width × height × 2)
//! 20      4    flags, u32: bit 0 = the camera pose below is valid
//! 24      8    timestamp, seconds, f64 (any clock; Unix time preferred)
//! 32      4    camera height above ground, metres, f32
//! 36      4    camera pitch, radians, f32 (positive looks down)
//! 40      4    camera roll, radians, f32
//! 44      4    head yaw, radians, f32 (positive turns left)
//! ```
//! It is the C struct in `docs/protocol.md`, with no padding.

use thiserror::Error;

use crate::geometry::CameraPose;

/// Size of the header.
pub const HEADER_SIZE: usize = 48;
/// First four bytes of every header.
pub const MAGIC: [u8; 4] = *b"RLF1";
/// The header version this relocd reads.
pub const VERSION: u16 = 1;
/// The only pixel format: YUYV 4:2:2, as the Nao cameras deliver it.
pub const FORMAT_YUYV: u16 = 1;
/// Largest frame accepted (the Nao camera's 1280×960 mode).
pub const MAX_PIXELS: u64 = 1280 * 960;

const FLAG_CAMERA_POSE: u32 = 1;

/// Why a header is refused.
#[derive(Debug, Error, PartialEq)]
pub enum HeaderError {
    /// The magic is not "RLF1".
    #[error("forwarded frame header starts with {0:?}, expected \"RLF1\"")]
    Magic([u8; 4]),
    /// Another header version.
    #[error("forwarded frame header version {0}, this relocd reads version {VERSION}")]
    Version(u16),
    /// A framing field (format, size, payload length) out of range: the stream is out of step.
    #[error("forwarded frame header: {0}")]
    Invalid(String),
    /// The framing is sound but a content field (flags, timestamp, camera pose) is not: skip
    /// `payload` bytes and the stream is in step again.
    #[error("forwarded frame header: {reason}")]
    Content {
        /// Bytes of the frame that follow.
        payload: usize,
        /// What is wrong.
        reason: String,
    },
}

impl HeaderError {
    /// Bytes to skip to stay in step, or `None` when the stream cannot be trusted any more.
    pub fn skippable_payload(&self) -> Option<usize> {
        match self {
            Self::Content { payload, .. } => Some(*payload),
            _ => None,
        }
    }
}

/// A decoded, checked header.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameHeader {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// When the frame was taken, seconds.
    pub timestamp: f64,
    /// The camera's pose on the robot, when the sender knows it.
    pub camera: Option<CameraPose>,
}

impl FrameHeader {
    /// Bytes of YUYV data after the header.
    pub fn payload_size(&self) -> usize {
        self.width as usize * self.height as usize * 2
    }

    /// Decodes and checks a header.
    pub fn parse(bytes: &[u8; HEADER_SIZE]) -> Result<Self, HeaderError> {
        let u16_at = |at: usize| u16::from_le_bytes([bytes[at], bytes[at + 1]]);
        let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
        let f32_at = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
        let invalid = |reason: String| Err(HeaderError::Invalid(reason));

        let magic: [u8; 4] = bytes[..4].try_into().expect("4 bytes");
        if magic != MAGIC {
            return Err(HeaderError::Magic(magic));
        }
        if u16_at(4) != VERSION {
            return Err(HeaderError::Version(u16_at(4)));
        }
        if u16_at(6) != FORMAT_YUYV {
            return invalid(format!("format {} is unknown, expected {FORMAT_YUYV} (YUYV)", u16_at(6)));
        }
        let (width, height, payload) = (u32_at(8), u32_at(12), u32_at(16));
        let pixels = u64::from(width) * u64::from(height);
        if width == 0 || height == 0 || width % 2 != 0 || pixels > MAX_PIXELS {
            return invalid(format!(
                "size {width}×{height} is not an even width and at most {MAX_PIXELS} pixels"
            ));
        }
        if u64::from(payload) != pixels * 2 {
            return invalid(format!(
                "payload of {payload} bytes does not fit {width}×{height} YUYV ({} bytes)",
                pixels * 2
            ));
        }
        let content = |reason: String| HeaderError::Content { payload: payload as usize, reason };
        let flags = u32_at(20);
        if flags & !FLAG_CAMERA_POSE != 0 {
            return Err(content(format!("unknown flags {flags:#x}")));
        }
        let timestamp = f64::from_le_bytes(bytes[24..32].try_into().expect("8 bytes"));
        if !timestamp.is_finite() {
            return Err(content(format!("timestamp {timestamp} is not finite")));
        }
        let camera = if flags & FLAG_CAMERA_POSE != 0 {
            let [height, pitch, roll, yaw] = [32, 36, 40, 44].map(|at| f64::from(f32_at(at)));
            Some(
                CameraPose::new(height, pitch, roll, yaw)
                    .map_err(|error| content(format!("camera pose: {error}")))?,
            )
        } else {
            None
        };
        Ok(Self { width, height, timestamp, camera })
    }

    /// Encodes the header, as a sender does.
    pub fn to_bytes(&self) -> [u8; HEADER_SIZE] {
        let mut bytes = [0u8; HEADER_SIZE];
        bytes[..4].copy_from_slice(&MAGIC);
        bytes[4..6].copy_from_slice(&VERSION.to_le_bytes());
        bytes[6..8].copy_from_slice(&FORMAT_YUYV.to_le_bytes());
        bytes[8..12].copy_from_slice(&self.width.to_le_bytes());
        bytes[12..16].copy_from_slice(&self.height.to_le_bytes());
        bytes[16..20].copy_from_slice(&(self.payload_size() as u32).to_le_bytes());
        bytes[24..32].copy_from_slice(&self.timestamp.to_le_bytes());
        if let Some(camera) = &self.camera {
            bytes[20..24].copy_from_slice(&FLAG_CAMERA_POSE.to_le_bytes());
            let values = [camera.height(), camera.pitch(), camera.roll(), camera.head_yaw()];
            for (at, value) in [32, 36, 40, 44].into_iter().zip(values) {
                bytes[at..at + 4].copy_from_slice(&(value as f32).to_le_bytes());
            }
        }
        bytes
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    fn header() -> FrameHeader {
        FrameHeader {
            width: 640,
            height: 480,
            timestamp: 1_763_900_000.5,
            camera: Some(CameraPose::new(0.5, 0.25, 0.0, -0.5).unwrap()),
        }
    }

    #[test]
    fn headers_round_trip_with_and_without_a_camera_pose() {
        let parsed = FrameHeader::parse(&header().to_bytes()).unwrap();
        assert_eq!((parsed.width, parsed.height, parsed.timestamp), (640, 480, 1_763_900_000.5));
        let camera = parsed.camera.unwrap();
        assert!((camera.head_yaw() + 0.5).abs() < 1e-6 && (camera.height() - 0.5).abs() < 1e-6);
        assert_eq!(parsed.payload_size(), 640 * 480 * 2);
        let bare = FrameHeader { camera: None, ..header() };
        assert_eq!(FrameHeader::parse(&bare.to_bytes()).unwrap(), bare);
    }

    #[test]
    fn broken_headers_name_the_field() {
        let patch = |at: usize, value: &[u8]| {
            let mut bytes = header().to_bytes();
            bytes[at..at + value.len()].copy_from_slice(value);
            FrameHeader::parse(&bytes).unwrap_err().to_string()
        };
        assert!(patch(0, b"RLF2").contains("RLF1"));
        assert!(patch(4, &2u16.to_le_bytes()).contains("version 2"));
        assert!(patch(6, &7u16.to_le_bytes()).contains("format 7"));
        assert!(patch(8, &641u32.to_le_bytes()).contains("size 641×480"));
        assert!(patch(8, &4000u32.to_le_bytes()).contains("at most"));
        assert!(patch(16, &100u32.to_le_bytes()).contains("payload of 100 bytes"));
        assert!(patch(20, &6u32.to_le_bytes()).contains("flags"));
        assert!(patch(24, &f64::NAN.to_le_bytes()).contains("timestamp"));
        assert!(patch(32, &(-1f32).to_le_bytes()).contains("camera pose"));

        let mut bytes = header().to_bytes();
        bytes[36..40].copy_from_slice(&3.0f32.to_le_bytes());
        let skip = FrameHeader::parse(&bytes).unwrap_err().skippable_payload();
        assert_eq!(skip, Some(640 * 480 * 2), "a bad pitch drops the frame, not the connection");
        bytes[0] = b'X';
        assert_eq!(FrameHeader::parse(&bytes).unwrap_err().skippable_payload(), None);
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::array::uniform32(any::<u8>()), tail in proptest::array::uniform16(any::<u8>())) {
            let mut header = [0u8; HEADER_SIZE];
            header[..32].copy_from_slice(&bytes);
            header[32..].copy_from_slice(&tail);
            if let Ok(parsed) = FrameHeader::parse(&header) {
                prop_assert_eq!(parsed.payload_size() as u64, u64::from(parsed.width) * u64::from(parsed.height) * 2);
            }
        }
    }
}
