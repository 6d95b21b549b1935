//! The settings a plan is made with: job.toml's planning tables (top-level `max_incidence_deg`,
//! `[beam]`, `[zoning]`, `[layers]`, `[field]`, `[machine]`, `[galvo]`, `[timing]`,
//! `[calibration]`, `[process]` and `[trim]`), and what a [`crate::Job`] records of them (`settings`). They live with the Job
//! contract so that the Job carries them typed; the algorithms that use them are trim-plan's.

use serde::{Deserialize, Serialize};

use crate::beam::Beam;
use crate::cell_model::{Calibration, ScanChain, ScanPose, TableModel};
use crate::error::{CellError, require_open_closed, require_range};
use crate::galvo_timing::TimingSettings;
use crate::job::{FieldCorrectionRecord, GalvoSettings, LensRecord};
use crate::kinematics::MachineSettings;
use crate::lens::{FieldCorrection, LensModel};
use crate::process::ProcessSettings;
use trim_geom::Num;

/// The default weight of the extent-scaled positions. Scaled positions span about 1 while
/// feature vectors a few degrees apart differ by about 0.09 (5°): at weight 1 the positions
/// swamp the directions and k-means clusters by position (the paper's Fig. 11(b) effect), so
/// the automatic k grows large before the incidence limit holds. At 0.1 both count.
pub const DEFAULT_POSITION_WEIGHT: f64 = 0.1;

/// The default largest k of the automatic search. Beyond it, splitting the violating zones
/// along their direction spread (and merging) is faster and gives fewer zones than more
/// k-means clusters: on the synthetic 60-contour core (f-theta lens) 21 zones from a cap of
/// 16 against 34 from the smallest feasible k (93); on 2,000 contours 68 zones in a fraction
/// of the time.
pub const DEFAULT_MAX_AUTO_K: usize = 16;

/// How contours are grouped into zones (job.toml `zoning.method`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(try_from = "String", into = "String")]
pub enum ZoningMethod {
    /// The paper's k-means zoning under (limit − lens budget), then field sections.
    Kmeans,
    /// Pose selection as covering with the real lens ray ([`crate::cover`]): the default, it
    /// plans the demo part into 18 poses against k-means' 50.
    #[default]
    Cover,
}

impl ZoningMethod {
    /// The job.toml name.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            ZoningMethod::Kmeans => "kmeans",
            ZoningMethod::Cover => "cover",
        }
    }
}

impl std::str::FromStr for ZoningMethod {
    type Err = CellError;

    fn from_str(s: &str) -> Result<Self, CellError> {
        match s {
            "kmeans" => Ok(ZoningMethod::Kmeans),
            "cover" => Ok(ZoningMethod::Cover),
            other => Err(CellError::setting(
                "zoning.method",
                format!("{other:?}"),
                "must be \"kmeans\" or \"cover\"",
            )),
        }
    }
}

impl TryFrom<String> for ZoningMethod {
    type Error = CellError;

    fn try_from(s: String) -> Result<Self, CellError> {
        s.parse()
    }
}

impl From<ZoningMethod> for String {
    fn from(m: ZoningMethod) -> String {
        m.name().to_owned()
    }
}

/// Zoning options (job.toml `[zoning]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ZoningSettings {
    /// "cover" (the default): pose selection as covering (axis + field centre per pose,
    /// incidence checked with the real lens ray), fewer poses; "kmeans": the paper's k-means
    /// zoning under (limit − lens budget), then field sections.
    pub method: ZoningMethod,
    /// A fixed number of k-means zones (zoning by k-means whatever the method); unset: the
    /// method decides (k-means: the smallest k that keeps the incidence limit).
    pub k: Option<usize>,
    /// The weight of the (extent-scaled) positions against the unit feature vectors.
    pub position_weight: f64,
    /// k-means runs with different k-means++ seeds; the lowest inertia wins.
    pub restarts: usize,
    /// The seed of the k-means random generator.
    pub seed: u64,
    /// The most Lloyd iterations per run.
    pub max_iterations: u64,
    /// The largest k the automatic search tries before splitting zones greedily.
    pub max_auto_k: usize,
    /// Merge zones after an automatic k-means while the union keeps the limits (see the module
    /// docs). A fixed k is kept as given.
    pub merge: bool,
}

