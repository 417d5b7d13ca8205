//! Max pooling for the Atom. tract's `OptMaxPool` folds a 3×3 window of stride 2 one tap at a time,
//! about 110 instructions per output on the Atom path, a sixth of an inference of the built-in
//! network (BENCHMARKS.md, "Max pooling in two passes, and two steps per turn of the kernel loop").
//! [`StridedMaxPool`] pools the same windows in two passes over each channel plane, the maxima of
//! three neighbours along each input row at stride 2, then of three rows, four outputs at a time with
//! SSE where the target has it. It picks the value tract picks, bit for bit: the same comparison, in
//! the same order of taps. Upstream, the same two passes would be a sibling of tract-core's
//! `try_nchw_2x2_f32` fast path in `OptMaxPool`; tract-core is not vendored here, so the op replaces
//! tract's after optimisation.

use tract_onnx::prelude::*;
use tract_onnx::tract_core::internal::{EvalContext, EvalOp, Op, StaticName, TypedOp, bail};
use tract_onnx::tract_core::ops::cnn::OptMaxPool;
use tract_onnx::tract_core::ops::nn::DataFormat;
use tract_onnx::tract_core::{as_op, op_as_typed_op, op_out_of_plan};

/// Replaces every tract max pool that [`StridedMaxPool`] covers (f32, channels first, 3×3 windows at
/// stride 2, no dilation) in an optimised model; the others stay tract's.
pub(super) fn pool_in_two_passes(mut model: TypedModel) -> TractResult<TypedModel> {
    for id in 0..model.nodes().len() {
        let node = model.node(id);
        let Some(pool) = node.op_as::<OptMaxPool>() else { continue };
        let input = model.outlet_fact(node.inputs[0])?;
        if let Some(replacement) = StridedMaxPool::replacing(pool, input)? {
            model.node_mut(id).op = Box::new(replacement);
        }
    }
    Ok(model)
}

/// A 3×3 max pool of stride 2 over f32 channel planes: tract's `OptMaxPool` for the windows it
/// covers, in two passes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct StridedMaxPool {
    /// The input's planes: `[n, c]` of them, each of the plane's `height` × `width`.
    planes: [usize; 2],
    /// The windows' placement on each plane.
    plane: PlaneGeometry,
}

impl StridedMaxPool {
    /// The two-pass pool for `pool` over `input`, or `None` where it does not cover it (another type,
    /// layout or window, or an empty plane in or out).
    fn replacing(pool: &OptMaxPool, input: &TypedFact) -> TractResult<Option<Self>> {
        let spec = &pool.pool_spec;
        let Some(shape) = input.shape.as_concrete() else { return Ok(None) };
        let covered = input.datum_type == f32::datum_type()
            && pool.with_index_outputs.is_none()
            && spec.data_format == DataFormat::NCHW
            && shape.len() == 4
            && !shape.contains(&0)
            && spec.kernel_shape[..] == [3, 3]
            && spec.strides()[..] == [2, 2]
            && spec.dilations()[..] == [1, 1];
        if !covered {
            return Ok(None);
        }
        let geometry = pool.geometry.to_concrete(shape)?;
        let patch = &geometry.patch;
        if patch.output_shape.contains(&0) {
            return Ok(None);
        }
        let plane = PlaneGeometry {
            height: shape[2],
            width: shape[3],
            out_height: patch.output_shape[0],
            out_width: patch.output_shape[1],
            pad_top: patch.pad_before[0],
            pad_left: patch.pad_before[1],
        };
        Ok(Some(Self { planes: [shape[0], shape[1]], plane }))
    }

    fn input_shape(&self) -> [usize; 4] {
        [self.planes[0], self.planes[1], self.plane.height, self.plane.width]
    }

    fn output_shape(&self) -> [usize; 4] {
        [self.planes[0], self.planes[1], self.plane.out_height, self.plane.out_width]
    }
}

impl Op for StridedMaxPool {
    fn name(&self) -> StaticName {
        "StridedMaxPool".into()
    }

    op_as_typed_op!();
}

