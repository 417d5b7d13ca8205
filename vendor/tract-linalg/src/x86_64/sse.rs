//! Matrix-multiply kernels for x86_64 CPUs without AVX (Atom Silvermont, e.g. the E3845; older
//! Core 2 / Nehalem parts), in Rust with SSE intrinsics.
//!
//! Every other x86_64 kernel needs AVX, so such a CPU used to run the generic Rust kernels: a 4x4
//! tile the compiler vectorises only partly. These keep the generic kernels' tile in memory
//! (`ab[row][col]`, so every fused op other than the product itself is the generic code, through
//! [`crate::generic::mmm::fused_ops`]) and replace only the `AddMatMul` loop, which is where the
//! time goes: the tile is loaded into xmm registers once per product, one register per 4 columns
//! of a row, and every step of `k` is a broadcast, a `mulps` and an `addps` per register. SSE2
//! is baseline on x86_64, so the f32 kernel runs on every x86_64 CPU; it declares no instruction
//! set and sits at the bottom of the ladder, under every AVX kernel, so it is only chosen where
//! none of those can run.
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
        crate::generic::mmm::fused_ops::<f32, MR, NR>(pnl, |ab, spec| match *spec {
            FusedKerSpec::AddMatMul { k, pa, pb, packing: 0 } => {
                add_mat_mul_f32::<MR, NR, NV>(ab, k, pa as *const f32, pb as *const f32);
                true
            }
            _ => false,
        })
    }
}

#[cfg(not(target_arch = "x86_64"))]
pub(crate) unsafe fn sse_kernel_f32<const MR: usize, const NR: usize, const NV: usize>(
    _pnl: *const FusedKerSpec<f32>,
) -> isize {
    panic!("sse kernels are not built for this target arch")
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
        for ik in 0..k {
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

MMMRustKernel!(x86_64; sse_kernel_f32::<8, 4, 1> => sse_mmm_f32_8x4<f32>(8, 4));

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use crate::isa::{Arch, Isa, IsaSet};
    use crate::mmm::Query;
    use tract_data::prelude::DatumType;

    fn picked(isa: IsaSet, m: usize, k: usize, n: usize) -> String {
        let query = Query::plain(DatumType::F32, Some(m), Some(k), Some(n));
        crate::MmmDispatch::for_isa(isa).pick(&query).unwrap().0.name().to_string()
    }

    /// An x86_64 CPU without AVX (what `TRACT_CPU_ISA=-avx,-avx2,-fma,...` leaves of this host)
    /// gets the SSE kernel instead of the generic one, at a convolution's shape and a matvec's.
    #[test]
    fn chosen_without_avx() {
        let sse2 = IsaSet::of_arch(Arch::X86_64);
        assert_eq!(picked(sse2, 64, 576, 4800), "sse_mmm_f32_8x4");
        assert_eq!(picked(sse2, 64, 576, 1), "sse_mmm_f32_8x4");
    }

    /// It never displaces a kernel written for AVX.
    #[test]
    fn not_chosen_with_avx() {
        for isa in [
            IsaSet::of_arch(Arch::X86_64).with(Isa::X86_64Avx),
            IsaSet::ladder(Arch::X86_64, 2),
            IsaSet::ladder(Arch::X86_64, 3),
        ] {
            assert!(!picked(isa, 64, 576, 4800).starts_with("sse"), "{isa:?}");
            assert!(!picked(isa, 64, 576, 1).starts_with("sse"), "{isa:?}");
        }
    }
}
