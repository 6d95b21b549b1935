//! Six-point datum fit (thesis §3.5.2): positioning constrained to the part's datum points
//! instead of the whole surface.
//!
//! 1. Best-fit the CAD surface to the scan (the coarse stage of [`crate::regional`], rigid).
//! 2. Identify each datum on the scan: the datum point carried by the best fit, projected onto
//!    the plane of its nearest scan points (the "points at the minimum distance with the nominal
//!    ones", with the scan's noise averaged out).
//! 3. A rigid least-squares fit (Umeyama, no scale) of the CAD datum points onto the identified
//!    ones replaces the surface best fit.

use trim_geom::normals::plane_normal;
use trim_geom::{KdTree, Point3, PointCloud, Similarity3};

use crate::error::{RegisterError, Result};
use crate::icp::IcpTarget;
use crate::regional::{CoarseSettings, coarse_fit};
use crate::sampling::{View, facing_indices};
use crate::umeyama::umeyama;

/// Scan points whose plane locates one datum.
pub const DATUM_NEIGHBOURS: usize = 30;

/// A datum farther than this from the scan after the best fit is not on it, mm.
pub const MAX_DATUM_DISTANCE_MM: f64 = 1.0;

/// The result of the datum fit.
#[derive(Debug, Clone, PartialEq)]
pub struct DatumFit {
    /// The datum-constrained rigid pose.
    pub scan_from_cad: Similarity3,
    /// The surface best fit it started from.
    pub surface_scan_from_cad: Similarity3,
    /// Each datum as identified on the scan, scan frame.
    pub datums_in_scan: Vec<Point3>,
    /// Each datum's distance after the fit, mm.
    pub residuals_mm: Vec<f64>,
}

/// Fits the part's pose to its datum points (`datums_in_cad`, at least 3, normally 6). `cad`
/// needs outward normals; `view_in_scan` says where the scanner was (for visibility).
pub fn datum_fit(
    cad: &PointCloud,
    scan: &PointCloud,
    datums_in_cad: &[Point3],
    initial_scan_from_cad: &Similarity3,
    view_in_scan: View,
    coarse: &CoarseSettings,
) -> Result<DatumFit> {
    if datums_in_cad.len() < 3 {
        return Err(RegisterError::TooFewCorrespondences {
            stage: "datum fit".into(),
            needed: 3,
            got: datums_in_cad.len(),
            max_distance_mm: MAX_DATUM_DISTANCE_MM,
        });
    }
    check_datums(datums_in_cad)?;
    if scan.is_empty() {
        return Err(RegisterError::EmptyCloud { which: "scan" });
    }
    let cad_from_scan0 = initial_scan_from_cad.inverse();
    let view = match view_in_scan {
        View::From(p) => View::From(cad_from_scan0 * p),
        View::Along(d) => View::Along(cad_from_scan0.isometry.rotation * d),
    };
    let facing = facing_indices(cad, view, -0.2)?;
    let target = IcpTarget::new(cad.select(&facing)?)?;
    let rigid = CoarseSettings {
        with_scale: false,
        ..coarse.clone()
    };
    let surface = coarse_fit(scan, &target, &cad_from_scan0, &rigid)?
        .target_from_source
        .inverse();
    let tree = KdTree::build(scan.points());
    let mut found = Vec::with_capacity(datums_in_cad.len());
    for (k, d) in datums_in_cad.iter().enumerate() {
        let guess = surface * d;
        let near = tree.knn(&guess, DATUM_NEIGHBOURS);
        if near
            .first()
            .is_none_or(|n| n.distance_sq > MAX_DATUM_DISTANCE_MM.powi(2))
        {
            return Err(RegisterError::Datum {
                datum: k,
                message: format!(
                    "not on the scan (no scan point within {MAX_DATUM_DISTANCE_MM} mm)"
                ),
            });
        }
        let pts: Vec<Point3> = near.iter().map(|n| scan.points()[n.index]).collect();
        let centre = Point3::from(
            pts.iter().map(|p| p.coords).sum::<trim_geom::Vector3>() / pts.len() as f64,
        );
        let n = plane_normal(pts.iter()).ok_or_else(|| RegisterError::Datum {
            datum: k,
            message: format!(
                "the {} scan points near it span no plane (at one place or on one \
                 line), so it cannot be put on the surface",
                pts.len()
            ),
        })?;
        found.push(guess - n * n.dot(&(guess - centre)));
    }
    let fit = umeyama(datums_in_cad, &found, false)?;
    let residuals_mm = datums_in_cad
        .iter()
        .zip(&found)
        .map(|(d, f)| (fit.target_from_source * d - f).norm())
        .collect();
    Ok(DatumFit {
        scan_from_cad: fit.target_from_source,
        surface_scan_from_cad: surface,
        datums_in_scan: found,
        residuals_mm,
    })
}