impl Default for ZoningSettings {
    fn default() -> Self {
        ZoningSettings {
            method: ZoningMethod::Cover,
            k: None,
            position_weight: DEFAULT_POSITION_WEIGHT,
            restarts: 10,
            seed: 0x7a0e_5eed,
            max_iterations: 300,
            max_auto_k: DEFAULT_MAX_AUTO_K,
            merge: true,
        }
    }
}

impl ZoningSettings {
    /// Refuses out-of-range values, naming the key.
    pub fn validate(&self) -> Result<(), CellError> {
        if self.k == Some(0) {
            return Err(CellError::setting("zoning.k", 0, "must be ≥ 1 (or unset)"));
        }
        if !(self.position_weight.is_finite() && self.position_weight >= 0.0) {
            return Err(CellError::setting(
                "zoning.position_weight",
                self.position_weight,
                "must be a finite number ≥ 0",
            ));
        }
        if self.restarts == 0 {
            return Err(CellError::setting("zoning.restarts", 0, "must be ≥ 1"));
        }
        if self.max_iterations == 0 {
            return Err(CellError::setting(
                "zoning.max_iterations",
                0,
                "must be ≥ 1",
            ));
        }
        if self.max_auto_k == 0 {
            return Err(CellError::setting("zoning.max_auto_k", 0, "must be ≥ 1"));
        }
        Ok(())
    }
}

/// The smallest layer step ΔH (mm), configured or derived from the beam: 1 µm, finer than any
/// depth a galvo cell positions to. Below it a zone's layers would number in the millions.
pub const MIN_LAYER_STEP_MM: f64 = 1e-3;

/// Layering options (job.toml `[layers]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct LayerSettings {
    /// ΔH (mm), at least [`MIN_LAYER_STEP_MM`] and with ΔH/2 within the focus processing
    /// length; unset: derived from the beam, 2 · focus half length · `step_safety`.
    pub step_mm: Option<f64>,
    /// The fraction of the focus processing length a layer may use on each side.
    pub step_safety: f64,
}

impl Default for LayerSettings {
    fn default() -> Self {
        LayerSettings {
            step_mm: None,
            step_safety: 0.75,
        }
    }
}

impl LayerSettings {
    /// Refuses out-of-range values, naming the key.
    pub fn validate(&self) -> Result<(), CellError> {
        require_open_closed("layers.step_safety", self.step_safety, 0.0, 1.0)?;
        if let Some(step) = self.step_mm
            && !(step.is_finite() && step >= MIN_LAYER_STEP_MM)
        {
            return Err(CellError::setting(
                "layers.step_mm",
                step,
                format!("must be a finite number ≥ {MIN_LAYER_STEP_MM} mm (1 µm)"),
            ));
        }
        Ok(())
    }

    /// ΔH (mm) for a beam whose focus processing length is `focus_half_length_mm`; refuses a
    /// configured ΔH with ΔH/2 beyond it, and a derived ΔH that is not finite or below
    /// [`MIN_LAYER_STEP_MM`] (naming the `[beam]` it comes from).
    pub fn step_for(&self, focus_half_length_mm: f64) -> Result<f64, CellError> {
        self.validate()?;
        match self.step_mm {
            None => {
                let step = 2.0 * focus_half_length_mm * self.step_safety;
                if step.is_finite() && step >= MIN_LAYER_STEP_MM {
                    Ok(step)
                } else {
                    Err(CellError::setting(
                        "layers.step_mm",
                        format!("unset (derived: {} mm)", Num(step)),
                        format!(
                            "ΔH = 2 × the beam's focus processing length {} mm × \
                             layers.step_safety {} must be a finite number ≥ \
                             {MIN_LAYER_STEP_MM} mm: check [beam] (wavelength_nm, m_squared, \
                             focal_length_mm, beam_diameter_mm, fluence_tolerance)",
                            Num(focus_half_length_mm),
                            self.step_safety
                        ),
                    ))
                }
            }
            Some(step) if step / 2.0 <= focus_half_length_mm => Ok(step),
            Some(step) => Err(CellError::setting(
                "layers.step_mm",
                step,
                format!(
                    "ΔH/2 must not exceed the focus processing length {} mm",
                    Num(focus_half_length_mm)
                ),
            )),
        }
    }
}

