//! Pieces: the unit the planner works on. A piece is a contour, or a part of a contour whose
//! feature vectors spread wider than the incidence limit (DESIGN.md "Zoning": the paper split
//! strip contours by hand). Every point remembers where on its input contour it lies, so the
//! validation can map galvo points back to the registered path.

use trim_geom::{Contour, ContourId, Path, Point3, UnitVector3, Vector3};

use crate::error::PlanError;

/// Two feature vectors closer than this (radians) count as the same direction when a piece's
/// distinct directions are collected.
pub const SAME_DIRECTION_RAD: f64 = 1e-12;

/// Minimum contour length (mm); shorter contours are refused as zero-length.
pub const MIN_CONTOUR_LENGTH_MM: f64 = 1e-9;

/// One piece of an input contour, in the work-piece frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Piece {
    /// The input contour's id (a split contour's pieces keep it).
    pub contour: ContourId,
    /// Points in path order (mm).
    pub points: Vec<Point3>,
    /// A unit feature vector per point.
    pub features: Vec<Vector3>,
    /// Where each point lies on the input contour: vertex index plus the fraction of the next
    /// segment (2.5 = halfway between vertices 2 and 3).
    pub source: Vec<f64>,
}

impl Piece {
    /// The normalised mean feature vector.
    #[must_use]
    pub fn feature(&self) -> UnitVector3 {
        UnitVector3::new_normalize(self.features.iter().sum())
    }

    /// The mean of the points.
    #[must_use]
    pub fn centroid(&self) -> Point3 {
        let sum: Vector3 = self.points.iter().map(|p| p.coords).sum();
        Point3::from(sum / self.points.len() as f64)
    }

    /// The polyline length (mm).
    #[must_use]
    pub fn length_mm(&self) -> f64 {
        self.points.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
    }

    /// The piece's feature directions with consecutive repeats removed (a contour with one
    /// feature vector gives one), for cheap angle checks.
    #[must_use]
    pub fn distinct_features(&self) -> Vec<Vector3> {
        let mut out: Vec<Vector3> = Vec::new();
        for f in &self.features {
            if out
                .last()
                .is_none_or(|last| angle_rad(last, f) > SAME_DIRECTION_RAD)
            {
                out.push(*f);
            }
        }
        out
    }
}

/// The angle between two unit vectors (radians), robust near 0 and π.
#[must_use]
pub fn angle_rad(a: &Vector3, b: &Vector3) -> f64 {
    a.cross(b).norm().atan2(a.dot(b))
}

/// Checks a contour the way the planner needs it (finite, non-zero features, non-zero length)
/// and names the contour when it refuses.
pub fn check_contour(c: &Contour) -> Result<(), PlanError> {
    let id = c.id();
    for (i, p) in c.points().iter().enumerate() {
        if !p.coords.iter().all(|v| v.is_finite()) {
            return Err(PlanError::NonFinite {
                contour: id,
                what: "point",
                index: i,
            });
        }
    }
    for (i, f) in c.features().iter().enumerate() {
        if !f.iter().all(|v| v.is_finite()) {
            return Err(PlanError::NonFinite {
                contour: id,
                what: "feature vector",
                index: i,
            });
        }
        if f.norm() < trim_geom::path::MIN_FEATURE_NORM {
            return Err(PlanError::ZeroFeature {
                contour: id,
                index: i,
            });
        }
    }
    let length_mm = c.length();
    if c.points().len() < 2 || length_mm < MIN_CONTOUR_LENGTH_MM {
        return Err(PlanError::ZeroLength {
            contour: id,
            points: c.points().len(),
            length_mm,
        });
    }
    Ok(())
}

