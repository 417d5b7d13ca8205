//! Matrix-multiply kernels for x86_64 CPUs without AVX (Atom Silvermont, e.g. the E3845; older
//! Core 2 / Nehalem parts), in Rust with SSE intrinsics.
//!
//! Every other x86_64 kernel needs AVX, so such a CPU used to run the generic Rust kernels: a 4x4
//! tile the compiler vectorises only partly. These keep the generic kernels' tile in memory
//! (`ab[row][col]`, so a fused op they do not replace is the generic code, through
//! [`crate::generic::mmm::fused_ops`]) and replace the `AddMatMul` loop, which is where the
//! time goes: the tile is loaded into xmm registers once per product, one register per 4 columns
//! of a row, and every step of `k` is a broadcast, a `mulps` and an `addps` per register (the i32
//! kernel: a `pmaddwd` per row for two steps of `k`), and the few other ops that showed in the
//! Atom's profile; the f32 kernel runs a convolution's usual tile (product, bias, ReLU, store) in
//! registers from start to end (`common_tile_8x4`). SSE2 is baseline on x86_64 and is all the
//! f32 kernel uses; both are declared as needing SSE4.1 (the i32 kernel's `pmovsxbw`; every Atom
//! since Silvermont has it) so that one `TRACT_CPU_ISA=-sse4.1` turns the pair off, and they sit
//! at the bottom of the ladder, under every AVX kernel: they are only chosen where none of those
//! can run.
use crate::frame::mmm::FusedKerSpec;

/// `MR`x`NR` f32 tile, `NR = 4 * NV` columns as `NV` xmm registers per row. `MR` must be a
/// multiple of 4 (the packed A column is read 4 rows at a time).
///
/// # Safety
/// `pnl` is a fused-op list as the frame builds them, with packing 0 (f32 A and B panels).
#[cfg(target_arch = "x86_64")]
pub(crate) unsafe fn sse_kernel_f32<const MR: usize, const NR: usize, const NV: usize>(
    pnl: *const FusedKerSpec<f32>,
) -> isize {
    unsafe {
        if MR == 8 && NR == 4 && !pnl.is_null() && common_tile_8x4(pnl) {
            return 0;
        }
        crate::generic::mmm::fused_ops::<f32, MR, NR>(pnl, |ab, spec| match *spec {
            FusedKerSpec::AddMatMul { k, pa, pb, packing: 0 } => {
                add_mat_mul_f32::<MR, NR, NV>(ab, k, pa as *const f32, pb as *const f32);
                true
            }
            FusedKerSpec::Store(tile) if tile.item_size == 4 && tile.col_byte_stride == 4 => {
                store_rows(ab, &tile);
                true
            }
            FusedKerSpec::Store(tile)
                if MR == 8 && NR == 4 && tile.item_size == 4 && tile.row_byte_stride == 4 =>
            {
                store_columns_8x4(load_rows(&*(ab as *const _ as *const [[f32; 4]; 8])), &tile);
                true
            }
            FusedKerSpec::PerRowAdd(bias) if MR == 8 && NR == 4 => {
                in_registers(&mut *(ab as *mut _ as *mut [[f32; 4]; 8]), |rows| add_row_bias(rows, bias));
                true
            }
            FusedKerSpec::PerColAdd(bias) if MR == 8 && NR == 4 => {
                in_registers(&mut *(ab as *mut _ as *mut [[f32; 4]; 8]), |rows| add_col_bias(rows, bias));
                true
            }
            _ => false,
        })
    }
}

/// An 8x4 tile held in memory, a register per row.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn load_rows(ab: &[[f32; 4]; 8]) -> [std::arch::x86_64::__m128; 8] {
    use std::arch::x86_64::*;
    let mut rows = [unsafe { _mm_setzero_ps() }; 8];
    for (row, ab) in rows.iter_mut().zip(ab.iter()) {
        *row = unsafe { _mm_loadu_ps(ab.as_ptr()) };
    }
    rows
}

/// Applies `op` to an 8x4 tile held in memory, a register per row, and stores it back.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn in_registers(
    ab: &mut [[f32; 4]; 8],
    op: impl FnOnce(&mut [std::arch::x86_64::__m128; 8]),
) {
    use std::arch::x86_64::*;
    unsafe {
        let mut rows = load_rows(ab);
        op(&mut rows);
        for (row, ab) in rows.iter().zip(ab.iter_mut()) {
            _mm_storeu_ps(ab.as_mut_ptr(), *row);
        }
    }
}

