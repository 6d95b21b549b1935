//! `job.toml`: one serde schema for a whole job. Defaults live in code; `trimctl config --dump`
//! prints the full default file with a comment on every key ([`dump_default`], from
//! [`KEY_DOCS`]); unknown keys and out-of-range values are refused with the key named.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use toml::Value;
use trim_io::twin::TruthSettings;
use trim_plan::cell::{Calibration, ScanPose};
use trim_plan::field::LensSettings;
use trim_plan::hatch::HatchSettings;
use trim_plan::kinematics::MachineSettings;
use trim_plan::layer::LayerSettings;
use trim_plan::planner::PlanSettings;
use trim_plan::{Beam, GalvoSettings, ZoningSettings};
use trim_register::regional::RegisterSettings;

/// A whole job: part files, registration, planning (incidence limit, beam, zoning, layers, lens
/// field, machine, galvo), the cell and the output folder. Each table is one section of job.toml.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JobConfig {
    /// The part's files.
    pub part: PartConfig,
    /// Registration of the CAM path onto the scan.
    pub register: RegisterSettings,
    /// The incidence limit (degrees).
    pub max_incidence_deg: f64,
    /// Beam optics (paper §2.1–2.2).
    pub beam: Beam,
    /// Zoning (paper §2.4).
    pub zoning: ZoningSettings,
    /// Layering (paper Eq. 14).
    pub layers: LayerSettings,
    /// Lens and scan-field sectioning.
    pub field: LensSettings,
    /// Machine kinematics, limits and speeds.
    pub machine: MachineSettings,
    /// Galvo field, calibration, speeds and delays.
    pub galvo: GalvoSettings,
    /// The cell as calibrated (`trimctl calibrate`): axis lines, scanner pose, field, lens.
    pub calibration: Calibration,
    /// Where the devices are.
    pub cell: CellConfig,
    /// The built-in simulators (the digital twin's true cell).
    pub sim: SimConfig,
    /// Where the run folder goes.
    pub output: OutputConfig,
    /// Regions to hatch (`[[hatch]]`), planned beside the contours.
    pub hatch: Vec<HatchRegion>,
}

/// One region to hatch (a `[[hatch]]` table): a boundary file plus the hatching keys
/// (`trim_plan::hatch::HatchSettings`: `pitch_mm`, `angle_deg`, `method`, `step_mm`,
/// `chord_tolerance_mm`, `outline`, `grid_mm`), all in one flat table.
#[derive(Debug, Clone, PartialEq)]
pub struct HatchRegion {
    /// Path CSV with one closed contour lying on the part's surface, in the CAD frame (like
    /// `part.path`): registration carries it onto the scan. Relative to the job file.
    pub boundary: PathBuf,
    /// How to hatch it.
    pub settings: HatchSettings,
}

impl Serialize for HatchRegion {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::Error as _;
        let settings = match Value::try_from(&self.settings).map_err(S::Error::custom)? {
            Value::Table(t) => t,
            other => return Err(S::Error::custom(format!("hatch settings: {other}"))),
        };
        // The boundary first, as a reader expects.
        let mut table = toml::Table::new();
        table.insert(
            "boundary".to_owned(),
            Value::String(self.boundary.display().to_string()),
        );
        table.extend(settings);
        table.serialize(s)
    }
}

impl<'de> Deserialize<'de> for HatchRegion {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::Error as _;
        let mut table = toml::Table::deserialize(d)?;
        let boundary = match table.remove("boundary") {
            Some(Value::String(s)) => PathBuf::from(s),
            Some(other) => {
                return Err(D::Error::custom(format!(
                    "boundary: expected a file name, got {other}"
                )));
            }
            None => return Err(D::Error::missing_field("boundary")),
        };
        let settings: HatchSettings = Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| D::Error::custom(e.message().trim()))?;
        Ok(HatchRegion { boundary, settings })
    }
}

impl Default for JobConfig {
    fn default() -> Self {
        let plan = PlanSettings::default();
        JobConfig {
            part: PartConfig::default(),
            register: RegisterSettings::default(),
            max_incidence_deg: plan.max_incidence_deg,
            beam: plan.beam,
            zoning: plan.zoning,
            layers: plan.layers,
            field: plan.field,
            machine: plan.machine,
            galvo: plan.galvo,
            calibration: plan.calibration,
            cell: CellConfig::default(),
            sim: SimConfig::default(),
            output: OutputConfig::default(),
            hatch: Vec::new(),
        }
    }
}

