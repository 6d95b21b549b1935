//! PCD (Point Cloud Library format, v0.7 and v0.6 headers): `DATA ascii` and `DATA binary`.
//!
//! Read: the fields `x y z` and, when all three are present, `normal_x normal_y normal_z`; every
//! other field is skipped using its `SIZE`, `TYPE` and `COUNT`. Binary bodies are little-endian,
//! point after point (PCL writes the host order, little-endian on every platform it supports).
//! `DATA binary_compressed` (LZF) is refused by name. Written: double-precision fields.

use std::fmt::Write as _;
use std::path::Path as FsPath;

use super::PcdEncoding;
use super::text::{Lines, truncate, utf8};
use crate::cloud::{MIN_NORMAL_NORM, PointCloud};
use crate::error::{GeomError, Location, Result};
use crate::math::{Point3, Vector3};

/// A PCD field's storage: `TYPE` (F, I, U) with `SIZE` in bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ty {
    F4,
    F8,
    I1,
    I2,
    I4,
    I8,
    U1,
    U2,
    U4,
    U8,
}

impl Ty {
    fn new(kind: &str, size: usize) -> Option<Ty> {
        Some(match (kind, size) {
            ("F", 4) => Ty::F4,
            ("F", 8) => Ty::F8,
            ("I", 1) => Ty::I1,
            ("I", 2) => Ty::I2,
            ("I", 4) => Ty::I4,
            ("I", 8) => Ty::I8,
            ("U", 1) => Ty::U1,
            ("U", 2) => Ty::U2,
            ("U", 4) => Ty::U4,
            ("U", 8) => Ty::U8,
            _ => return None,
        })
    }

    /// Decodes a little-endian value; `b` holds at least the type's size.
    fn decode(self, b: &[u8]) -> Option<f64> {
        fn arr<const N: usize>(b: &[u8]) -> Option<[u8; N]> {
            b.get(..N).and_then(|s| s.try_into().ok())
        }
        Some(match self {
            Ty::F4 => f64::from(f32::from_le_bytes(arr(b)?)),
            Ty::F8 => f64::from_le_bytes(arr(b)?),
            Ty::I1 => f64::from(i8::from_le_bytes(arr(b)?)),
            Ty::I2 => f64::from(i16::from_le_bytes(arr(b)?)),
            Ty::I4 => f64::from(i32::from_le_bytes(arr(b)?)),
            // 64-bit integers: the nearest f64 (exact up to 2^53).
            Ty::I8 => i64::from_le_bytes(arr(b)?) as f64,
            Ty::U1 => f64::from(u8::from_le_bytes(arr(b)?)),
            Ty::U2 => f64::from(u16::from_le_bytes(arr(b)?)),
            Ty::U4 => f64::from(u32::from_le_bytes(arr(b)?)),
            Ty::U8 => u64::from_le_bytes(arr(b)?) as f64,
        })
    }
}

#[derive(Debug)]
struct Field {
    name: String,
    ty: Ty,
    count: usize,
    /// Byte offset within a binary point.
    offset: usize,
}

struct Header {
    fields: Vec<Field>,
    points: usize,
    binary: bool,
    /// Byte offset of the body.
    body_start: usize,
    /// Line number of the DATA line.
    data_line: usize,
    /// The bytes of one binary point.
    point_size: usize,
    /// Total values per ascii row.
    values_per_row: usize,
    /// Field index of x y z, and of the normals if all three are present.
    xyz: [usize; 3],
    normals: Option<[usize; 3]>,
}

fn at_line(name: &FsPath, line: usize, message: impl Into<String>) -> GeomError {
    GeomError::parse(name, Location::Line(line), message)
}

fn parse_count(token: &str, name: &FsPath, line: usize, key: &str) -> Result<usize> {
    token.parse::<usize>().map_err(|_| {
        at_line(
            name,
            line,
            format!("{key}: {:?} is not a non-negative integer", truncate(token)),
        )
    })
}

