//! Debug probe (temporary).
use trim_geom::synth::{SynthParams, generate};
use trim_register::eval::path_errors;
use trim_register::icp::IcpTarget;
use trim_register::regional::{CoarseSettings, coarse_fit};
use trim_register::sampling::{View, facing_indices};
fn main() {
    let args: Vec<f64> = std::env::args().skip(1).map(|a| a.parse().unwrap()).collect();
    let params = SynthParams { seed: args[0] as u64, sag_mm: args[1], twist_deg: args[2], scale_range: args[3], pose_deg: args[4], pose_mm: args[5], ..SynthParams::default() };
    let case = generate(&params).unwrap();
    let rigid = case.path.transformed(&case.scan_from_cad_true);
    println!("true pose only: {:?}", path_errors(&rigid, &case.truth, |_| true).unwrap());
    println!("deformation {:?}", case.deformation);
    let view = View::From(case.scan_from_cad_nominal.inverse() * case.scanner_in_scan);
    let facing = facing_indices(&case.cad_points, view, -0.2).unwrap();
    println!("facing {} of {}", facing.len(), case.cad_points.len());
    let target = IcpTarget::new(case.cad_points.select(&facing).unwrap()).unwrap();
    let r = coarse_fit(&case.scan, &target, &case.scan_from_cad_nominal.inverse(), &CoarseSettings::default()).unwrap();
    println!("coarse: scale {} rmse {} fit {} it {} conv {}", r.scale, r.rmse_mm, r.fitness, r.iterations, r.converged);
    let s = r.target_from_source.inverse();
    println!("coarse vs true: rot {} deg, trans {}", trim_geom::transform::rotation_angle_between(&s, &case.scan_from_cad_true).to_degrees(), trim_geom::transform::translation_distance(&s, &case.scan_from_cad_true));
    println!("coarse path: {:?}", path_errors(&case.path.transformed(&s), &case.truth, |_| true).unwrap());
}
