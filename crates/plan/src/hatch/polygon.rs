//! The boundary as a polygon in plane coordinates: inside test by ray casting (paper §2.3
//! step 4, ref. [15]), distance, and segment crossings through a uniform grid of edges.

/// A closed polygon in plane coordinates (mm); the closing edge is implicit.
#[derive(Debug, Clone)]
pub struct Polygon {
    vertices: Vec<[f64; 2]>,
    lo: [f64; 2],
    cell: f64,
    nx: usize,
    ny: usize,
    /// Edge indices per grid cell (row-major).
    cells: Vec<Vec<u32>>,
    /// Edge indices per horizontal strip of height `cell` (the ray-casting test reads one).
    strips: Vec<Vec<u32>>,
}

impl Polygon {
    /// A polygon through `vertices` (a repeated closing vertex is dropped).
    #[must_use]
    pub fn new(mut vertices: Vec<[f64; 2]>) -> Polygon {
        if vertices.len() > 1 {
            let (a, b) = (vertices[0], vertices[vertices.len() - 1]);
            if (a[0] - b[0]).hypot(a[1] - b[1]) < 1e-12 {
                vertices.pop();
            }
        }
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for v in &vertices {
            lo = [lo[0].min(v[0]), lo[1].min(v[1])];
            hi = [hi[0].max(v[0]), hi[1].max(v[1])];
        }
        let n = vertices.len().max(1);
        let side = (n as f64).sqrt().ceil().max(1.0) as usize;
        let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-9);
        let cell = extent / side as f64 * 1.0001;
        let nx = (((hi[0] - lo[0]) / cell).floor() as usize + 1).max(1);
        let ny = (((hi[1] - lo[1]) / cell).floor() as usize + 1).max(1);
        let mut polygon = Polygon {
            vertices,
            lo,
            cell,
            nx,
            ny,
            cells: vec![Vec::new(); nx * ny],
            strips: vec![Vec::new(); ny],
        };
        for e in 0..polygon.vertices.len() {
            let (a, b) = polygon.edge(e);
            let (i0, j0, i1, j1) = polygon.cell_range(a, b);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    polygon.cells[j * nx + i].push(e as u32);
                }
                polygon.strips[j].push(e as u32);
            }
        }
        polygon
    }

    /// The vertices (without the closing repeat).
    #[must_use]
    pub fn vertices(&self) -> &[[f64; 2]] {
        &self.vertices
    }

    fn edge(&self, e: usize) -> ([f64; 2], [f64; 2]) {
        let n = self.vertices.len();
        (self.vertices[e], self.vertices[(e + 1) % n])
    }

    fn cell_range(&self, a: [f64; 2], b: [f64; 2]) -> (usize, usize, usize, usize) {
        let clamp = |v: f64, n: usize| (v.floor().max(0.0) as usize).min(n - 1);
        let i0 = clamp((a[0].min(b[0]) - self.lo[0]) / self.cell, self.nx);
        let i1 = clamp((a[0].max(b[0]) - self.lo[0]) / self.cell, self.nx);
        let j0 = clamp((a[1].min(b[1]) - self.lo[1]) / self.cell, self.ny);
        let j1 = clamp((a[1].max(b[1]) - self.lo[1]) / self.cell, self.ny);
        (i0, j0, i1, j1)
    }

    /// The box `(lo, hi)` around the polygon.
    #[must_use]
    pub fn bounds(&self) -> ([f64; 2], [f64; 2]) {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for v in &self.vertices {
            lo = [lo[0].min(v[0]), lo[1].min(v[1])];
            hi = [hi[0].max(v[0]), hi[1].max(v[1])];
        }
        (lo, hi)
    }

    /// The enclosed area (mm², unsigned).
    #[must_use]
    pub fn area(&self) -> f64 {
        let n = self.vertices.len();
        let mut twice = 0.0;
        for k in 0..n {
            let (a, b) = self.edge(k);
            twice += a[0] * b[1] - b[0] * a[1];
        }
        0.5 * twice.abs()
    }

    /// Whether `p` is inside (even–odd ray casting along +s, over the edges of `p`'s strip:
    /// an edge the ray can cross spans `p`'s height, so it lies in that strip).
    #[must_use]
    pub fn contains(&self, p: [f64; 2]) -> bool {
        let n = self.vertices.len();
        if n < 3 {
            return false;
        }
        if !(p[1] >= self.lo[1] && p[1] <= self.lo[1] + self.ny as f64 * self.cell) {
            return false;
        }
        let strip = (((p[1] - self.lo[1]) / self.cell).floor() as usize).min(self.ny - 1);
        let mut inside = false;
        for &e in &self.strips[strip] {
            let (a, b) = self.edge(e as usize);
            if (a[1] > p[1]) != (b[1] > p[1]) {
                let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
                if p[0] < x {
                    inside = !inside;
                }
            }
        }
        inside
    }

    /// The distance (mm) from `p` to the polygon's edges.
    #[must_use]
    pub fn distance(&self, p: [f64; 2]) -> f64 {
        (0..self.vertices.len())
            .map(|e| {
                let (a, b) = self.edge(e);
                segment_distance(p, a, b)
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// The first two edges that cross or touch, as `(i, j)` with `i < j`: edge `i` runs from
    /// vertex `i` to vertex `i + 1` (the last to vertex 0). `None` for a simple polygon. Edges
    /// that share a vertex are not compared; each edge is tested only against the edges in its
    /// grid cells, so a boundary of n vertices costs about n tests, not n².
    #[must_use]
    pub fn self_crossing(&self) -> Option<(usize, usize)> {
        let n = self.vertices.len();
        if n < 4 {
            return None;
        }
        let mut seen: Vec<u32> = Vec::new();
        for e in 0..n {
            let (a, b) = self.edge(e);
            let (i0, j0, i1, j1) = self.cell_range(a, b);
            seen.clear();
            for j in j0..=j1 {
                for i in i0..=i1 {
                    for &f in &self.cells[j * self.nx + i] {
                        let f = f as usize;
                        if f <= e || seen.contains(&(f as u32)) {
                            continue;
                        }
                        seen.push(f as u32);
                        let (c, d) = self.edge(f);
                        // Neighbours share a vertex, and so do edges that meet at a repeated
                        // vertex (a zero-length edge between them).
                        if a == c || a == d || b == c || b == d {
                            continue;
                        }
                        if segments_meet(a, b, c, d) {
                            return Some((e, f));
                        }
                    }
                }
            }
        }
        None
    }

    /// The crossings of segment `a`–`b` with the polygon: the parameters `u ∈ [0, 1)` along it,
    /// sorted.
    #[must_use]
    pub fn crossings(&self, a: [f64; 2], b: [f64; 2]) -> Vec<f64> {
        let mut out = Vec::new();
        if self.vertices.len() < 3 {
            return out;
        }
        let (i0, j0, i1, j1) = self.cell_range(a, b);
        let mut seen: Vec<u32> = Vec::new();
        for j in j0..=j1 {
            for i in i0..=i1 {
                for &e in &self.cells[j * self.nx + i] {
                    if seen.contains(&e) {
                        continue;
                    }
                    seen.push(e);
                    let (c, d) = self.edge(e as usize);
                    if let Some(u) = segment_crossing(a, b, c, d) {
                        out.push(u);
                    }
                }
            }
        }
        out.sort_by(f64::total_cmp);
        out
    }
}

/// The distance from `p` to segment `a`–`b`.
#[must_use]
pub fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let ab = [b[0] - a[0], b[1] - a[1]];
    let len2 = ab[0] * ab[0] + ab[1] * ab[1];
    let u = if len2 > 0.0 {
        (((p[0] - a[0]) * ab[0] + (p[1] - a[1]) * ab[1]) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - u * ab[0]).hypot(p[1] - a[1] - u * ab[1])
}

/// Whether closed segments `a`–`b` and `c`–`d` cross or touch (orientation signs; collinear
/// segments meet where they overlap).
fn segments_meet(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    let orient = |p: [f64; 2], q: [f64; 2], r: [f64; 2]| {
        let v = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]);
        if v > 0.0 {
            1
        } else if v < 0.0 {
            -1
        } else {
            0
        }
    };
    let within = |p: [f64; 2], q: [f64; 2], r: [f64; 2]| {
        r[0] >= p[0].min(q[0])
            && r[0] <= p[0].max(q[0])
            && r[1] >= p[1].min(q[1])
            && r[1] <= p[1].max(q[1])
    };
    let (o1, o2, o3, o4) = (
        orient(a, b, c),
        orient(a, b, d),
        orient(c, d, a),
        orient(c, d, b),
    );
    if o1 * o2 < 0 && o3 * o4 < 0 {
        return true;
    }
    (o1 == 0 && within(a, b, c))
        || (o2 == 0 && within(a, b, d))
        || (o3 == 0 && within(c, d, a))
        || (o4 == 0 && within(c, d, b))
}