/// `row[r] = bias[r] + row[r]` lane by lane, the generic `PerRowAdd` in its operands' order.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn add_row_bias(rows: &mut [std::arch::x86_64::__m128; 8], bias: *const f32) {
    use std::arch::x86_64::*;
    for (r, row) in rows.iter_mut().enumerate() {
        unsafe { *row = _mm_add_ps(_mm_set1_ps(*bias.add(r)), *row) };
    }
}

/// `row[r][c] = bias[c] + row[r][c]`, the generic `PerColAdd` in its operands' order.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn add_col_bias(rows: &mut [std::arch::x86_64::__m128; 8], bias: *const f32) {
    use std::arch::x86_64::*;
    unsafe {
        let bias = _mm_loadu_ps(bias);
        for row in rows.iter_mut() {
            *row = _mm_add_ps(bias, *row);
        }
    }
}

/// Stores an 8x4 tile, a register per row, whose columns are contiguous in C (a product tract
/// computes transposed, so that C's rows are the tile's columns): two 4x4 transposes in registers,
/// then each column's eight values in two stores; the generic store goes element by element.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn store_columns_8x4(
    rows: [std::arch::x86_64::__m128; 8],
    tile: &crate::frame::mmm::OutputStoreKer,
) {
    use std::arch::x86_64::*;
    unsafe {
        for half in 0..2 {
            let quad = &rows[4 * half..];
            let (mut r0, mut r1, mut r2, mut r3) = (quad[0], quad[1], quad[2], quad[3]);
            _MM_TRANSPOSE4_PS(&mut r0, &mut r1, &mut r2, &mut r3);
            for (c, column) in [r0, r1, r2, r3].into_iter().enumerate() {
                let dst = tile.ptr.offset(tile.col_byte_stride * c as isize) as *mut f32;
                _mm_storeu_ps(dst.add(4 * half), column);
            }
        }
    }
}

/// Runs the 8x4 tile most of a convolution's tiles are, with the tile in registers from the first
/// product to the store: `Clear`, `AddMatMul` (packing 0, the assembly loop's conditions), a bias
/// (`PerRowAdd` or `PerColAdd`) or none, `ScalarMax` (a ReLU) or none, a `Store` of rows or of
/// columns, `Done`. The operations are the generic ones, in their order, so the results are the
/// same bit for bit; what goes is the tile's round trips through memory between the ops and their
/// dispatch (~100 instructions per tile). Answers false, having touched nothing, for any other list.
#[cfg(target_arch = "x86_64")]
unsafe fn common_tile_8x4(pnl: *const FusedKerSpec<f32>) -> bool {
    use std::arch::x86_64::*;
    use FusedKerSpec::*;
    unsafe {
        let mut op = pnl;
        let mut next = || {
            let spec = *op;
            op = op.add(1);
            spec
        };
        if !matches!(next(), Clear) {
            return false;
        }
        let AddMatMul { k, pa, pb, packing: 0 } = next() else { return false };
        if k == 0 || (pa as usize) % 16 != 0 {
            return false;
        }
        let mut spec = next();
        let bias = match spec {
            PerRowAdd(_) | PerColAdd(_) => Some(std::mem::replace(&mut spec, next())),
            _ => None,
        };
        let relu = match spec {
            ScalarMax(floor) => {
                spec = next();
                Some(floor)
            }
            _ => None,
        };
        let Store(tile) = spec else { return false };
        let (rows, columns) = (tile.col_byte_stride == 4, tile.row_byte_stride == 4);
        if tile.item_size != 4 || !(rows || columns) || !matches!(next(), Done) {
            return false;
        }
        let mut acc = [_mm_setzero_ps(); 8];
        loop_8x4(&mut acc, k, pa as *const f32, pb as *const f32);
        match bias {
            Some(PerRowAdd(bias)) => add_row_bias(&mut acc, bias),
            Some(PerColAdd(bias)) => add_col_bias(&mut acc, bias),
            _ => {}
        }
        if let Some(floor) = relu {
            // The generic `if floor > x { floor } else { x }`, which is what `maxps(floor, x)` does.
            let floor = _mm_set1_ps(floor);
            for acc in acc.iter_mut() {
                *acc = _mm_max_ps(floor, *acc);
            }
        }
        if rows {
            for (r, acc) in acc.iter().enumerate() {
                _mm_storeu_ps(tile.ptr.offset(tile.row_byte_stride * r as isize) as *mut f32, *acc);
            }
        } else {
            store_columns_8x4(acc, &tile);
        }
        true
    }
}