/// The part's input files. Relative paths are relative to the job file's folder. With no CAD,
/// path and scan, `trimctl run` uses the built-in demo part.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PartConfig {
    /// The CAD model: STL or PLY mesh, or a point cloud (PLY, PCD, XYZ).
    pub cad: Option<PathBuf>,
    /// The CAM template path (path CSV).
    pub path: Option<PathBuf>,
    /// The scan of the clamped part (PLY, PCD, XYZ), in the scanner frame.
    pub scan: Option<PathBuf>,
    /// The machine pose the scan was taken at.
    pub scan_pose: ScanPose,
}

/// The built-in simulators (job.toml `[sim]`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// The true cell the simulators carry (the digital twin); the nominal cell when empty.
    pub truth: TruthSettings,
}

/// Device addresses. `"sim"` starts the built-in simulator for that device.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CellConfig {
    /// The CNC (LinuxCNC linuxcncrsh) as HOST:PORT, or "sim".
    pub cnc: String,
    /// The galvo controller as HOST:PORT, or "sim".
    pub galvo: String,
    /// The laser's serial device (e.g. /dev/ttyUSB0), or "sim".
    pub laser: String,
    /// The laser command profile: "monaco" or "ipg".
    pub laser_profile: String,
}

impl Default for CellConfig {
    fn default() -> Self {
        CellConfig {
            cnc: SIM.into(),
            galvo: SIM.into(),
            laser: SIM.into(),
            laser_profile: "monaco".into(),
        }
    }
}

/// The word that selects a built-in simulator in [`CellConfig`].
pub const SIM: &str = "sim";

/// Where runs are recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// The folder under which each run gets a new time-stamped folder.
    pub runs_dir: PathBuf,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            runs_dir: PathBuf::from("runs"),
        }
    }
}

impl JobConfig {
    /// Reads and checks a job file. Relative part paths are resolved against its folder.
    pub fn load(path: &Path) -> anyhow::Result<JobConfig> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read job file {}", path.display()))?;
        let mut config =
            JobConfig::parse(&text).with_context(|| format!("job file {}", path.display()))?;
        let base = path.parent().unwrap_or(Path::new("."));
        for p in [
            &mut config.part.cad,
            &mut config.part.path,
            &mut config.part.scan,
        ]
        .into_iter()
        .chain([
            &mut config.calibration.field_correction,
            &mut config.sim.truth.path,
        ])
        .flatten()
        {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        }
        for h in &mut config.hatch {
            if h.boundary.is_relative() {
                h.boundary = base.join(&h.boundary);
            }
        }
        Ok(config)
    }

    /// Parses job TOML and checks every value's range.
    pub fn parse(text: &str) -> anyhow::Result<JobConfig> {
        // One line: where (line and key path), then toml's message.
        let where_in = |e: &toml::de::Error| {
            e.span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
        };
        let de = toml::Deserializer::parse(text).map_err(|e| {
            let message = e.message().trim().replace('\n', " ");
            match where_in(&e) {
                Some(l) => anyhow::anyhow!("line {l}: {message}"),
                None => anyhow::anyhow!("{message}"),
            }
        })?;
        let config: JobConfig = serde_path_to_error::deserialize(de).map_err(|e| {
            let key = e.path().to_string();
            let inner = e.inner();
            let message = inner.message().trim().replace('\n', " ");
            let key = if key == "." {
                String::new()
            } else {
                format!("{key}: ")
            };
            match where_in(inner) {
                Some(l) => anyhow::anyhow!("line {l}: {key}{message}"),
                None => anyhow::anyhow!("{key}{message}"),
            }
        })?;
        config.validate()?;
        Ok(config)
    }

    /// Checks every value's range, naming the key at fault.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.plan_settings().validate()?;
        self.sim
            .truth
            .validate(self.machine.kinematics)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        self.register
            .validate()
            .map_err(|e| anyhow::anyhow!("register.{e}"))?;
        for (key, value) in [
            ("cell.cnc", &self.cell.cnc),
            ("cell.galvo", &self.cell.galvo),
        ] {
            if value != SIM && value.parse::<std::net::SocketAddr>().is_err() {
                bail!("{key}: expected HOST:PORT (e.g. 127.0.0.1:5007) or \"sim\", got {value:?}");
            }
        }
        if self.cell.laser.is_empty() {
            bail!("cell.laser: expected a serial device path or \"sim\"");
        }
        if !["monaco", "ipg"].contains(&self.cell.laser_profile.as_str()) {
            bail!(
                "cell.laser_profile: expected \"monaco\" or \"ipg\", got {:?}",
                self.cell.laser_profile
            );
        }
        for (i, h) in self.hatch.iter().enumerate() {
            h.settings
                .validate()
                .map_err(|e| anyhow::anyhow!("hatch[{i}] ({}): {e}", h.boundary.display()))?;
        }
        let parts = [&self.part.cad, &self.part.path, &self.part.scan];
        let given = parts.iter().filter(|p| p.is_some()).count();
        if given != 0 && given != 3 {
            bail!("part: give all of cad, path and scan, or none (for the built-in demo part)");
        }
        Ok(())
    }

    /// The planner's settings.
    pub fn plan_settings(&self) -> PlanSettings {
        PlanSettings {
            max_incidence_deg: self.max_incidence_deg,
            beam: self.beam,
            zoning: self.zoning,
            layers: self.layers,
            field: self.field,
            machine: self.machine,
            galvo: self.galvo,
            calibration: self.calibration.clone(),
        }
    }

    /// The scan (scanner frame) in the work-piece frame: through the scanner's pose on the
    /// head, the machine pose of `[part.scan_pose]` and the rotary axes, all as `[calibration]`
    /// says.
    pub fn scan_to_workpiece(
        &self,
        scan_in_scanner: &trim_geom::PointCloud,
    ) -> trim_geom::PointCloud {
        let settings = self.plan_settings();
        let chain = trim_plan::cell::ScanChain {
            table: settings.table(),
            scanner: self.calibration.scanner(),
            pose: self.part.scan_pose,
            workpiece_origin_mm: settings.machine.workpiece_origin_mm.into(),
        };
        scan_in_scanner.transformed(&trim_geom::math::Similarity3::from_isometry(
            chain.workpiece_from_scanner(),
            1.0,
        ))
    }

    /// Whether the job runs the built-in demo part.
    pub fn is_demo(&self) -> bool {
        self.part.cad.is_none()
    }
}

