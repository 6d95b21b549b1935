//! The path CSV.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    trimctl_fuzz::check_path(data, "fuzz.csv");
});
