#![no_main]
//! `relocd::fuzzing::control`: see src/fuzzing.rs for the contract it checks.

libfuzzer_sys::fuzz_target!(|data: &[u8]| relocd::fuzzing::control(data));