impl EvalOp for StridedMaxPool {
    op_out_of_plan!();

    fn eval(&self, _context: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let [input] = &inputs[..] else { bail!("StridedMaxPool takes one input, got {}", inputs.len()) };
        if input.shape() != self.input_shape() {
            bail!("StridedMaxPool was built for {:?}, got {:?}", self.input_shape(), input.shape());
        }
        let mut output = Tensor::zero::<f32>(&self.output_shape())?;
        self.plane.pool_planes(
            input.try_as_plain_ram()?.as_slice::<f32>()?,
            output.try_as_plain_ram_mut()?.as_slice_mut::<f32>()?,
        );
        Ok(tvec!(output.into_tvalue()))
    }
}

impl TypedOp for StridedMaxPool {
    fn output_facts(&self, _inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec!(f32::fact(self.output_shape())))
    }

    as_op!();
}

/// Where 3×3 windows of stride 2 lie on one channel plane: the windows start `pad_top` rows above and
/// `pad_left` columns left of it, and taps outside it are left out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PlaneGeometry {
    height: usize,
    width: usize,
    out_height: usize,
    out_width: usize,
    pad_top: usize,
    pad_left: usize,
}

/// Working rows for one plane. Taps outside the plane read NaN, which never replaces a running
/// maximum under [`fold`]: tract leaves those taps out, and so they change nothing here either.
struct Scratch {
    /// One input row, NaN left and right of it: `padded_row[pad_left + x]` is column `x`.
    padded_row: Vec<f32>,
    /// Each input row's three-column maxima, `outputs_padded` to a row, four outputs at a time.
    row_maxima: Vec<f32>,
    /// A row of NaN, for the rows above and below the plane.
    outside: Vec<f32>,
}

impl PlaneGeometry {
    /// Outputs along a row, rounded up to whole groups of four.
    fn outputs_padded(&self) -> usize {
        self.out_width.div_ceil(4) * 4
    }

    fn scratch(&self) -> Scratch {
        let outputs = self.outputs_padded();
        // The last group of four starts at column 2 (outputs - 4) and reads ten columns.
        let padded = (2 * outputs + 2).max(self.pad_left + self.width);
        Scratch {
            padded_row: vec![f32::NAN; padded],
            row_maxima: vec![f32::NAN; self.height * outputs],
            outside: vec![f32::NAN; outputs],
        }
    }

    /// Pools each plane of `input` into the plane of `output` at the same place.
    fn pool_planes(&self, input: &[f32], output: &mut [f32]) {
        let mut scratch = self.scratch();
        let planes = input
            .chunks_exact(self.height * self.width)
            .zip(output.chunks_exact_mut(self.out_height * self.out_width));
        for (input, output) in planes {
            self.pool(input, output, &mut scratch);
        }
    }

    /// Pools the plane `input` (`height` × `width`, rows contiguous) into `output` (`out_height` ×
    /// `out_width`).
    fn pool(&self, input: &[f32], output: &mut [f32], scratch: &mut Scratch) {
        let outputs = self.outputs_padded();
        for (row, maxima) in input.chunks_exact(self.width).zip(scratch.row_maxima.chunks_exact_mut(outputs))
        {
            scratch.padded_row[self.pad_left..][..self.width].copy_from_slice(row);
            pool_row(&scratch.padded_row, maxima);
        }
        let row = |y: usize| match y.checked_sub(self.pad_top).filter(|&y| y < self.height) {
            Some(y) => &scratch.row_maxima[y * outputs..][..outputs],
            None => &scratch.outside[..],
        };
        for (out_y, output) in output.chunks_exact_mut(self.out_width).enumerate() {
            let (first, second, third) = (row(2 * out_y), row(2 * out_y + 1), row(2 * out_y + 2));
            for (((output, &first), &second), &third) in output.iter_mut().zip(first).zip(second).zip(third) {
                *output = fold(fold(fold(f32::MIN, first), second), third);
            }
        }
    }
}