/// The file's opening comment.
const HEADER: &str = "\
# trimctl job file. Every key is optional: a missing key takes the default shown here.
# Units are in the key names: _mm millimetres, _deg degrees, _us microseconds, _s seconds.
# `trimctl config --dump > job.toml` writes this file; `trimctl run job.toml` runs it.
";

/// One comment per key (dotted path) and, for keys unset by default, an example value shown
/// commented out. A test checks that every key of the default file has one.
pub const KEY_DOCS: &[(&str, &str, Option<&str>)] = &[
    (
        "hatch",
        "Regions to hatch beside the contours, each a [[hatch]] table: boundary = a path CSV with one closed contour on the part's surface, CAD frame (registration carries it onto the scan), plus the hatching keys pitch_mm (default 0.05), angle_deg (0), method (\"geodesic\" or \"slab\"), step_mm or chord_tolerance_mm (point placement along a track; default a step of one pitch), outline (true) and grid_mm. The tracks (surface normals as feature vectors) are zoned, layered and projected like contours. The built-in demo part hatches one region of its top face when this is empty.",
        None,
    ),
    (
        "part",
        "The part's files, relative to this file. Leave all three out for the built-in demo part.",
        None,
    ),
    (
        "part.cad",
        "CAD model: STL or PLY mesh, or a PLY/PCD/XYZ point cloud with normals.",
        Some("\"cad.stl\""),
    ),
    (
        "part.path",
        "CAM template path: CSV with columns contour,x,y,z,u,v,w (mm, unit feature vector).",
        Some("\"path.csv\""),
    ),
    (
        "part.scan",
        "Scan of the clamped part: PLY, PCD or XYZ (normals optional).",
        Some("\"scan.ply\""),
    ),
    (
        "part.scan_pose",
        "The machine pose the scan was taken at: linear joint positions (the tool point, machine frame) and rotary axes. The scan is mapped into the work-piece frame through [calibration].",
        None,
    ),
    (
        "part.scan_pose.xyz_mm",
        "X, Y, Z joint positions, mm.",
        None,
    ),
    (
        "part.scan_pose.tilt_deg",
        "The tilting axis (A, or B on a B/C cell), degrees.",
        None,
    ),
    ("part.scan_pose.c_deg", "C, degrees.", None),
    (
        "calibration",
        "The cell as measured by `trimctl calibrate cell` / `calibrate field` (docs/DESIGN.md \"Frames and the calibration chain\"). A missing key is the nominal value of [machine] (axis lines), the identity (scanner) or none (field correction).",
        None,
    ),
    (
        "calibration.a_axis_point_mm",
        "A point on the A line at A = C = 0, machine frame, mm (xyzac-trt).",
        Some("[0.0, 20.0, 10.0]"),
    ),
    (
        "calibration.a_axis_direction",
        "The A line's unit direction (right-hand rule); nominal +X.",
        Some("[1.0, 0.0, 0.0]"),
    ),
    (
        "calibration.b_axis_point_mm",
        "A point on the B line at B = C = 0, machine frame, mm (xyzbc-trt).",
        Some("[-20.0, 0.0, -15.0]"),
    ),
    (
        "calibration.b_axis_direction",
        "The B line's unit direction; nominal +Y.",
        Some("[0.0, 1.0, 0.0]"),
    ),
    (
        "calibration.c_axis_point_mm",
        "A point on the C line, given at A (B) = 0, machine frame, mm.",
        Some("[0.0, 0.0, 0.0]"),
    ),
    (
        "calibration.c_axis_direction",
        "The C line's unit direction; nominal +Z.",
        Some("[0.0, 0.0, 1.0]"),
    ),
    (
        "calibration.scanner_rotation",
        "R of the scanner on the head (3×3, rows): a scanner point s is at (X, Y, Z) + R·s + t.",
        Some("[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]"),
    ),
    (
        "calibration.scanner_translation_mm",
        "t of the scanner on the head, mm.",
        Some("[0.0, 0.0, 0.0]"),
    ),
    (
        "calibration.field_correction",
        "The galvo field correction from `trimctl calibrate field` (field.json), relative to this file.",
        Some("\"field.json\""),
    ),
    ("calibration.lens", "The lens.", None),
    (
        "calibration.lens.pivot_to_focal_plane_mm",
        "L: the scan pivot's height above the focal plane, mm. A point h above the focal plane is reached at (L − h)/L of its focal-plane position. Unset: the field correction's value, else beam.focal_length_mm. Ignored for a telecentric lens.",
        Some("254.0"),
    ),
    (
        "sim",
        "The built-in simulators used where [cell] says \"sim\".",
        None,
    ),
    (
        "sim.truth",
        "The digital twin: the true cell the simulators carry, which may differ from the nominal one and from [calibration]. The galvo simulator lands every marked vector on the true part and the run reports the spot error. Empty: a perfect nominal cell.",
        None,
    ),
    (
        "sim.truth.a_axis_point_mm",
        "The true A line's point, machine frame, mm.",
        Some("[0.05, 20.08, 9.97]"),
    ),
    (
        "sim.truth.a_axis_direction",
        "The true A line's direction.",
        Some("[1.0, 0.0003, -0.0002]"),
    ),
    (
        "sim.truth.b_axis_point_mm",
        "The true B line's point (xyzbc-trt), mm.",
        Some("[-20.05, 0.0, -15.03]"),
    ),
    (
        "sim.truth.b_axis_direction",
        "The true B line's direction (xyzbc-trt).",
        Some("[0.0002, 1.0, 0.0003]"),
    ),
    (
        "sim.truth.c_axis_point_mm",
        "The true C line's point, mm.",
        Some("[-0.04, 0.06, 0.0]"),
    ),
    (
        "sim.truth.c_axis_direction",
        "The true C line's direction.",
        Some("[0.0004, -0.0001, 1.0]"),
    ),
    (
        "sim.truth.scanner_rotation",
        "The scanner's true rotation on the head (3×3, rows).",
        Some("[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]"),
    ),
    (
        "sim.truth.scanner_translation_mm",
        "The scanner's true translation on the head, mm.",
        Some("[0.3, -0.2, 0.15]"),
    ),
    (
        "sim.truth.pivot_to_focal_plane_mm",
        "The lens's true pivot height L, mm (unset: beam.focal_length_mm).",
        Some("262.0"),
    ),
    (
        "sim.truth.path",
        "The true trimming line (path CSV, work-piece frame) the spot error is measured against; the built-in demo part brings its own.",
        Some("\"truth.csv\""),
    ),
    (
        "sim.truth.head",
        "The galvo head's true field: where a command c lands on the focal plane, offset + rotation·(c·(1 + barrel·|c|²) + trapezoid terms).",
        None,
    ),
    (
        "sim.truth.head.offset_mm",
        "Where the zero command lands, head frame, mm.",
        None,
    ),
    (
        "sim.truth.head.rotation_deg",
        "The head's rotation about the beam axis, degrees.",
        None,
    ),
    (
        "sim.truth.head.barrel_per_mm2",
        "Radial distortion k: c ↦ c·(1 + k·|c|²), 1/mm².",
        None,
    ),
    (
        "sim.truth.head.trapezoid_per_mm",
        "Keystone: x gains x·(tx·y), y gains y·(ty·x), 1/mm.",
        None,
    ),
    (
        "max_incidence_deg",
        "Incidence limit: the largest angle between a contour's feature vector and the beam, lens ray angle included.",
        None,
    ),
    ("output", "Where runs are recorded.", None),
    (
        "output.runs_dir",
        "Each run writes a new time-stamped folder here (or the folder given with --out).",
        None,
    ),
    (
        "cell",
        "Where the devices are: \"sim\" starts the built-in simulator for that device.",
        None,
    ),
    (
        "cell.cnc",
        "LinuxCNC linuxcncrsh as HOST:PORT (e.g. \"127.0.0.1:5007\"), or \"sim\".",
        None,
    ),
    (
        "cell.galvo",
        "Galvo controller as HOST:PORT, or \"sim\".",
        None,
    ),
    (
        "cell.laser",
        "Laser serial device (e.g. \"/dev/ttyUSB0\"), or \"sim\".",
        None,
    ),
    (
        "cell.laser_profile",
        "Laser command profile: \"monaco\" (Coherent-Monaco-like) or \"ipg\" (IPG-like).",
        None,
    ),
    (
        "register",
        "Registration of the CAM path onto the scan (docs/DESIGN.md \"Registration\").",
        None,
    ),
    (
        "register.coarse",
        "The coarse stage: a global similarity from the fixture pose.",
        None,
    ),
    (
        "register.field",
        "The field stage: a smooth deformation field over the part.",
        None,
    ),
    (
        "register.quality",
        "The quality tests that flag a contour untrustworthy.",
        None,
    ),
    (
        "beam",
        "Laser and lens (paper §2.1-2.2); the defaults are the paper's cell.",
        None,
    ),
    (
        "zoning",
        "k-means zoning under the incidence limit (paper §2.4).",
        None,
    ),
    (
        "layers",
        "Layers along each zone axis (paper Eq. 14).",
        None,
    ),
    ("field", "The lens and the galvo field.", None),
    (
        "machine",
        "Machine kinematics, travel limits and speeds (LinuxCNC names).",
        None,
    ),
    (
        "galvo",
        "Galvo field, calibration, speeds and delays.",
        None,
    ),
    (
        "register.mode",
        "Regional (field) or global (similarity only).",
        None,
    ),
    (
        "register.scanner_viewpoint_mm",
        "The scanner's position in the scan frame, mm. When absent the scanner is taken to look along `−view_direction` from infinitely far.",
        Some("[0.0, 0.0, 500.0]"),
    ),
    (
        "register.view_direction",
        "Direction toward the scanner in the scan frame (used without a viewpoint).",
        None,
    ),
    (
        "register.facing_min_cos",
        "CAD points whose normal makes `cos < facing_min_cos` with the direction to the scanner are culled (−0.2 keeps walls up to 102° off the view).",
        None,
    ),
    (
        "register.cad_sample_points",
        "Points sampled from a CAD mesh.",
        None,
    ),
    ("register.coarse.init", "Where to start.", None),
    (
        "register.coarse.max_init_rotation_deg",
        "The principal-axes start is refused beyond this rotation from the nominal pose, degrees.",
        None,
    ),
    (
        "register.coarse.min_voxel_points",
        "A voxel must hold this many scan points to count (drops isolated outliers).",
        None,
    ),
    (
        "register.coarse.levels",
        "Pyramid levels, coarse to fine (scan voxel size, maximum distance, iterations).",
        None,
    ),
    (
        "register.coarse.with_scale",
        "Estimate a uniform scale at the finest level (the coarser levels are rigid: a scan → CAD fit with a free scale at coarse resolution can shrink the scan onto the surface).",
        None,
    ),
    (
        "register.coarse.huber_fraction",
        "Huber threshold as a fraction of each level's maximum distance.",
        None,
    ),
    (
        "register.field.spacing_mm",
        "Control-point spacing, mm.",
        None,
    ),
    (
        "register.field.voxel_mm",
        "Scan thinning voxel for the fit (one real point kept per voxel), mm.",
        None,
    ),
    (
        "register.field.iterations",
        "Gauss-Newton iterations.",
        None,
    ),
    (
        "register.field.max_distance_start_mm",
        "Maximum correspondence distance at the first iteration, mm.",
        None,
    ),
    (
        "register.field.max_distance_end_mm",
        "…shrinking geometrically to this by iteration `iterations − 3`, mm.",
        None,
    ),
    ("register.field.huber_mm", "Huber threshold, mm.", None),
    (
        "register.field.smoothness",
        "Weight of the second-difference prior relative to the mean data weight per unknown.",
        None,
    ),
    (
        "register.quality.coverage_radius_mm",
        "A contour point is covered when a matched scan point lies within this, mm.",
        None,
    ),
    (
        "register.quality.patch_radius_mm",
        "Scan points within this of a contour make its local patch, mm.",
        None,
    ),
    (
        "register.quality.min_coverage",
        "Flag a contour covered on less than this fraction of its points.",
        None,
    ),
    (
        "register.quality.max_residual_mm",
        "Flag a contour whose patch residual (RMS, mm) exceeds this.",
        None,
    ),
    (
        "register.quality.min_degeneracy_ratio",
        "A patch is degenerate when `λmin/λmax` of its `Σ n nᵀ` is below this.",
        None,
    ),
    (
        "register.quality.support_radius_mm",
        "The surroundings (within this, mm) must constrain a degenerate patch's weakest direction.",
        None,
    ),
    (
        "register.quality.min_overlap",
        "Refuse the whole registration when fewer than this fraction of scan points lie within `overlap_distance_mm` of the CAD after the coarse stage.",
        None,
    ),
    (
        "register.quality.overlap_distance_mm",
        "Distance for the overlap test, mm.",
        None,
    ),
    ("beam.power_w", "Average laser power P (W).", None),
    (
        "beam.repetition_rate_hz",
        "Pulse repetition rate h (Hz).",
        None,
    ),
    ("beam.wavelength_nm", "Wavelength λ (nm).", None),
    ("beam.m_squared", "Beam quality factor M².", None),
    (
        "beam.focal_length_mm",
        "Effective focal length f of the (f-theta) lens (mm).",
        None,
    ),
    (
        "beam.beam_diameter_mm",
        "Beam diameter D at the lens entrance (mm).",
        None,
    ),
    (
        "beam.fluence_tolerance",
        "Fluence tolerance t: the fraction of the peak fluence that still processes (0.97 means within 3 % of F0); sets the focus processing length.",
        None,
    ),
    (
        "beam.fluence_threshold_ratio",
        "F0/F_th: peak fluence over the material's ablation threshold.",
        None,
    ),
    (
        "beam.incidence_deg",
        "The incidence θ at which the spot ratios are reported (degrees).",
        None,
    ),
    (
        "beam.line_width_tolerance",
        "The allowed relative change of the spot radius (line width) with incidence, e.g. 0.005 for ±0.5 %; sets [`Beam::max_incidence_for_line_width_rad`].",
        None,
    ),
    (
        "zoning.method",
        "\"kmeans\": the paper's k-means zoning under (limit − lens budget), then field sections; \"cover\": pose selection as covering (axis + field centre per pose, incidence checked with the real lens ray), fewer poses.",
        None,
    ),
    (
        "zoning.k",
        "A fixed number of zones; unset: the smallest that keeps the incidence limit.",
        Some("10"),
    ),
    (
        "zoning.position_weight",
        "The weight of the (extent-scaled) positions against the unit feature vectors.",
        None,
    ),
    (
        "zoning.restarts",
        "k-means runs with different k-means++ seeds; the lowest inertia wins.",
        None,
    ),
    (
        "zoning.seed",
        "The seed of the k-means random generator.",
        None,
    ),
    (
        "zoning.max_iterations",
        "The most Lloyd iterations per run.",
        None,
    ),
    (
        "zoning.max_auto_k",
        "The largest k the automatic search tries before splitting zones greedily.",
        None,
    ),
    (
        "zoning.merge",
        "Merge zones after an automatic k-means while the union keeps the limits (see the module docs). A fixed k is kept as given.",
        None,
    ),
    (
        "layers.step_mm",
        "ΔH (mm); unset: derived from the beam, 2 · focus half length · `step_safety`.",
        Some("0.3"),
    ),
    (
        "layers.step_safety",
        "The fraction of the focus processing length a layer may use on each side.",
        None,
    ),
    (
        "field.telecentric",
        "A telecentric lens: the beam is parallel to the optical axis everywhere in the field.",
        None,
    ),
    (
        "field.lens_ray_budget_deg",
        "For a non-telecentric lens: the part of the incidence limit reserved for the lens ray angle (degrees). Zoning keeps feature vectors within (limit − this) of the zone axis; sectioning then keeps feature-to-ray angles within the full limit.",
        None,
    ),
    ("machine.kinematics", "The kinematics.", None),
    ("machine.pose_mode", "What the Job's pose values are.", None),
    (
        "machine.x_limits_mm",
        "X travel [min, max] (mm), axis and joint.",
        None,
    ),
    ("machine.y_limits_mm", "Y travel (mm).", None),
    ("machine.z_limits_mm", "Z travel (mm).", None),
    ("machine.a_limits_deg", "A travel (degrees).", None),
    (
        "machine.b_limits_deg",
        "B travel (degrees; the sim's joint 3 limits).",
        None,
    ),
    ("machine.c_limits_deg", "C travel (degrees).", None),
    (
        "machine.rot_point_mm",
        "LinuxCNC `x/y/z-rot-point` (mm).",
        None,
    ),
    (
        "machine.x_offset_mm",
        "LinuxCNC `x-offset` (B/C only; the sim's xyzbc-trt uses −20) (mm).",
        None,
    ),
    (
        "machine.y_offset_mm",
        "LinuxCNC `y-offset` (A/C only) (mm).",
        None,
    ),
    (
        "machine.z_offset_mm",
        "LinuxCNC `z-offset` (the sim's xyzac-trt uses 10, xyzbc-trt −15) (mm).",
        None,
    ),
    (
        "machine.tool_offset_mm",
        "LinuxCNC `tool-offset`: the tool length of the active tool (mm).",
        None,
    ),
    (
        "machine.workpiece_origin_mm",
        "The work-piece frame's origin in the table frame (mm).",
        None,
    ),
    (
        "machine.linear_speed_mm_per_s",
        "Linear joint speed for the time estimate (mm/s).",
        None,
    ),
    (
        "machine.rotary_speed_deg_per_s",
        "Rotary joint speed for the time estimate (degrees/s).",
        None,
    ),
    (
        "machine.settle_s",
        "Time to settle in position after each move (s).",
        None,
    ),
    (
        "galvo.field_mm",
        "The usable field, width and height (mm), centred on the optical axis.",
        None,
    ),
    (
        "galvo.bits_per_mm",
        "Calibration: galvo bits per millimetre in the field.",
        None,
    ),
    ("galvo.mark_speed_mm_per_s", "Marking speed (mm/s).", None),
    ("galvo.jump_speed_mm_per_s", "Jump speed (mm/s).", None),
    (
        "galvo.laser_on_delay_us",
        "Delay after the laser is switched on before the mirrors move (µs).",
        None,
    ),
    (
        "galvo.laser_off_delay_us",
        "Delay after a mark before the laser is switched off (µs).",
        None,
    ),
    (
        "galvo.jump_delay_us",
        "Settling delay after a jump (µs).",
        None,
    ),
    (
        "galvo.mark_delay_us",
        "Settling delay after a mark (µs).",
        None,
    ),
    (
        "galvo.polygon_delay_us",
        "Delay at each polyline vertex (µs).",
        None,
    ),
];

