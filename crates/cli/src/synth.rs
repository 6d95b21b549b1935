//! `trimctl synth`: writes a synthetic ceramic-core-like test case (see `trim_synth`).

use std::path::PathBuf;

use anyhow::Context;
use trim_synth::{SynthParams, generate};

/// Arguments of `trimctl synth`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder (created): cad.stl, cad_points.ply, path.csv, scan.ply, truth.csv, case.json;
    /// with --calibration: the calibration artefacts instead (see there).
    #[arg(long)]
    pub out: PathBuf,
    /// Write what the digital twin's true cell would give the calibration instead of a part:
    /// `job.toml` (the demo job on a twin carrying that true cell, `[sim.truth]`), the sphere
    /// scans `spheres/` with `poses.csv`, `tool_mark.txt` and `sphere_diameter_mm.txt` for
    /// `trimctl calibrate cell`, `marks.csv` for `trimctl calibrate field`, and `truth.json`.
    #[arg(long)]
    pub calibration: bool,
    /// With --calibration: which links of the true cell differ from nominal (comma-separated:
    /// axes, scanner, field, height), for a spot-error budget by link.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "axes,scanner,field,height"
    )]
    pub links: Vec<Link>,
    /// Random seed.
    #[arg(long, default_value_t = SynthParams::default().seed)]
    pub seed: u64,
    /// Bend: mid-length rise over the ends, mm.
    #[arg(long = "sag", default_value_t = SynthParams::default().sag_mm)]
    pub sag_mm: f64,
    /// Curl of the part's +Y end along its thickness (rising as the cube past 40 % of the half
    /// length), mm.
    #[arg(long = "tip-curl", default_value_t = SynthParams::default().tip_curl_mm)]
    pub tip_curl_mm: f64,
    /// The change of the part's shrinkage along its span, end to end (a density gradient from
    /// pressing: 0.002 is 0.2 % more at the +Y end than at the −Y end).
    #[arg(long = "shrink-gradient", default_value_t = SynthParams::default().shrink_gradient, allow_negative_numbers = true)]
    pub shrink_gradient: f64,
    /// Twist about the long axis end to end, degrees.
    #[arg(long = "twist", default_value_t = SynthParams::default().twist_deg)]
    pub twist_deg: f64,
    /// Per-axis scale drawn from [1 − R, 1 + R].
    #[arg(long, default_value_t = SynthParams::default().scale_range)]
    pub scale_range: f64,
    /// Scan noise (standard deviation per coordinate), mm.
    #[arg(long = "noise", default_value_t = SynthParams::default().noise_mm)]
    pub noise_mm: f64,
    /// Scan points drawn (before dropouts and the burr webs' thinning remove some, and the
    /// outliers are added).
    #[arg(long, default_value_t = SynthParams::default().scan_points)]
    pub scan_points: usize,
    /// Fixture rotation error, degrees.
    #[arg(long = "pose-deg", default_value_t = SynthParams::default().pose_deg)]
    pub pose_deg: f64,
    /// Fixture translation error, mm.
    #[arg(long = "pose-mm", default_value_t = SynthParams::default().pose_mm)]
    pub pose_mm: f64,
    /// Views of the scanner (1–4), fixed to the machine whatever the part's true pose: view 1
    /// looks at the top side, view 2 at the bottom, and so on, spread around the thickness axis.
    #[arg(long, default_value_t = SynthParams::default().scanner_views)]
    pub views: usize,
    /// The views' tilts from the thickness axis, degrees: one value (the first view; the others
    /// seeded in 10–55°) or one per view.
    #[arg(long = "view-tilts", value_delimiter = ',', default_values_t = [SynthParams::default().scanner_tilt_deg])]
    pub view_tilts_deg: Vec<f64>,
    /// The pressing axes (along which the per-axis scale acts) turned from the part's axes by up
    /// to this, degrees (0–30).
    #[arg(long = "pressing-tilt", default_value_t = SynthParams::default().pressing_tilt_deg)]
    pub pressing_tilt_deg: f64,
    /// The bend's direction turned from the part's thickness axis toward its chord, degrees
    /// (0–60): a core bends in its own plane too.
    #[arg(long = "bend-tilt", default_value_t = SynthParams::default().bend_tilt_deg)]
    pub bend_tilt_deg: f64,
    /// Share of contours with burrs (flash webs off the edge, 0–1); recorded in case.json.
    #[arg(long = "burrs", default_value_t = SynthParams::default().burr_fraction)]
    pub burr_fraction: f64,
    /// Burr height range (reach out of the material from the edge), mm.
    #[arg(long = "burr-height", value_delimiter = ',', num_args = 1, value_name = "MIN,MAX", default_values_t = SynthParams::default().burr_height_mm)]
    pub burr_height_mm: Vec<f64>,
    /// Burr thickness range, mm.
    #[arg(long = "burr-thickness", value_delimiter = ',', num_args = 1, value_name = "MIN,MAX", default_values_t = SynthParams::default().burr_thickness_mm)]
    pub burr_thickness_mm: Vec<f64>,
    /// Burr stretch length range along a contour, mm.
    #[arg(long = "burr-length", value_delimiter = ',', num_args = 1, value_name = "MIN,MAX", default_values_t = SynthParams::default().burr_length_mm)]
    pub burr_length_mm: Vec<f64>,
    /// Share of the holes and slots blocked by a film flush with the top face (0–1); recorded
    /// in case.json (`blockages`: contour, covered share, thickness, free edge).
    #[arg(long = "blockages", default_value_t = SynthParams::default().blockage_fraction)]
    pub blockage_fraction: f64,
    /// Blockage film thickness range, mm.
    #[arg(long = "blockage-thickness", value_delimiter = ',', num_args = 1, value_name = "MIN,MAX", default_values_t = SynthParams::default().blockage_thickness_mm)]
    pub blockage_thickness_mm: Vec<f64>,
    /// Range of the share of a blocked opening's area the film covers (0.05–1).
    #[arg(long = "blockage-share", value_delimiter = ',', num_args = 1, value_name = "MIN,MAX", default_values_t = SynthParams::default().blockage_share)]
    pub blockage_share: Vec<f64>,
    /// The template path's point spacing along its contours, mm (0.05–0.25; 0.05 gives ≈ 20k rows).
    #[arg(long = "path-spacing", default_value_t = SynthParams::default().path_spacing_mm)]
    pub path_spacing_mm: f64,
    /// The CAD mesh's edge length on the faces, mm (0.25–2; 0.35 gives 122k triangles).
    #[arg(long = "mesh-step", default_value_t = SynthParams::default().mesh_step_mm)]
    pub mesh_step_mm: f64,
    /// CAD points (cad_points.ply).
    #[arg(long, default_value_t = SynthParams::default().cad_points)]
    pub cad_points: usize,
    /// Outliers added, as a share of the scan points.
    #[arg(long = "outliers", default_value_t = SynthParams::default().outlier_fraction)]
    pub outlier_fraction: f64,
    /// Dropout patches (balls of 1.5–3 mm radius without scan points).
    #[arg(long, default_value_t = SynthParams::default().dropouts)]
    pub dropouts: usize,
}

