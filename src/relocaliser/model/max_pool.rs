//! Max pooling for the Atom. tract's `OptMaxPool` folds a 3×3 window of stride 2 one tap at a time,
//! about 110 instructions per output on the Atom path, a sixth of an inference of the built-in
//! network (BENCHMARKS.md, "Max pooling in two passes, and two steps per turn of the kernel loop").
//! [`StridedMaxPool`] pools the same windows in two passes over each channel plane, the maxima of
//! three neighbours along each input row at stride 2, then of three rows, with SSE where the target
//! has it: four f32 outputs at a time, or sixteen of the integer forms' u8 and i8. It picks the value
//! tract picks, bit for bit: the same comparison, in the same order of taps. Upstream, the same two
//! passes would be a sibling of tract-core's `try_nchw_2x2_f32` fast path in `OptMaxPool`; tract-core
//! is not vendored here, so the op replaces tract's after optimisation.

use tract_onnx::prelude::*;
use tract_onnx::tract_core::internal::{EvalContext, EvalOp, Op, StaticName, TypedOp, bail};
use tract_onnx::tract_core::ops::cnn::OptMaxPool;
use tract_onnx::tract_core::ops::nn::DataFormat;
use tract_onnx::tract_core::{as_op, op_as_typed_op, op_out_of_plan};

/// Replaces every tract max pool that [`StridedMaxPool`] covers (f32, u8 or i8, channels first, 3×3
/// windows at stride 2, no dilation) in an optimised model; the others stay tract's.
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

/// A 3×3 max pool of stride 2 over channel planes of f32, u8 or i8 (quantised or not): tract's
/// `OptMaxPool` for the windows it covers, in two passes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct StridedMaxPool {
    /// The planes' element type, quantisation included; the output keeps it.
    datum_type: DatumType,
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
        let covered = [DatumType::F32, DatumType::U8, DatumType::I8]
            .contains(&input.datum_type.unquantized())
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
        Ok(Some(Self { datum_type: input.datum_type, planes: [shape[0], shape[1]], plane }))
    }

    fn input_shape(&self) -> [usize; 4] {
        [self.planes[0], self.planes[1], self.plane.height, self.plane.width]
    }

    fn output_shape(&self) -> [usize; 4] {
        [self.planes[0], self.planes[1], self.plane.out_height, self.plane.out_width]
    }

    /// The pooled planes of `input`, whose elements are `T`.
    fn pool<T: Element>(&self, input: &Tensor) -> TractResult<Tensor> {
        let mut output = Tensor::zero_dt(self.datum_type, &self.output_shape())?;
        self.plane.pool_planes(
            input.try_as_plain_ram()?.as_slice::<T>()?,
            output.try_as_plain_ram_mut()?.as_slice_mut::<T>()?,
        );
        Ok(output)
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
        if input.shape() != self.input_shape() || input.datum_type() != self.datum_type {
            bail!(
                "StridedMaxPool was built for {:?} {:?}, got {:?} {:?}",
                self.datum_type,
                self.input_shape(),
                input.datum_type(),
                input.shape()
            );
        }
        let output = match self.datum_type.unquantized() {
            DatumType::F32 => self.pool::<f32>(input)?,
            DatumType::U8 => self.pool::<u8>(input)?,
            DatumType::I8 => self.pool::<i8>(input)?,
            other => bail!("StridedMaxPool does not pool {other:?}"),
        };
        Ok(tvec!(output.into_tvalue()))
    }
}

impl TypedOp for StridedMaxPool {
    fn output_facts(&self, _inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec!(self.datum_type.fact(self.output_shape())))
    }

    as_op!();
}

/// What a plane's element needs for the two passes.
trait Element: Datum + Copy + PartialOrd {
    /// tract's starting maximum, `min_value()`.
    const LEAST: Self;
    /// What a tap outside the plane reads: a value that never replaces a running maximum under
    /// [`fold`], as tract leaves such taps out.
    const OUTSIDE: Self;
    /// Outputs of a row that [`Self::pool_row`] makes at once.
    const LANES: usize;

    /// Each window's three-column maximum along a padded row: output `x` pools `row[2x..2x + 3]`,
    /// for the `maxima.len()` outputs (a multiple of [`Self::LANES`]); the row holds
    /// `2 maxima.len() + 2` columns. One output at a time unless the type has an SSE pass.
    fn pool_row(row: &[Self], maxima: &mut [Self]) {
        pool_row_scalar(row, maxima);
    }
}

impl Element for f32 {
    const LEAST: f32 = f32::MIN;
    // NaN never wins `acc < tap`.
    const OUTSIDE: f32 = f32::NAN;
    const LANES: usize = 4;

