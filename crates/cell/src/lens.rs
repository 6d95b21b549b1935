//! The galvo head and its lens: where a command lands (DESIGN.md "Frames and the calibration
//! chain").
//!
//! - A command c (mm, in the focal plane, head frame) lands at D(c) on a flat target in the
//!   focal plane; D is the identity plus distortion, head offset and rotation. Measured D is a
//!   [`FieldCorrection`] (field.json, from `trimctl calibrate field`); a parametric D for the
//!   digital twin and the tests is a [`LensDistortion`].
//! - Off the focal plane, the ray from a pivot at height L above the focal-plane centre meets
//!   height h (toward the lens) at (L − h)/L of its focal-plane position ([`height_scale`]); a
//!   telecentric lens has no height term.
//!
//! [`LensModel`] puts the two together: [`LensModel::land`] is where a command lands at a
//! height, [`LensModel::command_for`] the command that lands on a point.
//! [`CorrectionTable`] is the 65 × 65 table a BJJCZ/EzCad controller loads (`.cor`, layout in
//! docs/protocols/correction-table.md), made from and read back into a [`FieldCorrection`].

use std::path::Path;

use serde::{Deserialize, Serialize};

/// The field.json format version this code writes and reads.
pub const FIELD_VERSION: u32 = 1;

/// Newton iterations of the inverse, and its tolerance (mm).
const INVERSE_ITERATIONS: usize = 30;
const INVERSE_TOLERANCE_MM: f64 = 1e-9;

/// `(L − h)/L`: how far out, relative to its focal-plane position, the ray of a pivot at height
/// L above the focal-plane centre is at height h toward the lens.
#[must_use]
pub fn height_scale(pivot_to_focal_plane_mm: f64, height_mm: f64) -> f64 {
    (pivot_to_focal_plane_mm - height_mm) / pivot_to_focal_plane_mm
}

/// A file or a lens model that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum LensError {
    /// The file cannot be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// What went wrong.
        source: std::io::Error,
    },
    /// The file is not a field correction this code reads.
    #[error("{path}: not a field correction: {message}")]
    Format {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// No command lands on the point (outside the calibrated field, or at the pivot's height).
    #[error("no galvo command lands on ({x:.4}, {y:.4}) mm at height {h:.4} mm: {why}")]
    Unreachable {
        /// The point (mm).
        x: f64,
        /// The point (mm).
        y: f64,
        /// Its height (mm).
        h: f64,
        /// Why.
        why: String,
    },
}

/// A parametric head field for the digital twin and tests: `D(c) = offset + Rot(θ)·d(c)` with
/// `d(c) = c·(1 + k·|c|²) + (c_x·t_x·c_y, c_y·t_y·c_x)` (barrel k, keystone t).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct LensDistortion {
    /// Where the zero command lands, head frame, mm.
    pub offset_mm: [f64; 2],
    /// The head's rotation about the beam axis, degrees.
    pub rotation_deg: f64,
    /// Radial distortion k: c ↦ c·(1 + k·|c|²), 1/mm².
    pub barrel_per_mm2: f64,
    /// Keystone: x gains x·(tx·y), y gains y·(ty·x), 1/mm.
    pub trapezoid_per_mm: [f64; 2],
}

impl LensDistortion {
    /// D(c): where a command (mm) lands on the focal plane (mm).
    #[must_use]
    pub fn land(&self, c: [f64; 2]) -> [f64; 2] {
        let k = 1.0 + self.barrel_per_mm2 * (c[0] * c[0] + c[1] * c[1]);
        let x = c[0] * k + c[0] * self.trapezoid_per_mm[0] * c[1];
        let y = c[1] * k + c[1] * self.trapezoid_per_mm[1] * c[0];
        let (s, co) = self.rotation_deg.to_radians().sin_cos();
        [
            self.offset_mm[0] + co * x - s * y,
            self.offset_mm[1] + s * x + co * y,
        ]
    }

    /// Refuses non-finite values.
    pub fn validate(&self) -> Result<(), String> {
        let all = [
            self.offset_mm[0],
            self.offset_mm[1],
            self.rotation_deg,
            self.barrel_per_mm2,
            self.trapezoid_per_mm[0],
            self.trapezoid_per_mm[1],
        ];
        if all.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(format!("every value must be finite, got {self:?}"))
        }
    }
}

