//! Scan-field sections (PPGS paper: "divide the freeform surface into several sections, each
//! smaller than the scan range"; DESIGN.md "Scan field", "Incidence").
//!
//! A zone whose contours do not fit the galvo field from one pose is cut into sections, each
//! with its own origin (centred on its contours) and hence its own pose. A section is accepted
//! when, with its origin on the optical axis:
//! - every point lies within the field's inscribed circle, radius min(width, height)/2 — a
//!   circle because the in-plane rotation of the field about the zone axis is fixed later by
//!   the machine pose (see [`trim_cell::kinematics`]), and a circle fits every rotation;
//! - every point's incidence, the angle between its feature vector and the ray that reaches
//!   it, is within the limit. For an f-theta lens that is not telecentric the ray leans away
//!   from the axis by atan(r/f) at a distance r from the field centre (a pinhole model of the
//!   lens); for a telecentric lens the ray is the axis.
//!
//! A failing section is split in two across its longer in-plane extent: between whole pieces
//! when it holds several (seams where the contours already break), otherwise by cutting its one
//! piece at half its length (the cut point ends one part and starts the other). A piece shorter
//! than [`MIN_SPLIT_LENGTH_MM`] is not cut further; validation then reports what is left.

use trim_geom::{Point3, UnitVector3, Vector3};

use crate::piece::{Piece, angle_rad};
use trim_cell::frame::paper_frame;
pub use trim_cell::plan_settings::LensSettings;

/// Pieces shorter than this (mm) are not cut further by sectioning.
pub const MIN_SPLIT_LENGTH_MM: f64 = 0.05;

/// The lens seen by the incidence check.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lens {
    /// Telecentric: no ray angle.
    pub telecentric: bool,
    /// Focal length (mm), for the ray angle atan(r/f).
    pub focal_length_mm: f64,
}

impl Lens {
    /// The direction from the point toward the lens of the ray that reaches galvo position
    /// `(x, y)` (mm from the field centre), in the frame (X, Y, Z) given: Z·f − x·X − y·Y,
    /// normalised (a pinhole at the focal length above the field centre).
    #[must_use]
    pub fn ray(
        &self,
        x_axis: &Vector3,
        y_axis: &Vector3,
        z_axis: &Vector3,
        xy: [f64; 2],
    ) -> Vector3 {
        if self.telecentric {
            *z_axis
        } else {
            (z_axis * self.focal_length_mm - x_axis * xy[0] - y_axis * xy[1]).normalize()
        }
    }
}

/// One section: pieces processed from one pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Section {
    /// The pieces (some may be parts of the zone's pieces).
    pub pieces: Vec<Piece>,
    /// The section origin (mm, work-piece frame): the zone centre moved in-plane to the centre
    /// of the section's projected bounding box.
    pub origin: Point3,
}

/// What a section check found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SectionFit {
    /// The largest in-plane distance from the origin (mm).
    pub max_radius_mm: f64,
    /// The largest angle between a feature vector and its ray (radians).
    pub max_incidence_rad: f64,
}

fn in_plane(x: &Vector3, y: &Vector3, centre: &Point3, p: &Point3) -> [f64; 2] {
    let d = p - centre;
    [d.dot(x), d.dot(y)]
}

/// The origin of a set of pieces (bounding-box centre in the plane through `centre`) and how
/// they fit around it. Points whose feature vector is already more than `limit_rad` from the
/// axis are left out of the incidence: no section can fix them (validation reports them).
#[must_use]
pub fn fit(
    pieces: &[Piece],
    centre: &Point3,
    axis: &UnitVector3,
    lens: &Lens,
    limit_rad: f64,
) -> (Point3, SectionFit) {
    let frame = paper_frame(axis);
    let (x, y, z) = (frame.x_axis(), frame.y_axis(), frame.z_axis());
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in pieces.iter().flat_map(|p| p.points.iter()) {
        let uv = in_plane(&x, &y, centre, p);
        for i in 0..2 {
            lo[i] = lo[i].min(uv[i]);
            hi[i] = hi[i].max(uv[i]);
        }
    }
    let mid = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
    let origin = centre + x * mid[0] + y * mid[1];
    let mut result = SectionFit {
        max_radius_mm: 0.0,
        max_incidence_rad: 0.0,
    };
    for piece in pieces {
        for (p, f) in piece.points.iter().zip(&piece.features) {
            let uv = in_plane(&x, &y, &origin, p);
            result.max_radius_mm = result.max_radius_mm.max(uv[0].hypot(uv[1]));
            if angle_rad(f, &z) <= limit_rad {
                let ray = lens.ray(&x, &y, &z, uv);
                result.max_incidence_rad = result.max_incidence_rad.max(angle_rad(f, &ray));
            }
        }
    }
    (origin, result)
}

