//! The path CSV of DESIGN.md: header `contour,x,y,z,u,v,w` (any column order, extra columns
//! ignored), one row per path point, the rows of a contour contiguous and in path order.
//! Cells are separated by commas and trimmed of spaces; quoting is not part of the contract.

use std::fmt::Write as _;
use std::path::Path as FsPath;

use super::text::{Lines, parse_finite, truncate, utf8, warn_if_unterminated};
use crate::error::{GeomError, Location, Result};
use crate::math::{Point3, Vector3};
use crate::path::{Contour, ContourId, MIN_FEATURE_NORM, Path};

/// The required columns, in the order they are written.
const COLUMNS: [&str; 7] = ["contour", "x", "y", "z", "u", "v", "w"];

/// The header written by [`encode`].
const HEADER: &str = "contour,x,y,z,u,v,w";

/// The rows of one contour while it is being read.
struct Open {
    id: ContourId,
    first_line: usize,
    last_line: usize,
    points: Vec<Point3>,
    features: Vec<Vector3>,
}

impl Open {
    fn close(self, name: &FsPath) -> Result<Contour> {
        let (id, first, last) = (self.id, self.first_line, self.last_line);
        Contour::with_features(id, self.points, self.features).map_err(|e| {
            let message = match e {
                GeomError::InvalidContour { message, .. } => message,
                other => other.to_string(),
            };
            let rows = if first == last {
                format!("its only row is line {first}")
            } else {
                format!("rows at lines {first}–{last}")
            };
            GeomError::parse(
                name,
                Location::Line(first),
                format!("contour {id} ({rows}): {message}"),
            )
        })
    }
}

pub(super) fn parse(bytes: &[u8], name: &FsPath) -> Result<Path> {
    let parsed = parse_lines(bytes, name)?;
    warn_if_unterminated(bytes, name);
    Ok(parsed)
}

fn parse_lines(bytes: &[u8], name: &FsPath) -> Result<Path> {
    let mut lines = Lines::new(bytes);
    // The header: the first non-blank line.
    let (header_line, header) = loop {
        match lines.next() {
            Some((line_no, raw)) => {
                let line = utf8(raw, name, line_no)?;
                if !line.trim().is_empty() {
                    break (line_no, line);
                }
            }
            None => {
                return Err(GeomError::parse(
                    name,
                    Location::End,
                    format!("empty file: expected the header {HEADER}"),
                ));
            }
        }
    };
    // A byte-order mark (spreadsheet exports) is not part of the first column's name.
    let header = header.trim_start_matches('\u{feff}');
    let header_cells: Vec<&str> = header.split(',').map(str::trim).collect();
    // For each required column, its index among the cells.
    let mut index = [0usize; 7];
    let mut missing = Vec::new();
    for (slot, column) in COLUMNS.iter().enumerate() {
        let mut found = header_cells
            .iter()
            .enumerate()
            .filter(|(_, c)| *c == column);
        match (found.next(), found.next()) {
            (Some((i, _)), None) => index[slot] = i,
            (None, _) => missing.push(*column),
            (Some(_), Some(_)) => {
                return Err(GeomError::parse(
                    name,
                    Location::Line(header_line),
                    format!("column {column} appears more than once in the header"),
                ));
            }
        }
    }
    if !missing.is_empty() {
        return Err(GeomError::parse(
            name,
            Location::Line(header_line),
            format!(
                "missing column{} {} (the header must name {})",
                if missing.len() > 1 { "s" } else { "" },
                missing.join(", "),
                COLUMNS.join(", ")
            ),
        ));
    }
    let needed = index.iter().max().map_or(0, |m| m + 1);
    let mut contours: Vec<Contour> = Vec::new();
    // Every closed contour's id with its first and last line.
    let mut closed: std::collections::HashMap<ContourId, (usize, usize)> =
        std::collections::HashMap::new();
    let mut open: Option<Open> = None;
    let mut cells: Vec<&str> = Vec::with_capacity(header_cells.len());
    for (line_no, raw) in lines {
        let line = utf8(raw, name, line_no)?;
        if line.trim().is_empty() {
            continue;
        }
        let at = Location::Line(line_no);
        cells.clear();
        cells.extend(line.split(',').map(str::trim));
        if cells.len() < needed {
            return Err(GeomError::parse(
                name,
                at,
                format!(
                    "{} cells, the header's columns need at least {needed}",
                    cells.len()
                ),
            ));
        }
        let id_cell = cells[index[0]];
        let id: ContourId = id_cell.parse().map_err(|_| {
            GeomError::parse(
                name,
                at,
                format!(
                    "column contour: {:?} is not an integer id",
                    truncate(id_cell)
                ),
            )
        })?;
        let mut v = [0.0; 6];
        for (slot, value) in v.iter_mut().enumerate() {
            let column = COLUMNS[slot + 1];
            *value = parse_finite(
                cells[index[slot + 1]],
                name,
                at,
                &format!("column {column}"),
            )?;
        }
        if open.as_ref().is_none_or(|o| o.id != id) {
            if let Some(&(first, last)) = closed.get(&id) {
                let previous = open.as_ref().map_or(id, |o| o.id);
                return Err(GeomError::parse(
                    name,
                    at,
                    format!(
                        "contour {id} reappears after contour {previous}: its rows at lines \
                         {first}–{last} and this one must be contiguous"
                    ),
                ));
            }
            if let Some(done) = open.take() {
                closed.insert(done.id, (done.first_line, done.last_line));
                contours.push(done.close(name)?);
            }
            open = Some(Open {
                id,
                first_line: line_no,
                last_line: line_no,
                points: Vec::new(),
                features: Vec::new(),
            });
        }
        if let Some(o) = open.as_mut() {
            o.last_line = line_no;
            o.points.push(Point3::new(v[0], v[1], v[2]));
            let feature = Vector3::new(v[3], v[4], v[5]);
            let unit = super::unit_or_none(&feature, MIN_FEATURE_NORM).ok_or_else(|| {
                GeomError::parse(
                    name,
                    at,
                    format!("contour {id}: the feature vector (u, v, w) is zero"),
                )
            })?;
            o.features.push(unit);
        }
    }
    match open {
        Some(last) => contours.push(last.close(name)?),
        None => {
            return Err(GeomError::parse(
                name,
                Location::End,
                "no rows after the header: a path needs at least one contour",
            ));
        }
    }
    Path::new(contours).map_err(|e| super::in_file(name, e))
}

