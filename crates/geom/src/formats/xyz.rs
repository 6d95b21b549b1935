//! XYZ text: `x y z` or `x y z nx ny nz` per line, separated by spaces, tabs or commas. `#`
//! starts a comment (to the end of the line); blank lines are skipped. Every data line has the
//! column count of the first one.

use std::fmt::Write as _;
use std::path::Path as FsPath;

use super::text::{Lines, parse_finite, utf8, warn_if_unterminated};
use crate::cloud::PointCloud;
use crate::error::{GeomError, Location, Result};
use crate::math::{Point3, Vector3};

const AXES: [&str; 6] = ["x", "y", "z", "nx", "ny", "nz"];

pub(super) fn parse(bytes: &[u8], name: &FsPath) -> Result<PointCloud> {
    let parsed = parse_lines(bytes, name)?;
    warn_if_unterminated(bytes, name);
    Ok(parsed)
}

fn parse_lines(bytes: &[u8], name: &FsPath) -> Result<PointCloud> {
    let mut points = Vec::new();
    let mut normals = Vec::new();
    // (columns, line) of the first data line.
    let mut layout: Option<(usize, usize)> = None;
    let mut values = [0.0; 6];
    for (line_no, raw) in Lines::new(bytes) {
        let line = utf8(raw, name, line_no)?;
        let data = line.split('#').next().unwrap_or("");
        let at = Location::Line(line_no);
        let mut count = 0;
        for token in data
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
        {
            if count == AXES.len() {
                count += 1;
                break;
            }
            values[count] = parse_finite(token, name, at, AXES[count])?;
            count += 1;
        }
        if count == 0 {
            continue;
        }
        let columns = match layout {
            Some((columns, _)) => columns,
            None if count == 3 || count == 6 => {
                layout = Some((count, line_no));
                count
            }
            None => {
                return Err(GeomError::parse(
                    name,
                    at,
                    format!(
                        "expected 3 values (x y z) or 6 (x y z nx ny nz), found {}",
                        if count > 6 {
                            "more than 6".to_owned()
                        } else {
                            count.to_string()
                        }
                    ),
                ));
            }
        };
        if count != columns {
            let first = layout.map_or(0, |(_, l)| l);
            return Err(GeomError::parse(
                name,
                at,
                format!(
                    "expected {columns} values like line {first}, found {}",
                    if count > 6 {
                        "more than 6".to_owned()
                    } else {
                        count.to_string()
                    }
                ),
            ));
        }
        points.push(Point3::new(values[0], values[1], values[2]));
        if columns == 6 {
            let n = Vector3::new(values[3], values[4], values[5]);
            let Some(unit) = super::unit_or_none(&n, crate::cloud::MIN_NORMAL_NORM) else {
                return Err(GeomError::parse(name, at, "the normal (nx ny nz) is zero"));
            };
            normals.push(unit);
        }
    }
    let has_normals = layout.is_some_and(|(columns, _)| columns == 6);
    let cloud = if has_normals {
        PointCloud::with_normals(points, normals)
    } else {
        PointCloud::new(points)
    };
    cloud.map_err(|e| GeomError::parse(name, Location::End, e.to_string()))
}

pub(super) fn encode(cloud: &PointCloud) -> Vec<u8> {
    let mut out = String::with_capacity(cloud.len() * 64);
    match cloud.normals() {
        Some(normals) => {
            for (p, n) in cloud.points().iter().zip(normals) {
                let _ = writeln!(out, "{} {} {} {} {} {}", p.x, p.y, p.z, n.x, n.y, n.z);
            }
        }
        None => {
            for p in cloud.points() {
                let _ = writeln!(out, "{} {} {}", p.x, p.y, p.z);
            }
        }
    }
    out.into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn name() -> &'static FsPath {
        FsPath::new("scan.xyz")
    }

    #[test]
    fn reads_comments_commas_and_normals() {
        let c = parse(
            b"# header\n1 2 3 0 0 2 # trailing\n\n4,5,6,1,0,0\r\n",
            name(),
        )
        .unwrap();
        assert_eq!(
            c.points(),
            &[Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]
        );
        assert_eq!(c.normals().unwrap()[0], Vector3::z());
    }

    #[test]
    fn errors_name_file_and_line() {
        let e = parse(b"1 2 3\n1 2\n", name()).unwrap_err();
        assert_eq!(
            e.to_string(),
            "scan.xyz: line 2: expected 3 values like line 1, found 2"
        );
        let e = parse(b"1 2 3 4\n", name()).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("scan.xyz: line 1: expected 3 values"),
            "{e}"
        );
        let e = parse(b"1 2 3\n1 2 inf\n", name()).unwrap_err();
        assert_eq!(e.to_string(), "scan.xyz: line 2: z: inf is not finite");
        let e = parse(b"1 2 3 0 0 0\n", name()).unwrap_err();
        assert!(e.to_string().contains("line 1: the normal"), "{e}");
        let e = parse(b"1 2 3 4 5 6 7 8\n", name()).unwrap_err();
        assert!(e.to_string().contains("more than 6"), "{e}");
    }

    #[test]
    fn round_trips_exactly() {
        let c = PointCloud::with_normals(
            vec![Point3::new(0.1, -1e-300, 12_345.678_901_234_5)],
            vec![Vector3::new(0.6, 0.8, 0.0)],
        )
        .unwrap();
        let back = parse(&encode(&c), name()).unwrap();
        assert_eq!(back.points(), c.points());
        // Normals are renormalised on reading: equal to within an ulp or two.
        assert!((back.normals().unwrap()[0] - c.normals().unwrap()[0]).norm() < 1e-15);
    }
}