#[expect(
    clippy::too_many_lines,
    reason = "one pass over the header keys, each a few lines; splitting it scatters the checks"
)]
fn parse_header(bytes: &[u8], name: &FsPath) -> Result<Header> {
    let mut lines = Lines::new(bytes);
    let mut names: Option<(Vec<String>, usize)> = None;
    let mut sizes: Option<(Vec<usize>, usize)> = None;
    let mut types: Option<(Vec<String>, usize)> = None;
    let mut counts: Option<(Vec<usize>, usize)> = None;
    let mut width: Option<usize> = None;
    let mut height: Option<usize> = None;
    let mut declared_points: Option<(usize, usize)> = None;
    let mut data: Option<(bool, usize)> = None;
    for (line_no, raw) in lines.by_ref() {
        let line = utf8(raw, name, line_no)?;
        let line = line.split('#').next().unwrap_or("");
        let mut tokens = line.split_ascii_whitespace();
        let Some(key) = tokens.next() else { continue };
        let rest: Vec<&str> = tokens.collect();
        match key {
            "VERSION" | "VIEWPOINT" => {}
            "FIELDS" => names = Some((rest.iter().map(|s| (*s).to_owned()).collect(), line_no)),
            "SIZE" => {
                let v = rest
                    .iter()
                    .map(|t| parse_count(t, name, line_no, "SIZE"))
                    .collect::<Result<_>>()?;
                sizes = Some((v, line_no));
            }
            "TYPE" => types = Some((rest.iter().map(|s| (*s).to_owned()).collect(), line_no)),
            "COUNT" => {
                let v = rest
                    .iter()
                    .map(|t| parse_count(t, name, line_no, "COUNT"))
                    .collect::<Result<_>>()?;
                counts = Some((v, line_no));
            }
            "WIDTH" | "HEIGHT" | "POINTS" => {
                let [t] = rest.as_slice() else {
                    return Err(at_line(name, line_no, format!("{key} takes one number")));
                };
                let v = parse_count(t, name, line_no, key)?;
                match key {
                    "WIDTH" => width = Some(v),
                    "HEIGHT" => height = Some(v),
                    _ => declared_points = Some((v, line_no)),
                }
            }
            "DATA" => {
                let binary = match rest.as_slice() {
                    ["ascii"] => false,
                    ["binary"] => true,
                    ["binary_compressed"] => {
                        return Err(GeomError::UnsupportedFormat {
                            path: name.into(),
                            message: format!(
                                "line {line_no}: DATA binary_compressed (LZF) is not supported: \
                                 save the cloud as ascii or binary"
                            ),
                        });
                    }
                    _ => {
                        return Err(at_line(
                            name,
                            line_no,
                            "DATA must be ascii, binary or binary_compressed",
                        ));
                    }
                };
                data = Some((binary, line_no));
                break;
            }
            other => {
                return Err(at_line(
                    name,
                    line_no,
                    format!("unknown header key {:?} (not a PCD file?)", truncate(other)),
                ));
            }
        }
    }
    let Some((binary, data_line)) = data else {
        return Err(GeomError::parse(
            name,
            Location::End,
            "the header has no DATA line (not a PCD file?)",
        ));
    };
    let missing = |key: &str| at_line(name, data_line, format!("the header has no {key} line"));
    let (names, names_line) = names.ok_or_else(|| missing("FIELDS"))?;
    let (sizes, sizes_line) = sizes.ok_or_else(|| missing("SIZE"))?;
    let (types, types_line) = types.ok_or_else(|| missing("TYPE"))?;
    let (counts, counts_line) = counts.unwrap_or_else(|| (vec![1; names.len()], names_line));
    for (what, len, line) in [
        ("SIZE", sizes.len(), sizes_line),
        ("TYPE", types.len(), types_line),
        ("COUNT", counts.len(), counts_line),
    ] {
        if len != names.len() {
            return Err(at_line(
                name,
                line,
                format!("{what} has {len} entries for {} FIELDS", names.len()),
            ));
        }
    }
    let mut fields = Vec::with_capacity(names.len());
    let mut offset = 0usize;
    let mut values_per_row = 0usize;
    for (((field_name, size), kind), count) in names.into_iter().zip(sizes).zip(&types).zip(counts)
    {
        let ty = Ty::new(kind, size).ok_or_else(|| {
            at_line(
                name,
                types_line,
                format!(
                    "field {}: TYPE {:?} with SIZE {size} is not a PCD type (F 4/8, I or U 1/2/4/8)",
                    truncate(&field_name),
                    truncate(kind)
                ),
            )
        })?;
        let too_big = || at_line(name, sizes_line, "the point size overflows");
        let bytes = size.checked_mul(count).ok_or_else(too_big)?;
        fields.push(Field {
            name: field_name,
            ty,
            count,
            offset,
        });
        offset = offset.checked_add(bytes).ok_or_else(too_big)?;
        values_per_row = values_per_row.checked_add(count).ok_or_else(too_big)?;
    }
    let find = |n: &str| fields.iter().position(|f| f.name == n);
    let mut xyz = [0; 3];
    for (slot, axis) in ["x", "y", "z"].iter().enumerate() {
        xyz[slot] =
            find(axis).ok_or_else(|| at_line(name, names_line, format!("FIELDS has no {axis}")))?;
    }
    let normal_fields = ["normal_x", "normal_y", "normal_z"].map(find);
    let normals = match normal_fields {
        [Some(a), Some(b), Some(c)] => Some([a, b, c]),
        [None, None, None] => None,
        _ => {
            return Err(at_line(
                name,
                names_line,
                "FIELDS has some of normal_x normal_y normal_z but not all three",
            ));
        }
    };
    for &i in xyz.iter().chain(normals.iter().flatten()) {
        if fields[i].count != 1 {
            return Err(at_line(
                name,
                counts_line,
                format!(
                    "field {} must have COUNT 1, not {}",
                    fields[i].name, fields[i].count
                ),
            ));
        }
    }
    let from_size = match (width, height) {
        (Some(w), Some(h)) => w.checked_mul(h),
        (Some(w), None) => Some(w),
        _ => None,
    };
    let points = match (declared_points, from_size) {
        (Some((p, _)), None) => p,
        (None, Some(p)) => p,
        (Some((p, line)), Some(wh)) if p != wh => {
            return Err(at_line(
                name,
                line,
                format!("POINTS {p} differs from WIDTH × HEIGHT = {wh}"),
            ));
        }
        (Some((p, _)), Some(_)) => p,
        (None, None) => return Err(missing("POINTS (or WIDTH)")),
    };
    Ok(Header {
        fields,
        points,
        binary,
        body_start: lines.offset(),
        data_line,
        point_size: offset,
        values_per_row,
        xyz,
        normals,
    })
}

