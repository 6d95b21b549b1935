//! Hatching a blocked opening (issue 23: "blocked openings become hatch regions"): the film over
//! a hole or slot is cleared by hatch tracks inside the opening's rim.
//!
//! - *The region* is the rim contour (registered, work-piece frame) moved into the opening by
//!   half a kerf ([`inset_rim`]), so the outline track's kerf reaches the rim and no further:
//!   a track on the rim itself would cut the wall back by half a kerf, as an uncompensated
//!   trimming line does (`crate::kerf`). A round rim's chords lie inside the arc by up to
//!   their sagitta ([`chord_sagitta_mm`]; 5–8 µm on the synthetic core's 0.25 mm spacing), and
//!   a film sliver that wide left on the rim reads as a covered ring in the inspection (its
//!   nodes see points 0.15 mm across), so the caller takes the sagitta off the inset: the kerf
//!   then reaches the arc between the rim's points and cuts at most the sagitta into the wall
//!   at them.
//! - *The surface* the tracks are planned on is the face continued over the opening
//!   ([`face_over_opening`]): a film forms in the parting plane, flush with the face, so its
//!   top is where the face would be. It is interpolated from the rim's own heights (weights
//!   `1/d⁴` to the rim's points, as trim-inspect finds an opening's level), not taken from
//!   the scan: over an opening the scan holds the hole's walls and, where the film is gone
//!   already, nothing at the face's level at all, and the surface fit needs support everywhere.
//! - *The pitch* must not exceed the kerf: tracks further apart leave a strip of film between
//!   every two of them whatever the passes (`trim_sim::film_ablation`). [`film_settings`] sets
//!   it from the kerf and [`FILM_TRACK_OVERLAP`].
//! - *The direction* is the opening's long axis (a slot is hatched along its length: few long
//!   tracks instead of many short ones).

use trim_geom::{Contour, Point3, PointCloud, Vector3};

use super::{Hatch, HatchError, HatchSettings, hatch};

/// The share of the kerf two neighbouring tracks overlap when a film is hatched: pitch =
/// (1 − overlap) × kerf. A quarter leaves a landing error of an eighth of the kerf (5 µm on
/// the paper's 41 µm) either way before a strip of film stands between two tracks.
pub const FILM_TRACK_OVERLAP: f64 = 0.25;

/// The step of the face's points over an opening, mm.
pub const FACE_STEP_MM: f64 = 0.05;

/// How far beyond the rim the face's points reach, mm: the surface fit's grid covers the
/// boundary's box plus a margin.
pub const FACE_MARGIN_MM: f64 = 0.6;

/// A moved rim vertex must stay at least this share of the inset from the rim (the rest is the
/// chords' rounding on a curved rim).
const INSET_KEPT: f64 = 0.9;

/// The chord tolerance of a film's tracks, mm (vector marking, as the demo's region).
pub const FILM_CHORD_TOLERANCE_MM: f64 = 0.002;

/// The settings a film over an opening is hatched with, for a kerf `kerf_mm` wide: pitch
/// `(1 − FILM_TRACK_OVERLAP)·kerf`, points by [`FILM_CHORD_TOLERANCE_MM`], the outline on,
/// the other keys at their defaults (the direction is set per opening by [`hatch_opening`]).
pub fn film_settings(kerf_mm: f64) -> Result<HatchSettings, HatchError> {
    let mut s = HatchSettings::from_spot(kerf_mm, FILM_TRACK_OVERLAP)?;
    s.chord_tolerance_mm = Some(FILM_CHORD_TOLERANCE_MM);
    s.validate()?;
    Ok(s)
}

/// A closed rim's frame: its centre, the face normal (the contour's feature vector), the
/// plane axes (`e1` world X projected onto the plane, world Y when X is nearly normal, as the
/// hatch's own plane frame) and the rim's points in it (`a`, `b`, height).
struct RimFrame {
    centre: Point3,
    normal: Vector3,
    e1: Vector3,
    e2: Vector3,
    /// The rim's distinct points (the closing repeat left out): `(a, b, h)`, mm.
    rim: Vec<[f64; 3]>,
}

impl RimFrame {
    fn new(rim: &Contour) -> Result<RimFrame, HatchError> {
        super::check_boundary(rim.points())?;
        let mut points = rim.points().to_vec();
        if points.len() > 1
            && (points[0] - points[points.len() - 1]).norm() <= super::BOUNDARY_CLOSURE_TOL_MM
        {
            points.pop();
        }
        let normal = rim.feature().into_inner();
        let centre = Point3::from(
            points.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / points.len() as f64,
        );
        let reference = if normal.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let e1 = (reference - normal * reference.dot(&normal)).normalize();
        let e2 = normal.cross(&e1);
        let rim = points
            .iter()
            .map(|p| {
                let d = p - centre;
                [d.dot(&e1), d.dot(&e2), d.dot(&normal)]
            })
            .collect();
        Ok(RimFrame {
            centre,
            normal,
            e1,
            e2,
            rim,
        })
    }