pub(super) fn encode(path: &Path) -> Vec<u8> {
    let mut out = String::with_capacity(32 + path.num_points() * 96);
    out.push_str(HEADER);
    out.push('\n');
    for contour in path.contours() {
        let id = contour.id();
        for (p, f) in contour.points().iter().zip(contour.features()) {
            // `{}` of f64 is the shortest decimal that reads back to the same value.
            let _ = writeln!(out, "{id},{},{},{},{},{},{}", p.x, p.y, p.z, f.x, f.y, f.z);
        }
    }
    out.into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn name() -> &'static FsPath {
        FsPath::new("path.csv")
    }

    fn err(text: &str) -> String {
        parse(text.as_bytes(), name()).unwrap_err().to_string()
    }

    #[test]
    fn reads_any_column_order_with_extra_columns() {
        let p = parse(
            b"w,extra,z,y,x,contour,v,u\n1,a,0,0,0,5,0,0\n1,b,0,0,1,5,0,0\n\n1,c,0,1,1,2,0,0\n1,d,0,2,1,2,0,0\n",
            name(),
        )
        .unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!(p.contours()[0].id(), 5);
        assert_eq!(p.contours()[1].points()[1], Point3::new(1.0, 2.0, 0.0));
        assert_eq!(p.contours()[1].features()[0], Vector3::z());
    }

    #[test]
    fn errors_name_the_file_line_and_column() {
        assert_eq!(
            err("contour,x,y,z,u,w\n"),
            "path.csv: line 1: missing column v (the header must name contour, x, y, z, u, v, w)"
        );
        assert_eq!(
            err("contour,x,y,z,u,v,w\n1,0,0,0,0,0,1\n1,0,zero,0,0,0,1\n"),
            "path.csv: line 3: column y: \"zero\" is not a number"
        );
        assert_eq!(
            err("contour,x,y,z,u,v,w\n1,0,0,0,0,0,1\n1,0,NaN,0,0,0,1\n"),
            "path.csv: line 3: column y: NaN is not finite"
        );
        assert_eq!(
            err("contour,x,y,z,u,v,w\n1,0,0,0,0,0,1\n1,1,0,0,0,0,1\n2,0,0,0,0,0,1\n"),
            "path.csv: line 4: contour 2 (its only row is line 4): needs at least 2 points, got 1"
        );
        assert_eq!(
            err(
                "contour,x,y,z,u,v,w\n1,0,0,0,0,0,1\n1,1,0,0,0,0,1\n2,0,0,0,0,0,1\n2,1,0,0,0,0,1\n1,2,0,0,0,0,1\n"
            ),
            "path.csv: line 6: contour 1 reappears after contour 2: its rows at lines 2–3 and \
             this one must be contiguous"
        );
        assert_eq!(
            err("contour,x,y,z,u,v,w\n1.5,0,0,0,0,0,1\n"),
            "path.csv: line 2: column contour: \"1.5\" is not an integer id"
        );
        assert_eq!(
            err("contour,x,y,z,u,v,w\n1,0,0,0,0,0\n"),
            "path.csv: line 2: 6 cells, the header's columns need at least 7"
        );
        assert!(err("").contains("empty file"));
        assert!(err("contour,x,y,z,u,v,w\n").contains("no rows"));
    }
}
