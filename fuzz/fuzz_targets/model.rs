#![no_main]
//! `relocd::fuzzing::model`: see src/fuzzing.rs for the contract it checks.
//!
//! relocd catches tract's panics on corrupt graphs and turns them into errors; libFuzzer's panic hook
//! would abort on those caught panics too, so this target puts the default hook back. A panic that
//! escapes relocd still fails the run.

libfuzzer_sys::fuzz_target!(
    init: {
        let _ = std::panic::take_hook();
    },
    |data: &[u8]| relocd::fuzzing::model(data)
);
