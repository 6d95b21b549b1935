//! The Python module `trimctl._native` (wrapped by the pure-Python package `trimctl`).
//!
//! Logic lives in the trimctl crates; this crate converts arguments, releases the GIL for long
//! calls through one helper ([`gil::run_detached`]) and maps errors to one exception hierarchy
//! ([`errors`]).

mod arrays;
mod cloud;
mod errors;
mod gil;
mod inspect;
mod path;
mod register;
mod results;
mod scans;
mod workflow;

use pyo3::prelude::*;

/// The native module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    errors::register(m)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(cloud::estimate_normals, m)?)?;
    m.add_function(wrap_pyfunction!(cloud::voxel_downsample, m)?)?;
    m.add_class::<path::PyPath>()?;
    m.add_function(wrap_pyfunction!(path::read_points, m)?)?;
    m.add_function(wrap_pyfunction!(path::write_points, m)?)?;
    m.add_function(wrap_pyfunction!(path::read_path, m)?)?;
    m.add_function(wrap_pyfunction!(path::write_path, m)?)?;
    m.add_class::<register::IcpResult>()?;
    m.add_class::<register::UmeyamaResult>()?;
    m.add_class::<results::ContourQuality>()?;
    m.add_function(wrap_pyfunction!(register::icp, m)?)?;
    m.add_function(wrap_pyfunction!(register::umeyama, m)?)?;
    m.add_function(wrap_pyfunction!(workflow::synth_case, m)?)?;
    m.add_function(wrap_pyfunction!(workflow::register_path, m)?)?;
    m.add_function(wrap_pyfunction!(workflow::beam_report, m)?)?;
    m.add_function(wrap_pyfunction!(workflow::plan_path, m)?)?;
    m.add_function(wrap_pyfunction!(scans::merge_scans, m)?)?;
    m.add_function(wrap_pyfunction!(scans::merge_scan_files, m)?)?;
    m.add_function(wrap_pyfunction!(scans::read_poses, m)?)?;
    m.add_function(wrap_pyfunction!(workflow::hatch_surface, m)?)?;
    m.add_class::<inspect::PyInspection>()?;
    m.add_class::<inspect::PyContourInspection>()?;
    m.add_function(wrap_pyfunction!(inspect::inspect, m)?)?;
    Ok(())
}