    fn world(&self, a: f64, b: f64, h: f64) -> Point3 {
        self.centre + self.e1 * a + self.e2 * b + self.normal * h
    }

    /// Twice the rim's signed area in `(a, b)` (positive counter-clockwise about the normal).
    fn signed_area2(&self) -> f64 {
        let n = self.rim.len();
        (0..n)
            .map(|i| {
                let (p, q) = (self.rim[i], self.rim[(i + 1) % n]);
                p[0] * q[1] - q[0] * p[1]
            })
            .sum()
    }

    /// The face's height over `(a, b)`: weights `1/d⁴` to the rim's points.
    fn face_height(&self, a: f64, b: f64) -> f64 {
        let (mut wsum, mut hsum) = (0.0, 0.0);
        for p in &self.rim {
            let d2 = (p[0] - a).powi(2) + (p[1] - b).powi(2);
            let w = 1.0 / (d2 * d2).max(1e-12);
            wsum += w;
            hsum += w * p[2];
        }
        hsum / wsum
    }
}

/// The rim moved `inset_mm` into the opening it bounds, in its face (a mitred offset of each
/// vertex along the bisector of its two edges' inward normals), work-piece frame. Refused when
/// the rim is not a closed polygon, or the opening is too narrow for the inset (the moved
/// polygon turns over).
pub fn inset_rim(rim: &Contour, inset_mm: f64) -> Result<Vec<Point3>, HatchError> {
    if !(inset_mm.is_finite() && inset_mm >= 0.0) {
        return Err(HatchError::setting(
            "hatch.inset_mm",
            inset_mm,
            "must be a finite number ≥ 0",
        ));
    }
    let f = RimFrame::new(rim)?;
    let area2 = f.signed_area2();
    // Inward: left of travel for a counter-clockwise rim.
    let side = if area2 >= 0.0 { 1.0 } else { -1.0 };
    let n = f.rim.len();
    let inward = |i: usize| {
        let (p, q) = (f.rim[i], f.rim[(i + 1) % n]);
        let (da, db) = (q[0] - p[0], q[1] - p[1]);
        let len = da.hypot(db).max(1e-12);
        [-db / len * side, da / len * side]
    };
    let moved: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            let (m0, m1) = (inward((i + n - 1) % n), inward(i));
            let (sa, sb) = (m0[0] + m1[0], m0[1] + m1[1]);
            let len = sa.hypot(sb);
            let p = f.rim[i];
            if len < 1e-9 {
                return p;
            }
            let bis = [sa / len, sb / len];
            // Each edge moves `inset` along its normal: the vertex moves inset / cos(half turn),
            // at most twice the inset.
            let cos = (bis[0] * m1[0] + bis[1] * m1[1]).max(0.5);
            [
                p[0] + bis[0] * inset_mm / cos,
                p[1] + bis[1] * inset_mm / cos,
                p[2],
            ]
        })
        .collect();
    // Each moved vertex must lie inside the rim, the inset (within rounding) from every edge:
    // in a hole narrower than twice the inset the offset turns over and does not.
    let inside_by = |p: [f64; 3]| {
        let mut inside = false;
        let mut nearest = f64::INFINITY;
        for i in 0..n {
            let (q0, q1) = (f.rim[i], f.rim[(i + 1) % n]);
            if (q0[1] > p[1]) != (q1[1] > p[1])
                && p[0] < q0[0] + (p[1] - q0[1]) * (q1[0] - q0[0]) / (q1[1] - q0[1])
            {
                inside = !inside;
            }
            let (da, db) = (q1[0] - q0[0], q1[1] - q0[1]);
            let len2 = da * da + db * db;
            let t = if len2 > 0.0 {
                (((p[0] - q0[0]) * da + (p[1] - q0[1]) * db) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            nearest = nearest.min((q0[0] + t * da - p[0]).hypot(q0[1] + t * db - p[1]));
        }
        if inside { nearest } else { -nearest }
    };
    if moved.iter().any(|p| inside_by(*p) < INSET_KEPT * inset_mm) {
        return Err(HatchError::OpeningTooNarrow {
            inset_mm,
            area_mm2: area2.abs() / 2.0,
        });
    }
    let mut out: Vec<Point3> = moved.iter().map(|p| f.world(p[0], p[1], p[2])).collect();
    out.push(out[0]);
    Ok(out)
}

/// The face continued over the opening a closed rim bounds (work-piece frame): points every
/// [`FACE_STEP_MM`] over the rim's box plus [`FACE_MARGIN_MM`], at the height interpolated from
/// the rim's, each with the rim's feature vector as its normal.
pub fn face_over_opening(rim: &Contour) -> Result<PointCloud, HatchError> {
    let f = RimFrame::new(rim)?;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in &f.rim {
        lo = [lo[0].min(p[0]), lo[1].min(p[1])];
        hi = [hi[0].max(p[0]), hi[1].max(p[1])];
    }
    let steps = |l: f64, h: f64| ((h - l + 2.0 * FACE_MARGIN_MM) / FACE_STEP_MM).ceil() as usize;
    let (na, nb) = (steps(lo[0], hi[0]), steps(lo[1], hi[1]));
    let mut points = Vec::with_capacity((na + 1) * (nb + 1));
    for i in 0..=na {
        for j in 0..=nb {
            let a = lo[0] - FACE_MARGIN_MM + FACE_STEP_MM * i as f64;
            let b = lo[1] - FACE_MARGIN_MM + FACE_STEP_MM * j as f64;
            points.push(f.world(a, b, f.face_height(a, b)));
        }
    }
    let normals = vec![f.normal; points.len()];
    Ok(PointCloud::with_normals(points, normals)?)
}

/// The largest sagitta of the rim's chords, mm: how far inside the round rim it samples a
/// chord between two of its points lies (`L²/8R`, `R` the circle through each point and its
/// neighbours; 0 along straight stretches). A film is cut to the chords, so an outline on the
/// chord polygon moved a half kerf in leaves a sliver this wide on the rim itself; the caller
/// takes it off the inset (`crate::hatch::opening` module docs).
#[must_use]
pub fn chord_sagitta_mm(rim: &Contour) -> f64 {
    let Ok(f) = RimFrame::new(rim) else {
        return 0.0;
    };
    let n = f.rim.len();
    if n < 3 {
        return 0.0;
    }
    (0..n)
        .map(|i| {
            let (p, q, r) = (f.rim[(i + n - 1) % n], f.rim[i], f.rim[(i + 1) % n]);
            let d = |a: [f64; 3], b: [f64; 3]| (a[0] - b[0]).hypot(a[1] - b[1]);
            let (a, b, c) = (d(p, q), d(q, r), d(p, r));
            let area2 = ((q[0] - p[0]) * (r[1] - p[1]) - (r[0] - p[0]) * (q[1] - p[1])).abs();
            if area2 < 1e-15 {
                return 0.0;
            }
            let radius = a * b * c / (2.0 * area2);
            b * b / (8.0 * radius)
        })
        .fold(0.0, f64::max)
}

/// The opening's long axis as a hatch direction: degrees from the hatch plane's first axis
/// (world X projected onto the face), counter-clockwise about the face normal.
fn long_axis_deg(f: &RimFrame) -> f64 {
    let n = f.rim.len() as f64;
    let (ma, mb) = f
        .rim
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p[0] / n, b + p[1] / n));
    let (mut saa, mut sab, mut sbb) = (0.0, 0.0, 0.0);
    for p in &f.rim {
        let (a, b) = (p[0] - ma, p[1] - mb);
        saa += a * a;
        sab += a * b;
        sbb += b * b;
    }
    // The principal axis of the 2 × 2 scatter: half the angle of (saa − sbb, 2 sab).
    0.5 * (2.0 * sab).atan2(saa - sbb).to_degrees()
}

