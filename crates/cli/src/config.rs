//! `job.toml`: one serde schema for a whole job. Defaults live in code; `trimctl config --dump`
//! prints the full default file with a comment on every key ([`dump_default`]). The comments
//! are the settings types' doc comments, read back through the JSON Schema ([`key_docs`]), so a
//! key is documented in one place. Unknown keys and out-of-range values are refused with the
//! key named.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use toml::Value;
use trim_cell::cell_model::Calibration;
use trim_cell::cell_model::ScanPose;
use trim_cell::scans_at_poses;
use trim_cell::truth::{MOVED_TRUTH_KEYS, TruthSettings};
use trim_plan::hatch::HatchSettings;
use trim_plan::planner::PlanSettings;
use trim_register::regional::RegisterSettings;

/// A whole job: part files, registration, planning (incidence limit, beam, zoning, layers, lens
/// field, machine, galvo), the cell and the output folder. Each table is one section of job.toml.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default)]
pub struct JobConfig {
    /// The part's files, relative to this file. Leave all three out for the built-in demo part.
    pub part: PartConfig,
    /// Registration of the CAM path onto the scan (docs/DESIGN.md "Registration").
    pub register: RegisterSettings,
    /// The planning tables: top-level `max_incidence_deg` and `[beam]`, `[zoning]`, `[layers]`,
    /// `[field]`, `[machine]`, `[galvo]`, `[timing]`, `[calibration]`, `[process]`, `[trim]`, as
    /// the planner takes them.
    #[serde(flatten)]
    pub plan: PlanSettings,
    /// Where the devices are: "sim" starts the built-in simulator for that device.
    pub cell: CellConfig,
    /// The built-in simulators used where [cell] says "sim".
    pub sim: SimConfig,
    /// Where runs are recorded.
    pub output: OutputConfig,
    /// `run --verify` on a part of the job's own files: where each rescan comes from.
    pub verify: VerifyConfig,
    /// Regions to hatch beside the contours, each a [[hatch]] table: boundary = a path CSV with one
    /// closed contour on the part's surface, CAD frame (registration carries it onto the scan),
    /// plus the hatching keys pitch_mm (default 0.05), angle_deg (0), method ("geodesic" or
    /// "slab"), step_mm or chord_tolerance_mm (point placement along a track; default a step of one
    /// pitch), outline (true) and grid_mm. The tracks (surface normals as feature vectors) are
    /// zoned, layered and projected like contours. The built-in demo part hatches one region of its
    /// top face when this is empty.
    #[schemars(with = "Vec<serde_json::Value>")]
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

/// The part's input files. Relative paths are relative to the job file's folder. With no CAD,
/// path and scan, `trimctl run` uses the built-in demo part.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PartConfig {
    /// CAD model: STL or PLY mesh, or a PLY/PCD/XYZ point cloud with normals.
    pub cad: Option<PathBuf>,
    /// CAM template path: CSV with columns contour,x,y,z,u,v,w (mm, unit feature vector).
    pub path: Option<PathBuf>,
    /// Scan of the clamped part: PLY, PCD or XYZ (normals optional), in the scanner frame at
    /// scan_pose. For scans taken at several machine poses give scans and poses instead.
    pub scan: Option<PathBuf>,
    /// Scans of the clamped part taken at several machine poses (PLY, PCD or XYZ, scanner
    /// frame), instead of scan: each is carried into the work-piece frame through
    /// [calibration] and [machine] at its row of poses, and the clouds are merged into the one
    /// the run registers on. Relative to this file, like scan.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub scans: Vec<PathBuf>,
    /// The machine pose of each of scans: a CSV with the header scan,x,y,z,a,c (scan,x,y,z,b,c
    /// on a B/C cell; the format `trimctl calibrate cell` reads), one row per scan naming its
    /// file by file name, X, Y, Z joint positions in mm, the rotary axes in degrees. Relative to
    /// this file. Needed with scans, refused without them.
    pub poses: Option<PathBuf>,
    /// Where the machine stood when the scan was taken (the scanner's pose, not the part's):
    /// linear joint positions (the tool point, machine frame) and rotary axes. The scan is
    /// mapped into the work-piece frame through [calibration]. The part's pose in the fixture is
    /// scan_from_cad. With scans, each scan's pose is its row of poses, and `run --verify`
    /// rescans the part at each of them; this one is then not read.
    pub scan_pose: ScanPose,
    /// The fixture's nominal pose of the part (not the machine's: that is scan_pose): where the
    /// CAD frame sits in the work-piece frame the scan is mapped into, scan_from_cad = T·R.
    /// Registration starts here and captures a part up to register.coarse.capture_rotation_deg
    /// and capture_translation_mm away; farther is refused. The default, zero, puts the CAD
    /// frame on the work-piece frame. `trimctl register --initial FILE` overrides it.
    pub scan_from_cad: FixturePose,
}

/// Each of `[part] scans` with the machine pose it was taken at (its row of `[part] poses`).
pub type ScanPoses = Vec<(PathBuf, ScanPose)>;

/// A rigid pose given by angles and a translation (job.toml `[part.scan_from_cad]`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct FixturePose {
    /// Rotation [rx, ry, rz], degrees: about the work-piece frame's fixed X axis by rx, then its
    /// fixed Y axis by ry, then its fixed Z axis by rz (extrinsic X-Y-Z, R = Rz·Ry·Rx; the
    /// same as intrinsic Z-Y'-X'' yaw-pitch-roll).
    pub rotation_deg: [f64; 3],
    /// Translation: where the CAD origin lands in the work-piece frame, mm.
    pub translation_mm: [f64; 3],
}