/// Turns a path into pieces. A contour whose features spread more than `split_above_rad` from
/// its mean is split into pieces whose features all lie within `piece_spread_rad` of the
/// piece's first feature (so each piece fits a cone of that half-angle). Segments whose end
/// features differ by more than `piece_spread_rad` are first subdivided (positions linear,
/// features normalised-linear), so a piece always has at least two points. Consecutive pieces
/// share their boundary point: no gap, no overlap.
pub fn pieces_of(
    path: &Path,
    split_above_rad: f64,
    piece_spread_rad: f64,
) -> Result<Vec<Piece>, PlanError> {
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::new();
    for c in path.contours() {
        check_contour(c)?;
        if !seen.insert(c.id()) {
            return Err(PlanError::DuplicateContour { contour: c.id() });
        }
        let whole = Piece {
            contour: c.id(),
            points: c.points().to_vec(),
            features: c.features().iter().map(|f| f.normalize()).collect(),
            source: (0..c.points().len()).map(|i| i as f64).collect(),
        };
        let spread = whole
            .features
            .iter()
            .map(|f| angle_rad(f, &whole.feature()))
            .fold(0.0, f64::max);
        if spread <= split_above_rad {
            out.push(whole);
        } else {
            out.extend(split_piece(
                &densify(&whole, piece_spread_rad),
                piece_spread_rad,
            ));
        }
    }
    if out.is_empty() {
        return Err(PlanError::EmptyPath);
    }
    Ok(out)
}

/// Inserts points where consecutive features turn by more than `max_step_rad`.
fn densify(p: &Piece, max_step_rad: f64) -> Piece {
    let mut out = Piece {
        contour: p.contour,
        points: vec![p.points[0]],
        features: vec![p.features[0]],
        source: vec![p.source[0]],
    };
    for i in 1..p.points.len() {
        let angle = angle_rad(&p.features[i - 1], &p.features[i]);
        // Half the step, so a subdivided segment's ends are safely within the spread.
        let steps = (angle / (0.5 * max_step_rad)).ceil().max(1.0) as usize;
        for s in 1..=steps {
            let t = s as f64 / steps as f64;
            out.points
                .push(p.points[i - 1] + (p.points[i] - p.points[i - 1]) * t);
            out.features
                .push((p.features[i - 1] * (1.0 - t) + p.features[i] * t).normalize());
            out.source
                .push(p.source[i - 1] + (p.source[i] - p.source[i - 1]) * t);
        }
    }
    out
}

/// Greedy split: a piece grows while every feature stays within `spread_rad` of its first.
fn split_piece(p: &Piece, spread_rad: f64) -> Vec<Piece> {
    let mut out = Vec::new();
    let mut start = 0;
    while start + 1 < p.points.len() {
        let mut end = start + 1;
        while end + 1 < p.points.len()
            && angle_rad(&p.features[start], &p.features[end + 1]) <= spread_rad
        {
            end += 1;
        }
        out.push(Piece {
            contour: p.contour,
            points: p.points[start..=end].to_vec(),
            features: p.features[start..=end].to_vec(),
            source: p.source[start..=end].to_vec(),
        });
        start = end;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bent_contour(id: ContourId, total_deg: f64, n: usize) -> Contour {
        let points: Vec<Point3> = (0..n).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        let features = (0..n)
            .map(|i| {
                let a = (total_deg * i as f64 / (n - 1) as f64).to_radians();
                Vector3::new(a.sin(), 0.0, a.cos())
            })
            .collect();
        Contour::with_features(id, points, features).unwrap()
    }

    #[test]
    fn split_pieces_cover_the_contour_and_stay_tight() {
        let path = Path::new(vec![bent_contour(4, 30.0, 7)]).unwrap();
        let limit = 5f64.to_radians();
        let pieces = pieces_of(&path, limit, 0.5 * limit).unwrap();
        assert!(pieces.len() >= 12, "30° in ≤ 2.5° pieces: {}", pieces.len());
        assert!((pieces[0].source[0]).abs() < 1e-15);
        assert!((pieces.last().unwrap().source.last().unwrap() - 6.0).abs() < 1e-12);
        for w in pieces.windows(2) {
            assert_eq!(w[0].source.last(), w[1].source.first(), "shared boundary");
            assert_eq!(w[0].points.last(), w[1].points.first());
        }
        for p in &pieces {
            assert_eq!(p.contour, 4);
            assert!(p.points.len() >= 2);
            for f in &p.features {
                assert!(angle_rad(f, &p.features[0]) <= 0.5 * limit + 1e-12);
            }
        }
    }

    #[test]
    fn tight_contour_is_one_piece() {
        let path = Path::new(vec![bent_contour(1, 4.0, 5)]).unwrap();
        let limit = 5f64.to_radians();
        assert_eq!(pieces_of(&path, limit, 0.5 * limit).unwrap().len(), 1);
    }
}
