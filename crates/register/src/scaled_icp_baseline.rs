//! A re-implementation of the paper's registration (§4, Fig. 19) as the baseline the regional
//! registration is measured against: coarse rigid point-to-point ICP of the CAD points onto the
//! scan from the fixture pose, then, for each contour, a scaled point-to-point ICP of the CAD
//! points clipped within a radius of the contour onto the scan points clipped the same way,
//! applied to that contour.

use rayon::prelude::*;
use trim_geom::crop::crop_near_polyline;
use trim_geom::{KdTree, Path, PointCloud, Similarity3};

use crate::error::Result;
use crate::icp::{IcpMethod, IcpSettings, IcpTarget, PyramidLevel, icp, icp_pyramid};

/// The baseline's settings.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PaperSettings {
    /// Coarse rigid ICP pyramid (both clouds down-sampled per level).
    pub coarse_levels: Vec<PyramidLevel>,
    /// Clip radius around each contour, mm.
    pub clip_radius_mm: f64,
    /// Maximum correspondence distance of the local scaled ICP, mm.
    pub local_max_distance_mm: f64,
    /// Iteration cap of the local ICP.
    pub local_iterations: usize,
}

impl Default for PaperSettings {
    fn default() -> Self {
        let level = |voxel_mm, max_correspondence_distance_mm, max_iterations| PyramidLevel {
            voxel_mm,
            max_correspondence_distance_mm,
            max_iterations,
        };
        PaperSettings {
            coarse_levels: vec![
                level(2.0, 12.0, 30),
                level(1.0, 4.0, 30),
                level(0.5, 1.5, 30),
            ],
            clip_radius_mm: 3.0,
            local_max_distance_mm: 1.0,
            local_iterations: 50,
        }
    }
}

/// Runs the paper's method; a contour whose local fit fails keeps its coarse position (the
/// paper has no failure handling).
pub fn paper_method(
    cad: &PointCloud,
    scan: &PointCloud,
    path: &Path,
    initial_scan_from_cad: &Similarity3,
    settings: &PaperSettings,
) -> Result<Path> {
    let rigid = IcpSettings {
        method: IcpMethod::PointToPoint,
        with_scale: false,
        ..IcpSettings::default()
    };
    let cad_plain = PointCloud::new(cad.points().to_vec())?;
    let coarse = icp_pyramid(
        &cad_plain,
        scan,
        initial_scan_from_cad,
        &settings.coarse_levels,
        &rigid,
    )?;
    paper_local_fits(cad, scan, path, &coarse.target_from_source, settings)
}

/// The paper's second stage alone: from a coarse `scan_from_cad`, per contour a scaled
/// point-to-point ICP of the CAD points clipped around it onto the scan points clipped the same
/// way. With trimctl's coarse similarity as the start, this isolates the local stage's failure
/// modes (clip shrinkage, unseen faces, one similarity per contour).
pub fn paper_local_fits(
    cad: &PointCloud,
    scan: &PointCloud,
    path: &Path,
    scan_from_cad: &Similarity3,
    settings: &PaperSettings,
) -> Result<Path> {
    let cad_plain = PointCloud::new(cad.points().to_vec())?;
    let scan_from_cad = *scan_from_cad;
    let cad_moved = cad_plain.transformed(&scan_from_cad)?;
    let cad_tree = KdTree::build(cad_moved.points());
    let scan_tree = KdTree::build(scan.points());
    let local = IcpSettings {
        method: IcpMethod::PointToPoint,
        with_scale: true,
        max_correspondence_distance_mm: settings.local_max_distance_mm,
        max_iterations: settings.local_iterations,
        ..IcpSettings::default()
    };
    let contours = path
        .contours()
        .par_iter()
        .map(|c| -> Result<trim_geom::Contour> {
            let moved = c.transformed(&scan_from_cad)?;
            let fit = (|| -> Result<Similarity3> {
                let ci = crop_near_polyline(
                    cad_moved.points(),
                    &cad_tree,
                    moved.points(),
                    settings.clip_radius_mm,
                )?;
                let si = crop_near_polyline(
                    scan.points(),
                    &scan_tree,
                    moved.points(),
                    settings.clip_radius_mm,
                )?;
                let src = cad_moved.select(&ci)?;
                let tgt = IcpTarget::new(scan.select(&si)?)?;
                Ok(icp(&src, &tgt, &Similarity3::identity(), &local)?.target_from_source)
            })();
            Ok(match fit {
                Ok(t) => moved.transformed(&t)?,
                Err(_) => moved,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Path::new(contours)?)
}
