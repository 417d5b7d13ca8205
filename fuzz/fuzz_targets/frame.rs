#![no_main]
//! `relocd::fuzzing::frame`: see src/fuzzing.rs for the contract it checks.

libfuzzer_sys::fuzz_target!(|data: &[u8]| relocd::fuzzing::frame(data));
