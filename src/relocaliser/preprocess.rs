//! Frame → input tensor, in one pass: each input pixel is the mean of its block of camera pixels
//! (the camera image must be an integer multiple of the input size, e.g. 640×480 → 160×120 averages
//! 4×4 blocks), YUYV is averaged in YUV and converted once per input pixel, then normalised as the
//! contract says.

use thiserror::Error;

use super::contract::InputSpec;
use crate::frame::{Frame, yuv_to_rgb_f32};

/// A frame that cannot be turned into the network's input.
#[derive(Debug, Error, PartialEq)]
pub enum PreprocessError {
    /// The frame is not a whole multiple of the input size, in the same ratio on both axes.
    #[error(
        "a {frame_width}x{frame_height} frame cannot be reduced to the model's {input_width}x{input_height} input: \
         expected the same whole multiple on both axes (e.g. 640x480 or 320x240 for 160x120)"
    )]
    SizeMismatch {
        /// Frame width.
        frame_width: u32,
        /// Frame height.
        frame_height: u32,
        /// Input width.
        input_width: usize,
        /// Input height.
        input_height: usize,
    },
}

/// The network's input: NCHW floats.
#[derive(Clone, Debug, PartialEq)]
pub struct InputTensor {
    /// `[1, 3, height, width]`.
    pub shape: [usize; 4],
    /// Values in NCHW order.
    pub data: Vec<f32>,
}

