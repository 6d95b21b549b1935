//! The part's inputs for `trimctl run`: the built-in demo part (written into the run folder),
//! or the job's CAD, path and scan files (one scan, or scans at several machine poses merged).

use std::path::Path;

use anyhow::{Context, bail};
use trim_geom::formats;
use trim_geom::math::Similarity3;
use trim_geom::{Path as TrimPath, PointCloud};
use trim_synth::{DEMO_SCANNER_VIEWS, SynthParams, generate};

use super::files;
use crate::cad::load_cad;
use crate::config::{HatchRegion, JobConfig, ScanPoses};

/// The part's inputs: CAD cloud with outward normals, the scan mapped into the work-piece
/// frame through `[calibration]` (`part.scans` each at its pose, merged), template path, the
/// fixture's nominal pose (`[part.scan_from_cad]`).
pub(super) struct Inputs {
    pub(super) cad: PointCloud,
    pub(super) scan: PointCloud,
    /// Each of `[part] scans` with the machine pose it was carried at (empty for one scan).
    pub(super) scan_poses: ScanPoses,
    pub(super) path: TrimPath,
    /// The regions to hatch: `[[hatch]]`, or the demo part's own region.
    pub(super) hatch: Vec<HatchRegion>,
    pub(super) scan_from_cad_initial: Similarity3,
    pub(super) description: String,
    /// The built-in demo part as generated (its own frame) and where the fixture holds it:
    /// what the digital twin trims and rescans (`--verify`), and whose CAD mesh detection
    /// measures against (`[trim] only_detected`).
    pub(super) demo: Option<DemoPart>,
}

/// The built-in demo part: the synthetic case in its own frame and its placement.
#[cfg_attr(
    not(feature = "sim"),
    expect(dead_code, reason = "read by --verify, which needs the simulators")
)]
pub(super) struct DemoPart {
    pub(super) case: trim_synth::SynthCase,
    pub(super) workpiece_from_case: Similarity3,
}

/// The share of the demo's contours that carry burrs under `--verify` or `[trim] only_detected`.
pub const DEMO_VERIFY_BURRS: f64 = 0.3;

/// What makes the built-in demo part: `--demo-seed`, `--demo-blockages`, and whether it carries
/// burrs (something looks for them: `--verify`'s inspections or `[trim] only_detected`'s). The
/// generator is deterministic, so the same spec makes the same part again (a resumed
/// `--verify` run recreates the twin's part from it, `verify_state.json`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct DemoSpec {
    /// `--demo-seed`.
    pub(super) seed: u64,
    /// `--demo-blockages`: the share of the openings that carry a film.
    pub(super) blockages: f64,
    /// Whether 30 % of the contours carry burrs ([`DEMO_VERIFY_BURRS`]).
    pub(super) burred: bool,
}