/// Cuts a piece at half its length (the cut point is shared).
fn halve(p: &Piece) -> (Piece, Piece) {
    let half = 0.5 * p.length_mm();
    let mut walked = 0.0;
    for i in 0..p.points.len() - 1 {
        let seg = (p.points[i + 1] - p.points[i]).norm();
        if walked + seg >= half && seg > 0.0 {
            let t = ((half - walked) / seg).clamp(0.0, 1.0);
            let point = p.points[i] + (p.points[i + 1] - p.points[i]) * t;
            let feature = (p.features[i] * (1.0 - t) + p.features[i + 1] * t).normalize();
            let source = p.source[i] + (p.source[i + 1] - p.source[i]) * t;
            let mut a = Piece {
                contour: p.contour,
                points: p.points[..=i].to_vec(),
                features: p.features[..=i].to_vec(),
                source: p.source[..=i].to_vec(),
            };
            let mut b = Piece {
                contour: p.contour,
                points: vec![point],
                features: vec![feature],
                source: vec![source],
            };
            if t > 0.0 {
                a.points.push(point);
                a.features.push(feature);
                a.source.push(source);
            }
            let from = if t < 1.0 { i + 1 } else { i + 2 };
            b.points
                .extend_from_slice(&p.points[from.min(p.points.len())..]);
            b.features
                .extend_from_slice(&p.features[from.min(p.points.len())..]);
            b.source
                .extend_from_slice(&p.source[from.min(p.points.len())..]);
            if a.points.len() >= 2 && b.points.len() >= 2 {
                return (a, b);
            }
            break;
        }
        walked += seg;
    }
    // Fallback for degenerate spacing: split at the middle vertex (both keep it).
    let mid = p.points.len() / 2;
    let mid = mid.clamp(1, p.points.len() - 1);
    let take = |r: std::ops::RangeInclusive<usize>| Piece {
        contour: p.contour,
        points: p.points[r.clone()].to_vec(),
        features: p.features[r.clone()].to_vec(),
        source: p.source[r].to_vec(),
    };
    if p.points.len() >= 3 {
        (take(0..=mid), take(mid..=p.points.len() - 1))
    } else {
        (p.clone(), p.clone())
    }
}