/// tract's fold: the tap replaces the running maximum when it is greater, so a NaN never wins and of
/// equal values (0.0 and -0.0) the first stays.
fn fold(acc: f32, tap: f32) -> f32 {
    if acc < tap { tap } else { acc }
}

/// Each window's three-column maximum along a NaN-padded row: output `x` pools `row[2x..2x + 3]`, for
/// the `maxima.len()` (a multiple of four) outputs; the row holds `2 maxima.len() + 2` columns.
#[cfg(any(test, not(all(any(target_arch = "x86", target_arch = "x86_64"), target_feature = "sse2"))))]
fn pool_row_scalar(row: &[f32], maxima: &mut [f32]) {
    for (x, maximum) in maxima.iter_mut().enumerate() {
        *maximum = fold(fold(fold(f32::MIN, row[2 * x]), row[2 * x + 1]), row[2 * x + 2]);
    }
}

#[cfg(not(all(any(target_arch = "x86", target_arch = "x86_64"), target_feature = "sse2")))]
use pool_row_scalar as pool_row;

/// [`pool_row_scalar`] four outputs at a time: four loads, three shuffles that split even and odd
/// columns, and three `maxps`, which is [`fold`] lane by lane (`maxps(tap, acc)` keeps `acc` unless
/// `tap` is greater).
#[cfg(all(any(target_arch = "x86", target_arch = "x86_64"), target_feature = "sse2"))]
fn pool_row(row: &[f32], maxima: &mut [f32]) {
    #[cfg(target_arch = "x86")]
    use std::arch::x86::*;
    #[cfg(target_arch = "x86_64")]
    use std::arch::x86_64::*;
    assert!(maxima.len() % 4 == 0 && row.len() >= 2 * maxima.len() + 2);
    for (group, maxima) in maxima.chunks_exact_mut(4).enumerate() {
        // SAFETY: SSE2 is enabled for this target. Group g reads row[8g..8g + 10], and the assert
        // puts 8g + 10 <= 2 maxima.len() + 2 within the row; the store writes this chunk's four.
        unsafe {
            let p = row.as_ptr().add(8 * group);
            let (a, b) = (_mm_loadu_ps(p), _mm_loadu_ps(p.add(4)));
            let (c, d) = (_mm_loadu_ps(p.add(2)), _mm_loadu_ps(p.add(6)));
            let first = _mm_shuffle_ps::<0b10_00_10_00>(a, b);
            let second = _mm_shuffle_ps::<0b11_01_11_01>(a, b);
            let third = _mm_shuffle_ps::<0b10_00_10_00>(c, d);
            let mut acc = _mm_set1_ps(f32::MIN);
            acc = _mm_max_ps(first, acc);
            acc = _mm_max_ps(second, acc);
            acc = _mm_max_ps(third, acc);
            _mm_storeu_ps(maxima.as_mut_ptr(), acc);
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use tract_onnx::tract_core::ops::cnn::{MaxPool, PaddingSpec, PoolSpec};

    use super::*;

    /// A model of one tract max pool over `[1, channels, height, width]`, optimised by tract.
    fn one_pool(channels: usize, height: usize, width: usize, padding: PaddingSpec) -> TypedModel {
        let mut model = TypedModel::default();
        let source = model.add_source("input", f32::fact([1, channels, height, width])).unwrap();
        let spec = PoolSpec {
            data_format: DataFormat::NCHW,
            kernel_shape: tvec![3, 3],
            padding,
            dilations: None,
            strides: Some(tvec![2, 2]),
            input_channels: channels,
            output_channels: channels,
        };
        let pool = model.wire_node("pool", MaxPool::new(spec, None), &[source]).unwrap();
        model.select_output_outlets(&pool).unwrap();
        model.into_optimized().unwrap()
    }

    fn run(model: TypedModel, input: &Tensor) -> Tensor {
        let plan = model.into_runnable().unwrap();
        plan.run(tvec![input.clone().into()]).unwrap().remove(0).into_tensor()
    }

    /// Planes of random values with the ones a fold can get wrong: NaN, both zeros, the extremes.
    fn awkward_planes(channels: usize, height: usize, width: usize, rng: &mut ChaCha8Rng) -> Tensor {
        let special = [f32::NAN, 0.0, -0.0, f32::NEG_INFINITY, f32::INFINITY, f32::MIN, f32::MAX];
        let values: Vec<f32> = (0..channels * height * width)
            .map(|_| match rng.random_range(0..10) {
                0 => special[rng.random_range(0..special.len())],
                1..=3 => 0.0,
                _ => rng.random_range(-4.0..4.0),
            })
            .collect();
        tract_ndarray::Array4::from_shape_vec((1, channels, height, width), values).unwrap().into_tensor()
    }

    #[test]
    fn pools_every_plane_as_tract_does_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(22);
        let paddings = [
            ("ceil mode", PaddingSpec::ExplicitOnnxPool(tvec![0, 0], tvec![0, 0], true)),
            ("valid", PaddingSpec::Valid),
            ("one around", PaddingSpec::Explicit(tvec![1, 1], tvec![1, 1])),
            ("same upper", PaddingSpec::SameUpper),
        ];
        // The network's planes (60 x 80, 30 x 40, 15 x 20), odd and tiny ones, rows too short for SSE.
        let sizes = [(60, 80), (29, 39), (15, 20), (7, 9), (3, 3), (1, 12), (12, 1), (5, 10), (4, 11)];
        for (name, padding) in paddings {
            for (height, width) in sizes {
                if matches!(padding, PaddingSpec::Valid) && height.min(width) < 3 {
                    continue; // no window fits, and tract's own pool panics there
                }
                let model = one_pool(3, height, width, padding.clone());
                let two_passes = pool_in_two_passes(model.clone()).unwrap();
                let names: Vec<_> = two_passes.nodes().iter().map(|node| node.op.name()).collect();
                assert!(names.contains(&"StridedMaxPool".into()), "{name} {height}x{width}: {names:?}");
                for _ in 0..3 {
                    let input = awkward_planes(3, height, width, &mut rng);
                    let (tract, ours) = (run(model.clone(), &input), run(two_passes.clone(), &input));
                    assert_eq!(tract.shape(), ours.shape(), "{name} {height}x{width}");
                    let bits = |t: &Tensor| -> Vec<u32> {
                        t.to_plain_array_view::<f32>().unwrap().iter().map(|v| v.to_bits()).collect()
                    };
                    assert_eq!(bits(&tract), bits(&ours), "{name} {height}x{width}");
                }
            }
        }
    }

    #[test]
    fn leaves_pools_it_does_not_cover_to_tract() {
        let mut model = TypedModel::default();
        let source = model.add_source("input", f32::fact([1, 2, 8, 8])).unwrap();
        let spec = PoolSpec {
            data_format: DataFormat::NCHW,
            kernel_shape: tvec![2, 2],
            padding: PaddingSpec::Valid,
            dilations: None,
            strides: Some(tvec![2, 2]),
            input_channels: 2,
            output_channels: 2,
        };
        let pool = model.wire_node("pool", MaxPool::new(spec, None), &[source]).unwrap();
        model.select_output_outlets(&pool).unwrap();
        let model = pool_in_two_passes(model.into_optimized().unwrap()).unwrap();
        assert!(model.nodes().iter().any(|node| node.op_as::<OptMaxPool>().is_some()));
        assert!(!model.nodes().iter().any(|node| node.op_is::<StridedMaxPool>()));
    }

    #[test]
    fn a_row_is_pooled_as_the_scalar_fold_does() {
        let mut rng = ChaCha8Rng::seed_from_u64(23);
        let row = awkward_planes(1, 1, 2 * 24 + 2, &mut rng);
        let row = row.to_plain_array_view::<f32>().unwrap();
        let row = row.as_slice().unwrap();
        let (mut ours, mut scalar) = ([0.0; 24], [0.0; 24]);
        pool_row(row, &mut ours);
        pool_row_scalar(row, &mut scalar);
        assert_eq!(ours.map(f32::to_bits), scalar.map(f32::to_bits));
    }
}