impl FixturePose {
    /// The pose as `scan_from_cad`; refuses a non-finite value, naming the key under `key`.
    pub fn scan_from_cad(&self, key: &str) -> anyhow::Result<trim_geom::math::Similarity3> {
        for (name, v) in [
            ("rotation_deg", self.rotation_deg),
            ("translation_mm", self.translation_mm),
        ] {
            if !v.iter().all(|c| c.is_finite()) {
                bail!("{key}.{name}: expected three finite numbers, got {v:?}");
            }
        }
        // Beyond a few turns the degrees lose the digits the direction is in; beyond 100 m the
        // part is not in any cell.
        for (name, v, limit, unit) in [
            ("rotation_deg", self.rotation_deg, 360.0, "degrees"),
            (
                "translation_mm",
                self.translation_mm,
                trim_geom::path::MAX_COORDINATE_MM,
                "mm",
            ),
        ] {
            if let Some(c) = v.iter().find(|c| c.abs() > limit) {
                bail!(
                    "{key}.{name}: {} is beyond ±{limit} {unit}; give each within [-{limit}, {limit}]",
                    trim_geom::Num(*c)
                );
            }
        }
        let [rx, ry, rz] = self.rotation_deg.map(f64::to_radians);
        let rotation = nalgebra::UnitQuaternion::from_euler_angles(rx, ry, rz);
        Ok(trim_geom::math::Similarity3::from_parts(
            nalgebra::Translation3::from(nalgebra::Vector3::from(self.translation_mm)),
            rotation,
            1.0,
        ))
    }
}

/// The built-in simulators (job.toml `[sim]`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// The digital twin: the true cell the simulators carry, which may differ from the nominal one
    /// and from [calibration]. The galvo simulator lands every marked vector on the true part and
    /// the run reports the spot error. Empty: a perfect nominal cell.
    pub truth: TruthSettings,
}

/// Device addresses. `"sim"` starts the built-in simulator for that device.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CellConfig {
    /// LinuxCNC linuxcncrsh as HOST:PORT (e.g. "127.0.0.1:5007"), or "sim".
    pub cnc: String,
    /// Galvo controller as HOST:PORT, or "sim".
    pub galvo: String,
    /// Laser serial device (e.g. "/dev/ttyUSB0"), or "sim".
    pub laser: String,
    /// Laser profile (crates/io/profiles), which sets the commands and the source's limits:
    /// "high-energy" (a picosecond source, 60 W, 250 µJ, 200-2000 kHz, on the Monaco-like
    /// commands; allows the paper's 214 µJ point), "monaco" (Coherent-Monaco-like,
    /// 40 W, 40 µJ, 1-50000 kHz) or "ipg" (IPG-like, 30 W, 100 µJ, 100-1000 kHz). A [beam]
    /// operating point (power_w, repetition_rate_hz, their pulse energy) outside them is
    /// refused.
    pub laser_profile: String,
}

impl Default for CellConfig {
    fn default() -> Self {
        CellConfig {
            cnc: SIM.into(),
            galvo: SIM.into(),
            laser: SIM.into(),
            laser_profile: trim_io::laser::profile::DEFAULT_PROFILE.into(),
        }
    }
}

/// The word that selects a built-in simulator in [`CellConfig`].
pub const SIM: &str = "sim";

/// Where runs are recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Each run writes a new time-stamped folder here (or the folder given with --out).
    pub runs_dir: PathBuf,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            runs_dir: PathBuf::from("runs"),
        }
    }
}

/// `run --verify` on a real cell: after the job (and each retrim) the part is rescanned where
/// it stands, in the scanner frame at `[part.scan_pose]` like `part.scan`, or, when it was
/// scanned as `part.scans`, once at each of their poses (trimctl does not move the machine
/// there: the scan command, or the operator the run waits for, does). The run waits for the
/// file `scan_file`, or runs `scan_command` to make it. (The built-in demo part is rescanned
/// by the digital twin; this table is not read then.)
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct VerifyConfig {
    /// Where inspection k's rescan appears (PLY, PCD or XYZ); `{round}` becomes k, and `{pose}`
    /// the file stem of the part's scan whose pose it is taken at (with `part.scans` and no
    /// `{pose}`, `_<stem>` is put before the extension). Relative to the run folder.
    pub scan_file: String,
    /// A command that scans the part and writes `scan_file` (the program, then its arguments;
    /// `{scan}` becomes the file's path, `{round}` k, `{look}` 1 and `{pose}` as in scan_file;
    /// with `part.scans` it runs once per pose). When the scan leaves
    /// contours under the inspection's coverage it is run once more (`{look}` 2, `{scan}` the
    /// file with `_again` before its extension) and those contours are judged on the second
    /// scan where it covers them better. Left out, the run waits for the file (and takes it as
    /// given).
    pub scan_command: Vec<String>,
    /// The longest wait for a rescan (the command's run, or the file's arrival), s.
    pub scan_timeout_s: f64,
}

impl Default for VerifyConfig {
    fn default() -> Self {
        VerifyConfig {
            scan_file: "rescan_{round}.ply".to_owned(),
            scan_command: Vec::new(),
            scan_timeout_s: 600.0,
        }
    }
}

impl VerifyConfig {
    /// Refuses out-of-range values, naming the key.
    pub fn validate(&self) -> anyhow::Result<()> {
        if !(self.scan_timeout_s.is_finite() && (0.1..=86_400.0).contains(&self.scan_timeout_s)) {
            bail!(
                "verify.scan_timeout_s: expected 0.1–86400 s, got {}",
                self.scan_timeout_s
            );
        }
        if self.scan_file.trim().is_empty() {
            bail!("verify.scan_file: empty");
        }
        if self
            .scan_command
            .first()
            .is_some_and(|program| program.trim().is_empty())
        {
            bail!("verify.scan_command: the program (its first word) is empty");
        }
        Ok(())
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
            &mut config.part.poses,
        ]
        .into_iter()
        .chain([
            &mut config.plan.calibration.field_correction,
            &mut config.sim.truth.path,
        ])
        .flatten()
        .chain(&mut config.part.scans)
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
    ///
    /// The planning tables are flattened into JobConfig, so serde neither refuses an unknown
    /// top-level key nor keeps the key path and line of an error inside them: the unknown keys
    /// are refused first, and the planning tables are read once on their own.
    pub fn parse(text: &str) -> anyhow::Result<JobConfig> {
        let doc = parse_document(text)?;
        refuse_unknown_keys::<JobConfig>(text, doc.get_ref(), "", &[])?;
        let truth = sub_table(doc.get_ref(), "sim").and_then(|sim| sub_table(sim, "truth"));
        if let Some(truth) = truth {
            refuse_unknown_keys::<TruthSettings>(text, truth, "sim.truth.", MOVED_TRUTH_KEYS)?;
        }
        // The flattened parts alone: the planning tables, and [sim.truth]'s [calibration] keys.
        let span = doc.span();
        let plan_tables = only_keys::<PlanSettings>(doc.into_inner());
        deserialize::<PlanSettings>(text, toml::Spanned::new(span.clone(), plan_tables), "")?;
        let doc = parse_document(text)?;
        if let Some(truth) = sub_table(doc.get_ref(), "sim").and_then(|sim| sub_table(sim, "truth"))
        {
            let calibration = only_keys::<Calibration>(truth.clone());
            let at = toml::Spanned::new(span, calibration);
            deserialize::<Calibration>(text, at, "sim.truth.")?;
        }
        let config: JobConfig = deserialize(text, doc, "")?;
        config.validate()?;
        Ok(config)
    }

