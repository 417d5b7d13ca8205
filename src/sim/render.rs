//! The pixel loop: supersampled rays per pixel, then the sensor (gamma, noise, 8-bit quantisation and
//! the YUYV 4:2:2 chroma subsampling of the Nao camera).

use image::RgbImage;
use rayon::prelude::*;

use super::colour::linear_to_srgb;
use super::scene::Scene;
use super::trace::{Ray, mix_bits, trace};
use crate::frame::YuyvImage;
use crate::geometry::Camera;

/// How to turn the scene into pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Rays per pixel along each axis (n × n rays, averaged) for anti-aliasing; at least 1.
    pub supersample: u32,
    /// Standard deviation of the sensor noise, in 8-bit levels.
    pub noise_sigma: f64,
    /// Seed of the noise pattern.
    pub noise_seed: u64,
    /// Share chroma between horizontal pixel pairs as the camera's YUYV 4:2:2 does (needs an even
    /// width; images of odd width are left as they are).
    pub chroma_subsampling: bool,
    /// Motion blur: the image moves by (u, v) while the shutter is open, as shares of the image width
    /// (so the same blur at any resolution); the supersampled rays spread along it.
    pub motion_blur: [f64; 2],
}

impl Default for RenderSettings {
    /// 3×3 supersampling, no noise, no chroma subsampling, no blur: a clean image.
    fn default() -> Self {
        Self {
            supersample: 3,
            noise_sigma: 0.0,
            noise_seed: 0,
            chroma_subsampling: false,
            motion_blur: [0.0; 2],
        }
    }
}

/// Renders what `camera` sees of `scene` at the camera's resolution.
pub fn render(scene: &Scene, camera: &Camera, settings: &RenderSettings) -> RgbImage {
    let (width, height) = (camera.intrinsics().width, camera.intrinsics().height);
    let samples = settings.supersample.max(1);
    let offsets: Vec<f64> = (0..samples).map(|i| (i as f64 + 0.5) / samples as f64).collect();
    let origin = camera.position();
    let mut pixels = vec![0u8; width as usize * height as usize * 3];
    pixels.par_chunks_mut(width as usize * 3).enumerate().for_each(|(row, line)| {
        for (column, pixel) in line.chunks_exact_mut(3).enumerate() {
            let mut sum = [0.0; 3];
            for (i, dv) in offsets.iter().enumerate() {
                for (j, du) in offsets.iter().enumerate() {
                    // Each ray is a moment of the exposure: spread along the blur.
                    let moment =
                        (i * offsets.len() + j) as f64 / (offsets.len() * offsets.len()) as f64 - 0.5;
                    let [blur_u, blur_v] =
                        settings.motion_blur.map(|share| share * f64::from(width) * moment);
                    let direction =
                        camera.ray_direction(column as f64 + du + blur_u, row as f64 + dv + blur_v);
                    let colour = trace(scene, &Ray { origin, direction });
                    for channel in 0..3 {
                        sum[channel] += colour[channel];
                    }
                }
            }
            let index = (row * width as usize + column) as u64;
            for channel in 0..3 {
                let mean = sum[channel] / (samples * samples) as f64;
                let noise = settings.noise_sigma * gaussian(settings.noise_seed, index * 3 + channel as u64);
                pixel[channel] = (linear_to_srgb(mean) * 255.0 + noise).round().clamp(0.0, 255.0) as u8;
            }
        }
    });
    let image = RgbImage::from_raw(width, height, pixels).expect("buffer size matches the image");
    if settings.chroma_subsampling && width % 2 == 0 {
        YuyvImage::from_rgb(&image).expect("even, non-empty image").to_rgb()
    } else {
        image
    }
}

/// A standard normal sample that depends only on (seed, index), so the noise does not depend on how
/// rows are split across threads.
fn gaussian(seed: u64, index: u64) -> f64 {
    let bits = mix_bits(seed ^ mix_bits(index));
    let first = ((bits >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
    let second = (mix_bits(bits) >> 11) as f64 / (1u64 << 53) as f64;
    (-2.0 * first.ln()).sqrt() * (std::f64::consts::TAU * second).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_has_unit_variance() {
        let samples: Vec<f64> = (0..20_000).map(|index| gaussian(7, index)).collect();
        let mean = samples.iter().sum::<f64>() / samples.len() as f64;
        let variance = samples.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / samples.len() as f64;
        assert!(mean.abs() < 0.03, "{mean}");
        assert!((variance - 1.0).abs() < 0.05, "{variance}");
    }
}