/// Checks one point's values and stores them.
fn push_point(
    values: [f64; 6],
    has_normals: bool,
    index: usize,
    at: Location,
    name: &FsPath,
    points: &mut Vec<Point3>,
    normals: &mut Vec<Vector3>,
) -> Result<()> {
    let p = Point3::new(values[0], values[1], values[2]);
    if !p.coords.iter().all(|c| c.is_finite()) {
        return Err(GeomError::parse(
            name,
            at,
            format!("point {index}: ({}, {}, {}) is not finite", p.x, p.y, p.z),
        ));
    }
    points.push(p);
    if has_normals {
        let n = Vector3::new(values[3], values[4], values[5]);
        let Some(unit) = super::unit_or_none(&n, MIN_NORMAL_NORM) else {
            return Err(GeomError::parse(
                name,
                at,
                format!(
                    "point {index}: the normal ({}, {}, {}) is zero or not finite",
                    n.x, n.y, n.z
                ),
            ));
        };
        normals.push(unit);
    }
    Ok(())
}

pub(super) fn parse(bytes: &[u8], name: &FsPath) -> Result<PointCloud> {
    let header = parse_header(bytes, name)?;
    let body = bytes.get(header.body_start..).unwrap_or(&[]);
    let has_normals = header.normals.is_some();
    // (field index, value slot) of the fields read.
    let wanted: Vec<(usize, usize)> = header
        .xyz
        .iter()
        .chain(header.normals.iter().flatten())
        .copied()
        .enumerate()
        .map(|(slot, field)| (field, slot))
        .collect();
    let min_row_bytes = if header.binary {
        header.point_size
    } else {
        2 * header.values_per_row
    };
    let capacity = header.points.min(body.len() / min_row_bytes.max(1));
    let mut points = Vec::with_capacity(capacity);
    let mut normals = Vec::with_capacity(if has_normals { capacity } else { 0 });
    if header.binary {
        if header.point_size == 0 && header.points > 0 {
            return Err(at_line(name, header.data_line, "the fields take no bytes"));
        }
        for index in 0..header.points {
            let start = index * header.point_size;
            let row = body.get(start..start + header.point_size).ok_or_else(|| {
                GeomError::parse(
                    name,
                    Location::Element(index),
                    format!(
                        "truncated: POINTS declares {} points of {} bytes, the body ({} bytes) \
                         holds {}",
                        header.points,
                        header.point_size,
                        body.len(),
                        body.len() / header.point_size
                    ),
                )
            })?;
            let mut values = [0.0; 6];
            for &(field, slot) in &wanted {
                let f = &header.fields[field];
                values[slot] = row
                    .get(f.offset..)
                    .and_then(|b| f.ty.decode(b))
                    .unwrap_or(f64::NAN);
            }
            push_point(
                values,
                has_normals,
                index,
                Location::Element(index),
                name,
                &mut points,
                &mut normals,
            )?;
        }
        let used = header.points * header.point_size;
        let rest = body.get(used..).unwrap_or(&[]);
        if !rest.iter().all(u8::is_ascii_whitespace) {
            return Err(GeomError::parse(
                name,
                Location::Byte((header.body_start + used) as u64),
                format!(
                    "{} bytes follow the last point: the body holds more than POINTS declares",
                    rest.len()
                ),
            ));
        }
    } else {
        // Value index in a row of each wanted field (fields before it may have COUNT > 1).
        let mut first_value = Vec::with_capacity(header.fields.len());
        let mut acc = 0;
        for f in &header.fields {
            first_value.push(acc);
            acc += f.count;
        }
        let mut index = 0;
        let mut tokens: Vec<&str> = Vec::with_capacity(header.values_per_row.min(1024));
        for (line_no, raw) in Lines::starting_at(body, header.data_line + 1) {
            let line = utf8(raw, name, line_no)?;
            tokens.clear();
            tokens.extend(
                line.split_ascii_whitespace()
                    .take(header.values_per_row.saturating_add(1)),
            );
            if tokens.is_empty() {
                continue;
            }
            let at = Location::Line(line_no);
            if index == header.points {
                return Err(GeomError::parse(
                    name,
                    at,
                    format!("more points than POINTS declares ({})", header.points),
                ));
            }
            if tokens.len() != header.values_per_row {
                return Err(GeomError::parse(
                    name,
                    at,
                    format!(
                        "expected {} values (one per FIELDS × COUNT), found {}",
                        header.values_per_row,
                        if tokens.len() > header.values_per_row {
                            "more".to_owned()
                        } else {
                            tokens.len().to_string()
                        }
                    ),
                ));
            }
            let mut values = [0.0; 6];
            for &(field, slot) in &wanted {
                let f = &header.fields[field];
                let token = tokens.get(first_value[field]).copied().unwrap_or("");
                // An F 4 field holds an f32 in ascii as in binary: parse it as one.
                values[slot] = if f.ty == Ty::F4 {
                    token.parse::<f32>().map(f64::from).map_err(|_| {
                        GeomError::parse(
                            name,
                            at,
                            format!("{}: {:?} is not a number", f.name, truncate(token)),
                        )
                    })?
                } else {
                    super::text::parse_f64(token, name, at, &f.name)?
                };
            }
            push_point(
                values,
                has_normals,
                index,
                at,
                name,
                &mut points,
                &mut normals,
            )?;
            index += 1;
        }
        if index != header.points {
            return Err(GeomError::parse(
                name,
                Location::End,
                format!(
                    "truncated: POINTS declares {} points, found {index}",
                    header.points
                ),
            ));
        }
    }
    if has_normals {
        PointCloud::with_normals(points, normals)
    } else {
        PointCloud::new(points)
    }
    .map_err(|e| super::in_file(name, e))
}