/// The part's inputs. The demo part (`config.is_demo()`) is made from `spec`; its files (the
/// path, the true line, the scan as the scanner saw it, the CAD points, the hatch boundary) are
/// written into `run_dir/inputs/` when `write` (a resume finds them there).
pub(super) fn load_inputs(
    config: &JobConfig,
    spec: &DemoSpec,
    run_dir: &Path,
    write: bool,
) -> anyhow::Result<Inputs> {
    let fixture = config
        .part
        .scan_from_cad
        .scan_from_cad("part.scan_from_cad")?;
    if config.is_demo() {
        let burred = spec.burred;
        let params = SynthParams {
            seed: spec.seed,
            scanner_views: DEMO_SCANNER_VIEWS,
            burr_fraction: if burred { DEMO_VERIFY_BURRS } else { 0.0 },
            blockage_fraction: spec.blockages,
            ..SynthParams::default()
        };
        let mut case = generate(&params).context("building the demo part")?;
        let demo = burred.then(|| DemoPart {
            case: case.clone(),
            workpiece_from_case: fixture,
        });
        // The fixture holds the demo part at [part.scan_from_cad]: the synthetic scene (placed
        // about the identity) moves there, the ground truth with it.
        case.scan = case
            .scan
            .transformed(&fixture)
            .context("part.scan_from_cad")?;
        case.truth = case
            .truth
            .transformed(&fixture)
            .context("part.scan_from_cad")?;
        case.scan_from_cad_nominal = fixture * case.scan_from_cad_nominal;
        let dir = run_dir.join(files::INPUTS);
        // The synthetic part lives in the true work-piece frame; the scanner sees it through
        // the true cell ([sim.truth]) at the scan pose.
        let scanner_from_workpiece =
            Similarity3::from_isometry(crate::simulated::true_scanner_from_workpiece(config)?, 1.0);
        let scan_in_scanner = case
            .scan
            .transformed(&scanner_from_workpiece)
            .context("sim.truth at part.scan_pose")?;
        if write {
            std::fs::create_dir_all(&dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            formats::write_path(&dir.join("path.csv"), &case.path)?;
            formats::write_path(&dir.join(files::TRUTH), &case.truth)?;
            formats::write_ply(
                &dir.join("scan.ply"),
                &scan_in_scanner,
                formats::PlyEncoding::BinaryLittleEndian,
            )?;
            formats::write_ply(
                &dir.join("cad_points.ply"),
                &case.cad_points,
                formats::PlyEncoding::BinaryLittleEndian,
            )?;
        }
        // The demo hatches a flash film on its top face unless the job names its own regions.
        let hatch = if config.hatch.is_empty() {
            let boundary = dir.join(DEMO_HATCH_BOUNDARY);
            if write {
                formats::write_path(
                    &boundary,
                    &TrimPath::new(vec![trim_synth::demo_hatch_boundary()?])?,
                )?;
            }
            vec![HatchRegion {
                boundary,
                settings: demo_hatch_settings(),
            }]
        } else {
            config.hatch.clone()
        };
        return Ok(Inputs {
            hatch,
            description: format!(
                "built-in demo part (synthetic ceramic core, seed {}, {} contours, {} scan points)",
                spec.seed,
                case.path.len(),
                case.scan.len()
            ),
            cad: case.cad_points,
            scan: config.workpiece_from_scan(&scan_in_scanner)?,
            scan_poses: Vec::new(),
            path: case.path,
            scan_from_cad_initial: case.scan_from_cad_nominal,
            demo,
        });
    }
    let (Some(cad_file), Some(path_file)) = (&config.part.cad, &config.part.path) else {
        bail!("part: give all of cad, path and scan (or scans with poses)");
    };
    let scanned = match (&config.part.scan, config.part.poses.as_deref()) {
        (Some(scan_file), _) => format!("scan {}", scan_file.display()),
        (None, Some(poses_file)) => format!(
            "scans {} at the poses of {}",
            config
                .part
                .scans
                .iter()
                .map(|f| f.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
            poses_file.display()
        ),
        (None, None) => bail!("part: give all of cad, path and scan (or scans with poses)"),
    };
    let cad = load_cad(cad_file, "part.cad", config.register.cad_sample_points)?;
    let (scan, scan_poses) = config.part_scan_in_workpiece()?;
    let path = formats::read_path(path_file)?;
    if !config.hatch.is_empty() {
        crate::hatch::check_path_ids(&path, path_file)?;
    }
    Ok(Inputs {
        hatch: config.hatch.clone(),
        description: format!(
            "CAD {}, path {} ({} contours), {scanned} ({} points)",
            cad_file.display(),
            path_file.display(),
            path.len(),
            scan.len()
        ),
        cad,
        scan,
        scan_poses,
        path,
        scan_from_cad_initial: fixture,
        demo: None,
    })
}

/// The demo's hatch boundary file, in the run folder's inputs.
const DEMO_HATCH_BOUNDARY: &str = "hatch_boundary.csv";

/// The demo region's hatching: 0.05 mm pitch across the top face's camber (the planner splits
/// tracks where the incidence limit requires), points placed by a 2 µm chord tolerance (vector
/// marking).
fn demo_hatch_settings() -> trim_plan::hatch::HatchSettings {
    trim_plan::hatch::HatchSettings {
        pitch_mm: 0.05,
        chord_tolerance_mm: Some(0.002),
        ..trim_plan::hatch::HatchSettings::default()
    }
}
