//! Shapes the unit tests of several modules share.

use trim_geom::{Contour, ContourId, Point3, Vector3};

/// A square loop of side `s` centred at the origin in the plane z = 0, counter-clockwise seen
/// from +z (feature +z) unless `clockwise`, `n` points a side; closed (last point = first).
pub(crate) fn square(id: ContourId, s: f64, n: usize, clockwise: bool) -> Contour {
    let h = s / 2.0;
    let corners = [[-h, -h], [h, -h], [h, h], [-h, h], [-h, -h]];
    let mut points = Vec::new();
    for w in corners.windows(2) {
        for k in 0..n {
            let t = k as f64 / n as f64;
            points.push(Point3::new(
                w[0][0] + t * (w[1][0] - w[0][0]),
                w[0][1] + t * (w[1][1] - w[0][1]),
                0.0,
            ));
        }
    }
    points.push(points[0]);
    if clockwise {
        points.reverse();
    }
    Contour::new(id, points, Vector3::z()).expect("a square is a valid contour")
}