/// Lens options (job.toml `[field]`). The field size itself is `GalvoSettings::field_mm`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct LensSettings {
    /// A telecentric lens: the beam is parallel to the optical axis everywhere in the field.
    pub telecentric: bool,
    /// For a non-telecentric lens: the part of the incidence limit reserved for the lens ray angle
    /// (degrees). Zoning keeps feature vectors within (limit − this) of the zone axis; sectioning
    /// then keeps feature-to-ray angles within the full limit.
    pub lens_ray_budget_deg: f64,
}

impl Default for LensSettings {
    fn default() -> Self {
        LensSettings {
            telecentric: false,
            lens_ray_budget_deg: 2.0,
        }
    }
}

impl LensSettings {
    /// Refuses out-of-range values, naming the key. `limit_deg` is the incidence limit.
    pub fn validate(&self, limit_deg: f64) -> Result<(), CellError> {
        if !self.telecentric {
            require_range(
                "field.lens_ray_budget_deg",
                self.lens_ray_budget_deg,
                0.0,
                limit_deg,
            )?;
            if self.lens_ray_budget_deg >= limit_deg {
                return Err(CellError::setting(
                    "field.lens_ray_budget_deg",
                    self.lens_ray_budget_deg,
                    format!("must be below the incidence limit {limit_deg}°"),
                ));
            }
        }
        Ok(())
    }

    /// The incidence budget left for zoning (radians).
    #[must_use]
    pub fn zoning_limit_rad(&self, limit_rad: f64) -> f64 {
        if self.telecentric {
            limit_rad
        } else {
            limit_rad - self.lens_ray_budget_deg.to_radians()
        }
    }
}

/// The largest extra clearance of kerf compensation, µm (`trim.kerf_clearance_um`): the line
/// then stands this far beyond the half kerf, and a web stub as tall stays on the edge, so more
/// than 100 µm (over three times the ±30 µm product tolerance) is no trim.
pub const MAX_KERF_CLEARANCE_UM: f64 = 100.0;

/// Trimming options (job.toml `[trim]`): kerf compensation, and what `run` trims.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TrimSettings {
    /// Offset every trimming line out of the material by half the kerf ([process]
    /// kerf_width_um, or the spot diameter when it is unset) plus kerf_clearance_um, in the face
    /// the contour edges, so the kerf's inner side lies on the edge instead of half a kerf
    /// inside it. The material side comes from the path's geometry (closed loops and their
    /// nesting); a contour whose side cannot be told (an open strip whose ends meet no other
    /// contour, a lone loop) is left on the edge and named in the plan output. false: every
    /// line on the edge.
    pub kerf_compensation: bool,
    /// Extra clearance beyond the half kerf, µm (0-100): the line stands this much further out
    /// of the material, and a web stub this tall stays on the edge.
    pub kerf_clearance_um: f64,
    /// true: `trimctl run` inspects the first scan after registration (as `trimctl inspect`)
    /// and trims only the contours that carry excess (failing on it, or within U of the
    /// tolerance) or that the scan covers too little to tell (those are listed as such), each
    /// with the passes its measured excess height needs at process.depth_per_pass_um; clean
    /// contours are skipped and listed. Needs part.cad to be a mesh (STL or PLY faces). false:
    /// trim every contour, one pass each.
    pub only_detected: bool,
    /// true: where the first scan is inspected (only_detected) and in `run --verify`'s
    /// retrims, every contour rimming an opening whose blocked_fraction exceeds the
    /// inspection's max_blocked_fraction (0.1: the share that fails it) becomes a hatch region:
    /// the film is hatched inside the rim moved half a kerf inward, at a pitch of 3/4 of the
    /// kerf, each track with the passes through the film's thickness: measured where the scan
    /// sees the film from both sides, else film_thickness_um. false: blocked openings are
    /// left as they are (and fail inspection).
    pub hatch_blocked: bool,
    /// The film thickness a blocked opening's hatch passes are set for where the scan sees the
    /// film from one side only, µm (1-2000): where it sees both sides (a view from below
    /// through the opening) the inspection measures the thickness and the passes cut through
    /// that plus twice its uncertainty instead; from above alone it sees whether an opening is
    /// covered, not how thick the cover is, so give the thickest film expected; the default is
    /// the thickest the synthetic part makes (200 µm: 5 passes at 40 µm per pass).
    pub film_thickness_um: f64,
}