/// A `MIN,MAX` flag's two numbers.
fn range(flag: &str, values: &[f64]) -> anyhow::Result<[f64; 2]> {
    match values {
        [lo, hi] => Ok([*lo, *hi]),
        _ => anyhow::bail!("--{flag}: expected MIN,MAX, got {} numbers", values.len()),
    }
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    if args.calibration {
        return calibration_artefacts(&args);
    }
    let (scanner_tilt_deg, view_tilts_deg) = match args.view_tilts_deg.as_slice() {
        [first] => (*first, Vec::new()),
        [first, rest @ ..] if args.view_tilts_deg.len() == args.views => (*first, rest.to_vec()),
        tilts => anyhow::bail!(
            "--view-tilts: expected one tilt (the first view) or one per view ({}), got {}",
            args.views,
            tilts.len()
        ),
    };
    let params = SynthParams {
        seed: args.seed,
        sag_mm: args.sag_mm,
        tip_curl_mm: args.tip_curl_mm,
        shrink_gradient: args.shrink_gradient,
        twist_deg: args.twist_deg,
        scale_range: args.scale_range,
        pressing_tilt_deg: args.pressing_tilt_deg,
        bend_tilt_deg: args.bend_tilt_deg,
        noise_mm: args.noise_mm,
        scan_points: args.scan_points,
        cad_points: args.cad_points,
        pose_deg: args.pose_deg,
        pose_mm: args.pose_mm,
        outlier_fraction: args.outlier_fraction,
        dropouts: args.dropouts,
        scanner_views: args.views,
        scanner_tilt_deg,
        view_tilts_deg,
        path_spacing_mm: args.path_spacing_mm,
        mesh_step_mm: args.mesh_step_mm,
        burr_fraction: args.burr_fraction,
        burr_height_mm: range("burr-height", &args.burr_height_mm)?,
        burr_thickness_mm: range("burr-thickness", &args.burr_thickness_mm)?,
        burr_length_mm: range("burr-length", &args.burr_length_mm)?,
        blockage_fraction: args.blockage_fraction,
        blockage_thickness_mm: range("blockage-thickness", &args.blockage_thickness_mm)?,
        blockage_share: range("blockage-share", &args.blockage_share)?,
    };
    let case = generate(&params).context("generating the synthetic case")?;
    case.write_case(&args.out)
        .with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "{}: {} contours ({} path points), {} scan points from {} view(s), {} CAD points, {} CAD triangles, {} burrs, {} blockages",
        args.out.display(),
        case.path.len(),
        case.path.points().count(),
        case.scan.len(),
        case.views.len(),
        case.cad_points.len(),
        case.cad_triangles.len(),
        case.burrs.len(),
        case.blockages.len()
    );
    Ok(())
}

