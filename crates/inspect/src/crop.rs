//! The crop of the scan to the points near the registered contours and openings (scan frame).
//!
//! A point is kept when its nearest anchor (the registered path, densified, and the openings'
//! grid nodes) lies within the reach. One kd-tree query per scan point decides it, but a query
//! from a point far from every anchor visits many leaves before it can be sure, and most of a
//! scan is far from the contours: at 500k points those queries were most of the inspection's
//! time. So a coarse occupancy grid answers first: cells at least as wide as the reach, marked
//! where an anchor lies and dilated by one cell. A point whose cell is not marked has no anchor
//! within the reach (an anchor within the reach lies in the same or a neighbouring cell) and is
//! dropped without a query; the others get the exact test. The kept set is the same as the
//! query's alone.

use trim_geom::{Aabb, KdTree, Point3};

/// The most cells of the occupancy grid (the cells grow past it).
const MAX_CELLS: usize = 1 << 22;

/// The grid's cells are this much wider than the reach, so an anchor within the reach of a
/// point is never two cells away by rounding.
const CELL_MARGIN: f64 = 1.001;

/// The scan points within `reach_mm` of any anchor.
#[derive(Debug)]
pub struct Crop {
    tree: KdTree,
    reach2_mm2: f64,
    grid: Option<Occupancy>,
}

/// Which cells hold an anchor or neighbour one that does.
#[derive(Debug)]
struct Occupancy {
    origin: Point3,
    cell_mm: f64,
    dims: [usize; 3],
    marked: Vec<bool>,
}

impl Crop {
    /// The crop around `anchors` (scan frame, finite), `reach_mm` > 0.
    #[must_use]
    pub fn new(anchors: &[Point3], reach_mm: f64) -> Crop {
        Crop {
            tree: KdTree::build(anchors),
            reach2_mm2: reach_mm * reach_mm,
            grid: Occupancy::new(anchors, reach_mm),
        }
    }

    /// Whether `q` (scan frame) lies within the reach of an anchor.
    #[must_use]
    pub fn contains(&self, q: &Point3) -> bool {
        self.grid.as_ref().is_some_and(|g| g.marked(q))
            && self
                .tree
                .nearest(q)
                .is_some_and(|n| n.distance_sq <= self.reach2_mm2)
    }
}

impl Occupancy {
    /// None when there are no anchors.
    fn new(anchors: &[Point3], reach_mm: f64) -> Option<Occupancy> {
        let bounds = Aabb::around(anchors)?;
        let extent = bounds.max - bounds.min;
        let cells_for = |cell: f64| {
            // One cell of margin either side for the dilation.
            let n = |e: f64| (e / cell).floor() as usize + 3;
            [n(extent.x), n(extent.y), n(extent.z)]
        };
        let mut cell_mm = reach_mm * CELL_MARGIN;
        let mut dims = cells_for(cell_mm);
        while dims.iter().product::<usize>() > MAX_CELLS {
            cell_mm *= 1.25;
            dims = cells_for(cell_mm);
        }
        let origin = bounds.min - trim_geom::Vector3::repeat(cell_mm);
        let mut grid = Occupancy {
            origin,
            cell_mm,
            dims,
            marked: vec![false; dims.iter().product()],
        };
        for a in anchors {
            if let Some(i) = grid.index(a) {
                grid.marked[i] = true;
            }
        }
        for axis in 0..3 {
            grid.dilate(axis);
        }
        Some(grid)
    }

    /// The flat index of the cell holding `p`, none outside the grid.
    fn index(&self, p: &Point3) -> Option<usize> {
        let mut flat = 0;
        for axis in (0..3).rev() {
            let c = ((p[axis] - self.origin[axis]) / self.cell_mm).floor();
            if !(c >= 0.0 && c < self.dims[axis] as f64) {
                return None;
            }
            flat = flat * self.dims[axis] + c as usize;
        }
        Some(flat)
    }

    fn marked(&self, p: &Point3) -> bool {
        self.index(p).is_some_and(|i| self.marked[i])
    }

    /// Marks the neighbours of every marked cell along `axis`.
    fn dilate(&mut self, axis: usize) {
        let stride: usize = self.dims[..axis].iter().product();
        let n = self.dims[axis];
        let before = self.marked.clone();
        for (i, m) in self.marked.iter_mut().enumerate() {
            let c = (i / stride) % n;
            *m = before[i] || (c > 0 && before[i - stride]) || (c + 1 < n && before[i + stride]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The crop keeps exactly the points whose nearest anchor lies within the reach, with and
    /// without the grid's shortcut, on points scattered from far off to right at the anchors.
    #[test]
    fn the_grid_drops_only_points_out_of_reach() {
        let anchors: Vec<Point3> = (0..200)
            .map(|k| {
                let t = f64::from(k) * 0.1;
                Point3::new(t, (0.3 * t).sin() * 3.0, 0.1 * t)
            })
            .collect();
        let reach = 0.7;
        let crop = Crop::new(&anchors, reach);
        let tree = KdTree::build(&anchors);
        // A deterministic scatter (a Weyl sequence) over a box well past the anchors.
        let (mut kept, mut total) = (0, 0);
        for k in 0..40_000u32 {
            let f = f64::from(k);
            let frac = |a: f64| (f * a).fract();
            let q = Point3::new(
                -3.0 + 26.0 * frac(0.618_033_988_75),
                -6.0 + 12.0 * frac(0.754_877_666_2),
                -3.0 + 8.0 * frac(0.569_840_290_9),
            );
            let truth = tree
                .nearest(&q)
                .is_some_and(|n| n.distance_sq <= reach * reach);
            assert_eq!(crop.contains(&q), truth, "{q:?}");
            kept += usize::from(truth);
            total += 1;
        }
        // The case holds both kinds.
        assert!(kept > 100 && kept < total / 2, "{kept} of {total}");
        // A point just within the reach of the last anchor, along each axis.
        let last = anchors[anchors.len() - 1];
        for axis in 0..3 {
            let mut q = last;
            q[axis] += reach * 0.999_999;
            assert!(crop.contains(&q));
        }
        assert!(!Crop::new(&[], reach).contains(&Point3::origin()));
    }
}
