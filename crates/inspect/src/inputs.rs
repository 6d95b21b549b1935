//! Checks of the inputs that run before anything is sized by them: the path's contours against
//! the CAD's extent (a contour far off the part spans a raster, a grid and a densified crop as
//! wide as its distance), the scan's size for the fit, and which points stand near enough to
//! the part to be measured at all.
//!
//! Callers that fit the scan before [`crate::inspect`] (the CLI, Python) run
//! [`check_path_on_cad`] and [`check_scan_for_fit`] first: the registration sizes its own
//! structures by the path and gives a sparse scan's failure in its own terms.

use trim_geom::{Aabb, Path, Point3};
use trim_register::regional::{PATH_OUTSIDE_CAD_DIAGONAL_SHARE, PATH_OUTSIDE_CAD_MM};

use crate::error::{InspectError, Result};

/// A contour or a scan point may stand this share of the CAD's bounding-box diagonal outside
/// the box and still be the part's (fixture slack, a web reaching off an edge): the
/// registration's bound, so a path that was registered and trimmed is one inspection takes.
pub const OUTSIDE_SHARE: f64 = PATH_OUTSIDE_CAD_DIAGONAL_SHARE;

/// ... and at least this far, mm (a small part's box leaves little slack); the registration's.
pub const OUTSIDE_MIN_MM: f64 = PATH_OUTSIDE_CAD_MM;

/// The registration's coarse ICP needs this many correspondences at every level, each a scan
/// voxel centroid (`trim_register::regional::coarse`, `min_correspondences: 50`).
pub const FIT_MIN_VOXELS: usize = 50;

/// The CAD's bounding box and how far outside it the part's points may lie.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CadExtent {
    /// The box around the CAD mesh's vertices, CAD frame, mm.
    pub aabb: Aabb,
    /// How far outside the box a point may lie and still be the part's, mm: the larger of
    /// [`OUTSIDE_SHARE`] × the box's diagonal and [`OUTSIDE_MIN_MM`].
    pub margin_mm: f64,
}

impl CadExtent {
    /// The extent of the CAD mesh's `vertices` (finite); none when there are none.
    #[must_use]
    pub fn new(vertices: &[Point3]) -> Option<CadExtent> {
        let aabb = Aabb::around(vertices)?;
        Some(CadExtent {
            aabb,
            margin_mm: (OUTSIDE_SHARE * aabb.diagonal()).max(OUTSIDE_MIN_MM),
        })
    }

    /// How far `p` (CAD frame) lies outside the box, mm: 0 inside, infinite when `p` is not
    /// finite.
    #[must_use]
    pub fn outside_mm(&self, p: &Point3) -> f64 {
        self.aabb.distance_outside(p)
    }

    /// Whether `p` (CAD frame) lies within the margin of the box: near enough to be the part's.
    #[must_use]
    pub fn near(&self, p: &Point3) -> bool {
        self.outside_mm(p) <= self.margin_mm
    }
}

/// Refuses a contour of `path` (CAD frame) with a point further than the margin outside the
/// box of the CAD mesh's `vertices`, naming the contour, the point and how far: the path and
/// the CAD are then in different frames or units, and the measurement (a densified crop and an
/// opening's grid as wide as the contour) would be sized by the distance.
pub fn check_path_on_cad(vertices: &[Point3], path: &Path) -> Result<()> {
    let Some(extent) = CadExtent::new(vertices) else {
        return Err(InspectError::Empty {
            what: "CAD mesh".into(),
        });
    };
    for c in path.contours() {
        let worst = c
            .points()
            .iter()
            .enumerate()
            .map(|(i, p)| (i, extent.outside_mm(p)))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((index, outside_mm)) = worst
            && outside_mm > extent.margin_mm
        {
            return Err(InspectError::OutsideCad {
                contour: c.id(),
                index,
                outside_mm,
                margin_mm: extent.margin_mm,
            });
        }
    }
    Ok(())
}