/// A measured head field (field.json): `D(c) = c + δ(c)`, δ a displacement sampled on a regular
/// `n × n` grid over `[−half_field, half_field]²` and interpolated bicubically (Catmull–Rom),
/// so D is smooth (C¹) and follows any barrel, keystone, offset and rotation the fit found.
/// Beyond the grid D is extrapolated linearly from the edge cells; commands there are refused
/// by [`FieldCorrection::command_for`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FieldCorrection {
    /// [`FIELD_VERSION`].
    pub version: u32,
    /// Half the side of the grid (mm): nodes from −this to +this.
    pub half_field_mm: f64,
    /// Nodes per side (n ≥ 4).
    pub nodes: usize,
    /// δ at the nodes (mm), row-major: index `j·n + i` is at
    /// `(−h + i·step, −h + j·step)`, step = 2h/(n − 1).
    pub displacement_mm: Vec<[f64; 2]>,
    /// L fitted from raised marks (mm), if any.
    pub pivot_to_focal_plane_mm: Option<f64>,
    /// What the fit reported (residuals before and after, leave-one-out, parameters).
    #[serde(default)]
    pub fit: serde_json::Value,
}

impl FieldCorrection {
    /// A field correction sampled from any D on an `n × n` grid.
    #[must_use]
    pub fn sample(
        half_field_mm: f64,
        nodes: usize,
        mut d: impl FnMut([f64; 2]) -> [f64; 2],
    ) -> Self {
        let n = nodes.max(4);
        let step = 2.0 * half_field_mm / (n - 1) as f64;
        let mut displacement_mm = Vec::with_capacity(n * n);
        for j in 0..n {
            for i in 0..n {
                let c = [
                    -half_field_mm + i as f64 * step,
                    -half_field_mm + j as f64 * step,
                ];
                let l = d(c);
                displacement_mm.push([l[0] - c[0], l[1] - c[1]]);
            }
        }
        FieldCorrection {
            version: FIELD_VERSION,
            half_field_mm,
            nodes: n,
            displacement_mm,
            pivot_to_focal_plane_mm: None,
            fit: serde_json::Value::Null,
        }
    }

    fn check(&self) -> Result<(), String> {
        if self.version != FIELD_VERSION {
            return Err(format!(
                "version {} (this trimctl reads {FIELD_VERSION})",
                self.version
            ));
        }
        if !(self.half_field_mm.is_finite() && self.half_field_mm > 0.0) {
            return Err(format!(
                "half_field_mm must be > 0, got {}",
                self.half_field_mm
            ));
        }
        if self.nodes < 4 || self.displacement_mm.len() != self.nodes * self.nodes {
            return Err(format!(
                "{} displacements for {} × {} nodes (n ≥ 4)",
                self.displacement_mm.len(),
                self.nodes,
                self.nodes
            ));
        }
        if let Some(i) = self
            .displacement_mm
            .iter()
            .position(|d| !(d[0].is_finite() && d[1].is_finite()))
        {
            return Err(format!("displacement {i} is not finite"));
        }
        if let Some(l) = self.pivot_to_focal_plane_mm
            && !(l.is_finite() && l > 0.0)
        {
            return Err(format!("pivot_to_focal_plane_mm must be > 0, got {l}"));
        }
        Ok(())
    }