    /// Checks every value's range, naming the key at fault.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.plan.validate()?;
        self.sim
            .truth
            .validate(self.plan.machine.kinematics)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        self.register
            .validate()
            .map_err(|e| anyhow::anyhow!("register.{e}"))?;
        self.verify.validate()?;
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
        let profile = trim_io::laser::Profile::builtin(&self.cell.laser_profile)
            .map_err(|e| anyhow::anyhow!("cell.laser_profile: {e}"))?;
        profile
            .check_operating_point(&self.plan.beam)
            .map_err(|e| {
                anyhow::anyhow!(
                    "[beam] with cell.laser_profile = {:?}: {e} (crates/io/profiles/{}.toml)",
                    self.cell.laser_profile,
                    profile.name
                )
            })?;
        for (i, h) in self.hatch.iter().enumerate() {
            h.settings
                .validate()
                .map_err(|e| anyhow::anyhow!("hatch[{i}] ({}): {e}", h.boundary.display()))?;
        }
        self.part
            .scan_from_cad
            .scan_from_cad("part.scan_from_cad")?;
        self.part
            .scan_pose
            .validate()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let part = &self.part;
        if part.scan.is_some() && !part.scans.is_empty() {
            bail!(
                "part.scan and part.scans: give one scan (scan, at scan_pose) or scans at their poses (scans and poses), not both"
            );
        }
        if !part.scans.is_empty() && part.poses.is_none() {
            bail!(
                "part.scans: needs part.poses, the CSV (scan,x,y,z,a,c) of the machine pose each scan was taken at"
            );
        }
        if part.scans.is_empty()
            && let Some(poses) = &part.poses
        {
            bail!(
                "part.poses {}: given without part.scans (the scans it holds the poses of)",
                poses.display()
            );
        }
        let scanned = part.scan.is_some() || !part.scans.is_empty();
        let given = [part.cad.is_some(), part.path.is_some(), scanned]
            .iter()
            .filter(|g| **g)
            .count();
        if given != 0 && given != 3 {
            bail!(
                "part: give all of cad, path and scan (or scans with poses), or none (for the built-in demo part)"
            );
        }
        if self.plan.trim.only_detected
            && let Some(cad) = &self.part.cad
            && !cad_may_be_a_mesh(cad)
        {
            bail!(
                "trim.only_detected: part.cad {} is a point-cloud format; detecting burrs measures distances to the CAD's surface: give the STL or PLY mesh",
                cad.display()
            );
        }
        Ok(())
    }

    /// The scan (scanner frame) in the work-piece frame: through the scanner's pose on the
    /// head, the machine pose of `[part.scan_pose]` and the rotary axes, all as `[calibration]`
    /// says. Refuses a non-finite pose by its key, and a chain that carries a point out of the
    /// finite range.
    pub fn workpiece_from_scan(
        &self,
        scan_in_scanner: &trim_geom::PointCloud,
    ) -> anyhow::Result<trim_geom::PointCloud> {
        self.part
            .scan_pose
            .validate()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        scans_at_poses::workpiece_from_scanner_at(&self.plan, self.part.scan_pose, scan_in_scanner)
            .context("the scan through [calibration] at [part.scan_pose] into the work-piece frame")
    }

    /// The part's scan in the work-piece frame: `part.scan` at `[part.scan_pose]`
    /// ([`JobConfig::workpiece_from_scan`]), or `part.scans` each at its row of `part.poses`,
    /// merged (`trim_cell::scans_at_poses`); and each of `part.scans` with the pose it was
    /// carried at (empty with `part.scan`), for the record. Errors name the key and the file.
    pub fn part_scan_in_workpiece(&self) -> anyhow::Result<(trim_geom::PointCloud, ScanPoses)> {
        if let Some(scan_file) = &self.part.scan {
            let scan = self
                .workpiece_from_scan(&trim_geom::formats::read_points(scan_file)?)
                .with_context(|| format!("part.scan {}", scan_file.display()))?;
            return Ok((scan, Vec::new()));
        }
        let poses = self.part_poses()?;
        let cloud = scans_at_poses::merge_files(&self.part.scans, &poses, &self.plan)
            .context("part.scans")?;
        let at = self
            .part
            .scans
            .iter()
            .map(|f| Ok((f.clone(), poses.pose_of(f)?)))
            .collect::<Result<_, scans_at_poses::ScansError>>()
            .context("part.scans")?;
        Ok((cloud, at))
    }

    /// Where each `run --verify` rescan is taken when the part was scanned as `part.scans`: one
    /// per scan, in order, named by the scan's file stem (what `{pose}` becomes in `[verify]`),
    /// at that scan's row of `part.poses`. None with `part.scan` (one rescan at
    /// `[part.scan_pose]`). Two scans of one stem are refused: their rescans would share a file.
    #[cfg(feature = "sim")]
    pub fn rescan_poses(&self) -> anyhow::Result<Option<Vec<(String, ScanPose)>>> {
        if self.part.scan.is_some() || self.part.scans.is_empty() {
            return Ok(None);
        }
        let poses = self.part_poses()?;
        let mut at: Vec<(String, ScanPose)> = Vec::with_capacity(self.part.scans.len());
        for file in &self.part.scans {
            let label = file
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .filter(|s| !s.is_empty())
                .with_context(|| format!("part.scans: {} has no file name", file.display()))?;
            if at.iter().any(|(l, _)| *l == label) {
                bail!(
                    "part.scans: two scans are named {label:?}; their `run --verify` rescans \
                     would share one file"
                );
            }
            let pose = poses.pose_of(file).context("part.scans")?;
            at.push((label, pose));
        }
        Ok(Some(at))
    }

    /// `part.poses`, read and checked against `[machine]`.
    fn part_poses(&self) -> anyhow::Result<scans_at_poses::Poses> {
        let file = self
            .part
            .poses
            .as_deref()
            .context("part.scans: needs part.poses")?;
        let poses = scans_at_poses::read_poses(file).context("part.poses")?;
        poses
            .require_kinematics(self.plan.machine.kinematics)
            .context("part.poses")?;
        Ok(poses)
    }

    /// Whether the job runs the built-in demo part.
    pub fn is_demo(&self) -> bool {
        self.part.cad.is_none()
    }
}

