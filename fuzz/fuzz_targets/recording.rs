#![no_main]
//! `relocd::fuzzing::recording`: see src/fuzzing.rs for the contract it checks.

libfuzzer_sys::fuzz_target!(|data: &[u8]| relocd::fuzzing::recording(data));