    /// Reads field.json, checking its version and shape; errors name the file.
    pub fn read(path: &Path) -> Result<FieldCorrection, LensError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| LensError::Io {
            path: name.clone(),
            source,
        })?;
        let f: FieldCorrection = serde_json::from_str(&text).map_err(|e| LensError::Format {
            path: name.clone(),
            message: e.to_string(),
        })?;
        f.check().map_err(|message| LensError::Format {
            path: name,
            message,
        })?;
        Ok(f)
    }

    /// Writes field.json.
    pub fn write(&self, path: &Path) -> Result<(), LensError> {
        let text = serde_json::to_string_pretty(self).map_err(|e| LensError::Format {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        trim_geom::fs::write_atomic(path, text).map_err(|source| LensError::Io {
            path: path.display().to_string(),
            source,
        })
    }

    fn node(&self, i: isize, j: isize) -> [f64; 2] {
        let n = self.nodes as isize;
        // Linear extrapolation one node beyond the edge keeps Catmull–Rom exact for linear δ.
        let clamp = |k: isize| k.clamp(0, n - 1);
        let (ci, cj) = (clamp(i), clamp(j));
        let at = |i: isize, j: isize| self.displacement_mm[(j * n + i) as usize];
        let base = at(ci, cj);
        let (di, dj) = (i - ci, j - cj);
        let mut out = base;
        if di != 0 {
            let inner = at(clamp(ci - di.signum()), cj);
            for k in 0..2 {
                out[k] += (base[k] - inner[k]) * di.abs() as f64;
            }
        }
        if dj != 0 {
            let inner = at(ci, clamp(cj - dj.signum()));
            for k in 0..2 {
                out[k] += (base[k] - inner[k]) * dj.abs() as f64;
            }
        }
        out
    }

    /// δ(c) (mm), bicubic Catmull–Rom over the grid.
    #[must_use]
    pub fn displacement(&self, c: [f64; 2]) -> [f64; 2] {
        let step = 2.0 * self.half_field_mm / (self.nodes - 1) as f64;
        let u = (c[0] + self.half_field_mm) / step;
        let v = (c[1] + self.half_field_mm) / step;
        let last = (self.nodes - 2) as f64;
        let (fi, fj) = (u.floor().clamp(0.0, last), v.floor().clamp(0.0, last));
        let (tx, ty) = (u - fi, v - fj);
        let (i0, j0) = (fi as isize, fj as isize);
        let wx = catmull_rom(tx);
        let wy = catmull_rom(ty);
        let mut out = [0.0; 2];
        for (b, wyb) in wy.iter().enumerate() {
            for (a, wxa) in wx.iter().enumerate() {
                let d = self.node(i0 - 1 + a as isize, j0 - 1 + b as isize);
                out[0] += wxa * wyb * d[0];
                out[1] += wxa * wyb * d[1];
            }
        }
        out
    }

    /// D(c): where a command (mm) lands on the focal plane (mm).
    #[must_use]
    pub fn land(&self, c: [f64; 2]) -> [f64; 2] {
        let d = self.displacement(c);
        [c[0] + d[0], c[1] + d[1]]
    }

    /// D⁻¹(target): the command (mm) that lands on `target` (mm), by Newton's method with a
    /// numerical Jacobian, to 1e-9 mm; `None` when the command would lie outside the grid (the
    /// calibrated range) or Newton does not converge.
    #[must_use]
    pub fn command_for(&self, target_mm: [f64; 2]) -> Option<[f64; 2]> {
        let c = self.invert(target_mm)?;
        let inside = c[0].abs() <= self.half_field_mm + INSIDE_SLACK_MM
            && c[1].abs() <= self.half_field_mm + INSIDE_SLACK_MM;
        inside.then_some(c)
    }

    /// D⁻¹ without the range check: beyond the grid D is the linear extrapolation of its edge
    /// cells. For tables that must cover more than the marked range; `None` when Newton does
    /// not converge.
    #[must_use]
    pub fn command_for_extrapolated(&self, target_mm: [f64; 2]) -> Option<[f64; 2]> {
        self.invert(target_mm)
    }

    fn invert(&self, target_mm: [f64; 2]) -> Option<[f64; 2]> {
        let d0 = self.displacement(target_mm);
        let mut c = [target_mm[0] - d0[0], target_mm[1] - d0[1]];
        let e = JACOBIAN_STEP_MM;
        for _ in 0..INVERSE_ITERATIONS {
            let l = self.land(c);
            let r = [l[0] - target_mm[0], l[1] - target_mm[1]];
            if r[0].hypot(r[1]) < INVERSE_TOLERANCE_MM {
                return Some(c);
            }
            let lx = self.land([c[0] + e, c[1]]);
            let ly = self.land([c[0], c[1] + e]);
            let j = [
                [(lx[0] - l[0]) / e, (ly[0] - l[0]) / e],
                [(lx[1] - l[1]) / e, (ly[1] - l[1]) / e],
            ];
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if det.is_nan() || det.abs() < 1e-12 {
                return None;
            }
            c[0] -= (j[1][1] * r[0] - j[0][1] * r[1]) / det;
            c[1] -= (-j[1][0] * r[0] + j[0][0] * r[1]) / det;
        }
        None
    }
}

/// The numerical Jacobian's step in the inverse (mm).
const JACOBIAN_STEP_MM: f64 = 1e-4;
/// How far past the grid's edge an inverse still counts as inside (mm).
const INSIDE_SLACK_MM: f64 = 1e-9;

/// Catmull–Rom weights of the four nodes around a cell at fraction t.
fn catmull_rom(t: f64) -> [f64; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

/// A checksum of a file's bytes, for the Job's record of the field correction used: CRC-32
/// (IEEE) as 8 hex digits.
#[must_use]
pub fn checksum(bytes: &[u8]) -> String {
    format!("crc32:{:08x}", crc32fast::hash(bytes))
}

/// Nodes per side of a BJJCZ/EzCad correction table.
pub const TABLE_NODES: usize = 65;
/// Controller bits between neighbouring table nodes (the table spans 2¹⁶ bits).
const TABLE_NODE_STEP_BITS: f64 = 1024.0;
/// The label of the integer layout trimctl writes (UTF-16LE, 22 bytes).
const COR_LABEL_V2: &str = "JCZ_COR_2_1";
/// The label of the older floating-point layout trimctl also reads.
const COR_LABEL_V1: &str = "LMC1COR_1.0";
/// Byte offsets of the integer layout: label, reserved, scale, table.
const COR_V2_SCALE_AT: usize = 0x1C;
const COR_V2_TABLE_AT: usize = 0x24;
/// Byte offsets of the floating-point layout: 63 doubles after label and 2 bytes, the scale
/// the 44th of them, then the table.
const COR_V1_HEADER_AT: usize = 0x18;
const COR_V1_SCALE_INDEX: usize = 43;
const COR_V1_TABLE_AT: usize = COR_V1_HEADER_AT + 63 * 8;
/// The header line of the plain text table.
const TEXT_TABLE_HEADER: &str = "i,j,x_mm,y_mm,dx_bits,dy_bits";

/// A 65 × 65 correction table as a BJJCZ (EzCad, LMC) galvo controller loads it, layout in
/// docs/protocols/correction-table.md. The controller's field is 2¹⁶ bits wide, centred;
/// node (i, j) sits at bits `(1024·i, 1024·j)`, i.e. at `((i − 32), (j − 32))·1024/bits_per_mm`
/// mm in the head frame, and holds the correction (bits) the controller adds to a command
/// there: asked for a target t it sends `t + correction(t)`. trimctl fills it with
/// `D⁻¹(t) − t`, so the spot lands on t.
#[derive(Debug, Clone, PartialEq)]
pub struct CorrectionTable {
    /// The controller's bits per millimetre (the file's scale): the table spans
    /// `65536 / bits_per_mm` mm.
    pub bits_per_mm: f64,
    /// Corrections (bits, x and y) at the nodes, index `j·65 + i` (x fastest).
    pub correction_bits: Vec<[i32; 2]>,
}

impl CorrectionTable {
    /// Node (i, j)'s target in the head frame (mm).
    #[must_use]
    pub fn node_mm(&self, i: usize, j: usize) -> [f64; 2] {
        let half = (TABLE_NODES / 2) as f64;
        [
            (i as f64 - half) * TABLE_NODE_STEP_BITS / self.bits_per_mm,
            (j as f64 - half) * TABLE_NODE_STEP_BITS / self.bits_per_mm,
        ]
    }

    /// The table that makes a controller land on target: `D⁻¹(t) − t` at every node of a field
    /// `field_size_mm` wide (beyond the calibrated range D is extrapolated linearly). Refuses a
    /// correction beyond ±32767 bits (the controller's sign-magnitude limit) or a node where
    /// the inverse fails.
    pub fn from_field(field: &FieldCorrection, field_size_mm: f64) -> Result<Self, LensError> {
        let format = |message: String| LensError::Format {
            path: "correction table".into(),
            message,
        };
        if !(field_size_mm.is_finite() && field_size_mm > 0.0) {
            return Err(format(format!(
                "field size must be > 0 mm, got {field_size_mm}"
            )));
        }
        let mut table = CorrectionTable {
            bits_per_mm: 65536.0 / field_size_mm,
            correction_bits: Vec::with_capacity(TABLE_NODES * TABLE_NODES),
        };
        for j in 0..TABLE_NODES {
            for i in 0..TABLE_NODES {
                let t = table.node_mm(i, j);
                let c = field
                    .command_for_extrapolated(t)
                    .ok_or_else(|| format(format!("node ({i}, {j}) at {t:?} mm: no inverse")))?;
                let bits = |k: usize| ((c[k] - t[k]) * table.bits_per_mm).round();
                let (bx, by) = (bits(0), bits(1));
                if bx.abs() > 32767.0 || by.abs() > 32767.0 {
                    return Err(format(format!(
                        "node ({i}, {j}): correction ({bx}, {by}) bits beyond ±32767"
                    )));
                }
                table.correction_bits.push([bx as i32, by as i32]);
            }
        }
        Ok(table)
    }

    /// The head field the table corrects: the table's map `t ↦ t + correction(t)` (Catmull–Rom
    /// between nodes) is `D⁻¹`, inverted node by node onto a 65 × 65 grid over the table's
    /// field. L is not in a table (`pivot_to_focal_plane_mm` is `None`).
    pub fn to_field(&self) -> Result<FieldCorrection, LensError> {
        let half = (TABLE_NODES / 2) as f64 * TABLE_NODE_STEP_BITS / self.bits_per_mm;
        let inverse = FieldCorrection {
            version: FIELD_VERSION,
            half_field_mm: half,
            nodes: TABLE_NODES,
            displacement_mm: self
                .correction_bits
                .iter()
                .map(|b| {
                    [
                        f64::from(b[0]) / self.bits_per_mm,
                        f64::from(b[1]) / self.bits_per_mm,
                    ]
                })
                .collect(),
            pivot_to_focal_plane_mm: None,
            fit: serde_json::Value::Null,
        };
        inverse.check().map_err(|message| LensError::Format {
            path: "correction table".into(),
            message,
        })?;
        let mut failed = None;
        let field = FieldCorrection::sample(half, TABLE_NODES, |c| {
            inverse.command_for_extrapolated(c).unwrap_or_else(|| {
                failed = Some(c);
                c
            })
        });
        match failed {
            Some(c) => Err(LensError::Format {
                path: "correction table".into(),
                message: format!("the table's map cannot be inverted at {c:?} mm"),
            }),
            None => Ok(field),
        }
    }

    /// The `.cor` bytes, integer layout (`JCZ_COR_2_1`): label, 6 zero bytes, the scale
    /// (f64 LE, bits per mm), then 65 × 65 pairs of i32 LE (dx, dy), x fastest.
    #[must_use]
    pub fn to_cor_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(COR_V2_TABLE_AT + TABLE_NODES * TABLE_NODES * 8);
        for unit in COR_LABEL_V2.encode_utf16() {
            out.extend_from_slice(&unit.to_le_bytes());
        }
        out.resize(COR_V2_SCALE_AT, 0);
        out.extend_from_slice(&self.bits_per_mm.to_le_bytes());
        for b in &self.correction_bits {
            out.extend_from_slice(&b[0].to_le_bytes());
            out.extend_from_slice(&b[1].to_le_bytes());
        }
        out
    }

    /// Parses `.cor` bytes: the integer layout (any label but `LMC1COR_1.0`) or the
    /// floating-point one (`LMC1COR_1.0`, values rounded to bits). The error says what is
    /// wrong and at which byte.
    pub fn from_cor_bytes(bytes: &[u8]) -> Result<Self, String> {
        let label: String = char::decode_utf16(
            bytes
                .get(..0x16)
                .ok_or_else(|| format!("{} bytes: shorter than the label", bytes.len()))?
                .chunks_exact(2)
                .map(|p| u16::from_le_bytes([p[0], p[1]])),
        )
        .map(|c| c.unwrap_or(char::REPLACEMENT_CHARACTER))
        .collect();
        let label = label.trim_end_matches('\0');
        let f64_at = |at: usize| -> Result<f64, String> {
            let b = bytes
                .get(at..at + 8)
                .ok_or_else(|| format!("byte {at}: the file ends ({} bytes)", bytes.len()))?;
            let mut a = [0u8; 8];
            a.copy_from_slice(b);
            Ok(f64::from_le_bytes(a))
        };
        let i32_at = |at: usize| -> Result<i32, String> {
            let b = bytes
                .get(at..at + 4)
                .ok_or_else(|| format!("byte {at}: the file ends ({} bytes)", bytes.len()))?;
            Ok(i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        };
        let n = TABLE_NODES * TABLE_NODES;
        let (bits_per_mm, correction_bits) = if label == COR_LABEL_V1 {
            let scale = f64_at(COR_V1_HEADER_AT + 8 * COR_V1_SCALE_INDEX)?;
            let mut v = Vec::with_capacity(n);
            for k in 0..n {
                let at = COR_V1_TABLE_AT + 16 * k;
                let (dx, dy) = (f64_at(at)?, f64_at(at + 8)?);
                if !(dx.abs() <= 32767.0 && dy.abs() <= 32767.0) {
                    return Err(format!("byte {at}: correction ({dx}, {dy}) out of range"));
                }
                v.push([dx.round() as i32, dy.round() as i32]);
            }
            (scale, v)
        } else {
            let scale = f64_at(COR_V2_SCALE_AT)?;
            let mut v = Vec::with_capacity(n);
            for k in 0..n {
                let at = COR_V2_TABLE_AT + 8 * k;
                v.push([i32_at(at)?, i32_at(at + 4)?]);
            }
            (scale, v)
        };
        if !(bits_per_mm.is_finite() && bits_per_mm > 0.0) {
            return Err(format!(
                "scale (bits per mm) must be > 0, got {bits_per_mm}"
            ));
        }
        Ok(CorrectionTable {
            bits_per_mm,
            correction_bits,
        })
    }

    /// The plain text table: a comment with the scale, the header
    /// `i,j,x_mm,y_mm,dx_bits,dy_bits`, then one line per node, x fastest.
    #[must_use]
    pub fn to_text(&self) -> String {
        let mut s = format!(
            "# trimctl correction table: {TABLE_NODES} x {TABLE_NODES} nodes, bits_per_mm = {}\n\
             {TEXT_TABLE_HEADER}\n",
            self.bits_per_mm
        );
        for j in 0..TABLE_NODES {
            for i in 0..TABLE_NODES {
                let t = self.node_mm(i, j);
                let b = self.correction_bits[j * TABLE_NODES + i];
                s.push_str(&format!("{i},{j},{},{},{},{}\n", t[0], t[1], b[0], b[1]));
            }
        }
        s
    }

    /// Parses the plain text table; the error names the line.
    pub fn from_text(text: &str) -> Result<Self, String> {
        let mut bits_per_mm = None;
        let mut header = false;
        let mut correction_bits = vec![None; TABLE_NODES * TABLE_NODES];
        for (k, line) in text.lines().enumerate() {
            let line = line.trim();
            let at = k + 1;
            if let Some(comment) = line.strip_prefix('#') {
                if let Some((_, v)) = comment.split_once("bits_per_mm =") {
                    bits_per_mm = Some(
                        v.trim()
                            .parse::<f64>()
                            .map_err(|e| format!("line {at}: bits_per_mm: {e}"))?,
                    );
                }
                continue;
            }
            if line.is_empty() {
                continue;
            }
            if !header {
                if line != TEXT_TABLE_HEADER {
                    return Err(format!(
                        "line {at}: expected the header `{TEXT_TABLE_HEADER}`"
                    ));
                }
                header = true;
                continue;
            }
            let f: Vec<&str> = line.split(',').map(str::trim).collect();
            if f.len() != 6 {
                return Err(format!("line {at}: expected 6 columns, got {}", f.len()));
            }
            let int = |s: &str| {
                s.parse::<i64>()
                    .map_err(|e| format!("line {at}: `{s}`: {e}"))
            };
            let (i, j) = (int(f[0])?, int(f[1])?);
            if !((0..TABLE_NODES as i64).contains(&i) && (0..TABLE_NODES as i64).contains(&j)) {
                return Err(format!(
                    "line {at}: node ({i}, {j}) outside 0..{TABLE_NODES}"
                ));
            }
            let (dx, dy) = (int(f[4])?, int(f[5])?);
            if dx.abs() > 32767 || dy.abs() > 32767 {
                return Err(format!(
                    "line {at}: correction ({dx}, {dy}) beyond ±32767 bits"
                ));
            }
            correction_bits[j as usize * TABLE_NODES + i as usize] = Some([dx as i32, dy as i32]);
        }
        let bits_per_mm =
            bits_per_mm.ok_or("no `# ... bits_per_mm = <value>` line before the table")?;
        if !(bits_per_mm.is_finite() && bits_per_mm > 0.0) {
            return Err(format!("bits_per_mm must be > 0, got {bits_per_mm}"));
        }
        let missing = correction_bits.iter().filter(|b| b.is_none()).count();
        if missing > 0 {
            return Err(format!(
                "{missing} of {} nodes missing",
                TABLE_NODES * TABLE_NODES
            ));
        }
        Ok(CorrectionTable {
            bits_per_mm,
            correction_bits: correction_bits.into_iter().flatten().collect(),
        })
    }

    /// Reads a table: the `.cor` binary layouts when the file starts with a UTF-16 label
    /// (`J`/`L` then a zero byte), the plain text table otherwise. Errors name the file.
    pub fn read(path: &Path) -> Result<Self, LensError> {
        let name = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| LensError::Io {
            path: name.clone(),
            source,
        })?;
        let binary = bytes.len() >= 2 && bytes[1] == 0 && bytes[0] != 0;
        let parsed = if binary {
            Self::from_cor_bytes(&bytes)
        } else {
            std::str::from_utf8(&bytes)
                .map_err(|e| format!("not text: {e}"))
                .and_then(Self::from_text)
        };
        parsed.map_err(|message| LensError::Format {
            path: name,
            message,
        })
    }

    /// Writes the table: the `.cor` integer layout when the name ends in `.cor`, the plain
    /// text table otherwise. Errors name the file.
    pub fn write(&self, path: &Path) -> Result<(), LensError> {
        let binary = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("cor"));
        let bytes = if binary {
            self.to_cor_bytes()
        } else {
            self.to_text().into_bytes()
        };
        trim_geom::fs::write_atomic(path, bytes).map_err(|source| LensError::Io {
            path: path.display().to_string(),
            source,
        })
    }
}