/// Whether `file`'s format can hold a mesh (STL, PLY); PCD and XYZ are point clouds only. A
/// PLY holding points alone is refused when it is read.
fn cad_may_be_a_mesh(file: &Path) -> bool {
    !file
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("pcd") || e.eq_ignore_ascii_case("xyz"))
}

/// The 1-based line of byte `at` of `text`.
fn line_of(text: &str, at: usize) -> usize {
    text[..at.min(text.len())].matches('\n').count() + 1
}

/// Parses TOML, keeping every key's and value's place; a syntax error names its line.
fn parse_document(text: &str) -> anyhow::Result<toml::Spanned<toml::de::DeTable<'_>>> {
    toml::de::DeTable::parse(text).map_err(|e| {
        let message = e.message().trim().replace('\n', " ");
        match e.span() {
            Some(s) => anyhow::anyhow!("line {}: {message}", line_of(text, s.start)),
            None => anyhow::anyhow!("{message}"),
        }
    })
}

/// Deserializes a parsed job file (`text` its source) into `T`; an error reads on one line:
/// where (line and key path), then serde's message.
fn deserialize<T: serde::de::DeserializeOwned>(
    text: &str,
    doc: toml::Spanned<toml::de::DeTable<'_>>,
    prefix: &str,
) -> anyhow::Result<T> {
    serde_path_to_error::deserialize(toml::Deserializer::from(doc)).map_err(|e| {
        let key = e.path().to_string();
        let inner = e.inner();
        let message = inner.message().trim().replace('\n', " ");
        let key = if key == "." {
            String::new()
        } else {
            format!("{prefix}{key}: ")
        };
        match inner.span() {
            Some(s) => anyhow::anyhow!("line {}: {key}{message}", line_of(text, s.start)),
            None => anyhow::anyhow!("{key}{message}"),
        }
    })
}

/// The keys of a settings table, in order, from its JSON Schema (flattened structs' keys
/// included).
fn schema_keys<T: schemars::JsonSchema>() -> Vec<String> {
    let schema = schemars::schema_for!(T).to_value();
    schema
        .get("properties")
        .and_then(serde_json::Value::as_object)
        .map(|p| p.keys().cloned().collect())
        .unwrap_or_default()
}

/// The table under `key` of `table`, if it is one.
fn sub_table<'a, 'i>(
    table: &'a toml::de::DeTable<'i>,
    key: &str,
) -> Option<&'a toml::de::DeTable<'i>> {
    table.iter().find_map(|(k, v)| match v.get_ref() {
        toml::de::DeValue::Table(t) if k.get_ref() == key => Some(t),
        _ => None,
    })
}

/// The entries of `table` whose keys `T` has.
fn only_keys<'i, T: schemars::JsonSchema>(table: toml::de::DeTable<'i>) -> toml::de::DeTable<'i> {
    let keys = schema_keys::<T>();
    table
        .into_iter()
        .filter(|(key, _)| keys.iter().any(|k| k == key.get_ref()))
        .collect()
}

/// Refuses a key of `table` (at `prefix`, e.g. "sim.truth.") that `T` does not have, naming its
/// line, and a `moved` one with where it went. Serde refuses no unknown key beside a flattened
/// struct, so the tables that flatten one are checked here.
fn refuse_unknown_keys<T: schemars::JsonSchema>(
    text: &str,
    table: &toml::de::DeTable<'_>,
    prefix: &str,
    moved: &[(&str, &str)],
) -> anyhow::Result<()> {
    let known = schema_keys::<T>();
    let Some((key, _)) = table
        .iter()
        .find(|(key, _)| !known.iter().any(|k| k == key.get_ref()))
    else {
        return Ok(());
    };
    let (line, key) = (line_of(text, key.span().start), key.get_ref());
    if let Some((_, to)) = moved.iter().find(|(old, _)| old == key) {
        bail!("line {line}: {prefix}{key}: this key moved: write it as {to}");
    }
    let expected: Vec<String> = known.iter().map(|k| format!("`{k}`")).collect();
    bail!(
        "line {line}: {prefix}{key}: unknown field `{key}`, expected one of {}",
        expected.join(", ")
    );
}

/// The file's opening comment.
const HEADER: &str = "\
# trimctl job file. Every key is optional: a missing key takes the default shown here.
# Units are in the key names: _mm millimetres, _deg degrees, _us microseconds, _s seconds.
# `trimctl config --dump > job.toml` writes this file; `trimctl run job.toml` runs it.
";