/// Two datums nearer than this are one point given twice, mm.
pub const MIN_DATUM_SEPARATION_MM: f64 = 1e-3;

/// Refuses datums that cannot fix a rigid pose: one that is not finite, one given twice
/// (within [`MIN_DATUM_SEPARATION_MM`] of an earlier one), or all on one line.
fn check_datums(datums: &[Point3]) -> Result<()> {
    for (k, d) in datums.iter().enumerate() {
        if !d.iter().all(|c| c.is_finite()) {
            return Err(RegisterError::Datum {
                datum: k,
                message: format!("({}, {}, {}) is not finite", d.x, d.y, d.z),
            });
        }
        if let Some(j) = datums[..k]
            .iter()
            .position(|e| (d - e).norm() < MIN_DATUM_SEPARATION_MM)
        {
            return Err(RegisterError::Datum {
                datum: k,
                message: format!(
                    "({}, {}, {}) repeats datum {j}: each datum is a different point on the part",
                    d.x, d.y, d.z
                ),
            });
        }
    }
    if plane_normal(datums.iter()).is_none() {
        return Err(RegisterError::Datum {
            datum: datums.len() - 1,
            message: format!(
                "the {} datums lie on one line, which leaves the turn about it free: a rigid fit \
                 needs datums that span a plane",
                datums.len()
            ),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_geom::transform::{rotation_angle_between, translation_distance};
    use trim_synth::{SynthParams, design_point, generate};

    #[test]
    fn recovers_the_pose_of_an_undeformed_part_from_six_datums() {
        let case = generate(&SynthParams {
            seed: 3,
            sag_mm: 0.0,
            twist_deg: 0.0,
            scale_range: 0.0,
            scan_points: 40_000,
            cad_points: 60_000,
            // The datum fit culls the CAD by one view (`View`): a one-view scan. With a scan
            // from both sides (the synthetic default, three views) its residuals reach 27 µm.
            scanner_views: 1,
            ..SynthParams::default()
        })
        .unwrap();
        // Six datums on the top face (w = 1.5), clear of holes: 3-2-1 style spread.
        let datums: Vec<Point3> = [
            (-13.0, -40.0),
            (13.0, -40.0),
            (0.0, 40.0),
            (-13.0, 10.0),
            (13.0, 10.0),
            (0.0, -30.0),
        ]
        .iter()
        .map(|&(u, v)| design_point(u, v, 1.5))
        .collect();
        let fit = datum_fit(
            &case.cad_points,
            &case.scan,
            &datums,
            &case.scan_from_cad_nominal,
            View::From(case.scanner_in_scan),
            &CoarseSettings::default(),
        )
        .unwrap();
        // Six points on a near-flat face fix the tilt and height well and the in-plane pose
        // only through the face's camber and twist: the thesis notes the datum fit deviates
        // more than the surface fit. Check the datum residuals and the tilt.
        assert!(
            fit.residuals_mm.iter().all(|r| *r < 0.02),
            "{:?}",
            fit.residuals_mm
        );
        assert!(
            rotation_angle_between(&fit.scan_from_cad, &case.scan_from_cad_true)
                < 0.2f64.to_radians()
        );
        assert!(translation_distance(&fit.surface_scan_from_cad, &case.scan_from_cad_true) < 0.2);
        assert!(
            datum_fit(
                &case.cad_points,
                &case.scan,
                &datums[..2],
                &case.scan_from_cad_nominal,
                View::From(case.scanner_in_scan),
                &CoarseSettings::default()
            )
            .is_err()
        );
        // Datums that cannot fix a pose are refused by what is wrong with them, not as "not on
        // the scan".
        let fit = |datums: &[Point3]| {
            datum_fit(
                &case.cad_points,
                &case.scan,
                datums,
                &case.scan_from_cad_nominal,
                View::From(case.scanner_in_scan),
                &CoarseSettings::default(),
            )
            .unwrap_err()
            .to_string()
        };
        let mut twice = datums.clone();
        twice[4] = datums[1];
        let e = fit(&twice);
        assert!(
            e.starts_with("datum 4: ") && e.contains("repeats datum 1"),
            "{e}"
        );
        let (a, b) = (design_point(0.0, 0.0, 1.5), design_point(0.0, 30.0, 1.5));
        let line: Vec<Point3> = (0..4).map(|i| a + (b - a) * f64::from(i) / 3.0).collect();
        let e = fit(&line);
        assert!(e.contains("the 4 datums lie on one line"), "{e}");
        let mut nan = datums.clone();
        nan[2].y = f64::NAN;
        let e = fit(&nan);
        assert!(
            e.starts_with("datum 2: ") && e.contains("not finite"),
            "{e}"
        );
    }
}