#[cfg(not(target_arch = "x86_64"))]
pub(crate) unsafe fn sse_kernel_f32<const MR: usize, const NR: usize, const NV: usize>(
    _pnl: *const FusedKerSpec<f32>,
) -> isize {
    panic!("sse kernels are not built for this target arch")
}

/// Stores a tile whose rows are contiguous in C (a convolution's output: channels by pixels) a
/// whole row at a time; the generic store goes element by element, for any strides.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn store_rows<T: Copy, const MR: usize, const NR: usize>(
    ab: &[[T; NR]; MR],
    tile: &crate::frame::mmm::OutputStoreKer,
) {
    for (i, row) in ab.iter().enumerate() {
        unsafe {
            let dst = tile.ptr.offset(tile.row_byte_stride * i as isize) as *mut T;
            std::ptr::copy_nonoverlapping(row.as_ptr(), dst, NR);
        }
    }
}

/// `ab += A * B` over `k` steps of packed panels: A holds `MR` f32 per step, B `NR`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn add_mat_mul_f32<const MR: usize, const NR: usize, const NV: usize>(
    ab: &mut [[f32; NR]; MR],
    k: usize,
    pa: *const f32,
    pb: *const f32,
) {
    use std::arch::x86_64::*;
    debug_assert!(NR == 4 * NV && MR % 4 == 0);
    unsafe {
        let mut acc = [[_mm_setzero_ps(); NV]; MR];
        for (row, acc) in ab.iter().zip(acc.iter_mut()) {
            for (v, acc) in acc.iter_mut().enumerate() {
                *acc = _mm_loadu_ps(row.as_ptr().add(4 * v));
            }
        }
        let asm_loop = MR == 8 && NV == 1 && k > 0 && (pa as usize) % 16 == 0;
        if asm_loop {
            let acc = &mut *(acc.as_mut_ptr() as *mut [__m128; 8]);
            loop_8x4(acc, k, pa, pb);
        }
        for ik in 0..if asm_loop { 0 } else { k } {
            let a = pa.add(MR * ik);
            let b = pb.add(NR * ik);
            let mut bv = [_mm_setzero_ps(); NV];
            for (v, bv) in bv.iter_mut().enumerate() {
                *bv = _mm_loadu_ps(b.add(4 * v));
            }
            for quad in 0..MR / 4 {
                let a4 = _mm_loadu_ps(a.add(4 * quad));
                for lane in 0..4 {
                    let ai = splat(a4, lane);
                    let acc = &mut acc[4 * quad + lane];
                    for v in 0..NV {
                        acc[v] = _mm_add_ps(acc[v], _mm_mul_ps(ai, bv[v]));
                    }
                }
            }
        }
        for (row, acc) in ab.iter_mut().zip(acc.iter()) {
            for (v, acc) in acc.iter().enumerate() {
                _mm_storeu_ps(row.as_mut_ptr().add(4 * v), *acc);
            }
        }
    }
}