/// Commented-out examples that `--dump` shows for the keys without a default value (unset
/// `Option`s): (dotted key, TOML value). Each key's description is its doc comment in code
/// ([`key_docs`]).
const EXAMPLES: &[(&str, &str)] = &[
    ("part.cad", "\"cad.stl\""),
    ("part.path", "\"path.csv\""),
    ("part.scan", "\"scan.ply\""),
    ("part.scans", "[\"side_a.ply\", \"side_b.ply\"]"),
    ("part.poses", "\"poses.csv\""),
    ("calibration.a_axis_point_mm", "[0.0, 20.0, 10.0]"),
    ("calibration.a_axis_direction", "[1.0, 0.0, 0.0]"),
    ("calibration.b_axis_point_mm", "[-20.0, 0.0, -15.0]"),
    ("calibration.b_axis_direction", "[0.0, 1.0, 0.0]"),
    ("calibration.c_axis_point_mm", "[0.0, 0.0, 0.0]"),
    ("calibration.c_axis_direction", "[0.0, 0.0, 1.0]"),
    (
        "calibration.scanner_rotation",
        "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]",
    ),
    ("calibration.scanner_translation_mm", "[0.0, 0.0, 0.0]"),
    ("calibration.field_correction", "\"field.json\""),
    ("calibration.lens.pivot_to_focal_plane_mm", "254.0"),
    ("sim.truth.a_axis_point_mm", "[0.05, 20.08, 9.97]"),
    ("sim.truth.a_axis_direction", "[1.0, 0.0003, -0.0002]"),
    ("sim.truth.b_axis_point_mm", "[-20.05, 0.0, -15.03]"),
    ("sim.truth.b_axis_direction", "[0.0002, 1.0, 0.0003]"),
    ("sim.truth.c_axis_point_mm", "[-0.04, 0.06, 0.0]"),
    ("sim.truth.c_axis_direction", "[0.0004, -0.0001, 1.0]"),
    (
        "sim.truth.scanner_rotation",
        "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]",
    ),
    ("sim.truth.scanner_translation_mm", "[0.3, -0.2, 0.15]"),
    ("sim.truth.lens.pivot_to_focal_plane_mm", "262.0"),
    ("sim.truth.path", "\"truth.csv\""),
    ("register.scanner_viewpoint_mm", "[0.0, 0.0, 500.0]"),
    ("zoning.k", "10"),
    ("layers.step_mm", "0.3"),
];

/// job.toml's JSON Schema: every key's description is its doc comment in code.
#[must_use]
pub fn schema() -> serde_json::Value {
    schemars::schema_for!(JobConfig).to_value()
}

/// Every key's description, by dotted key path (tables included): the doc comments of the
/// settings types in code, read back through job.toml's JSON Schema. The one source of the
/// `--dump` comments.
#[must_use]
pub fn key_docs() -> std::collections::BTreeMap<String, String> {
    let schema = schema();
    let empty = serde_json::Map::new();
    let defs = schema
        .get("$defs")
        .and_then(serde_json::Value::as_object)
        .unwrap_or(&empty);
    let mut out = std::collections::BTreeMap::new();
    collect_docs(&schema, defs, "", &mut out);
    out
}

/// The schema a property stands for: through `$ref`, and through `anyOf`/`oneOf`/`allOf` (an
/// `Option` of a table) to the first branch that has properties.
fn resolve<'a>(
    schema: &'a serde_json::Value,
    defs: &'a serde_json::Map<String, serde_json::Value>,
) -> &'a serde_json::Value {
    if let Some(name) = schema
        .get("$ref")
        .and_then(serde_json::Value::as_str)
        .and_then(|r| r.strip_prefix("#/$defs/"))
        && let Some(def) = defs.get(name)
    {
        return resolve(def, defs);
    }
    for combinator in ["anyOf", "oneOf", "allOf"] {
        if let Some(branches) = schema.get(combinator).and_then(serde_json::Value::as_array) {
            for b in branches {
                let r = resolve(b, defs);
                if r.get("properties").is_some() {
                    return r;
                }
            }
        }
    }
    schema
}

fn collect_docs(
    schema: &serde_json::Value,
    defs: &serde_json::Map<String, serde_json::Value>,
    prefix: &str,
    out: &mut std::collections::BTreeMap<String, String>,
) {
    let Some(props) = resolve(schema, defs)
        .get("properties")
        .and_then(serde_json::Value::as_object)
    else {
        return;
    };
    for (name, prop) in props {
        let key = if prefix.is_empty() {
            name.clone()
        } else {
            format!("{prefix}.{name}")
        };
        if let Some(doc) = prop.get("description").and_then(serde_json::Value::as_str) {
            out.insert(key.clone(), doc.to_owned());
        }
        collect_docs(prop, defs, &key, out);
    }
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
    render_table(&mut out, &key_docs(), "", &root);
    out
}

