//! Camera frames as relocd receives them: packed YUYV 4:2:2 (what the Nao camera streams) or RGB
//! (PNG/JPEG recordings), and the conversions between them.
//!
//! Colour conversion is BT.601 full range (JFIF), the V4L2 default for this kind of camera.

use image::RgbImage;
use thiserror::Error;

/// A frame buffer that does not match its declared size or format.
#[derive(Debug, Error, PartialEq)]
pub enum FrameError {
    /// Width or height is zero.
    #[error("frame size {width}x{height} is empty")]
    Empty {
        /// Declared width.
        width: u32,
        /// Declared height.
        height: u32,
    },
    /// YUYV packs two pixels per four bytes, so the width must be even.
    #[error("YUYV frame width {0} is odd: YUYV needs an even width")]
    OddWidth(u32),
    /// The buffer is shorter or longer than width × height × bytes per pixel.
    #[error("frame of {width}x{height} needs {expected} bytes, got {found} (truncated or wrong size?)")]
    WrongLength {
        /// Declared width.
        width: u32,
        /// Declared height.
        height: u32,
        /// Bytes the size implies.
        expected: usize,
        /// Bytes present.
        found: usize,
    },
}

/// A packed YUYV 4:2:2 image: per pixel pair the bytes Y0 U Y1 V.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct YuyvImage {
    width: u32,
    height: u32,
    data: Vec<u8>,
}

impl YuyvImage {
    /// Wraps a YUYV buffer after checking its size.
    pub fn new(width: u32, height: u32, data: Vec<u8>) -> Result<Self, FrameError> {
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        if width % 2 != 0 {
            return Err(FrameError::OddWidth(width));
        }
        let expected = width as usize * height as usize * 2;
        if data.len() != expected {
            return Err(FrameError::WrongLength { width, height, expected, found: data.len() });
        }
        Ok(Self { width, height, data })
    }

    /// Encodes an RGB image as the camera would: each horizontal pixel pair shares the mean of its
    /// two chroma samples. The image width must be even.
    pub fn from_rgb(image: &RgbImage) -> Result<Self, FrameError> {
        let (width, height) = image.dimensions();
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        if width % 2 != 0 {
            return Err(FrameError::OddWidth(width));
        }
        let mut data = Vec::with_capacity(width as usize * height as usize * 2);
        for pair in image.as_raw().chunks_exact(6) {
            let (y0, u0, v0) = rgb_to_yuv(pair[0], pair[1], pair[2]);
            let (y1, u1, v1) = rgb_to_yuv(pair[3], pair[4], pair[5]);
            data.extend_from_slice(&[
                clamp_u8(y0),
                clamp_u8((u0 + u1) / 2.0),
                clamp_u8(y1),
                clamp_u8((v0 + v1) / 2.0),
            ]);
        }
        Ok(Self { width, height, data })
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The packed bytes.
    pub fn as_bytes(&self) -> &[u8] {
        &self.data
    }

    /// Decodes to RGB.
    pub fn to_rgb(&self) -> RgbImage {
        let mut rgb = Vec::with_capacity(self.width as usize * self.height as usize * 3);
        for quad in self.data.chunks_exact(4) {
            let (u, v) = (quad[1] as f32, quad[3] as f32);
            for y in [quad[0], quad[2]] {
                rgb.extend_from_slice(&yuv_to_rgb(y as f32, u, v));
            }
        }
        RgbImage::from_raw(self.width, self.height, rgb).expect("buffer size matches the image")
    }
}

/// One frame, in whichever format it arrived.
#[derive(Clone, Debug, PartialEq)]
pub enum Frame {
    /// 8-bit RGB, e.g. from a PNG or JPEG recording.
    Rgb(RgbImage),
    /// Packed YUYV from the camera.
    Yuyv(YuyvImage),
}

impl Frame {
    /// (width, height) in pixels.
    pub fn dimensions(&self) -> (u32, u32) {
        match self {
            Frame::Rgb(image) => image.dimensions(),
            Frame::Yuyv(image) => (image.width, image.height),
        }
    }

    /// The frame as RGB (decoding YUYV).
    pub fn to_rgb(&self) -> RgbImage {
        match self {
            Frame::Rgb(image) => image.clone(),
            Frame::Yuyv(image) => image.to_rgb(),
        }
    }
}

/// BT.601 full-range RGB → YUV (U, V centred on 128), unclamped.
pub fn rgb_to_yuv(r: u8, g: u8, b: u8) -> (f32, f32, f32) {
    let (r, g, b) = (r as f32, g as f32, b as f32);
    let y = 0.299 * r + 0.587 * g + 0.114 * b;
    let u = 128.0 - 0.168_736 * r - 0.331_264 * g + 0.5 * b;
    let v = 128.0 + 0.5 * r - 0.418_688 * g - 0.081_312 * b;
    (y, u, v)
}

/// BT.601 full-range YUV → RGB, clamped to bytes.
pub fn yuv_to_rgb(y: f32, u: f32, v: f32) -> [u8; 3] {
    yuv_to_rgb_f32(y, u, v).map(clamp_u8)
}

/// BT.601 full-range YUV → RGB as floats clamped to [0, 255], not rounded.
pub fn yuv_to_rgb_f32(y: f32, u: f32, v: f32) -> [f32; 3] {
    let (u, v) = (u - 128.0, v - 128.0);
    [y + 1.402 * v, y - 0.344_136 * u - 0.714_136 * v, y + 1.772 * u].map(|channel| channel.clamp(0.0, 255.0))
}

fn clamp_u8(value: f32) -> u8 {
    value.round().clamp(0.0, 255.0) as u8
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;

    #[test]
    fn grey_survives_the_round_trip_exactly() {
        for level in [0u8, 17, 128, 200, 255] {
            let image = RgbImage::from_pixel(4, 2, Rgb([level; 3]));
            assert_eq!(YuyvImage::from_rgb(&image).unwrap().to_rgb(), image);
        }
    }

    #[test]
    fn colours_survive_within_rounding() {
        let image = RgbImage::from_fn(8, 2, |x, _| Rgb([30 + 20 * x as u8, 160, 60]));
        let decoded = YuyvImage::from_rgb(&image).unwrap().to_rgb();
        for (a, b) in image.pixels().zip(decoded.pixels()) {
            for channel in 0..3 {
                assert!((a[channel] as i32 - b[channel] as i32).abs() <= 16, "{a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn chroma_is_shared_by_pixel_pairs() {
        let image = RgbImage::from_fn(2, 1, |x, _| if x == 0 { Rgb([255, 0, 0]) } else { Rgb([0, 0, 255]) });
        let yuyv = YuyvImage::from_rgb(&image).unwrap();
        let decoded = yuyv.to_rgb();
        assert_ne!(decoded.get_pixel(0, 0), &Rgb([255, 0, 0]), "red bleeds into its neighbour");
        assert_eq!(yuyv.as_bytes().len(), 4);
    }

    #[test]
    fn wrong_sizes_are_rejected() {
        assert_eq!(
            YuyvImage::new(4, 2, vec![0; 15]).unwrap_err().to_string(),
            "frame of 4x2 needs 16 bytes, got 15 (truncated or wrong size?)"
        );
        assert_eq!(YuyvImage::new(3, 2, vec![0; 12]).unwrap_err(), FrameError::OddWidth(3));
        assert!(matches!(YuyvImage::new(0, 2, vec![]), Err(FrameError::Empty { .. })));
        assert!(YuyvImage::from_rgb(&RgbImage::new(3, 2)).is_err());
    }
}