    #[cfg(all(any(target_arch = "x86", target_arch = "x86_64"), target_feature = "sse2"))]
    fn pool_row(row: &[f32], maxima: &mut [f32]) {
        sse::pool_row_f32(row, maxima);
    }
}

impl Element for u8 {
    const LEAST: u8 = u8::MIN;
    const OUTSIDE: u8 = u8::MIN;
    const LANES: usize = 16;

    #[cfg(all(any(target_arch = "x86", target_arch = "x86_64"), target_feature = "sse2"))]
    fn pool_row(row: &[u8], maxima: &mut [u8]) {
        sse::pool_row_bytes(row, maxima, 0);
    }
}

impl Element for i8 {
    const LEAST: i8 = i8::MIN;
    const OUTSIDE: i8 = i8::MIN;
    const LANES: usize = 16;

    #[cfg(all(any(target_arch = "x86", target_arch = "x86_64"), target_feature = "sse2"))]
    fn pool_row(row: &[i8], maxima: &mut [i8]) {
        // SAFETY: i8 and u8 have the same size and alignment, and every bit pattern is valid in
        // both; the bytes' order is kept by flipping their sign bits (0x80).
        let (row, maxima) = unsafe {
            (
                std::slice::from_raw_parts(row.as_ptr() as *const u8, row.len()),
                std::slice::from_raw_parts_mut(maxima.as_mut_ptr() as *mut u8, maxima.len()),
            )
        };
        sse::pool_row_bytes(row, maxima, 0x80);
    }
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

/// Working rows for one plane. Taps outside the plane read [`Element::OUTSIDE`], which never
/// replaces a running maximum under [`fold`]: tract leaves those taps out, and so they change
/// nothing here either.
struct Scratch<T> {
    /// One input row, `OUTSIDE` left and right of it: `padded_row[pad_left + x]` is column `x`.
    padded_row: Vec<T>,
    /// Each input row's three-column maxima, `outputs_padded` to a row.
    row_maxima: Vec<T>,
    /// A row of `OUTSIDE`, for the rows above and below the plane.
    outside: Vec<T>,
}

impl PlaneGeometry {
    /// Outputs along a row, rounded up to whole groups of `lanes`.
    fn outputs_padded(&self, lanes: usize) -> usize {
        self.out_width.div_ceil(lanes) * lanes
    }

    fn scratch<T: Element>(&self) -> Scratch<T> {
        let outputs = self.outputs_padded(T::LANES);
        // The last group starts at column 2 (outputs - LANES) and reads 2 LANES + 2 columns.
        let padded = (2 * outputs + 2).max(self.pad_left + self.width);
        Scratch {
            padded_row: vec![T::OUTSIDE; padded],
            row_maxima: vec![T::OUTSIDE; self.height * outputs],
            outside: vec![T::OUTSIDE; outputs],
        }
    }

    /// Pools each plane of `input` into the plane of `output` at the same place.
    fn pool_planes<T: Element>(&self, input: &[T], output: &mut [T]) {
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
    fn pool<T: Element>(&self, input: &[T], output: &mut [T], scratch: &mut Scratch<T>) {
        let outputs = self.outputs_padded(T::LANES);
        for (row, maxima) in input.chunks_exact(self.width).zip(scratch.row_maxima.chunks_exact_mut(outputs))
        {
            scratch.padded_row[self.pad_left..][..self.width].copy_from_slice(row);
            T::pool_row(&scratch.padded_row, maxima);
        }
        let row = |y: usize| match y.checked_sub(self.pad_top).filter(|&y| y < self.height) {
            Some(y) => &scratch.row_maxima[y * outputs..][..outputs],
            None => &scratch.outside[..],
        };
        for (out_y, output) in output.chunks_exact_mut(self.out_width).enumerate() {
            let (first, second, third) = (row(2 * out_y), row(2 * out_y + 1), row(2 * out_y + 2));
            for (((output, &first), &second), &third) in output.iter_mut().zip(first).zip(second).zip(third) {
                *output = fold(fold(fold(T::LEAST, first), second), third);
            }
        }
    }
}

/// tract's fold: the tap replaces the running maximum when it is greater, so a NaN never wins and of
/// equal values (0.0 and -0.0) the first stays.
fn fold<T: PartialOrd>(acc: T, tap: T) -> T {
    if acc < tap { tap } else { acc }
}

/// [`Element::pool_row`] one output at a time: what types and targets without an SSE pass use, and the
/// tests' reference.
fn pool_row_scalar<T: Element>(row: &[T], maxima: &mut [T]) {
    for (x, maximum) in maxima.iter_mut().enumerate() {
        *maximum = fold(fold(fold(T::LEAST, row[2 * x]), row[2 * x + 1]), row[2 * x + 2]);
    }
}

/// The row pass with SSE2 (x86 and x86_64: the V5's 32-bit build has it too).
#[cfg(all(any(target_arch = "x86", target_arch = "x86_64"), target_feature = "sse2"))]
mod sse {
    #[cfg(target_arch = "x86")]
    use std::arch::x86::*;
    #[cfg(target_arch = "x86_64")]
    use std::arch::x86_64::*;