/// One step of `k` of the 8x4 product, `a` and `b` bytes into the packed panels: the 8 rows' A
/// values broadcast from memory one `pshufd` each, times the 4 B values, added into the rows.
#[cfg(target_arch = "x86_64")]
macro_rules! step_8x4 {
    ($a:literal, $b:literal) => {
        concat!(
            "movups {b}, xmmword ptr [{pb} + ", $b, "]\n",
            "pshufd {t0}, xmmword ptr [{pa} + ", $a, "], 0x00\n",
            "pshufd {t1}, xmmword ptr [{pa} + ", $a, "], 0x55\n",
            "mulps {t0}, {b}\n",
            "mulps {t1}, {b}\n",
            "addps {c0}, {t0}\n",
            "addps {c1}, {t1}\n",
            "pshufd {t0}, xmmword ptr [{pa} + ", $a, "], 0xaa\n",
            "pshufd {t1}, xmmword ptr [{pa} + ", $a, "], 0xff\n",
            "mulps {t0}, {b}\n",
            "mulps {t1}, {b}\n",
            "addps {c2}, {t0}\n",
            "addps {c3}, {t1}\n",
            "pshufd {t0}, xmmword ptr [{pa} + ", $a, " + 16], 0x00\n",
            "pshufd {t1}, xmmword ptr [{pa} + ", $a, " + 16], 0x55\n",
            "mulps {t0}, {b}\n",
            "mulps {t1}, {b}\n",
            "addps {c4}, {t0}\n",
            "addps {c5}, {t1}\n",
            "pshufd {t0}, xmmword ptr [{pa} + ", $a, " + 16], 0xaa\n",
            "pshufd {t1}, xmmword ptr [{pa} + ", $a, " + 16], 0xff\n",
            "mulps {t0}, {b}\n",
            "mulps {t1}, {b}\n",
            "addps {c6}, {t0}\n",
            "addps {c7}, {t1}\n",
        )
    };
}

/// The 8x4 product's loop in assembly: each broadcast is one `pshufd` from memory into a fresh
/// register, where the compiler's own code copies a register and `shufps` it; an odd first step,
/// then two steps of `k` per turn of the loop (27 instructions per step against the compiler's 38;
/// 29 with one step per turn). The steps run in `k`'s order, so the sums are the same. `k` must be
/// at least 1 and `pa` 16-byte aligned (packed panels are; `pshufd` faults on an unaligned memory
/// operand, so the caller checks).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn loop_8x4(acc: &mut [std::arch::x86_64::__m128; 8], k: usize, pa: *const f32, pb: *const f32) {
    let [mut c0, mut c1, mut c2, mut c3, mut c4, mut c5, mut c6, mut c7] = *acc;
    unsafe {
        std::arch::asm!(
            "test {k}, 1",
            "jz 3f",
            step_8x4!("0", "0"),
            "add {pa}, 32",
            "add {pb}, 16",
            "3:",
            "shr {k}, 1",
            "jz 4f",
            "2:",
            step_8x4!("0", "0"),
            step_8x4!("32", "16"),
            "add {pa}, 64",
            "add {pb}, 32",
            "dec {k}",
            "jnz 2b",
            "4:",
            pa = inout(reg) pa => _,
            pb = inout(reg) pb => _,
            k = inout(reg) k => _,
            b = out(xmm_reg) _,
            t0 = out(xmm_reg) _,
            t1 = out(xmm_reg) _,
            c0 = inout(xmm_reg) c0,
            c1 = inout(xmm_reg) c1,
            c2 = inout(xmm_reg) c2,
            c3 = inout(xmm_reg) c3,
            c4 = inout(xmm_reg) c4,
            c5 = inout(xmm_reg) c5,
            c6 = inout(xmm_reg) c6,
            c7 = inout(xmm_reg) c7,
            options(nostack, readonly),
        );
    }
    *acc = [c0, c1, c2, c3, c4, c5, c6, c7];
}

/// Lane `lane` of `x` in all four lanes (`lane` is a constant once the loops are unrolled).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn splat(x: std::arch::x86_64::__m128, lane: usize) -> std::arch::x86_64::__m128 {
    use std::arch::x86_64::*;
    unsafe {
        match lane {
            0 => _mm_shuffle_ps::<0x00>(x, x),
            1 => _mm_shuffle_ps::<0x55>(x, x),
            2 => _mm_shuffle_ps::<0xaa>(x, x),
            _ => _mm_shuffle_ps::<0xff>(x, x),
        }
    }
}