/// The largest `trim.film_thickness_um`, µm.
pub const MAX_FILM_THICKNESS_UM: f64 = 2000.0;

impl Default for TrimSettings {
    fn default() -> Self {
        TrimSettings {
            kerf_compensation: true,
            kerf_clearance_um: 0.0,
            only_detected: false,
            hatch_blocked: true,
            film_thickness_um: 200.0,
        }
    }
}

impl TrimSettings {
    /// Refuses out-of-range values, naming the key.
    pub fn validate(&self) -> Result<(), CellError> {
        require_range(
            "trim.kerf_clearance_um",
            self.kerf_clearance_um,
            0.0,
            MAX_KERF_CLEARANCE_UM,
        )?;
        require_range(
            "trim.film_thickness_um",
            self.film_thickness_um,
            1.0,
            MAX_FILM_THICKNESS_UM,
        )
    }
}

/// Every planning option: job.toml's top-level `max_incidence_deg` and its `[beam]`,
/// `[zoning]`, `[layers]`, `[field]`, `[machine]`, `[galvo]`, `[timing]`, `[calibration]`,
/// `[process]` and `[trim]` tables (trimctl's `JobConfig` embeds them; a Job records them as `settings`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PlanSettings {
    /// Incidence limit: the largest angle between a contour's feature vector and the beam, lens ray
    /// angle included.
    pub max_incidence_deg: f64,
    /// Laser and lens (paper §2.1-2.2); the defaults are the paper's cell. The operating point
    /// (power_w, repetition_rate_hz) must be within the limits of cell.laser_profile.
    pub beam: Beam,
    /// k-means zoning under the incidence limit (paper §2.4).
    pub zoning: ZoningSettings,
    /// Layers along each zone axis (paper Eq. 14).
    pub layers: LayerSettings,
    /// The lens and the galvo field.
    pub field: LensSettings,
    /// Machine kinematics, travel limits and speeds (LinuxCNC names).
    pub machine: MachineSettings,
    /// Galvo field, calibration, speeds and delays.
    pub galvo: GalvoSettings,
    /// What the cell adds to the commanded cycle-time model, learned from recorded runs by
    /// `trimctl calibrate timing` (which also writes the [machine] move keys). 0: the commanded
    /// speeds and delays alone.
    pub timing: TimingSettings,
    /// The cell as measured by `trimctl calibrate cell` / `calibrate field` (docs/DESIGN.md "Frames
    /// and the calibration chain"). A missing key is the nominal value of [machine] (axis lines),
    /// the identity (scanner) or none (field correction).
    pub calibration: Calibration,
    /// The ablation figures (depth_per_pass_um, kerf_width_um): the kerf that [trim]
    /// compensates, how many passes a measured burr needs (`run --verify`), and what the
    /// digital twin's cuts remove.
    pub process: ProcessSettings,
    /// Trimming: kerf compensation (the line offset out of the material by half the kerf).
    pub trim: TrimSettings,
}