/// The lens as the planner models it: the height term and the field correction.
#[derive(Debug, Clone, PartialEq)]
pub struct LensModel {
    /// A telecentric lens: no height term.
    pub telecentric: bool,
    /// L (mm).
    pub pivot_to_focal_plane_mm: f64,
    /// The measured head field; `None`: D is the identity.
    pub field: Option<FieldCorrection>,
}

impl LensModel {
    /// Where a command (mm) lands at height h (mm, toward the lens) above the focal plane:
    /// `(L − h)/L · D(c)` (telecentric: `D(c)`), head frame, mm.
    #[must_use]
    pub fn land(&self, command_mm: [f64; 2], height_mm: f64) -> [f64; 2] {
        let d = self
            .field
            .as_ref()
            .map_or(command_mm, |f| f.land(command_mm));
        if self.telecentric {
            return d;
        }
        let s = height_scale(self.pivot_to_focal_plane_mm, height_mm);
        [d[0] * s, d[1] * s]
    }

    /// The command that lands on `point_mm` at height h: `D⁻¹(L/(L − h) · p)`.
    pub fn command_for(&self, point_mm: [f64; 2], height_mm: f64) -> Result<[f64; 2], LensError> {
        let unreachable = |why: &str| LensError::Unreachable {
            x: point_mm[0],
            y: point_mm[1],
            h: height_mm,
            why: why.to_owned(),
        };
        let on_plane = if self.telecentric {
            point_mm
        } else {
            if height_mm >= self.pivot_to_focal_plane_mm {
                return Err(unreachable("at or above the scan pivot"));
            }
            let s = height_scale(self.pivot_to_focal_plane_mm, height_mm);
            [point_mm[0] / s, point_mm[1] / s]
        };
        match &self.field {
            None => Ok(on_plane),
            Some(f) => f
                .command_for(on_plane)
                .ok_or_else(|| unreachable("outside the field correction's grid")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An independent ray computation: the line from the pivot (0, 0, L) through the
    /// focal-plane point (x, y, 0), met with the plane z = h.
    fn ray_at_height(pivot_mm: f64, on_plane: [f64; 2], h: f64) -> [f64; 2] {
        let (p, q) = ([0.0, 0.0, pivot_mm], [on_plane[0], on_plane[1], 0.0]);
        let dir = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
        let t = (h - p[2]) / dir[2];
        [p[0] + t * dir[0], p[1] + t * dir[1]]
    }

    fn head() -> LensDistortion {
        LensDistortion {
            offset_mm: [0.12, -0.2],
            rotation_deg: 0.15,
            barrel_per_mm2: 4.0e-7,
            trapezoid_per_mm: [1.0e-5, -8.0e-6],
        }
    }

    #[test]
    fn the_height_term_matches_an_independent_ray() {
        let lens = LensModel {
            telecentric: false,
            pivot_to_focal_plane_mm: 254.0,
            field: None,
        };
        for (c, h) in [
            ([30.0, -20.0], 0.3),
            ([-45.0, 45.0], -0.4),
            ([5.0, 1.0], 2.0),
        ] {
            let a = lens.land(c, h);
            let b = ray_at_height(254.0, c, h);
            assert!((a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12);
            let back = lens.command_for(a, h).expect("reachable");
            assert!((back[0] - c[0]).hypot(back[1] - c[1]) < 1e-12);
        }
        let tele = LensModel {
            telecentric: true,
            ..lens.clone()
        };
        assert_eq!(tele.land([3.0, 4.0], 0.5), [3.0, 4.0]);
        assert!(lens.command_for([1.0, 1.0], 254.0).is_err());
    }

    /// A 3-D line–plane intersection, written independently of `height_scale`: the line
    /// through `a` and `b` met with the plane `n·x = d`.
    fn line_meets_plane(a: [f64; 3], b: [f64; 3], n: [f64; 3], d: f64) -> [f64; 3] {
        let dot = |u: [f64; 3], v: [f64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
        let dir = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let t = (d - dot(n, a)) / dot(n, dir);
        [a[0] + t * dir[0], a[1] + t * dir[1], a[2] + t * dir[2]]
    }

    #[test]
    fn with_a_field_the_height_term_follows_the_ray_through_d_of_c_and_inverts() {
        let truth = head();
        let pivot = 254.0;
        let lens = LensModel {
            telecentric: false,
            pivot_to_focal_plane_mm: pivot,
            field: Some(FieldCorrection::sample(50.0, 65, |c| truth.land(c))),
        };
        let field = lens.field.as_ref().expect("field");
        let mut worst_ray: f64 = 0.0;
        let mut worst_inverse: f64 = 0.0;
        for h in [-2.0, -0.35, 0.0, 0.5, 2.0] {
            for i in -8..=8 {
                for j in -8..=8 {
                    let c = [f64::from(i) * 5.5, f64::from(j) * 5.5];
                    // The beam: from the pivot (0, 0, L) through D(c) on the focal plane.
                    let d = field.land(c);
                    let hit =
                        line_meets_plane([0.0, 0.0, pivot], [d[0], d[1], 0.0], [0.0, 0.0, 1.0], h);
                    assert!((hit[2] - h).abs() < 1e-12);
                    let l = lens.land(c, h);
                    worst_ray = worst_ray.max((l[0] - hit[0]).abs().max((l[1] - hit[1]).abs()));
                    // And back: the command for a point at height h lands on it.
                    let p = [f64::from(i) * 5.4, f64::from(j) * 5.4];
                    let c = lens.command_for(p, h).expect("inside the field");
                    let back = lens.land(c, h);
                    worst_inverse = worst_inverse.max((back[0] - p[0]).hypot(back[1] - p[1]));
                }
            }
        }
        assert!(worst_ray <= 1e-12, "ray {worst_ray}");
        assert!(worst_inverse <= 1e-9, "inverse {worst_inverse}");
        assert_eq!(height_scale(pivot, 0.0), 1.0);
        // A point beyond the calibrated range has no command; the pivot's height none at all.
        assert!(lens.command_for([60.0, 0.0], 0.0).is_err());
        assert!(lens.command_for([1.0, 0.0], 300.0).is_err());
    }

    #[test]
    fn a_correction_table_round_trips_through_cor_bytes_text_and_back_to_the_field() {
        let truth = head();
        let field = FieldCorrection::sample(50.0, 65, |c| truth.land(c));
        let table = CorrectionTable::from_field(&field, 100.0).expect("table");
        assert_eq!(table.correction_bits.len(), TABLE_NODES * TABLE_NODES);
        // Bytes: the integer layout, exactly.
        let bytes = table.to_cor_bytes();
        assert_eq!(bytes.len(), 0x24 + 65 * 65 * 8);
        assert_eq!(&bytes[..4], &[b'J', 0, b'C', 0]);
        assert_eq!(
            CorrectionTable::from_cor_bytes(&bytes).expect("parse"),
            table
        );
        assert_eq!(
            CorrectionTable::from_text(&table.to_text()).expect("text"),
            table
        );
        // The centre node holds D⁻¹(0) − 0: minus the head offset (rotated), in bits.
        let centre = table.correction_bits[32 * 65 + 32];
        let c0 = field.command_for([0.0, 0.0]).expect("centre");
        assert!((f64::from(centre[0]) - c0[0] * table.bits_per_mm).abs() <= 0.5);
        assert!((f64::from(centre[1]) - c0[1] * table.bits_per_mm).abs() <= 0.5);
        // Back to a field: within the quantisation (½ bit = 0.76 µm per axis at 655 bits/mm).
        let back = table.to_field().expect("field");
        let mut worst: f64 = 0.0;
        for i in -9..=9 {
            for j in -9..=9 {
                let c = [f64::from(i) * 5.0, f64::from(j) * 5.0];
                let (a, b) = (back.land(c), field.land(c));
                worst = worst.max((a[0] - b[0]).hypot(a[1] - b[1]));
            }
        }
        assert!(worst < 1.5e-3, "table round trip {worst} mm");
        // A truncated file is refused, naming the byte.
        let e = CorrectionTable::from_cor_bytes(&bytes[..100]).expect_err("short");
        assert!(e.contains("byte"), "{e}");
    }

    #[test]
    fn a_sampled_field_reproduces_a_smooth_head_and_inverts() {
        let truth = head();
        let f = FieldCorrection::sample(55.0, 65, |c| truth.land(c));
        let mut worst: f64 = 0.0;
        for i in -10..=10 {
            for j in -10..=10 {
                let c = [f64::from(i) * 4.9, f64::from(j) * 4.9];
                let (a, b) = (f.land(c), truth.land(c));
                worst = worst.max((a[0] - b[0]).hypot(a[1] - b[1]));
                let back = f.command_for(a).expect("inside");
                assert!((back[0] - c[0]).hypot(back[1] - c[1]) < 1e-8);
            }
        }
        // Catmull–Rom on a 1.7 mm grid of a cubic field: well under a micrometre.
        assert!(worst < 1e-4, "{worst}");
        assert!(f.command_for([80.0, 0.0]).is_none());
    }

    #[test]
    fn lens_model_with_field_and_height_round_trips() {
        let truth = head();
        let lens = LensModel {
            telecentric: false,
            pivot_to_focal_plane_mm: 260.0,
            field: Some(FieldCorrection::sample(55.0, 65, |c| truth.land(c))),
        };
        for (p, h) in [([40.0, -35.0], 0.25), ([-10.0, 3.0], -0.3)] {
            let c = lens.command_for(p, h).expect("reachable");
            let l = lens.land(c, h);
            assert!((l[0] - p[0]).hypot(l[1] - p[1]) < 1e-8);
        }
    }

    #[test]
    fn bad_files_are_refused_naming_the_file() {
        let dir = std::env::temp_dir().join(format!("trim-lens-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let p = dir.join("field.json");
        trim_geom::fs::write_atomic(&p, "{\"version\": 1}").expect("write");
        let e = FieldCorrection::read(&p)
            .expect_err("incomplete")
            .to_string();
        assert!(e.contains("field.json"), "{e}");
        let mut f = FieldCorrection::sample(50.0, 5, |c| c);
        f.displacement_mm.pop();
        f.write(&p).expect("write");
        let e = FieldCorrection::read(&p).expect_err("short").to_string();
        assert!(e.contains("displacements"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