/// The fewest scan points the registration can fit: [`FIT_MIN_VOXELS`] voxels of
/// `min_voxel_points` points each (`[register.coarse] min_voxel_points`).
#[must_use]
pub fn fit_min_points(min_voxel_points: usize) -> usize {
    FIT_MIN_VOXELS * min_voxel_points.max(1)
}

/// Refuses a scan (`what`: its file or "scan") of `points` points too few for the registration
/// to fit ([`fit_min_points`]), naming the scan and both counts.
pub fn check_scan_for_fit(what: &str, points: usize, min_voxel_points: usize) -> Result<()> {
    let needed = fit_min_points(min_voxel_points);
    if points < needed {
        return Err(InspectError::TooFewPoints {
            what: what.into(),
            got: points,
            needed,
            why: format!(
                "the fit to the CAD needs {FIT_MIN_VOXELS} scan voxels of at least {} points each",
                min_voxel_points.max(1)
            ),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_geom::{Contour, Vector3};

    fn square(id: i64, at: Point3) -> Contour {
        let points = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
            .iter()
            .map(|&(x, y)| at + Vector3::new(x, y, 0.0))
            .collect();
        Contour::new(id, points, Vector3::z()).unwrap_or_else(|e| panic!("{e}"))
    }

    /// A 10 × 10 × 2 mm box's corners.
    fn cad() -> Vec<Point3> {
        vec![Point3::new(0.0, 0.0, -2.0), Point3::new(10.0, 10.0, 0.0)]
    }

    #[test]
    fn a_contour_off_the_cad_is_refused_naming_it() {
        let near = square(1, Point3::new(2.0, 2.0, 0.0));
        // Off an edge by 9 mm: within the 10 mm floor of the margin, the registration's, so a
        // path the run registered and trimmed is one the inspection takes.
        let slack = square(2, Point3::new(18.0, 2.0, 0.0));
        let ok = Path::new(vec![near.clone(), slack]).unwrap_or_else(|e| panic!("{e}"));
        assert!(check_path_on_cad(&cad(), &ok).is_ok());
        let beyond = square(4, Point3::new(20.5, 2.0, 0.0));
        let e = check_path_on_cad(&cad(), &Path::new(vec![beyond]).unwrap())
            .expect_err("11.5 mm off is beyond the margin")
            .to_string();
        assert!(
            e.contains("contour 4 lies 12 mm outside") && e.contains("10.0 mm allowed"),
            "{e}"
        );
        let far = square(3, Point3::new(5e4, 2.0, 0.0));
        let bad = Path::new(vec![near, far]).unwrap_or_else(|e| panic!("{e}"));
        let e = check_path_on_cad(&cad(), &bad)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            e.contains("contour 3") && e.contains("49991") && e.contains("share a frame and units"),
            "{e}"
        );
    }

    #[test]
    fn distances_outside_the_box_do_not_overflow() {
        let extent = CadExtent::new(&cad()).unwrap_or_else(|| panic!("no extent"));
        assert_eq!(extent.outside_mm(&Point3::new(5.0, 5.0, -1.0)), 0.0);
        assert!((extent.outside_mm(&Point3::new(13.0, 14.0, 0.0)) - 5.0).abs() < 1e-12);
        assert_eq!(
            extent.outside_mm(&Point3::new(1e300, 5.0, 0.0)),
            1e300 - 10.0
        );
        assert_eq!(
            extent.outside_mm(&Point3::new(f64::NAN, 0.0, 0.0)),
            f64::INFINITY
        );
        assert!(extent.near(&Point3::new(12.0, 5.0, 0.0)));
        assert!(!extent.near(&Point3::new(1e4, 5.0, 0.0)));
    }

    #[test]
    fn a_scan_too_sparse_to_fit_is_refused_with_its_count() {
        assert!(check_scan_for_fit("scan.ply", 150, 3).is_ok());
        let e = check_scan_for_fit("scan50.ply", 50, 3)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            e.contains("scan50.ply") && e.contains("50 points") && e.contains("at least 150"),
            "{e}"
        );
    }
}