/// Where segment `a`–`b` crosses edge `c`–`d`: the parameter along `a`–`b`. Half-open on the
/// edge (`[c, d)`) so a crossing through a shared vertex counts once, consistent with
/// [`Polygon::contains`].
fn segment_crossing(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> Option<f64> {
    let r = [b[0] - a[0], b[1] - a[1]];
    let s = [d[0] - c[0], d[1] - c[1]];
    let den = r[0] * s[1] - r[1] * s[0];
    if den.abs() < 1e-300 {
        return None;
    }
    let ca = [c[0] - a[0], c[1] - a[1]];
    let u = (ca[0] * s[1] - ca[1] * s[0]) / den;
    let v = (ca[0] * r[1] - ca[1] * r[0]) / den;
    ((0.0..1.0).contains(&u) && (0.0..1.0).contains(&v)).then_some(u)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_inside_distance_crossings() {
        let p = Polygon::new(vec![
            [0.0, 0.0],
            [2.0, 0.0],
            [2.0, 2.0],
            [0.0, 2.0],
            [0.0, 0.0],
        ]);
        assert_eq!(p.vertices().len(), 4);
        assert!(p.contains([1.0, 1.0]));
        assert!(!p.contains([3.0, 1.0]));
        assert!((p.area() - 4.0).abs() < 1e-12);
        assert!((p.distance([1.0, 1.5]) - 0.5).abs() < 1e-12);
        let c = p.crossings([-1.0, 1.0], [3.0, 1.0]);
        assert_eq!(c.len(), 2);
        assert!((c[0] - 0.25).abs() < 1e-12 && (c[1] - 0.75).abs() < 1e-12);
        assert_eq!(p.self_crossing(), None);
    }

    #[test]
    fn a_figure_eight_crosses_itself_and_a_loop_with_repeated_points_does_not() {
        let eight: Vec<[f64; 2]> = (0..200)
            .map(|i| {
                let t = f64::from(i) / 200.0 * std::f64::consts::TAU;
                [6.0 * t.sin(), 6.0 * t.sin() * t.cos()]
            })
            .collect();
        let (e, f) = Polygon::new(eight)
            .self_crossing()
            .expect("the eight crosses itself");
        // The crossing is at the origin: the edges about t = 0 and t = π.
        assert!(e == 0 || e == 199 || f == 199, "{e}, {f}");
        assert!(
            (99..=100).contains(&e) || (99..=100).contains(&f),
            "{e}, {f}"
        );
        // An ellipse with every fifth point given twice (a CAM export's repeats) is simple.
        let ellipse: Vec<[f64; 2]> = (0..300)
            .flat_map(|i| {
                let t = f64::from(i) / 300.0 * std::f64::consts::TAU;
                let p = [6.0 * t.cos(), 4.0 * t.sin()];
                std::iter::repeat_n(p, if i % 5 == 0 { 2 } else { 1 })
            })
            .collect();
        assert_eq!(Polygon::new(ellipse).self_crossing(), None);
        // A bow tie: the first edge crosses the third.
        let bow = Polygon::new(vec![[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0]]);
        assert_eq!(bow.self_crossing(), Some((0, 2)));
    }
}
