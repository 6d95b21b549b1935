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
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LensDistortion {
    /// Where the zero command lands (mm).
    pub offset_mm: [f64; 2],
    /// The head's rotation about the beam axis (degrees).
    pub rotation_deg: f64,
    /// Radial distortion k: c ↦ c·(1 + k·|c|²) (1/mm²; > 0 pincushion, < 0 barrel).
    pub barrel_per_mm2: f64,
    /// Keystone: x gains x·t_x·y, y gains y·t_y·x (1/mm).
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
    pub fn sample(half_field_mm: f64, nodes: usize, d: impl Fn([f64; 2]) -> [f64; 2]) -> Self {
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
        std::fs::write(path, text).map_err(|source| LensError::Io {
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

    /// D⁻¹(target): the command that lands on `target` (Newton with a numerical Jacobian, to
    /// 1e-9 mm); `None` when it would lie outside the grid or does not converge.
    #[must_use]
    pub fn command_for(&self, target_mm: [f64; 2]) -> Option<[f64; 2]> {
        let mut c = target_mm;
        let d0 = self.displacement(c);
        c = [c[0] - d0[0], c[1] - d0[1]];
        let e = 1e-4;
        for _ in 0..INVERSE_ITERATIONS {
            let l = self.land(c);
            let r = [l[0] - target_mm[0], l[1] - target_mm[1]];
            if r[0].hypot(r[1]) < INVERSE_TOLERANCE_MM {
                let inside = c[0].abs() <= self.half_field_mm + 1e-9
                    && c[1].abs() <= self.half_field_mm + 1e-9;
                return inside.then_some(c);
            }
            let lx = self.land([c[0] + e, c[1]]);
            let ly = self.land([c[0], c[1] + e]);
            let j = [
                [(lx[0] - l[0]) / e, (ly[0] - l[0]) / e],
                [(lx[1] - l[1]) / e, (ly[1] - l[1]) / e],
            ];
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if det.abs() < 1e-12 {
                return None;
            }
            c[0] -= (j[1][1] * r[0] - j[0][1] * r[1]) / det;
            c[1] -= (-j[1][0] * r[0] + j[0][0] * r[1]) / det;
        }
        None
    }
}

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
        std::fs::write(&p, "{\"version\": 1}").expect("write");
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