/// Turns a frame into the input tensor `spec` describes.
pub fn preprocess(frame: &Frame, spec: &InputSpec) -> Result<InputTensor, PreprocessError> {
    let (input_width, input_height) = spec.image_size();
    let (frame_width, frame_height) = frame.dimensions();
    let mismatch = || PreprocessError::SizeMismatch { frame_width, frame_height, input_width, input_height };
    let (fw, fh) = (frame_width as usize, frame_height as usize);
    if fw % input_width != 0 || fh % input_height != 0 || fw / input_width != fh / input_height {
        return Err(mismatch());
    }
    let factor = fw / input_width;
    let plane = input_width * input_height;
    let mut data = vec![0.0f32; 3 * plane];
    let gains: [f32; 3] = std::array::from_fn(|c| spec.scale / spec.std[c]);
    let offsets: [f32; 3] = std::array::from_fn(|c| spec.mean[c] / spec.std[c]);
    let count = (factor * factor) as f32;
    // Per input pixel of the current row: the sums of its camera pixels' three channels.
    let mut sums = vec![[0u32; 3]; input_width];
    // Per byte of a YUYV row: its sum over the current input row's camera lines.
    let mut line_sums: Vec<u32> = Vec::new();
    for row in 0..input_height {
        sums.fill([0; 3]);
        let lines = row * factor..(row + 1) * factor;
        match frame {
            Frame::Rgb(image) => {
                let raw = image.as_raw();
                for y in lines {
                    let line = &raw[y * fw * 3..(y + 1) * fw * 3];
                    for (sum, block) in sums.iter_mut().zip(line.chunks_exact(factor * 3)) {
                        for pixel in block.chunks_exact(3) {
                            for channel in 0..3 {
                                sum[channel] += pixel[channel] as u32;
                            }
                        }
                    }
                }
            }
            // An even block holds whole Y0 U Y1 V pairs: each U and V counts for both pixels. The
            // block's lines are added byte by byte first (a loop the compiler vectorises), then
            // each block's pairs once.
            Frame::Yuyv(image) if factor % 2 == 0 => {
                let raw = image.as_bytes();
                let line = |y: usize| &raw[y * fw * 2..(y + 1) * fw * 2];
                line_sums.clear();
                line_sums.extend(line(lines.start).iter().map(|&byte| u32::from(byte)));
                for y in lines.start + 1..lines.end {
                    for (total, &byte) in line_sums.iter_mut().zip(line(y)) {
                        *total += u32::from(byte);
                    }
                }
                for (sum, block) in sums.iter_mut().zip(line_sums.chunks_exact(factor * 2)) {
                    let (mut luma, mut u, mut v) = (0, 0, 0);
                    for pair in block.chunks_exact(4) {
                        luma += pair[0] + pair[2];
                        u += pair[1];
                        v += pair[3];
                    }
                    *sum = [luma, 2 * u, 2 * v];
                }
            }
            Frame::Yuyv(image) => {
                let raw = image.as_bytes();
                for y in lines {
                    let line = &raw[y * fw * 2..(y + 1) * fw * 2];
                    for (column, sum) in sums.iter_mut().enumerate() {
                        for x in column * factor..(column + 1) * factor {
                            let pair = (x / 2) * 4;
                            sum[0] += line[x * 2] as u32;
                            sum[1] += line[pair + 1] as u32;
                            sum[2] += line[pair + 3] as u32;
                        }
                    }
                }
            }
        }
        for (column, sum) in sums.iter().enumerate() {
            let mean = sum.map(|total| total as f32 / count);
            let rgb = match frame {
                Frame::Rgb(_) => mean,
                Frame::Yuyv(_) => yuv_to_rgb_f32(mean[0], mean[1], mean[2]),
            };
            let index = row * input_width + column;
            for channel in 0..3 {
                data[channel * plane + index] = rgb[channel] * gains[channel] - offsets[channel];
            }
        }
    }
    Ok(InputTensor { shape: [1, 3, input_height, input_width], data })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::YuyvImage;
    use image::{Rgb, RgbImage};

    fn spec(width: usize, height: usize) -> InputSpec {
        InputSpec {
            name: "image".into(),
            shape: vec![1, 3, height, width],
            layout: "NCHW".into(),
            colour: "RGB".into(),
            scale: 1.0 / 255.0,
            mean: [0.5; 3],
            std: [0.25; 3],
        }
    }

    #[test]
    fn rgb_blocks_are_averaged_and_normalised() {
        // 4x2 image → 2x1 input: left block mean (0, 102, 255), right block white.
        let image = RgbImage::from_fn(4, 2, |x, y| match (x, y) {
            (0, 0) => Rgb([0, 204, 255]),
            (0..=1, _) => Rgb([0, 68, 255]),
            _ => Rgb([255, 255, 255]),
        });
        let tensor = preprocess(&Frame::Rgb(image), &spec(2, 1)).unwrap();
        assert_eq!(tensor.shape, [1, 3, 1, 2]);
        let expected = [-2.0, 2.0, (102.0 / 255.0 - 0.5) / 0.25, 2.0, 2.0, 2.0];
        for (value, expected) in tensor.data.iter().zip(expected) {
            assert!((value - expected).abs() < 1e-5, "{:?}", tensor.data);
        }
    }

    #[test]
    fn yuyv_and_rgb_of_the_same_image_agree() {
        let image = RgbImage::from_fn(16, 12, |x, y| Rgb([(x * 15) as u8, 120 + y as u8 * 5, 60]));
        let yuyv = YuyvImage::from_rgb(&image).unwrap();
        let from_rgb = preprocess(&Frame::Rgb(yuyv.to_rgb()), &spec(4, 3)).unwrap();
        let from_yuyv = preprocess(&Frame::Yuyv(yuyv), &spec(4, 3)).unwrap();
        for (a, b) in from_rgb.data.iter().zip(&from_yuyv.data) {
            assert!((a - b).abs() < 0.02, "{a} vs {b}");
        }
    }

    /// The per-pixel walk the pair sums replaced, as the reference: every camera pixel adds its
    /// own Y and its pair's U and V.
    fn yuyv_reference(image: &YuyvImage, spec: &InputSpec) -> Vec<f32> {
        let (width, height) = spec.image_size();
        let fw = image.width() as usize;
        let factor = fw / width;
        let raw = image.as_bytes();
        let count = (factor * factor) as f32;
        let mut data = vec![0.0; 3 * width * height];
        for row in 0..height {
            for column in 0..width {
                let mut sum = [0u32; 3];
                for y in row * factor..(row + 1) * factor {
                    for x in column * factor..(column + 1) * factor {
                        let pair = y * fw * 2 + (x / 2) * 4;
                        sum[0] += raw[y * fw * 2 + x * 2] as u32;
                        sum[1] += raw[pair + 1] as u32;
                        sum[2] += raw[pair + 3] as u32;
                    }
                }
                let [y, u, v] = sum.map(|total| total as f32 / count);
                let rgb = yuv_to_rgb_f32(y, u, v);
                for channel in 0..3 {
                    data[channel * width * height + row * width + column] = rgb[channel]
                        * (spec.scale / spec.std[channel])
                        - spec.mean[channel] / spec.std[channel];
                }
            }
        }
        data
    }

    #[test]
    fn yuyv_pair_sums_match_the_per_pixel_walk_exactly() {
        let bytes: Vec<u8> =
            (0u32..24 * 12 * 2).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
        let image = YuyvImage::new(24, 12, bytes).unwrap();
        for (width, height) in [(6, 3), (12, 6), (8, 4), (24, 12)] {
            let spec = spec(width, height);
            let tensor = preprocess(&Frame::Yuyv(image.clone()), &spec).unwrap();
            assert_eq!(tensor.data, yuyv_reference(&image, &spec), "{width}x{height}");
        }
    }

    #[test]
    fn sizes_that_do_not_divide_are_rejected() {
        let error = preprocess(&Frame::Rgb(RgbImage::new(500, 400)), &spec(160, 120)).unwrap_err();
        assert!(
            error.to_string().starts_with("a 500x400 frame cannot be reduced to the model's 160x120 input")
        );
        assert!(preprocess(&Frame::Rgb(RgbImage::new(640, 240)), &spec(160, 120)).is_err());
        assert!(preprocess(&Frame::Rgb(RgbImage::new(320, 240)), &spec(160, 120)).is_ok());
    }
}