impl Default for PlanSettings {
    fn default() -> Self {
        PlanSettings {
            max_incidence_deg: 5.0,
            beam: Beam::default(),
            zoning: ZoningSettings::default(),
            layers: LayerSettings::default(),
            field: LensSettings::default(),
            machine: MachineSettings::default(),
            galvo: GalvoSettings::default(),
            timing: TimingSettings::default(),
            calibration: Calibration::default(),
            process: ProcessSettings::default(),
            trim: TrimSettings::default(),
        }
    }
}

impl PlanSettings {
    /// Refuses out-of-range values, naming the key.
    pub fn validate(&self) -> Result<(), CellError> {
        require_open_closed("max_incidence_deg", self.max_incidence_deg, 0.0, 45.0)?;
        self.beam.validate()?;
        self.zoning.validate()?;
        self.timing.validate()?;
        self.layers.validate()?;
        self.field.validate(self.max_incidence_deg)?;
        self.machine.validate()?;
        self.galvo.validate()?;
        self.calibration.validate(self.machine.kinematics)?;
        self.process.validate()?;
        self.trim.validate()?;
        Ok(())
    }

    /// How far kerf compensation offsets a trimming line out of the material, mm: half the
    /// kerf (`[process]`) plus `trim.kerf_clearance_um`; `None` with `trim.kerf_compensation`
    /// off.
    #[must_use]
    pub fn kerf_offset_mm(&self) -> Option<f64> {
        self.trim.kerf_compensation.then(|| {
            0.5 * self.process.kerf_width_mm(&self.beam) + self.trim.kerf_clearance_um * 1e-3
        })
    }

    /// The lens model the galvo commands are computed with: the height term with L from
    /// `calibration.lens.pivot_to_focal_plane_mm`, else the field correction file's, else the
    /// focal length; and the field correction when `calibration.field_correction` names one.
    /// Also what the Job records of it (file and checksum).
    pub fn lens_model(&self) -> Result<(LensModel, LensRecord), CellError> {
        let field = match &self.calibration.field_correction {
            None => None,
            Some(file) => {
                let bytes = std::fs::read(file).map_err(|e| {
                    CellError::setting(
                        "calibration.field_correction",
                        file.display(),
                        format!("cannot read it: {e}"),
                    )
                })?;
                let field = FieldCorrection::read(file).map_err(|e| {
                    CellError::setting(
                        "calibration.field_correction",
                        file.display(),
                        e.to_string(),
                    )
                })?;
                Some((
                    field,
                    crate::lens::checksum(&bytes),
                    file.display().to_string(),
                ))
            }
        };
        let pivot = self
            .calibration
            .lens
            .pivot_to_focal_plane_mm
            .or_else(|| {
                field
                    .as_ref()
                    .and_then(|(f, _, _)| f.pivot_to_focal_plane_mm)
            })
            .unwrap_or(self.beam.focal_length_mm);
        let record = LensRecord {
            telecentric: self.field.telecentric,
            pivot_to_focal_plane_mm: (!self.field.telecentric).then_some(pivot),
            field_correction: field
                .as_ref()
                .map(|(_, checksum, file)| FieldCorrectionRecord {
                    file: file.clone(),
                    checksum: checksum.clone(),
                }),
        };
        Ok((
            LensModel {
                telecentric: self.field.telecentric,
                pivot_to_focal_plane_mm: pivot,
                field: field.map(|(f, _, _)| f),
            },
            record,
        ))
    }

    /// The rotary table as calibrated (nominal lines where `[calibration]` gives none).
    #[must_use]
    pub fn table(&self) -> TableModel {
        self.calibration.table(&self.machine)
    }