/// The job file of the twin: the demo part on the simulated cell whose true cell is `truth`.
#[derive(serde::Serialize)]
struct TwinJob<'a> {
    sim: TwinSim<'a>,
}

#[derive(serde::Serialize)]
struct TwinSim<'a> {
    truth: &'a trim_cell::truth::TruthSettings,
}

/// A link of the chain from the scanner to the spot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Link {
    /// The rotary axis lines.
    Axes,
    /// The scanner's pose on the head.
    Scanner,
    /// The galvo head's field (offset, rotation, distortion).
    Field,
    /// The lens pivot height L (the height term).
    Height,
}

/// Marks per side of the field grid `synth --calibration` writes.
const FIELD_GRID: usize = 21;
/// Coupon heights of the field marks (mm).
const FIELD_HEIGHTS_MM: [f64; 3] = [0.0, 2.0, -2.0];
/// Measurement noise of a mark, per coordinate (µm; the thesis's microscope).
const MARK_NOISE_UM: f64 = 2.0;

/// The calibration sphere's diameter (mm).
const SPHERE_DIAMETER_MM: f64 = 25.4;
/// Where it sits on the table (table frame, mm).
const SPHERE_TABLE_MM: [f64; 3] = [40.0, 30.0, 25.0];
/// Scanner noise per coordinate (mm; the thesis's scanner).
const SCAN_NOISE_MM: f64 = 0.010;