/// 8x4 i32 tile over i8 panels, exact: each step of two `k` interleaves the two A columns and
/// the two B rows byte by byte, sign-extends them to i16 (`pmovsxbw`, SSE4.1) and lets one
/// `pmaddwd` per row do 4 columns x 2 products, summed in i32. (`pmaddubsw` would do twice the
/// products per instruction but saturates its i16 pair sums, so it would not match the other
/// kernels bit for bit.)
///
/// # Safety
/// `pnl` is a fused-op list as the frame builds them; the CPU must have SSE4.1.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse4.1")]
pub(crate) unsafe fn sse_kernel_i32_8x4(pnl: *const FusedKerSpec<i32>) -> isize {
    unsafe {
        crate::generic::mmm::fused_ops::<i32, 8, 4>(pnl, |ab, spec| match *spec {
            FusedKerSpec::AddMatMul { k, pa, pb, packing: 1 } => {
                add_mat_mul_i8_8x4(ab, k, pa as *const i8, pb as *const i8);
                true
            }
            FusedKerSpec::QScale(shift, policy, mult) => q_scale_rows(ab, shift, policy, mult),
            FusedKerSpec::Store(tile) if tile.item_size == 4 && tile.col_byte_stride == 4 => {
                store_rows(ab, &tile);
                true
            }
            FusedKerSpec::Store(tile) if tile.item_size == 1 && tile.col_byte_stride == 1 => {
                store_rows_i8(ab, &tile);
                true
            }
            _ => false,
        })
    }
}

#[cfg(not(target_arch = "x86_64"))]
pub(crate) unsafe fn sse_kernel_i32_8x4(_pnl: *const FusedKerSpec<i32>) -> isize {
    panic!("sse kernels are not built for this target arch")
}

/// `ab += A * B` over `k` steps of packed i8 panels: A holds 8 i8 per step, B 4.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse4.1")]
unsafe fn add_mat_mul_i8_8x4(ab: &mut [[i32; 4]; 8], k: usize, pa: *const i8, pb: *const i8) {
    use std::arch::x86_64::*;
    unsafe {
        let mut acc = [_mm_setzero_si128(); 8];
        for (row, acc) in ab.iter().zip(acc.iter_mut()) {
            *acc = _mm_loadu_si128(row.as_ptr() as *const __m128i);
        }
        // One step of two `k` (the second all zeros past an odd `k`).
        let step = |acc: &mut [__m128i; 8], a0: __m128i, a1: __m128i, b0: __m128i, b1: __m128i| {
            // Row r's pair (A[r][k], A[r][k+1]) as two i16, rows 0-3 and 4-7.
            let a = _mm_unpacklo_epi8(a0, a1);
            let a_lo = _mm_cvtepi8_epi16(a);
            let a_hi = _mm_cvtepi8_epi16(_mm_unpackhi_epi64(a, a));
            // Column c's pair (B[k][c], B[k+1][c]) as two i16, columns 0-3.
            let b = _mm_cvtepi8_epi16(_mm_unpacklo_epi8(b0, b1));
            macro_rules! row {
                ($r:expr, $a:expr, $lane:expr) => {
                    acc[$r] = _mm_add_epi32(acc[$r], _mm_madd_epi16(_mm_shuffle_epi32::<$lane>($a), b))
                };
            }
            row!(0, a_lo, 0x00);
            row!(1, a_lo, 0x55);
            row!(2, a_lo, 0xaa);
            row!(3, a_lo, 0xff);
            row!(4, a_hi, 0x00);
            row!(5, a_hi, 0x55);
            row!(6, a_hi, 0xaa);
            row!(7, a_hi, 0xff);
        };
        let a8 = |ik: usize| _mm_loadl_epi64(pa.add(8 * ik) as *const __m128i);
        let b4 = |ik: usize| _mm_cvtsi32_si128((pb.add(4 * ik) as *const i32).read_unaligned());
        for pair in 0..k / 2 {
            step(&mut acc, a8(2 * pair), a8(2 * pair + 1), b4(2 * pair), b4(2 * pair + 1));
        }
        if k % 2 == 1 {
            let zero = _mm_setzero_si128();
            step(&mut acc, a8(k - 1), zero, b4(k - 1), zero);
        }
        for (row, acc) in ab.iter_mut().zip(acc.iter()) {
            _mm_storeu_si128(row.as_mut_ptr() as *mut __m128i, *acc);
        }
    }
}