    /// Four outputs at a time: four loads, three shuffles that split even and odd columns, and three
    /// `maxps`, which is [`super::fold`] lane by lane (`maxps(tap, acc)` keeps `acc` unless `tap` is
    /// greater).
    pub(super) fn pool_row_f32(row: &[f32], maxima: &mut [f32]) {
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

    /// Sixteen byte outputs at a time: the even and odd columns split by masking or shifting each
    /// 16-bit pair and packing, then two `pmaxub`. Bytes are compared as unsigned once `flip` (0 for
    /// u8, 0x80 for i8) is XORed into them, and flipped back after; a maximum of integers is the
    /// same whatever the order of its taps.
    pub(super) fn pool_row_bytes(row: &[u8], maxima: &mut [u8], flip: u8) {
        assert!(maxima.len() % 16 == 0 && row.len() >= 2 * maxima.len() + 2);
        for (group, maxima) in maxima.chunks_exact_mut(16).enumerate() {
            // SAFETY: SSE2 is enabled for this target. Group g reads row[32g..32g + 34], and the
            // assert puts 32g + 34 <= 2 maxima.len() + 2 within the row; the store writes this
            // chunk's sixteen.
            unsafe {
                let p = row.as_ptr().add(32 * group);
                let load = |offset: usize| _mm_loadu_si128(p.add(offset) as *const __m128i);
                let low = _mm_set1_epi16(0x00ff);
                let even =
                    |a: __m128i, b: __m128i| _mm_packus_epi16(_mm_and_si128(a, low), _mm_and_si128(b, low));
                let odd =
                    |a: __m128i, b: __m128i| _mm_packus_epi16(_mm_srli_epi16::<8>(a), _mm_srli_epi16::<8>(b));
                let flip = _mm_set1_epi8(flip as i8);
                let first = _mm_xor_si128(even(load(0), load(16)), flip);
                let second = _mm_xor_si128(odd(load(0), load(16)), flip);
                let third = _mm_xor_si128(even(load(2), load(18)), flip);
                let maximum = _mm_max_epu8(_mm_max_epu8(first, second), third);
                _mm_storeu_si128(maxima.as_mut_ptr() as *mut __m128i, _mm_xor_si128(maximum, flip));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use tract_onnx::tract_core::ops::cnn::{MaxPool, PaddingSpec, PoolSpec};

    use super::*;

    /// A model of one tract max pool over `[1, channels, height, width]` of `datum_type`, optimised
    /// by tract.
    fn one_pool(
        datum_type: DatumType,
        channels: usize,
        height: usize,
        width: usize,
        padding: PaddingSpec,
    ) -> TypedModel {
        let mut model = TypedModel::default();
        let source = model.add_source("input", datum_type.fact([1, channels, height, width])).unwrap();
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

    /// Random f32 values with the ones a fold can get wrong: NaN, both zeros, the extremes.
    fn awkward_floats(count: usize, rng: &mut ChaCha8Rng) -> Vec<f32> {
        let special = [f32::NAN, 0.0, -0.0, f32::NEG_INFINITY, f32::INFINITY, f32::MIN, f32::MAX];
        (0..count)
            .map(|_| match rng.random_range(0..10) {
                0 => special[rng.random_range(0..special.len())],
                1..=3 => 0.0,
                _ => rng.random_range(-4.0..4.0),
            })
            .collect()
    }

    /// Random bytes, a third of them the extremes of both readings (0, 127, 128, 255).
    fn awkward_bytes(count: usize, rng: &mut ChaCha8Rng) -> Vec<u8> {
        (0..count)
            .map(|_| match rng.random_range(0..6) {
                0 => [0, 127, 128, 255][rng.random_range(0..4)],
                _ => rng.random(),
            })
            .collect()
    }

    /// `[1, channels, height, width]` planes of awkward values of `datum_type`.
    fn awkward_planes(
        datum_type: DatumType,
        channels: usize,
        height: usize,
        width: usize,
        rng: &mut ChaCha8Rng,
    ) -> Tensor {
        let shape = (1, channels, height, width);
        let count = channels * height * width;
        let mut tensor = match datum_type.unquantized() {
            DatumType::F32 => tract_ndarray::Array4::from_shape_vec(shape, awkward_floats(count, rng))
                .unwrap()
                .into_tensor(),
            DatumType::U8 => {
                tract_ndarray::Array4::from_shape_vec(shape, awkward_bytes(count, rng)).unwrap().into_tensor()
            }
            DatumType::I8 => {
                let bytes = awkward_bytes(count, rng).into_iter().map(|byte| byte as i8).collect();
                tract_ndarray::Array4::from_shape_vec(shape, bytes).unwrap().into_tensor()
            }
            other => panic!("no awkward planes of {other:?}"),
        };
        // SAFETY: a quantised type has the same representation as its plain one.
        unsafe { tensor.set_datum_type(datum_type) };
        tensor
    }

    /// The tensor's elements as raw bits, so that NaN equals NaN and 0.0 differs from -0.0.
    fn bits(tensor: &Tensor) -> Vec<u32> {
        match tensor.datum_type().unquantized() {
            DatumType::F32 => {
                tensor.to_plain_array_view::<f32>().unwrap().iter().map(|v| v.to_bits()).collect()
            }
            DatumType::U8 => tensor.to_plain_array_view::<u8>().unwrap().iter().map(|&v| v as u32).collect(),
            DatumType::I8 => {
                tensor.to_plain_array_view::<i8>().unwrap().iter().map(|&v| v as u8 as u32).collect()
            }
            other => panic!("no bits of {other:?}"),
        }
    }

    #[test]
    fn pools_every_plane_as_tract_does_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(22);
        let quantised = DatumType::QU8(QParams::ZpScale { zero_point: 3, scale: 0.25 });
        let paddings = [
            ("ceil mode", PaddingSpec::ExplicitOnnxPool(tvec![0, 0], tvec![0, 0], true)),
            ("valid", PaddingSpec::Valid),
            ("one around", PaddingSpec::Explicit(tvec![1, 1], tvec![1, 1])),
            ("same upper", PaddingSpec::SameUpper),
        ];
        // The network's planes (60 x 80, 30 x 40, 15 x 20), odd and tiny ones, rows too short for
        // one group of SSE lanes and rows of more than one group of sixteen bytes.
        let sizes =
            [(60, 80), (29, 39), (15, 20), (7, 9), (3, 3), (1, 12), (12, 1), (5, 10), (4, 11), (9, 67)];
        for datum_type in [DatumType::F32, DatumType::U8, DatumType::I8, quantised] {
            for (name, padding) in &paddings {
                for (height, width) in sizes {
                    if matches!(padding, PaddingSpec::Valid) && height.min(width) < 3 {
                        continue; // no window fits, and tract's own pool panics there
                    }
                    let case = format!("{datum_type:?} {name} {height}x{width}");
                    let model = one_pool(datum_type, 3, height, width, padding.clone());
                    let two_passes = pool_in_two_passes(model.clone()).unwrap();
                    let names: Vec<_> = two_passes.nodes().iter().map(|node| node.op.name()).collect();
                    assert!(names.contains(&"StridedMaxPool".into()), "{case}: {names:?}");
                    for _ in 0..3 {
                        let input = awkward_planes(datum_type, 3, height, width, &mut rng);
                        let (tract, ours) = (run(model.clone(), &input), run(two_passes.clone(), &input));
                        assert_eq!(tract.shape(), ours.shape(), "{case}");
                        assert_eq!(tract.datum_type(), ours.datum_type(), "{case}");
                        assert_eq!(bits(&tract), bits(&ours), "{case}");
                    }
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
        let i32_pool = pool_in_two_passes(one_pool(DatumType::I32, 2, 8, 8, PaddingSpec::Valid)).unwrap();
        assert!(!i32_pool.nodes().iter().any(|node| node.op_is::<StridedMaxPool>()));
    }

    #[test]
    fn a_row_is_pooled_as_the_scalar_fold_does() {
        let mut rng = ChaCha8Rng::seed_from_u64(23);
        let row = awkward_floats(2 * 24 + 2, &mut rng);
        let (mut ours, mut scalar) = ([0.0; 24], [0.0; 24]);
        f32::pool_row(&row, &mut ours);
        pool_row_scalar(&row, &mut scalar);
        assert_eq!(ours.map(f32::to_bits), scalar.map(f32::to_bits));

        let row = awkward_bytes(2 * 48 + 2, &mut rng);
        let (mut ours, mut scalar) = ([0u8; 48], [0u8; 48]);
        u8::pool_row(&row, &mut ours);
        pool_row_scalar(&row, &mut scalar);
        assert_eq!(ours, scalar);

        let row: Vec<i8> = row.iter().map(|&byte| byte as i8).collect();
        let (mut ours, mut scalar) = ([0i8; 48], [0i8; 48]);
        i8::pool_row(&row, &mut ours);
        pool_row_scalar(&row, &mut scalar);
        assert_eq!(ours, scalar);
    }
}
