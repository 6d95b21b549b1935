//! The fit of the part to its CAD that an inspection measures through, and its per-contour
//! bound on the error that fit makes across each contour.

use std::collections::BTreeMap;

use trim_geom::{ContourId, Point3, Similarity3};
use trim_register::Registration;
use trim_register::deformation::BSplineField;

use crate::error::{InspectError, Result};

/// Where the scanned part sits on its CAD: `scan = scan_from_cad · F(cad)`, `F(x) = x + d(x)`
/// the registration's deformation field (none for a rigid fit).
#[derive(Debug, Clone)]
pub struct Placement {
    /// The similarity from the CAD frame to the scan frame.
    pub scan_from_cad: Similarity3,
    /// The deformation field, CAD frame (none: rigid).
    pub field: Option<BSplineField>,
    /// Per contour, the fit's predicted largest error across it, µm
    /// (`ContourQuality::predicted_max_error_um`).
    pub bound_um: BTreeMap<ContourId, f64>,
    /// The bound of a contour not in `bound_um`, µm; `None`: such a contour is an error.
    pub default_bound_um: Option<f64>,
}

impl Placement {
    /// The registration's fit and its per-contour bounds.
    #[must_use]
    pub fn from_registration(registration: &Registration) -> Placement {
        Placement {
            scan_from_cad: registration.scan_from_cad,
            field: registration.field.clone(),
            bound_um: registration
                .report
                .contours
                .iter()
                .map(|q| (q.id, q.predicted_max_error_um))
                .collect(),
            default_bound_um: None,
        }
    }

    /// A rigid fit (the six-point datum fit) with one bound for every contour, µm.
    #[must_use]
    pub fn rigid(scan_from_cad: Similarity3, bound_um: f64) -> Placement {
        Placement {
            scan_from_cad,
            field: None,
            bound_um: BTreeMap::new(),
            default_bound_um: Some(bound_um),
        }
    }

    /// A registered position of a CAD-frame point, scan frame.
    #[must_use]
    pub fn scan_from_cad_point(&self, p_cad: &Point3) -> Point3 {
        let moved = self.field.as_ref().map_or(*p_cad, |f| f.apply(p_cad));
        self.scan_from_cad * moved
    }

    /// A scan point carried into the CAD frame: `F⁻¹(cad_from_scan · q)`, the field inverted
    /// by `iterations` fixed-point steps `x ← y − d(x)` (the field's gradient is of the order
    /// of the part's shrinkage and bend, ~10⁻², so each step gains about two digits).
    #[must_use]
    pub fn cad_from_scan_point(
        &self,
        cad_from_scan: &Similarity3,
        q_scan: &Point3,
        iterations: usize,
    ) -> Point3 {
        let y = cad_from_scan * q_scan;
        self.field
            .as_ref()
            .map_or(y, |f| f.inverse_apply(&y, iterations))
    }

    /// The bound for contour `id`, µm.
    pub fn bound_for(&self, id: ContourId) -> Result<f64> {
        self.bound_um
            .get(&id)
            .copied()
            .or(self.default_bound_um)
            .ok_or(InspectError::MissingBound { contour: id })
    }
}