/// `trimctl synth --calibration`.
fn calibration_artefacts(args: &Args) -> anyhow::Result<()> {
    let defaults = crate::config::JobConfig::default();
    let mut magnitudes = crate::twin_demo::TruthMagnitudes::default();
    if !args.links.contains(&Link::Axes) {
        magnitudes.axis_tilt_deg = 0.0;
        magnitudes.axis_offset_mm = 0.0;
    }
    if !args.links.contains(&Link::Scanner) {
        magnitudes.scanner_rotation_deg = 0.0;
        magnitudes.scanner_translation_mm = 0.0;
    }
    if !args.links.contains(&Link::Field) {
        magnitudes.head_offset_mm = 0.0;
        magnitudes.head_rotation_deg = 0.0;
        magnitudes.barrel_at_50_mm_um = 0.0;
        magnitudes.trapezoid_at_corner_um = 0.0;
    }
    if !args.links.contains(&Link::Height) {
        magnitudes.pivot_fraction = 0.0;
    }
    let truth = crate::twin_demo::demo_truth(
        args.seed,
        &defaults.plan.machine,
        defaults.plan.beam.focal_length_mm,
        &magnitudes,
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let job = format!(
        "# The built-in demo part on a simulated cell whose true geometry differs from the nominal\n\
         # one ([sim.truth], seed {}). Run it as is for the spot error before calibration; add the\n\
         # [calibration] that `trimctl calibrate cell` and `calibrate field` find for the after.\n\n{}",
        args.seed,
        toml::to_string(&TwinJob {
            sim: TwinSim { truth: &truth }
        })
        .context("serialising the twin's job")?
    );
    let job_file = args.out.join("job.toml");
    trim_geom::fs::write_atomic(&job_file, job)
        .with_context(|| format!("cannot write {}", job_file.display()))?;
    trim_geom::fs::write_atomic(
        args.out.join("truth.json"),
        serde_json::to_string_pretty(&truth)?,
    )?;
    // The field marks: a 21 × 21 grid over the field on coupons at 0 and ±2 mm, measured
    // (2 µm noise) relative to the field-centre mark, which the tool mark ties to the machine.
    let centred = trim_cell::lens::LensDistortion {
        offset_mm: [0.0, 0.0],
        ..truth.head
    };
    let marks = trim_calib::field_correction::synth_marks(
        &centred,
        truth
            .calibration
            .lens
            .pivot_to_focal_plane_mm
            .unwrap_or(defaults.plan.beam.focal_length_mm),
        &trim_calib::field_correction::MarkGrid {
            grid: FIELD_GRID,
            half_field_mm: 0.5
                * defaults.plan.galvo.field_mm[0].min(defaults.plan.galvo.field_mm[1]),
            heights_mm: FIELD_HEIGHTS_MM.to_vec(),
            noise_um: MARK_NOISE_UM,
            offset_fraction: 0.0,
        },
        args.seed,
    );
    trim_calib::field_correction::write_marks(&args.out.join("marks.csv"), &marks)?;
    // The sphere scans: a Ø 25.4 mm sphere on a stem on the table, scanned at the default
    // poses by the true scanner on the true table; the tool mark at command 0 lands where the
    // true head puts it.
    let plan = defaults.plan.clone();
    let nominal = trim_cell::cell_model::TableModel::nominal(&plan.machine);
    // The true cell's lines and scanner (as the digital twin resolves them).
    let true_cell = &truth.calibration;
    let sphere = trim_geom::Point3::from(SPHERE_TABLE_MM);
    let poses = trim_calib::artefact::default_poses(&nominal, &sphere);
    let artefacts = trim_calib::artefact::synth_artefacts(
        &trim_calib::artefact::ArtefactTruth {
            table: true_cell.table(&plan.machine),
            scanner: true_cell.scanner(),
            sphere_table_mm: sphere,
            diameter_mm: SPHERE_DIAMETER_MM,
            tool_offset_mm: truth.head.offset_mm,
        },
        &poses,
        SCAN_NOISE_MM,
        args.seed,
    );
    trim_calib::artefact::write_artefacts(&args.out, &artefacts, plan.machine.kinematics)?;
    trim_geom::fs::write_atomic(
        args.out.join("sphere_diameter_mm.txt"),
        format!("{SPHERE_DIAMETER_MM}\n"),
    )?;
    println!(
        "{}: job.toml (the twin's true cell), truth.json, marks.csv ({} marks), spheres/ ({} scans), poses.csv, tool_mark.txt, sphere_diameter_mm.txt",
        args.out.display(),
        marks.len(),
        artefacts.scans.len()
    );
    Ok(())
}
