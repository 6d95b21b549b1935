//! STL (ascii and binary).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    trimctl_fuzz::check_mesh(data, "fuzz.stl");
});
