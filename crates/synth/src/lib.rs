//! Synthetic ceramic-core-like test cases: a twisted, cambered 40 × 100 mm slab with holes and
//! slots, its trimming path, a deformed and re-posed scan of it, and the ground-truth path.
//!
//! The part is built in *domain* coordinates `(u, v, w)`: `u` across the width, `v` along the
//! length, `w` through the thickness, all millimetres, centred on 0. The design map
//! [`design_point`](part::design_point) bends this box into the CAD shape (camber across `u`, a design twist about the
//! long axis). Every sample is placed exactly on the analytic surface (holes and slots are exact
//! circles and stadiums), with its exact normal from the map's Jacobian (`n' ∝ J⁻ᵀ n`); the
//! triangle mesh is only for `cad.stl` and for the scanner's occlusion test.
//!
//! The deformed part is `deform(cad)` ([`Deformation`](part::Deformation): per-axis scale along
//! pressing axes that may be tilted from the CAD axes, twist about the long axis, bend), placed
//! by `scan_from_cad_true = scan_from_cad_nominal · fixture_error`. The scanner is fixed to the
//! machine: one to four [`ScanView`]s defined in the scan frame about the *nominal* pose, so a
//! fixture error turns the part under them. A point is in the scan when at least one view sees
//! it (facing it within the maximum incidence, no ray-cast occlusion by the part), with
//! Gaussian noise, outliers and dropout patches. Burrs ([`Burr`]: thin flash webs standing off
//! stretches of the contours' edges) are scanned with the part. `truth` is the template path
//! under the same map (feature vectors as normals, `J⁻ᵀn`).
//!
//! Modules: [`part`] (geometry, design map, deformation), [`mesh`] (the triangle mesh),
//! [`scanner`] (the fixed views and what they see), [`burr`] (flash on the edges), [`blockage`]
//! (films over holes and slots), [`edges`] (the true edges, what a trim leaves, the
//! after-scan), [`case`] (parameters, the generator, files) and
//! [`testing`] (a planning-sized synthetic path for tests and benches).

pub mod blockage;
pub mod burr;
pub mod case;
pub mod edges;
pub mod mesh;
pub mod part;
pub mod scanner;
pub mod testing;

pub use blockage::{Blockage, FILM_GRID_MM, Film};
pub use burr::Burr;
pub use case::{CaseInfo, SynthCase, SynthParams, generate};
pub use edges::{EdgeTruth, stubs};
pub use part::{
    CAMBER_MM, Cutout, DESIGN_TWIST_DEG, Deformation, LENGTH_MM, THICKNESS_MM, WIDTH_MM, cutouts,
    demo_hatch_boundary, design_point,
};
pub use scanner::{DEMO_SCANNER_VIEWS, ScanView};

#[cfg(test)]
mod tests;