pub(super) fn encode(cloud: &PointCloud, encoding: PcdEncoding) -> Vec<u8> {
    let (fields, sizes, types, counts) = if cloud.has_normals() {
        (
            "x y z normal_x normal_y normal_z",
            "8 8 8 8 8 8",
            "F F F F F F",
            "1 1 1 1 1 1",
        )
    } else {
        ("x y z", "8 8 8", "F F F", "1 1 1")
    };
    let n = cloud.len();
    let data = match encoding {
        PcdEncoding::Ascii => "ascii",
        PcdEncoding::Binary => "binary",
    };
    let mut out = format!(
        "# .PCD v0.7 - Point Cloud Data file format (written by trimctl)\nVERSION 0.7\n\
         FIELDS {fields}\nSIZE {sizes}\nTYPE {types}\nCOUNT {counts}\nWIDTH {n}\nHEIGHT 1\n\
         VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    )
    .into_bytes();
    let rows = cloud.points().iter().enumerate().map(|(i, p)| {
        let normal = cloud.normals().and_then(|ns| ns.get(i)).copied();
        (p, normal)
    });
    match encoding {
        PcdEncoding::Ascii => {
            let mut body = String::with_capacity(n * 64);
            for (p, normal) in rows {
                let _ = match normal {
                    Some(m) => writeln!(body, "{} {} {} {} {} {}", p.x, p.y, p.z, m.x, m.y, m.z),
                    None => writeln!(body, "{} {} {}", p.x, p.y, p.z),
                };
            }
            out.extend_from_slice(body.as_bytes());
        }
        PcdEncoding::Binary => {
            out.reserve(n * if cloud.has_normals() { 48 } else { 24 });
            for (p, normal) in rows {
                for v in [p.x, p.y, p.z] {
                    out.extend_from_slice(&v.to_le_bytes());
                }
                if let Some(m) = normal {
                    for v in [m.x, m.y, m.z] {
                        out.extend_from_slice(&v.to_le_bytes());
                    }
                }
            }
        }
    }
    out
}