    /// The chain from the scanner to the work-piece frame with the machine at `pose`: the
    /// table and the scanner's pose on the head as `[calibration]` says (nominal where it says
    /// nothing), the work-piece origin of `[machine]`.
    #[must_use]
    pub fn scan_chain(&self, pose: ScanPose) -> ScanChain {
        ScanChain {
            table: self.table(),
            scanner: self.calibration.scanner(),
            pose,
            workpiece_origin_mm: self.machine.workpiece_origin_mm.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kerf_offset_is_half_the_kerf_plus_the_clearance_and_none_when_off() {
        let s = PlanSettings::default();
        let half = 0.5 * s.process.kerf_width_mm(&s.beam);
        assert!((s.kerf_offset_mm().unwrap() - half).abs() < 1e-15);
        let cleared = PlanSettings {
            trim: TrimSettings {
                kerf_clearance_um: 5.0,
                ..TrimSettings::default()
            },
            ..PlanSettings::default()
        };
        assert!((cleared.kerf_offset_mm().unwrap() - (half + 0.005)).abs() < 1e-15);
        let off = PlanSettings {
            trim: TrimSettings {
                kerf_compensation: false,
                ..TrimSettings::default()
            },
            ..PlanSettings::default()
        };
        assert_eq!(off.kerf_offset_mm(), None);
    }

    #[test]
    fn an_out_of_range_clearance_is_refused_by_its_key() {
        for bad in [-1.0, 100.5, f64::NAN, f64::INFINITY] {
            let s = PlanSettings {
                trim: TrimSettings {
                    kerf_clearance_um: bad,
                    ..TrimSettings::default()
                },
                ..PlanSettings::default()
            };
            let e = s.validate().unwrap_err().to_string();
            assert!(e.contains("trim.kerf_clearance_um"), "{bad}: {e}");
        }
        for good in [0.0, 12.5, MAX_KERF_CLEARANCE_UM] {
            let s = PlanSettings {
                trim: TrimSettings {
                    kerf_clearance_um: good,
                    ..TrimSettings::default()
                },
                ..PlanSettings::default()
            };
            s.validate().unwrap();
        }
    }

    #[test]
    fn a_layer_step_below_a_micrometre_is_refused_by_its_key() {
        for bad in [1e-9, 1e-300, 0.0, -0.3, f64::NAN, f64::INFINITY] {
            let s = LayerSettings {
                step_mm: Some(bad),
                ..LayerSettings::default()
            };
            let e = s.validate().unwrap_err().to_string();
            assert!(e.contains("layers.step_mm"), "{bad}: {e}");
            let e = s.step_for(0.4).unwrap_err().to_string();
            assert!(e.contains("layers.step_mm"), "{bad}: {e}");
        }
        // A mistyped exponent reads back as typed, not as 300 digits.
        let e = LayerSettings {
            step_mm: Some(1e-300),
            ..LayerSettings::default()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.starts_with("setting layers.step_mm = 1e-300: "), "{e}");
        let e = LayerSettings::default()
            .step_for(1e-300)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("derived: 1.5e-300 mm") && e.contains("length 1e-300 mm") && e.len() < 400,
            "{e}"
        );
        let s = LayerSettings {
            step_mm: Some(MIN_LAYER_STEP_MM),
            ..LayerSettings::default()
        };
        assert_eq!(s.step_for(0.4).unwrap(), MIN_LAYER_STEP_MM);
        // A derived step below 1 µm (or not finite) is refused naming the beam.
        for focus in [1e-9, 0.0, f64::NAN, f64::INFINITY] {
            let e = LayerSettings::default()
                .step_for(focus)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("layers.step_mm") && e.contains("[beam]"),
                "{focus}: {e}"
            );
        }
    }

    #[test]
    fn an_out_of_range_film_thickness_is_refused_by_its_key() {
        let with = |t: f64| PlanSettings {
            trim: TrimSettings {
                film_thickness_um: t,
                ..TrimSettings::default()
            },
            ..PlanSettings::default()
        };
        for bad in [0.0, -5.0, 2000.5, f64::NAN] {
            let e = with(bad).validate().unwrap_err().to_string();
            assert!(e.contains("trim.film_thickness_um"), "{bad}: {e}");
        }
        with(50.0).validate().unwrap();
        assert!(TrimSettings::default().hatch_blocked);
    }
}