/// Splits a zone into sections that fit the field radius and the incidence limit (see the
/// module docs). `centre` is the zone centre, `axis` its axis.
#[must_use]
pub fn sections(
    pieces: Vec<Piece>,
    centre: &Point3,
    axis: &UnitVector3,
    field_radius_mm: f64,
    limit_rad: f64,
    lens: &Lens,
) -> Vec<Section> {
    let frame = paper_frame(axis);
    let (x, y) = (frame.x_axis(), frame.y_axis());
    let mut out = Vec::new();
    let mut stack = vec![pieces];
    while let Some(group) = stack.pop() {
        let (origin, f) = fit(&group, centre, axis, lens, limit_rad);
        let fits = f.max_radius_mm <= field_radius_mm && f.max_incidence_rad <= limit_rad;
        if fits {
            out.push(Section {
                pieces: group,
                origin,
            });
            continue;
        }
        // The longer in-plane extent decides the cut direction.
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in group.iter().flat_map(|p| p.points.iter()) {
            let uv = in_plane(&x, &y, centre, p);
            for i in 0..2 {
                lo[i] = lo[i].min(uv[i]);
                hi[i] = hi[i].max(uv[i]);
            }
        }
        let dir = if hi[0] - lo[0] >= hi[1] - lo[1] { x } else { y };
        if group.len() >= 2 {
            let mut keyed: Vec<(f64, Piece)> = group
                .into_iter()
                .map(|p| ((p.centroid() - centre).dot(&dir), p))
                .collect();
            keyed.sort_by(|a, b| a.0.total_cmp(&b.0));
            let right: Vec<Piece> = keyed
                .split_off(keyed.len() / 2)
                .into_iter()
                .map(|k| k.1)
                .collect();
            let left: Vec<Piece> = keyed.into_iter().map(|k| k.1).collect();
            // Pushed so the left half is processed first: sections come out in a stable order.
            stack.push(right);
            stack.push(left);
        } else if let Some(piece) = group
            .first()
            .filter(|p| p.length_mm() >= MIN_SPLIT_LENGTH_MM && p.points.len() >= 2)
        {
            let (a, b) = halve(piece);
            if a.points.len() >= 2 && b.points.len() >= 2 && a != *piece {
                stack.push(vec![b]);
                stack.push(vec![a]);
            } else {
                out.push(Section {
                    pieces: group,
                    origin,
                });
            }
        } else {
            out.push(Section {
                pieces: group,
                origin,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_geom::ContourId;

    fn line(id: ContourId, from: [f64; 3], to: [f64; 3], n: usize, feature: Vector3) -> Piece {
        let (a, b) = (Point3::from(from), Point3::from(to));
        Piece {
            contour: id,
            points: (0..n)
                .map(|i| a + (b - a) * (i as f64 / (n - 1) as f64))
                .collect(),
            features: vec![feature.normalize(); n],
            source: (0..n).map(|i| i as f64).collect(),
        }
    }

    #[test]
    fn ray_angle_is_atan_r_over_f() {
        let lens = Lens {
            telecentric: false,
            focal_length_mm: 259.4,
        };
        let ray = lens.ray(&Vector3::x(), &Vector3::y(), &Vector3::z(), [30.0, 40.0]);
        let angle = angle_rad(&ray, &Vector3::z());
        assert!((angle - (50.0f64 / 259.4).atan()).abs() < 1e-12);
    }

    #[test]
    fn long_zone_is_cut_into_fitting_sections_at_contour_breaks_first() {
        let axis = UnitVector3::new_normalize(Vector3::z());
        let pieces: Vec<Piece> = (0..6)
            .map(|i| {
                let x0 = i as f64 * 40.0;
                line(i, [x0, 0.0, 0.0], [x0 + 30.0, 0.0, 0.0], 4, Vector3::z())
            })
            .collect();
        let lens = Lens {
            telecentric: true,
            focal_length_mm: 259.4,
        };
        let s = sections(
            pieces,
            &Point3::new(115.0, 0.0, 0.0),
            &axis,
            50.0,
            0.1,
            &lens,
        );
        assert!(s.len() >= 3, "230 mm in a 100 mm field: {}", s.len());
        for sec in &s {
            let (_, f) = fit(&sec.pieces, &sec.origin, &axis, &lens, 0.1);
            assert!(f.max_radius_mm <= 50.0);
            // Whole contours: no piece was cut.
            for p in &sec.pieces {
                assert_eq!(p.points.len(), 4);
            }
        }
    }

    #[test]
    fn ray_angle_forces_smaller_sections_for_f_theta() {
        let axis = UnitVector3::new_normalize(Vector3::z());
        let lens = Lens {
            telecentric: false,
            focal_length_mm: 259.4,
        };
        let pieces = vec![line(1, [0.0, 0.0, 0.0], [60.0, 0.0, 0.0], 61, Vector3::z())];
        let limit = 3f64.to_radians();
        let s = sections(
            pieces,
            &Point3::new(30.0, 0.0, 0.0),
            &axis,
            50.0,
            limit,
            &lens,
        );
        assert!(s.len() >= 4, "{}", s.len());
        let mut covered: Vec<(f64, f64)> = Vec::new();
        for sec in &s {
            let (_, f) = fit(&sec.pieces, &sec.origin, &axis, &lens, limit);
            assert!(f.max_incidence_rad <= limit);
            for p in &sec.pieces {
                covered.push((p.source[0], *p.source.last().unwrap()));
            }
        }
        covered.sort_by(|a, b| a.0.total_cmp(&b.0));
        for w in covered.windows(2) {
            assert!((w[0].1 - w[1].0).abs() < 1e-12);
        }
    }
}