/// The re-quantisation of a tile, `ab[r][c].q_scale(Scaler::from_fuse_params(shift, policy,
/// mult))`, four columns at a time and exactly: the product with `mult` in 64 bits
/// (`pmuludq` on the magnitudes), the policy's nudge, the shift, the sign back (`psignd`).
/// Answers false, leaving it to the generic code, where the vector form does not hold: a negative
/// multiplier, a shift out of 1..=62 bits, or the `Native` policy.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse4.1")]
unsafe fn q_scale_rows(
    ab: &mut [[i32; 4]; 8],
    shift: isize,
    policy: crate::frame::mmm::RoundingPolicy,
    mult: i32,
) -> bool {
    use crate::frame::mmm::RoundingPolicy::*;
    let bits = shift + 31;
    if mult < 0 || !(1..=62).contains(&bits) || policy == Native {
        return false;
    }
    for row in ab.iter_mut() {
        unsafe {
            let x = std::arch::x86_64::_mm_loadu_si128(row.as_ptr() as _);
            let y = q_scale_x4(x, mult as u32, bits as u32, policy);
            std::arch::x86_64::_mm_storeu_si128(row.as_mut_ptr() as _, y);
        }
    }
    true
}

/// Four lanes of `Scaler * i32` for a non-negative `mult` and `bits = shift + 31` in 1..=62:
/// `sign(x) * ((|x| * mult + half + nudge) >> bits)`, truncated to i32, with `half = 1 << (bits -
/// 1)` and the policy's nudge (`generic/rounding.rs`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse4.1")]
unsafe fn q_scale_x4(
    x: std::arch::x86_64::__m128i,
    mult: u32,
    bits: u32,
    policy: crate::frame::mmm::RoundingPolicy,
) -> std::arch::x86_64::__m128i {
    use crate::frame::mmm::RoundingPolicy::*;
    use std::arch::x86_64::*;
    let magnitude = _mm_abs_epi32(x); // |i32::MIN| reads right as u32
    let mult = _mm_set1_epi32(mult as i32);
    let count = _mm_cvtsi32_si128(bits as i32);
    let half_minus_one = _mm_set1_epi64x((1i64 << (bits - 1)) - 1);
    let one = _mm_set1_epi64x(1);
    // x < 0 and x > 0 as 0 or 1 in 64-bit lanes: the even 32-bit lanes, then the odd ones.
    let negative = _mm_cmplt_epi32(x, _mm_setzero_si128());
    let positive = _mm_cmpgt_epi32(x, _mm_setzero_si128());
    let (negative_even, positive_even) =
        (_mm_and_si128(negative, one), _mm_and_si128(positive, one));
    let (negative_odd, positive_odd) = (
        _mm_and_si128(_mm_srli_epi64::<32>(negative), one),
        _mm_and_si128(_mm_srli_epi64::<32>(positive), one),
    );
    // Half of the lanes: `value` holds two magnitudes times `mult` in 64 bits.
    let round = |value: __m128i, negative: __m128i, positive: __m128i| {
        let add = match policy {
            Zero => half_minus_one,
            Away => _mm_add_epi64(half_minus_one, one),
            MinusInf => _mm_add_epi64(half_minus_one, negative),
            PlusInf => _mm_add_epi64(half_minus_one, positive),
            Even => _mm_add_epi64(half_minus_one, _mm_and_si128(_mm_srl_epi64(value, count), one)),
            _ => _mm_sub_epi64(
                _mm_add_epi64(half_minus_one, one),
                _mm_and_si128(_mm_srl_epi64(value, count), one),
            ),
        };
        _mm_srl_epi64(_mm_add_epi64(value, add), count)
    };
    let even = round(_mm_mul_epu32(magnitude, mult), negative_even, positive_even);
    let odd =
        round(_mm_mul_epu32(_mm_srli_epi64::<32>(magnitude), mult), negative_odd, positive_odd);
    let scaled = _mm_blend_epi16::<0b1100_1100>(even, _mm_slli_epi64::<32>(odd));
    _mm_sign_epi32(scaled, x)
}

/// Stores an i8 tile whose rows are contiguous in C: each row's four low bytes in one go.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse4.1")]
unsafe fn store_rows_i8(ab: &[[i32; 4]; 8], tile: &crate::frame::mmm::OutputStoreKer) {
    use std::arch::x86_64::*;
    let low_bytes = _mm_setr_epi8(0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1);
    for (i, row) in ab.iter().enumerate() {
        unsafe {
            let packed = _mm_shuffle_epi8(_mm_loadu_si128(row.as_ptr() as _), low_bytes);
            let dst = tile.ptr.offset(tile.row_byte_stride * i as isize) as *mut i32;
            dst.write_unaligned(_mm_cvtsi128_si32(packed));
        }
    }
}