fn render_table(
    out: &mut String,
    docs: &std::collections::BTreeMap<String, String>,
    prefix: &str,
    table: &toml::map::Map<String, Value>,
) {
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
        if let Some(doc) = docs.get(&key) {
            comment(out, doc);
        }
        out.push_str(&format!("{k} = {v}\n"));
    }
    for (key, example) in EXAMPLES {
        let (parent, leaf) = key.rsplit_once('.').unwrap_or(("", key));
        if parent == prefix && !table.contains_key(leaf) {
            if let Some(doc) = docs.get(*key) {
                comment(out, doc);
            }
            out.push_str(&format!("# {leaf} = {example}\n"));
        }
    }
    for (k, v) in table.iter() {
        if let Value::Table(t) = v {
            let key = join(k);
            out.push('\n');
            if let Some(doc) = docs.get(&key) {
                comment(out, doc);
            }
            out.push_str(&format!("[{key}]\n"));
            render_table(out, docs, &key, t);
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
        let docs = key_docs();
        let missing: Vec<&String> = keys
            .iter()
            .filter(|k| docs.get(*k).is_none_or(|d| d.trim().is_empty()))
            .collect();
        assert!(
            missing.is_empty(),
            "keys without a doc comment in code: {missing:?}"
        );
        let lines: Vec<&str> = dump.lines().collect();
        for (i, line) in lines.iter().enumerate().skip(1) {
            if !line.starts_with('#') && (line.contains(" = ") || line.starts_with('[')) {
                assert!(
                    lines[i - 1].starts_with('#'),
                    "{line:?} has no comment above it in the dump"
                );
            }
        }
        // Every example names a key the schema documents, and the dump shows it.
        for (key, example) in EXAMPLES {
            let leaf = key.rsplit('.').next().unwrap();
            assert!(
                docs.contains_key(*key),
                "EXAMPLES names {key}, which the config does not have"
            );
            assert!(
                dump.contains(&format!("# {leaf} = {example}")),
                "{key} example missing"
            );
        }
        // The descriptions are the code's: one documented field, checked word for word.
        assert_eq!(
            docs.get("galvo.polygon_delay_us").map(String::as_str),
            Some("Delay at each polyline vertex (µs).")
        );
    }

    #[test]
    fn unset_keys_shown_as_examples_are_accepted() {
        for (key, example) in EXAMPLES {
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
    fn the_fixture_pose_is_extrinsic_xyz_in_degrees_and_refuses_non_finite_values() {
        let c = JobConfig::parse(
            "[part.scan_from_cad]\nrotation_deg = [90.0, 0.0, 90.0]\ntranslation_mm = [1.0, 2.0, 3.0]\n",
        )
        .unwrap();
        let s = c.part.scan_from_cad.scan_from_cad("k").unwrap();
        // About the fixed X by 90° (y → z), then about the fixed Z by 90° (x → y): R = Rz·Rx
        // takes x → y, y → z, z → x; then the translation.
        for (from, to) in [
            ([1.0, 0.0, 0.0], [1.0, 3.0, 3.0]),
            ([0.0, 1.0, 0.0], [1.0, 2.0, 4.0]),
            ([0.0, 0.0, 1.0], [2.0, 2.0, 3.0]),
        ] {
            let got = s * trim_geom::Point3::from(from);
            assert!(
                (got - trim_geom::Point3::from(to)).norm() < 1e-12,
                "{from:?} → {got}"
            );
        }
        let identity = JobConfig::default()
            .part
            .scan_from_cad
            .scan_from_cad("k")
            .unwrap();
        assert_eq!(identity, trim_geom::math::Similarity3::identity());
        let e = format!(
            "{:#}",
            JobConfig::parse("[part.scan_from_cad]\nrotation_deg = [0.0, nan, 0.0]\n").unwrap_err()
        );
        assert!(e.contains("part.scan_from_cad.rotation_deg"), "{e}");
        for (text, key) in [
            (
                "rotation_deg = [0.0, 1e300, 0.0]",
                "part.scan_from_cad.rotation_deg: 1e300 is beyond ±360 degrees",
            ),
            (
                "translation_mm = [-2e5, 0.0, 0.0]",
                "part.scan_from_cad.translation_mm: -200000 is beyond ±100000 mm",
            ),
        ] {
            let e = format!(
                "{:#}",
                JobConfig::parse(&format!("[part.scan_from_cad]\n{text}\n")).unwrap_err()
            );
            assert!(e.contains(key), "{text}: {e}");
        }
        // The two poses of [part] say which is which.
        let docs = key_docs();
        assert!(docs["part.scan_pose"].contains("not the part's"));
        assert!(docs["part.scan_from_cad"].contains("not the machine's"));
    }

    #[test]
    fn a_non_finite_scan_pose_is_refused_by_key_wherever_it_enters() {
        for (text, key) in [
            (
                "[part.scan_pose]\nxyz_mm = [0.0, nan, 0.0]\n",
                "part.scan_pose.xyz_mm",
            ),
            (
                "[part.scan_pose]\ntilt_deg = inf\n",
                "part.scan_pose.tilt_deg",
            ),
            ("[part.scan_pose]\nc_deg = -inf\n", "part.scan_pose.c_deg"),
        ] {
            let e = format!("{:#}", JobConfig::parse(text).unwrap_err());
            assert!(e.contains(key), "{text}: {e}");
        }
        // Built in code, past the parser: the scan is refused, not carried to NaN (voxel 0).
        let scan = trim_geom::PointCloud::new(vec![trim_geom::Point3::new(1.0, 2.0, 3.0)]).unwrap();
        let mut c = JobConfig::default();
        assert!(
            c.workpiece_from_scan(&scan).unwrap().points()[0]
                .iter()
                .all(|v| v.is_finite())
        );
        c.part.scan_pose.c_deg = f64::NAN;
        let e = format!("{:#}", c.workpiece_from_scan(&scan).unwrap_err());
        assert!(e.contains("part.scan_pose.c_deg"), "{e}");
        // A finite pose whose chain overflows a point is refused too.
        let mut c = JobConfig::default();
        c.part.scan_pose.xyz_mm = [f64::MAX, 0.0, 0.0];
        let huge =
            trim_geom::PointCloud::new(vec![trim_geom::Point3::new(f64::MAX, 0.0, 0.0)]).unwrap();
        let e = format!("{:#}", c.workpiece_from_scan(&huge).unwrap_err());
        assert!(
            e.contains("part.scan_pose") && e.contains("not finite"),
            "{e}"
        );
    }

    #[test]
    fn the_planning_tables_are_plan_settings_and_keep_line_and_key_in_errors() {
        // A job with a value in every planning table reads into PlanSettings as the planner's
        // own parse does, and the effective file a run writes reads back the same.
        let text = "max_incidence_deg = 4.0\n[beam]\npower_w = 40.0\n[zoning]\nmethod = \"kmeans\"\nk = 3\n\
            [layers]\nstep_mm = 0.2\n[field]\ntelecentric = true\n[machine]\nkinematics = \"xyzbc-trt\"\n\
            [galvo]\nfield_mm = [80.0, 80.0]\n[timing]\nlayer_overhead_s = 0.01\n\
            [calibration.lens]\npivot_to_focal_plane_mm = 250.0\n[register]\nmode = \"global\"\n";
        let c = JobConfig::parse(text).unwrap();
        let alone: PlanSettings =
            toml::from_str(&text[..text.find("[register]").unwrap()]).unwrap();
        assert_eq!(c.plan, alone);
        assert_ne!(c.plan, PlanSettings::default());
        assert_eq!(JobConfig::parse(&toml::to_string(&c).unwrap()).unwrap(), c);
        assert_eq!(
            JobConfig::parse(&toml::to_string(&JobConfig::default()).unwrap()).unwrap(),
            JobConfig::default()
        );
        // Errors inside a flattened table name their line and key path, as any other table's.
        for (text, expected) in [
            (
                "\n[beam]\npowr_w = 10\n",
                "line 3: beam.powr_w: unknown field `powr_w`",
            ),
            (
                "[layers]\nstep_mm = \"a\"\n",
                "line 2: layers.step_mm: invalid type",
            ),
            (
                "max_incidence_deg = \"x\"\n",
                "line 1: max_incidence_deg: invalid type",
            ),
            (
                "[part]\n[bem]\n",
                "line 2: bem: unknown field `bem`, expected one of ",
            ),
        ] {
            let e = format!("{:#}", JobConfig::parse(text).unwrap_err());
            assert!(e.starts_with(expected), "{text}: {e}");
        }
    }

    #[test]
    fn sim_truth_reads_as_a_calibration_plus_the_head_and_refuses_the_old_pivot_key() {
        let text = "[sim.truth]\nc_axis_point_mm = [0.1, 0.0, 0.0]\npath = \"t.csv\"\n\
            [sim.truth.lens]\npivot_to_focal_plane_mm = 262.0\n[sim.truth.head]\nrotation_deg = 0.1\n";
        let c = JobConfig::parse(text).unwrap();
        let truth = &c.sim.truth;
        assert_eq!(truth.calibration.c_axis_point_mm, Some([0.1, 0.0, 0.0]));
        assert_eq!(truth.calibration.lens.pivot_to_focal_plane_mm, Some(262.0));
        assert_eq!(truth.path, Some(PathBuf::from("t.csv")));
        assert!((truth.head.rotation_deg - 0.1).abs() < 1e-12);
        assert_eq!(JobConfig::parse(&toml::to_string(&c).unwrap()).unwrap(), c);
        for (text, expected) in [
            (
                "[sim.truth]\npivot_to_focal_plane_mm = 262.0\n",
                "line 2: sim.truth.pivot_to_focal_plane_mm: this key moved: write it as \
                 [sim.truth.lens] pivot_to_focal_plane_mm",
            ),
            (
                "[sim.truth]\n\nc_axis_pont_mm = [0.0, 0.0, 0.0]\n",
                "line 3: sim.truth.c_axis_pont_mm: unknown field `c_axis_pont_mm`",
            ),
            (
                "[sim.truth]\nc_axis_point_mm = \"x\"\n",
                "line 2: sim.truth.c_axis_point_mm: invalid type",
            ),
            (
                "[sim.truth.lens]\npivot_to_focal_plane_mm = -1.0\n",
                "setting sim.truth.lens.pivot_to_focal_plane_mm",
            ),
            (
                "[sim.truth]\nfield_correction = \"f.json\"\n",
                "sim.truth.field_correction: the true head's field is [sim.truth.head]",
            ),
        ] {
            let e = format!("{:#}", JobConfig::parse(text).unwrap_err());
            assert!(e.starts_with(expected), "{text}: {e}");
        }
    }

    #[test]
    fn trim_only_detected_reads_defaults_to_false_and_is_refused_by_name() {
        assert!(!JobConfig::default().plan.trim.only_detected);
        let c = JobConfig::parse("[trim]\nonly_detected = true\n").unwrap();
        assert!(c.plan.trim.only_detected);
        assert_eq!(JobConfig::parse(&toml::to_string(&c).unwrap()).unwrap(), c);
        for (text, expected) in [
            (
                "[trim]\nonly_detected = \"yes\"\n",
                "line 2: trim.only_detected: invalid type",
            ),
            (
                "[trim]\nonly_detect = true\n",
                "line 2: trim.only_detect: unknown field `only_detect`",
            ),
            (
                "[trim]\nonly_detected = true\n[part]\ncad = \"cad.xyz\"\npath = \"p.csv\"\nscan = \"s.ply\"\n",
                "trim.only_detected: part.cad cad.xyz is a point-cloud format",
            ),
        ] {
            let e = format!("{:#}", JobConfig::parse(text).unwrap_err());
            assert!(e.starts_with(expected), "{text}: {e}");
        }
        // The same files without only_detected are a job (registration takes a cloud).
        JobConfig::parse("[part]\ncad = \"cad.xyz\"\npath = \"p.csv\"\nscan = \"s.ply\"\n")
            .unwrap();
    }

    #[test]
    fn part_scans_need_poses_and_exclude_scan() {
        let files = "[part]\ncad = \"cad.stl\"\npath = \"path.csv\"\n";
        let c = JobConfig::parse(&format!(
            "{files}scans = [\"a.ply\", \"b.ply\"]\nposes = \"poses.csv\"\n"
        ))
        .unwrap();
        assert_eq!(
            c.part.scans,
            vec![PathBuf::from("a.ply"), PathBuf::from("b.ply")]
        );
        assert_eq!(c.part.poses, Some(PathBuf::from("poses.csv")));
        assert!(!c.is_demo());
        // The effective job file a run writes reads back the same.
        assert_eq!(JobConfig::parse(&toml::to_string(&c).unwrap()).unwrap(), c);
        for (text, expected) in [
            (
                format!("{files}scan = \"s.ply\"\nscans = [\"a.ply\"]\nposes = \"p.csv\"\n"),
                "part.scan and part.scans: give one scan",
            ),
            (
                format!("{files}scans = [\"a.ply\", \"b.ply\"]\n"),
                "part.scans: needs part.poses",
            ),
            (
                format!("{files}scan = \"s.ply\"\nposes = \"p.csv\"\n"),
                "part.poses p.csv: given without part.scans",
            ),
            (
                "[part]\nscans = [\"a.ply\"]\nposes = \"p.csv\"\n".to_owned(),
                "part: give all of cad, path and scan (or scans with poses), or none",
            ),
            (
                format!("{files}scans = \"a.ply\"\nposes = \"p.csv\"\n"),
                "line 4: part.scans: invalid type",
            ),
        ] {
            let e = format!("{:#}", JobConfig::parse(&text).unwrap_err());
            assert!(e.starts_with(expected), "{text}: {e}");
        }
    }

    #[test]
    fn part_scans_and_poses_are_read_relative_to_the_job_file_and_merged() {
        let dir = tempfile::tempdir().unwrap();
        let scans = dir.path().join("scans");
        std::fs::create_dir_all(&scans).unwrap();
        let at =
            |p: [f64; 3]| trim_geom::PointCloud::new(vec![trim_geom::Point3::from(p)]).unwrap();
        for (name, p) in [("a.ply", [1.0, 2.0, 3.0]), ("b.ply", [-4.0, 5.0, 6.0])] {
            trim_geom::formats::write_ply(
                &scans.join(name),
                &at(p),
                trim_geom::formats::PlyEncoding::Ascii,
            )
            .unwrap();
        }
        trim_geom::fs::write_atomic(
            scans.join("poses.csv"),
            "scan,x,y,z,a,c\nb.ply,0,0,10,0,90\na.ply,1,0,0,0,0\n",
        )
        .unwrap();
        let job = dir.path().join("job.toml");
        trim_geom::fs::write_atomic(
            &job,
            "[part]\ncad = \"cad.stl\"\npath = \"path.csv\"\nscans = [\"scans/a.ply\", \"scans/b.ply\"]\nposes = \"scans/poses.csv\"\n",
        )
        .unwrap();
        let c = JobConfig::load(&job).unwrap();
        assert_eq!(c.part.scans[1], scans.join("b.ply"));
        assert_eq!(c.part.poses, Some(scans.join("poses.csv")));
        // The nominal cell: a scanner point s is at (X, Y, Z) + s, and the table at C = 90°
        // turns the work piece under it, so the work-piece point is Rot_C(−90°)·(s + (X, Y, Z)).
        let (merged, at) = c.part_scan_in_workpiece().unwrap();
        let expected = [[2.0, 2.0, 3.0], [5.0, 4.0, 16.0]];
        assert_eq!(merged.len(), 2);
        for (got, want) in merged.points().iter().zip(expected) {
            assert!(
                (got - trim_geom::Point3::from(want)).norm() < 1e-12,
                "{got} vs {want:?}"
            );
        }
        assert_eq!(at[1].0, scans.join("b.ply"));
        assert_eq!(at[1].1.c_deg, 90.0);
        // `run --verify` rescans at each scan's pose, named by its stem; with part.scan, at
        // [part.scan_pose] alone (None).
        let rescans = c.rescan_poses().unwrap().unwrap();
        assert_eq!(
            rescans.iter().map(|(l, _)| l.as_str()).collect::<Vec<_>>(),
            ["a", "b"]
        );
        assert_eq!(rescans[1].1.c_deg, 90.0);
        let mut one = c.clone();
        one.part.scans.clear();
        one.part.scan = Some(scans.join("a.ply"));
        assert!(one.rescan_poses().unwrap().is_none());
        // Two scans of one stem would share a rescan file: refused, naming the stem.
        let mut twice = c.clone();
        twice.part.scans = vec![scans.join("a.ply"), scans.join("a.ply")];
        let e = format!("{:#}", twice.rescan_poses().unwrap_err());
        assert!(e.contains("two scans are named \"a\""), "{e}");
        // A B/C cell's job refuses the A/C poses file, naming it.
        let mut bc = c.clone();
        bc.plan.machine.kinematics = trim_cell::KinematicsKind::XyzbcTrt;
        let e = format!("{:#}", bc.part_scan_in_workpiece().unwrap_err());
        assert!(
            e.starts_with("part.poses: ")
                && e.contains("poses.csv: the header names a xyzac-trt cell"),
            "{e}"
        );
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

    #[test]
    fn the_default_job_is_within_its_lasers_limits_and_other_profiles_refuse_the_papers_point() {
        // The default: the paper's 53.59 W at 250 kHz on the high-energy profile.
        let c = JobConfig::default();
        assert_eq!(c.cell.laser_profile, "high-energy");
        c.validate().unwrap();
        // The same point on the monaco source (40 µJ) is refused, naming the limit, the value,
        // the profile and the keys.
        let e = format!(
            "{:#}",
            JobConfig::parse("[cell]\nlaser_profile = \"monaco\"\n").unwrap_err()
        );
        for part in [
            "cell.laser_profile = \"monaco\"",
            "pulse energy 214.36 µJ",
            "beam.power_w / beam.repetition_rate_hz",
            "limits.pulse_energy_uj_max = 40 µJ",
            "monaco.toml",
        ] {
            assert!(e.contains(part), "{part:?} missing: {e}");
        }
        // The key's doc (the --dump comment) quotes every built-in profile's limits.
        let doc = &key_docs()["cell.laser_profile"];
        for name in trim_io::laser::profile::BUILTIN {
            let l = trim_io::laser::Profile::builtin(name).unwrap().limits;
            let quoted = format!(
                "{} W, {} µJ, {}-{} kHz",
                l.average_power_w_max,
                l.pulse_energy_uj_max,
                l.rep_rate_khz_min,
                l.rep_rate_khz_max
            );
            assert!(
                doc.contains(&format!("\"{name}\"")) && doc.contains(&quoted),
                "{quoted}: {doc}"
            );
        }
        // Within monaco's limits: 10 W at 250 kHz = 40 µJ.
        JobConfig::parse("[cell]\nlaser_profile = \"monaco\"\n[beam]\npower_w = 10.0\n").unwrap();
        // Above the default source's power and below its repetition-rate range.
        let e = format!(
            "{:#}",
            JobConfig::parse("[beam]\npower_w = 61.0\nrepetition_rate_hz = 1e6\n").unwrap_err()
        );
        assert!(e.contains("limits.average_power_w_max = 60 W"), "{e}");
        let e = format!(
            "{:#}",
            JobConfig::parse("[beam]\npower_w = 1.0\nrepetition_rate_hz = 1e5\n").unwrap_err()
        );
        assert!(
            e.contains("repetition rate 100 kHz (beam.repetition_rate_hz) is below limits.rep_rate_khz_min = 200 kHz"),
            "{e}"
        );
    }
}