/// Hatches the film over the opening a closed rim contour bounds (work-piece frame): the rim
/// moved `inset_mm` into the opening ([`inset_rim`]; half the kerf), on the face continued over
/// the opening ([`face_over_opening`]), with `settings` and the direction along the opening's
/// long axis.
pub fn hatch_opening(
    rim: &Contour,
    inset_mm: f64,
    settings: &HatchSettings,
) -> Result<Hatch, HatchError> {
    let frame = RimFrame::new(rim)?;
    let boundary = inset_rim(rim, inset_mm)?;
    let face = face_over_opening(rim)?;
    let settings = HatchSettings {
        angle_deg: long_axis_deg(&frame),
        ..settings.clone()
    };
    hatch(&face, &boundary, &settings)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed rim: a circle of `r` (or a stadium with straight sides `half_len` either side of
    /// the centre along Y) on a face tilted about X by `tilt_rad`, around `centre`.
    fn rim(r: f64, half_len: f64, tilt_rad: f64, clockwise: bool) -> Contour {
        let normal = Vector3::new(0.0, -tilt_rad.sin(), tilt_rad.cos());
        let (e1, e2) = (Vector3::x(), normal.cross(&Vector3::x()));
        let centre = Point3::new(3.0, -2.0, 10.0);
        let mut pts: Vec<Point3> = Vec::new();
        let n = 160;
        let perimeter = 2.0 * std::f64::consts::PI * r + 4.0 * half_len;
        for k in 0..n {
            let s = perimeter * f64::from(k) / f64::from(n);
            // Counter-clockwise from (r, −half_len): right side up, top arc, left side down,
            // bottom arc.
            let arc = std::f64::consts::PI * r;
            let (a, b) = if s < 2.0 * half_len {
                (r, -half_len + s)
            } else if s < 2.0 * half_len + arc {
                let t = (s - 2.0 * half_len) / r;
                (r * t.cos(), half_len + r * t.sin())
            } else if s < 4.0 * half_len + arc {
                (-r, half_len - (s - 2.0 * half_len - arc))
            } else {
                let t = std::f64::consts::PI + (s - 4.0 * half_len - arc) / r;
                (r * t.cos(), -half_len + r * t.sin())
            };
            pts.push(centre + e1 * a + e2 * b);
        }
        if clockwise {
            pts.reverse();
        }
        pts.push(pts[0]);
        let features = vec![normal; pts.len()];
        Contour::with_features(7, pts, features).unwrap()
    }

    #[test]
    fn the_inset_rim_lies_half_a_kerf_inside_either_way_round() {
        for clockwise in [false, true] {
            let c = rim(1.2, 0.0, 0.2, clockwise);
            let inset = inset_rim(&c, 0.0205).unwrap();
            let centre = Point3::new(3.0, -2.0, 10.0);
            for p in &inset {
                let r = (p - centre).norm();
                assert!((r - (1.2 - 0.0205)).abs() < 1e-3, "{r}");
            }
        }
        // A hole narrower than twice the inset is refused, naming it.
        let e = inset_rim(&rim(0.01, 0.0, 0.0, false), 0.02).unwrap_err();
        assert!(matches!(e, HatchError::OpeningTooNarrow { .. }), "{e:?}");
        assert!(e.to_string().contains("too narrow"), "{e}");
        assert!(inset_rim(&rim(1.0, 0.0, 0.0, false), f64::NAN).is_err());
    }

    #[test]
    fn a_slot_is_hatched_along_its_length_at_the_film_pitch_inside_the_inset_rim() {
        let c = rim(1.0, 3.0, 0.3, false);
        let kerf = 0.041;
        let settings = film_settings(kerf).unwrap();
        assert!((settings.pitch_mm - 0.75 * kerf).abs() < 1e-12);
        let h = hatch_opening(&c, kerf / 2.0, &settings).unwrap();
        let centre = Point3::new(3.0, -2.0, 10.0);
        let normal = Vector3::new(0.0, -0.3f64.sin(), 0.3f64.cos());
        let e2 = normal.cross(&Vector3::x());
        // Tracks run along the slot (e2), all on the face and inside the rim less the inset.
        let mut along = 0usize;
        for t in h.hatch_tracks() {
            let (first, last) = (t.points[0], t.points[t.points.len() - 1]);
            if ((last - first).normalize().dot(&e2)).abs() > 0.99 {
                along += 1;
            }
            for p in &t.points {
                let d = p - centre;
                assert!(d.dot(&normal).abs() < 1e-3, "{p} off the face");
                let (a, b) = (d.dot(&Vector3::x()), d.dot(&e2));
                let axis = if b.abs() <= 3.0 {
                    a.abs()
                } else {
                    a.hypot(b.abs() - 3.0)
                };
                assert!(axis <= 1.0 - kerf / 2.0 + 2e-3, "{p}: {axis}");
            }
        }
        let n = h.hatch_tracks().count();
        assert!(along * 10 >= n * 9, "{along} of {n} along the slot");
        // 2 mm across less the inset at 30.75 µm: about 64 tracks.
        assert!((60..=68).contains(&n), "{n}");
    }

    #[test]
    fn the_chord_sagitta_is_that_of_the_rims_spacing_on_its_radius() {
        // 160 chords on a circle of 1.2 mm: L = 2π·1.2/160, sagitta L²/(8·1.2).
        let l = 2.0 * std::f64::consts::PI * 1.2 / 160.0;
        let s = chord_sagitta_mm(&rim(1.2, 0.0, 0.2, true));
        assert!((s - l * l / 9.6).abs() < 1e-6, "{s}");
        // A slot's arcs set it, not its straight sides.
        assert!(chord_sagitta_mm(&rim(1.0, 3.0, 0.0, false)) > 0.0);
    }

    #[test]
    fn film_settings_refuse_a_bad_kerf() {
        assert!(film_settings(0.0).is_err());
        assert!(film_settings(f64::NAN).is_err());
    }
}