MMMRustKernel!(x86_64; sse_kernel_f32::<8, 4, 1> => sse_mmm_f32_8x4<f32>(8, 4) isa(X86_64Sse41));

MMMRustKernel! { x86_64; sse_kernel_i32_8x4 => sse_mmm_i32_8x4<i32>(8, 4) isa(X86_64Sse41)
    packing[1] = i8i8 => |k| k.with_packing(i8::packing(8), i8::packing(4));
    store(i8)
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use crate::isa::{Arch, Isa, IsaSet};
    use crate::mmm::Query;
    use tract_data::prelude::DatumType;

    fn picked(isa: IsaSet, acc: DatumType, m: usize, k: usize, n: usize) -> String {
        let query = Query::plain(acc, Some(m), Some(k), Some(n));
        crate::MmmDispatch::for_isa(isa).pick(&query).unwrap().0.name().to_string()
    }

    /// What an Atom E3845 offers (and `TRACT_CPU_ISA=-avx,-avx2,-fma,...` leaves of this host).
    fn atom() -> IsaSet {
        IsaSet::of_arch(Arch::X86_64).with(Isa::X86_64Sse41)
    }

    /// Without AVX the SSE kernels replace the generic ones, at a convolution's shape and a
    /// matvec's, for f32 and for int8.
    #[test]
    fn chosen_without_avx() {
        for n in [4800, 1] {
            assert_eq!(picked(atom(), DatumType::F32, 64, 576, n), "sse_mmm_f32_8x4");
            assert_eq!(picked(atom(), DatumType::I32, 64, 576, n), "sse_mmm_i32_8x4");
        }
    }

    /// `-sse4.1` brings the generic kernels back.
    #[test]
    fn not_chosen_without_sse41() {
        let sse2 = IsaSet::of_arch(Arch::X86_64);
        assert!(picked(sse2, DatumType::F32, 64, 576, 4800).starts_with("generic"));
        assert!(picked(sse2, DatumType::I32, 64, 576, 4800).starts_with("generic"));
    }

    /// The register-only path for a convolution's common tile gives what the generic ops give, bit
    /// for bit, for every mix of bias, ReLU and store it takes, odd and even `k`, and values with
    /// NaN and both zeros (which a ReLU must leave as the generic code does).
    #[test]
    fn common_tile_matches_the_generic_ops() {
        use crate::frame::mmm::{FusedKerSpec, OutputStoreKer};
        let mut seed = 22u32;
        let mut value = move || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            match seed >> 28 {
                0 => f32::NAN,
                1 => -0.0,
                2 => 0.0,
                _ => (seed >> 8) as f32 / (1 << 23) as f32 - 1.0,
            }
        };
        // 16-byte aligned panels, as tract packs them: A 8 values per step of k, B 4.
        #[repr(align(16))]
        #[derive(Clone, Copy)]
        struct Quad([f32; 4]);
        let mut a_panel = vec![Quad([0.0; 4]); 2 * 13];
        let mut b_panel = vec![Quad([0.0; 4]); 13];
        a_panel.iter_mut().chain(b_panel.iter_mut()).flat_map(|q| &mut q.0).for_each(|v| *v = value());
        let (rows_bias, cols_bias) = ([0; 8].map(|_| value()), [0; 4].map(|_| value()));
        for k in [1, 2, 3, 8, 13] {
            for bias in 0..3 {
                for relu in [None, Some(0.0f32), Some(-0.5)] {
                    for by_columns in [false, true] {
                        // C with padding between rows (or columns), so the strides are used.
                        let (row_stride, col_stride) = if by_columns { (4, 4 * 11) } else { (4 * 6, 4) };
                        let store = |c: &mut Vec<f32>| OutputStoreKer {
                            ptr: c.as_mut_ptr() as *mut u8,
                            row_byte_stride: row_stride,
                            col_byte_stride: col_stride,
                            item_size: 4,
                        };
                        let (mut ours, mut generic) = (vec![7f32; 64], vec![7f32; 64]);
                        let ops = |c: &mut Vec<f32>| {
                            let mut ops = vec![
                                FusedKerSpec::Clear,
                                FusedKerSpec::AddMatMul {
                                    k,
                                    pa: a_panel.as_ptr() as *const u8,
                                    pb: b_panel.as_ptr() as *const u8,
                                    packing: 0,
                                },
                            ];
                            match bias {
                                1 => ops.push(FusedKerSpec::PerRowAdd(rows_bias.as_ptr())),
                                2 => ops.push(FusedKerSpec::PerColAdd(cols_bias.as_ptr())),
                                _ => {}
                            }
                            ops.extend(relu.map(FusedKerSpec::ScalarMax));
                            ops.extend([FusedKerSpec::Store(store(c)), FusedKerSpec::Done]);
                            ops
                        };
                        let case = format!("k {k}, bias {bias}, relu {relu:?}, by columns {by_columns}");
                        unsafe {
                            assert!(super::common_tile_8x4(ops(&mut ours).as_ptr()), "{case}");
                            crate::generic::mmm::fused_ops::<f32, 8, 4>(ops(&mut generic).as_ptr(), |_, _| false);
                        }
                        let bits = |c: &[f32]| c.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                        assert_eq!(bits(&ours), bits(&generic), "{case}");
                    }
                }
            }
        }
    }

    /// The tiles the register-only path does not take are left to the general one untouched.
    #[test]
    fn common_tile_declines_other_lists() {
        use crate::frame::mmm::FusedKerSpec;
        let panel = [[0f32; 4]; 4];
        let add_mat_mul = |k| FusedKerSpec::AddMatMul {
            k,
            pa: panel.as_ptr() as *const u8,
            pb: panel.as_ptr() as *const u8,
            packing: 0,
        };
        for ops in [
            vec![add_mat_mul(1), FusedKerSpec::Done],
            vec![FusedKerSpec::Clear, add_mat_mul(0), FusedKerSpec::Done],
            vec![FusedKerSpec::Clear, add_mat_mul(1), FusedKerSpec::ScalarMin(0.0), FusedKerSpec::Done],
            vec![FusedKerSpec::Clear, add_mat_mul(1), FusedKerSpec::Done],
        ] {
            assert!(!unsafe { super::common_tile_8x4(ops.as_ptr()) }, "{ops:?}");
        }
    }

    /// The vector re-quantisation is the scalar one, bit for bit, over the whole i32 range.
    #[test]
    fn q_scale_matches_the_scalar_one() {
        use crate::frame::mmm::RoundingPolicy::*;
        use crate::generic::rounding::{ScaleShiftAndRound, Scaler};
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let edges = [0, 1, -1, 2, -2, i32::MAX, i32::MIN, i32::MIN + 1, 1 << 30, -(1 << 30)];
        for round in 0..20_000 {
            let policy = [Zero, Away, MinusInf, PlusInf, Even, Odd][round % 6];
            let mult = match round % 4 {
                0 => (next() as u32 >> 1) as i32,
                1 => i32::MAX,
                2 => 1 << 30,
                _ => (next() % 1000) as i32,
            };
            let shift = (next() % 62) as isize - 30; // bits = shift + 31 in 1..=62
            let mut ab = [[0i32; 4]; 8];
            for (ix, v) in ab.iter_mut().flatten().enumerate() {
                *v = if ix < edges.len() { edges[ix] } else { next() as i32 >> (next() % 31) };
            }
            let expected = ab.map(|row| {
                row.map(|v| v.q_scale(Scaler::from_fuse_params(shift, policy, mult)))
            });
            assert!(unsafe { super::q_scale_rows(&mut ab, shift, policy, mult) });
            assert_eq!(ab, expected, "mult {mult} shift {shift} {policy:?}");
        }
    }

    /// They never displace a kernel written for AVX.
    #[test]
    fn not_chosen_with_avx() {
        for isa in [
            atom().with(Isa::X86_64Avx),
            IsaSet::ladder(Arch::X86_64, 2),
            IsaSet::ladder(Arch::X86_64, 3),
        ] {
            for n in [4800, 1] {
                assert!(!picked(isa, DatumType::F32, 64, 576, n).starts_with("sse"), "{isa:?}");
            }
            assert!(!picked(isa, DatumType::I32, 64, 576, 4800).starts_with("sse"), "{isa:?}");
        }
    }
}
