//! PLY: as a point cloud and as a mesh.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    trimctl_fuzz::check_points(data, "fuzz.ply");
    trimctl_fuzz::check_mesh(data, "fuzz.ply");
});