fn doc_for(key: &str) -> Option<&'static (&'static str, &'static str, Option<&'static str>)> {
    KEY_DOCS.iter().find(|(k, _, _)| *k == key)
}

fn comment(out: &mut String, text: &str) {
    for line in text.lines() {
        out.push_str("# ");
        out.push_str(line);
        out.push('\n');
    }
}

/// The full default job file, with a comment on every key.
#[must_use]
pub fn dump_default() -> String {
    let mut out = String::from(HEADER);
    let Ok(Value::Table(root)) = Value::try_from(JobConfig::default()) else {
        return out;
    };
    render_table(&mut out, "", &root);
    out
}

fn render_table(out: &mut String, prefix: &str, table: &toml::map::Map<String, Value>) {
    let join = |k: &str| {
        if prefix.is_empty() {
            k.to_string()
        } else {
            format!("{prefix}.{k}")
        }
    };
    // Scalars and arrays first (TOML puts them before sub-tables), then the unset keys.
    for (k, v) in table.iter().filter(|(_, v)| !v.is_table()) {
        let key = join(k);
        if let Some((_, doc, _)) = doc_for(&key) {
            comment(out, doc);
        }
        out.push_str(&format!("{k} = {v}\n"));
    }
    let depth = prefix.matches('.').count() + usize::from(!prefix.is_empty());
    for (key, doc, example) in KEY_DOCS {
        let (parent, leaf) = key.rsplit_once('.').unwrap_or(("", key));
        if parent == prefix && key.matches('.').count() == depth && !table.contains_key(leaf) {
            if let Some(example) = example {
                comment(out, doc);
                out.push_str(&format!("# {leaf} = {example}\n"));
            }
        }
    }
    for (k, v) in table.iter() {
        if let Value::Table(t) = v {
            let key = join(k);
            out.push('\n');
            if let Some((_, doc, _)) = doc_for(&key) {
                comment(out, doc);
            }
            out.push_str(&format!("[{key}]\n"));
            render_table(out, &key, t);
        }
    }
}

/// Every key path of a TOML table, tables included.
#[cfg(test)]
fn key_paths(prefix: &str, table: &toml::map::Map<String, Value>, out: &mut Vec<String>) {
    for (k, v) in table {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        out.push(key.clone());
        if let Value::Table(t) = v {
            key_paths(&key, t, out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dump_is_the_default_and_documents_every_key() {
        let dump = dump_default();
        let parsed = JobConfig::parse(&dump).expect("the dump parses");
        assert_eq!(parsed, JobConfig::default());
        let Value::Table(root) = Value::try_from(JobConfig::default()).unwrap() else {
            panic!("the config is a table");
        };
        let mut keys = Vec::new();
        key_paths("", &root, &mut keys);
        let missing: Vec<&String> = keys.iter().filter(|k| doc_for(k).is_none()).collect();
        assert!(
            missing.is_empty(),
            "keys without a comment in KEY_DOCS: {missing:?}"
        );
        // Documented keys exist: set or shown as a commented-out example.
        for (key, _, example) in KEY_DOCS {
            let leaf = key.rsplit('.').next().unwrap();
            assert!(
                keys.contains(&key.to_string()) || example.is_some(),
                "KEY_DOCS names {key}, which the config does not have"
            );
            if let Some(example) = example {
                assert!(
                    dump.contains(&format!("# {leaf} = {example}")),
                    "{key} example missing"
                );
            }
        }
    }

    #[test]
    fn unset_keys_shown_as_examples_are_accepted() {
        for (key, _, example) in KEY_DOCS {
            let Some(example) = example else { continue };
            let (section, leaf) = key.rsplit_once('.').unwrap_or(("", key));
            let text = if section.is_empty() {
                format!("{leaf} = {example}\n")
            } else {
                format!("[{section}]\n{leaf} = {example}\n")
            };
            let parsed: Result<JobConfig, _> = toml::from_str(&text);
            assert!(parsed.is_ok(), "{key} = {example}: {parsed:?}");
        }
    }

    #[test]
    fn hatch_regions_parse_flat_refuse_bad_keys_by_name_and_round_trip() {
        let c = JobConfig::parse(
            "[[hatch]]\nboundary = \"face.csv\"\npitch_mm = 0.08\nmethod = \"slab\"\n\n[[hatch]]\nboundary = \"hole.csv\"\nchord_tolerance_mm = 0.002\n",
        )
        .unwrap();
        assert_eq!(c.hatch.len(), 2);
        assert_eq!(c.hatch[0].boundary, PathBuf::from("face.csv"));
        assert!((c.hatch[0].settings.pitch_mm - 0.08).abs() < 1e-12);
        assert_eq!(
            c.hatch[0].settings.method,
            trim_plan::hatch::HatchMethod::Slab
        );
        assert_eq!(c.hatch[1].settings.chord_tolerance_mm, Some(0.002));
        assert_eq!(
            c.hatch[1].settings.pitch_mm,
            HatchSettings::default().pitch_mm
        );
        // The effective job file a run writes reads back the same.
        let back = JobConfig::parse(&toml::to_string(&c).unwrap()).unwrap();
        assert_eq!(back, c);
        for (text, named) in [
            (
                "[[hatch]]\nboundary = \"a.csv\"\npich_mm = 0.1\n",
                "pich_mm",
            ),
            ("[[hatch]]\npitch_mm = 0.1\n", "boundary"),
            (
                "[[hatch]]\nboundary = \"a.csv\"\npitch_mm = -1\n",
                "pitch_mm",
            ),
            (
                "[[hatch]]\nboundary = \"a.csv\"\nmethod = \"zigzag\"\n",
                "zigzag",
            ),
        ] {
            let e = format!("{:#}", JobConfig::parse(text).unwrap_err());
            assert!(e.contains("hatch") && e.contains(named), "{text}: {e}");
        }
    }

    #[test]
    fn unknown_keys_are_refused_with_the_key_named() {
        let e = JobConfig::parse("[beam]\npowr_w = 10\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("powr_w"), "{e}");
        let e = JobConfig::parse("[bem]\n").unwrap_err().to_string();
        assert!(e.contains("bem"), "{e}");
        let e = JobConfig::parse("[register]\nmode = \"sideways\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("register.mode") && e.contains("line 2"), "{e}");
    }

    #[test]
    fn out_of_range_values_are_refused_with_the_key_named() {
        for (text, key) in [
            (
                "[galvo]\nmark_speed_mm_per_s = -5\n",
                "galvo.mark_speed_mm_per_s",
            ),
            ("[galvo]\njump_delay_us = nan\n", "galvo.jump_delay_us"),
            ("[cell]\ncnc = \"localhost\"\n", "cell.cnc"),
            ("[cell]\nlaser_profile = \"acme\"\n", "cell.laser_profile"),
            ("[part]\ncad = \"a.stl\"\n", "part"),
        ] {
            let e = format!("{:#}", JobConfig::parse(text).unwrap_err());
            assert!(e.contains(key), "{text}: {e}");
        }
        let e = format!(
            "{:#}",
            JobConfig::parse("[beam]\npower_w = -1\n").unwrap_err()
        );
        assert!(e.contains("power_w"), "{e}");
    }
}
