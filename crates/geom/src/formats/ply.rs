//! PLY: ascii, binary little-endian and binary big-endian.
//!
//! Read: the `vertex` element's `x y z` (any scalar type, usually float or double) and, when all
//! three are present, `nx ny nz`; the `face` element's `vertex_indices` (or `vertex_index`) list,
//! fan-triangulated. Every other element and property, of any type, scalar or list, is read past
//! and ignored. Written: `x y z [nx ny nz]` as float or double.

use std::fmt::Write as _;
use std::path::Path as FsPath;

use super::PlyEncoding;
use super::text::{Lines, truncate, utf8};
use crate::cloud::{MIN_NORMAL_NORM, PointCloud};
use crate::error::{GeomError, Location, Result};
use crate::math::{Point3, Vector3};
use crate::mesh::Mesh;

/// The scalar type PLY coordinates (and normals) are written in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyScalar {
    /// `float` (32-bit): each value is rounded to the nearest `f32`.
    Float,
    /// `double` (64-bit): values round-trip exactly.
    Double,
}

/// A PLY scalar type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn from_name(s: &str) -> Option<Ty> {
        Some(match s {
            "char" | "int8" => Ty::I8,
            "uchar" | "uint8" => Ty::U8,
            "short" | "int16" => Ty::I16,
            "ushort" | "uint16" => Ty::U16,
            "int" | "int32" => Ty::I32,
            "uint" | "uint32" => Ty::U32,
            "float" | "float32" => Ty::F32,
            "double" | "float64" => Ty::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Scalar(Ty),
    List { count: Ty, item: Ty },
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
    /// The header line that declares it.
    line: usize,
}

impl Element {
    /// The fewest bytes one instance takes in a binary body (lists empty).
    fn min_binary_size(&self) -> usize {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(t) => t.size(),
                Kind::List { count, .. } => count.size(),
            })
            .sum()
    }
}

struct Header {
    encoding: PlyEncoding,
    elements: Vec<Element>,
    /// Byte offset of the body.
    body_start: usize,
    /// Line number of the header's last line (`end_header`).
    header_lines: usize,
}

/// What a property of the vertex or face element is used for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    /// Index into the vertex value slots: x y z nx ny nz.
    Vertex(usize),
    FaceIndices,
    Ignored,
}

/// The content of a PLY file that trimctl uses.
pub(super) struct PlyData {
    /// The vertices, with normals when the file has `nx ny nz`.
    pub cloud: PointCloud,
    /// The faces, fan-triangulated.
    pub faces: Vec<[u32; 3]>,
}

fn header_error(name: &FsPath, line: usize, message: impl Into<String>) -> GeomError {
    GeomError::parse(name, Location::Line(line), message)
}

fn parse_header(bytes: &[u8], name: &FsPath) -> Result<Header> {
    let mut lines = Lines::new(bytes);
    match lines.next() {
        Some((_, b"ply")) => {}
        _ => {
            return Err(header_error(
                name,
                1,
                "not a PLY file: the first line must be \"ply\"",
            ));
        }
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for (line_no, raw) in lines.by_ref() {
        let line = utf8(raw, name, line_no)?;
        let tokens: Vec<&str> = line.split_whitespace().collect();
        match tokens.as_slice() {
            [] | ["comment" | "obj_info", ..] => {}
            ["format", enc, version] => {
                if encoding.is_some() {
                    return Err(header_error(name, line_no, "a second format line"));
                }
                if !matches!(*version, "1.0" | "1") {
                    return Err(header_error(
                        name,
                        line_no,
                        format!(
                            "PLY version {:?} is not supported (only 1.0)",
                            truncate(version)
                        ),
                    ));
                }
                encoding = Some(match *enc {
                    "ascii" => PlyEncoding::Ascii,
                    "binary_little_endian" => PlyEncoding::BinaryLittleEndian,
                    "binary_big_endian" => PlyEncoding::BinaryBigEndian,
                    other => {
                        return Err(header_error(
                            name,
                            line_no,
                            format!(
                                "unknown format {:?} (ascii, binary_little_endian or \
                                 binary_big_endian)",
                                truncate(other)
                            ),
                        ));
                    }
                });
            }
            ["element", elem_name, count] => {
                let count = count.parse::<usize>().map_err(|_| {
                    header_error(
                        name,
                        line_no,
                        format!(
                            "element {}: count {:?} is not a non-negative integer",
                            truncate(elem_name),
                            truncate(count)
                        ),
                    )
                })?;
                if elements.iter().any(|e| e.name == *elem_name) {
                    return Err(header_error(
                        name,
                        line_no,
                        format!("element {} is declared twice", truncate(elem_name)),
                    ));
                }
                elements.push(Element {
                    name: (*elem_name).to_owned(),
                    count,
                    props: Vec::new(),
                    line: line_no,
                });
            }
            ["property", rest @ ..] => {
                let Some(element) = elements.last_mut() else {
                    return Err(header_error(name, line_no, "a property before any element"));
                };
                let ty = |s: &str| {
                    Ty::from_name(s).ok_or_else(|| {
                        header_error(
                            name,
                            line_no,
                            format!("unknown property type {:?}", truncate(s)),
                        )
                    })
                };
                let (prop_name, kind) = match rest {
                    ["list", count, item, prop_name] => {
                        let count = ty(count)?;
                        if matches!(count, Ty::F32 | Ty::F64) {
                            return Err(header_error(
                                name,
                                line_no,
                                "a list count must have an integer type",
                            ));
                        }
                        (
                            *prop_name,
                            Kind::List {
                                count,
                                item: ty(item)?,
                            },
                        )
                    }
                    [t, prop_name] if *t != "list" => (*prop_name, Kind::Scalar(ty(t)?)),
                    _ => {
                        return Err(header_error(
                            name,
                            line_no,
                            "expected \"property TYPE NAME\" or \"property list COUNT_TYPE \
                             ITEM_TYPE NAME\"",
                        ));
                    }
                };
                if element.props.iter().any(|p| p.name == prop_name) {
                    return Err(header_error(
                        name,
                        line_no,
                        format!(
                            "element {}: property {} is declared twice",
                            element.name,
                            truncate(prop_name)
                        ),
                    ));
                }
                element.props.push(Property {
                    name: prop_name.to_owned(),
                    kind,
                });
            }
            ["end_header"] => {
                let encoding = encoding.ok_or_else(|| {
                    header_error(name, line_no, "the header ends without a format line")
                })?;
                if let Some(e) = elements.iter().find(|e| e.props.is_empty() && e.count > 0) {
                    return Err(header_error(
                        name,
                        e.line,
                        format!("element {} has no properties", e.name),
                    ));
                }
                return Ok(Header {
                    encoding,
                    elements,
                    body_start: lines.offset(),
                    header_lines: line_no,
                });
            }
            [keyword, ..] => {
                return Err(header_error(
                    name,
                    line_no,
                    format!(
                        "unknown or malformed header line starting {:?}",
                        truncate(keyword)
                    ),
                ));
            }
        }
    }
    Err(GeomError::parse(
        name,
        Location::End,
        "the header has no end_header line",
    ))
}

/// The role of each property of `element`.
fn roles(element: &Element, name: &FsPath) -> Result<Vec<Role>> {
    let find = |n: &str| element.props.iter().position(|p| p.name == n);
    let mut roles = vec![Role::Ignored; element.props.len()];
    match element.name.as_str() {
        "vertex" => {
            for (slot, axis) in ["x", "y", "z", "nx", "ny", "nz"].iter().enumerate() {
                if let Some(i) = find(axis) {
                    if !matches!(element.props[i].kind, Kind::Scalar(_)) {
                        return Err(header_error(
                            name,
                            element.line,
                            format!("vertex property {axis} must be a scalar, not a list"),
                        ));
                    }
                    roles[i] = Role::Vertex(slot);
                } else if slot < 3 {
                    return Err(header_error(
                        name,
                        element.line,
                        format!("element vertex has no property {axis}"),
                    ));
                }
            }
            let normals = ["nx", "ny", "nz"].map(|n| find(n).is_some());
            if normals.iter().any(|&b| b) && !normals.iter().all(|&b| b) {
                return Err(header_error(
                    name,
                    element.line,
                    "element vertex has some of nx ny nz but not all three",
                ));
            }
        }
        "face" => {
            let i = find("vertex_indices")
                .or_else(|| find("vertex_index"))
                .ok_or_else(|| {
                    header_error(
                        name,
                        element.line,
                        "element face has no vertex_indices (or vertex_index) property",
                    )
                })?;
            if !matches!(element.props[i].kind, Kind::List { .. }) {
                return Err(header_error(
                    name,
                    element.line,
                    "face property vertex_indices must be a list",
                ));
            }
            roles[i] = Role::FaceIndices;
        }
        _ => {}
    }
    Ok(roles)
}

/// Receives one element instance: its index, its place in the file and its vertex slots
/// (x y z nx ny nz).
type RowSink<'a> = dyn FnMut(usize, Location, &[f64; 6]) -> Result<()> + 'a;

/// Where body values come from: the ascii token stream or the binary bytes.
trait Source {
    /// Starts instance `index` of `element` (ascii: reads its line).
    fn begin(&mut self, element: &Element, index: usize) -> Result<()>;
    /// Reads one value.
    fn value(&mut self, ty: Ty, element: &Element, index: usize) -> Result<f64>;
    /// Skips `n` values.
    fn skip(&mut self, ty: Ty, n: usize, element: &Element, index: usize) -> Result<()>;
    /// Ends the instance (ascii: checks nothing is left on the line).
    fn end(&mut self, element: &Element, index: usize) -> Result<()>;
    /// Where instance `index` is, for errors.
    fn at(&self, index: usize) -> Location;
    /// Checks nothing but white space follows the last element.
    fn finish(&mut self) -> Result<()>;
    /// A lower bound on the bytes one instance of `element` needs, for capping allocations.
    fn min_instance_bytes(&self, element: &Element) -> usize;
    /// The bytes not yet read.
    fn remaining_bytes(&self) -> usize;
    /// Reads every instance of an element whose properties are all scalars in one pass, calling
    /// `row(index, place, slots)` with each instance's vertex slots (x y z nx ny nz). `None` when
    /// this source has no such fast path; the caller then reads value by value.
    fn scalar_rows(
        &mut self,
        _element: &Element,
        _roles: &[Role],
        _row: &mut RowSink<'_>,
    ) -> Option<Result<()>> {
        None
    }
}

struct Binary<'a> {
    body: &'a [u8],
    pos: usize,
    big_endian: bool,
    body_start: usize,
    name: &'a FsPath,
}

impl Binary<'_> {
    fn take<const N: usize>(&mut self, element: &Element, index: usize) -> Result<[u8; N]> {
        let bytes = self
            .body
            .get(self.pos..self.pos + N)
            .and_then(|s| <[u8; N]>::try_from(s).ok())
            .ok_or_else(|| self.truncated(element, index))?;
        self.pos += N;
        Ok(bytes)
    }

    fn truncated(&self, element: &Element, index: usize) -> GeomError {
        GeomError::parse(
            self.name,
            Location::Element(index),
            format!(
                "truncated: the header declares {} {} elements, the body ends (at byte {}) \
                 inside element {index}, so {index} were found",
                element.count,
                element.name,
                self.body_start + self.body.len()
            ),
        )
    }
}

macro_rules! read_as {
    ($self:ident, $t:ty, $element:ident, $index:ident) => {{
        let b = $self.take::<{ size_of::<$t>() }>($element, $index)?;
        let v = if $self.big_endian {
            <$t>::from_be_bytes(b)
        } else {
            <$t>::from_le_bytes(b)
        };
        f64::from(v)
    }};
}

impl Source for Binary<'_> {
    fn begin(&mut self, element: &Element, index: usize) -> Result<()> {
        if self.pos >= self.body.len() {
            return Err(self.truncated(element, index));
        }
        Ok(())
    }

    fn value(&mut self, ty: Ty, element: &Element, index: usize) -> Result<f64> {
        Ok(match ty {
            Ty::I8 => read_as!(self, i8, element, index),
            Ty::U8 => read_as!(self, u8, element, index),
            Ty::I16 => read_as!(self, i16, element, index),
            Ty::U16 => read_as!(self, u16, element, index),
            Ty::I32 => read_as!(self, i32, element, index),
            Ty::U32 => read_as!(self, u32, element, index),
            Ty::F32 => read_as!(self, f32, element, index),
            Ty::F64 => {
                let b = self.take::<8>(element, index)?;
                if self.big_endian {
                    f64::from_be_bytes(b)
                } else {
                    f64::from_le_bytes(b)
                }
            }
        })
    }

    fn skip(&mut self, ty: Ty, n: usize, element: &Element, index: usize) -> Result<()> {
        let len = n
            .checked_mul(ty.size())
            .filter(|&len| len <= self.body.len() - self.pos)
            .ok_or_else(|| self.truncated(element, index))?;
        self.pos += len;
        Ok(())
    }

    fn end(&mut self, _element: &Element, _index: usize) -> Result<()> {
        Ok(())
    }

    fn at(&self, index: usize) -> Location {
        Location::Element(index)
    }

    fn finish(&mut self) -> Result<()> {
        let rest = &self.body[self.pos..];
        if rest.iter().all(u8::is_ascii_whitespace) {
            Ok(())
        } else {
            Err(GeomError::parse(
                self.name,
                Location::Byte((self.body_start + self.pos) as u64),
                format!(
                    "{} bytes follow the last element: the body holds more than the header \
                     declares",
                    rest.len()
                ),
            ))
        }
    }

    fn min_instance_bytes(&self, element: &Element) -> usize {
        element.min_binary_size()
    }

    fn remaining_bytes(&self) -> usize {
        self.body.len() - self.pos
    }

    fn scalar_rows(
        &mut self,
        element: &Element,
        roles: &[Role],
        row: &mut RowSink<'_>,
    ) -> Option<Result<()>> {
        // (offset in the row, type, vertex slot) of the values used; the rest is skipped by stride.
        let mut used = Vec::with_capacity(6);
        let mut stride = 0;
        for (prop, role) in element.props.iter().zip(roles) {
            let Kind::Scalar(ty) = prop.kind else {
                return None;
            };
            if let Role::Vertex(slot) = role {
                used.push((stride, ty, *slot));
            }
            stride += ty.size();
        }
        if stride == 0 {
            return None;
        }
        let rest = &self.body[self.pos..];
        let whole_rows = rest.len() / stride;
        let rows = element.count.min(whole_rows);
        let big_endian = self.big_endian;
        for (index, bytes) in rest.chunks_exact(stride).take(rows).enumerate() {
            let mut slots = [0.0; 6];
            for &(offset, ty, slot) in &used {
                slots[slot] = decode(&bytes[offset..], ty, big_endian);
            }
            if let Err(e) = row(index, Location::Element(index), &slots) {
                return Some(Err(e));
            }
        }
        self.pos += rows * stride;
        if rows < element.count {
            return Some(Err(self.truncated(element, rows)));
        }
        Some(Ok(()))
    }
}

/// Decodes one value; `bytes` holds at least the type's size (the caller sliced a whole row).
fn decode(bytes: &[u8], ty: Ty, big_endian: bool) -> f64 {
    fn arr<const N: usize>(b: &[u8]) -> [u8; N] {
        let mut a = [0; N];
        a.copy_from_slice(&b[..N]);
        a
    }
    macro_rules! get {
        ($t:ty) => {{
            let a = arr::<{ size_of::<$t>() }>(bytes);
            if big_endian {
                <$t>::from_be_bytes(a)
            } else {
                <$t>::from_le_bytes(a)
            }
        }};
    }
    match ty {
        Ty::I8 => f64::from(get!(i8)),
        Ty::U8 => f64::from(get!(u8)),
        Ty::I16 => f64::from(get!(i16)),
        Ty::U16 => f64::from(get!(u16)),
        Ty::I32 => f64::from(get!(i32)),
        Ty::U32 => f64::from(get!(u32)),
        Ty::F32 => f64::from(get!(f32)),
        Ty::F64 => get!(f64),
    }
}

struct Ascii<'a> {
    lines: Lines<'a>,
    tokens: std::str::SplitAsciiWhitespace<'a>,
    line_no: usize,
    name: &'a FsPath,
}

impl Ascii<'_> {
    fn short(&self, element: &Element, index: usize) -> GeomError {
        GeomError::parse(
            self.name,
            Location::Line(self.line_no),
            format!(
                "{} {index}: fewer values than the header's properties of element {} need",
                element.name, element.name
            ),
        )
    }
}

impl Source for Ascii<'_> {
    fn begin(&mut self, element: &Element, index: usize) -> Result<()> {
        loop {
            let Some((line_no, raw)) = self.lines.next() else {
                return Err(GeomError::parse(
                    self.name,
                    Location::End,
                    format!(
                        "truncated: the header declares {} {} elements, found {index}",
                        element.count, element.name
                    ),
                ));
            };
            self.line_no = line_no;
            let line = utf8(raw, self.name, line_no)?;
            if !line.trim().is_empty() {
                self.tokens = line.split_ascii_whitespace();
                return Ok(());
            }
        }
    }

    fn value(&mut self, ty: Ty, element: &Element, index: usize) -> Result<f64> {
        let token = self
            .tokens
            .next()
            .ok_or_else(|| self.short(element, index))?;
        // A `float` property holds an f32 in ascii as in binary: parse it as one, so both
        // encodings of a file read to the same values.
        let parsed = if ty == Ty::F32 {
            token.parse::<f32>().map(f64::from)
        } else {
            token.parse::<f64>()
        };
        parsed.map_err(|_| {
            GeomError::parse(
                self.name,
                Location::Line(self.line_no),
                format!(
                    "{} {index}: {:?} is not a number",
                    element.name,
                    truncate(token)
                ),
            )
        })
    }

    fn skip(&mut self, ty: Ty, n: usize, element: &Element, index: usize) -> Result<()> {
        for _ in 0..n {
            self.value(ty, element, index)?;
        }
        Ok(())
    }

    fn end(&mut self, element: &Element, index: usize) -> Result<()> {
        if self.tokens.next().is_some() {
            return Err(GeomError::parse(
                self.name,
                Location::Line(self.line_no),
                format!(
                    "{} {index}: more values than the header's properties of element {} declare",
                    element.name, element.name
                ),
            ));
        }
        Ok(())
    }

    fn at(&self, _index: usize) -> Location {
        Location::Line(self.line_no)
    }

    fn finish(&mut self) -> Result<()> {
        for (line_no, raw) in self.lines.by_ref() {
            if !raw.iter().all(u8::is_ascii_whitespace) {
                return Err(GeomError::parse(
                    self.name,
                    Location::Line(line_no),
                    "data after the last element: the body holds more than the header declares",
                ));
            }
        }
        Ok(())
    }

    fn min_instance_bytes(&self, element: &Element) -> usize {
        // Each value takes at least one character and one separator.
        2 * element.props.len()
    }

    fn remaining_bytes(&self) -> usize {
        self.lines.remaining().len()
    }
}

/// Reads a list length: a non-negative integer.
fn list_len<S: Source>(
    src: &mut S,
    ty: Ty,
    element: &Element,
    index: usize,
    name: &FsPath,
) -> Result<usize> {
    let n = src.value(ty, element, index)?;
    if n >= 0.0 && n.fract() == 0.0 && n <= f64::from(u32::MAX) {
        // A non-negative integer at most u32::MAX: the cast is exact.
        Ok(n as usize)
    } else {
        Err(GeomError::parse(
            name,
            src.at(index),
            format!(
                "{} {index}: list length {n} is not a non-negative integer",
                element.name
            ),
        ))
    }
}

fn parse_body<S: Source>(src: &mut S, header: &Header, name: &FsPath) -> Result<PlyData> {
    let vertex_count = header
        .elements
        .iter()
        .find(|e| e.name == "vertex")
        .map(|e| e.count)
        .ok_or_else(|| GeomError::parse(name, Location::Header, "no vertex element"))?;
    let mut points = Vec::new();
    let mut normals = Vec::new();
    let mut has_normals = false;
    let mut faces = Vec::new();
    let mut polygon: Vec<u32> = Vec::new();
    for element in &header.elements {
        let roles = roles(element, name)?;
        let capacity = element
            .count
            .min(src.remaining_bytes() / src.min_instance_bytes(element).max(1));
        let is_vertex = element.name == "vertex";
        if is_vertex {
            has_normals = roles.contains(&Role::Vertex(3));
            points.reserve_exact(capacity);
            if has_normals {
                normals.reserve_exact(capacity);
            }
        }
        let mut push_vertex = |index: usize, at: Location, slots: &[f64; 6]| -> Result<()> {
            let p = Point3::new(slots[0], slots[1], slots[2]);
            if !p.coords.iter().all(|c| c.is_finite()) {
                return Err(GeomError::parse(
                    name,
                    at,
                    format!("vertex {index}: ({}, {}, {}) is not finite", p.x, p.y, p.z),
                ));
            }
            points.push(p);
            if has_normals {
                let n = Vector3::new(slots[3], slots[4], slots[5]);
                let Some(unit) = super::unit_or_none(&n, MIN_NORMAL_NORM) else {
                    return Err(GeomError::parse(
                        name,
                        at,
                        format!(
                            "vertex {index}: the normal ({}, {}, {}) is zero or not finite",
                            n.x, n.y, n.z
                        ),
                    ));
                };
                normals.push(unit);
            }
            Ok(())
        };
        let mut ignore = |_: usize, _: Location, _: &[f64; 6]| Ok(());
        let on_row: &mut RowSink<'_> = if is_vertex {
            &mut push_vertex
        } else {
            &mut ignore
        };
        if let Some(done) = src.scalar_rows(element, &roles, on_row) {
            done?;
            continue;
        }
        for index in 0..element.count {
            src.begin(element, index)?;
            let mut slots = [0.0; 6];
            for (prop, role) in element.props.iter().zip(&roles) {
                match (prop.kind, role) {
                    (Kind::Scalar(ty), Role::Vertex(slot)) => {
                        slots[*slot] = src.value(ty, element, index)?;
                    }
                    (Kind::Scalar(ty), _) => src.skip(ty, 1, element, index)?,
                    (Kind::List { count, item }, Role::FaceIndices) => {
                        let n = list_len(src, count, element, index, name)?;
                        polygon.clear();
                        for _ in 0..n {
                            let v = src.value(item, element, index)?;
                            polygon.push(vertex_index(v, vertex_count, index, src, name)?);
                        }
                        triangulate(&polygon, &mut faces).map_err(|message| {
                            GeomError::parse(
                                name,
                                src.at(index),
                                format!("face {index}: {message}"),
                            )
                        })?;
                    }
                    (Kind::List { count, item }, _) => {
                        let n = list_len(src, count, element, index, name)?;
                        src.skip(item, n, element, index)?;
                    }
                }
            }
            src.end(element, index)?;
            if is_vertex {
                on_row(index, src.at(index), &slots)?;
            }
        }
    }
    src.finish()?;
    let cloud = if has_normals {
        PointCloud::with_normals(points, normals)
    } else {
        PointCloud::new(points)
    }
    .map_err(|e| super::in_file(name, e))?;
    Ok(PlyData { cloud, faces })
}

fn vertex_index<S: Source>(
    v: f64,
    vertex_count: usize,
    face: usize,
    src: &S,
    name: &FsPath,
) -> Result<u32> {
    if v >= 0.0 && v.fract() == 0.0 && v < vertex_count as f64 && v <= f64::from(u32::MAX) {
        // A non-negative integer at most u32::MAX: the cast is exact.
        Ok(v as u32)
    } else {
        Err(GeomError::parse(
            name,
            src.at(face),
            format!("face {face}: vertex index {v} is not one of the {vertex_count} vertices"),
        ))
    }
}

/// Appends the fan triangulation of a polygon.
fn triangulate(polygon: &[u32], faces: &mut Vec<[u32; 3]>) -> std::result::Result<(), String> {
    match polygon {
        [first, rest @ ..] if rest.len() >= 2 => {
            faces.extend(rest.windows(2).map(|w| [*first, w[0], w[1]]));
            Ok(())
        }
        _ => Err(format!(
            "{} vertices: a face needs at least 3",
            polygon.len()
        )),
    }
}

/// Parses a PLY file.
pub(super) fn parse(bytes: &[u8], name: &FsPath) -> Result<PlyData> {
    let header = parse_header(bytes, name)?;
    let body = bytes.get(header.body_start..).unwrap_or(&[]);
    match header.encoding {
        PlyEncoding::Ascii => {
            // The body's line numbers continue the header's.
            let mut src = Ascii {
                lines: Lines::starting_at(body, header.header_lines + 1),
                tokens: "".split_ascii_whitespace(),
                line_no: header.header_lines,
                name,
            };
            parse_body(&mut src, &header, name)
        }
        PlyEncoding::BinaryLittleEndian | PlyEncoding::BinaryBigEndian => {
            let mut src = Binary {
                body,
                pos: 0,
                big_endian: header.encoding == PlyEncoding::BinaryBigEndian,
                body_start: header.body_start,
                name,
            };
            parse_body(&mut src, &header, name)
        }
    }
}

/// The mesh of a parsed PLY file; refuses a file without faces.
pub(super) fn into_mesh(data: PlyData, name: &FsPath) -> Result<Mesh> {
    if data.faces.is_empty() {
        return Err(GeomError::parse(
            name,
            Location::Header,
            "no faces (the face element is missing or empty): this PLY file is a point cloud, \
             read it with read_points",
        ));
    }
    let (vertices, _) = data.cloud.into_parts();
    Mesh::new(vertices, data.faces).map_err(|e| super::in_file(name, e))
}

/// The bytes of a PLY file of `cloud`.
pub(super) fn encode(cloud: &PointCloud, encoding: PlyEncoding, scalar: PlyScalar) -> Vec<u8> {
    let ty = match scalar {
        PlyScalar::Float => "float",
        PlyScalar::Double => "double",
    };
    let format = match encoding {
        PlyEncoding::Ascii => "ascii",
        PlyEncoding::BinaryLittleEndian => "binary_little_endian",
        PlyEncoding::BinaryBigEndian => "binary_big_endian",
    };
    let mut header = format!(
        "ply\nformat {format} 1.0\ncomment written by trimctl\nelement vertex {}\n",
        cloud.len()
    );
    let axes: &[&str] = if cloud.has_normals() {
        &["x", "y", "z", "nx", "ny", "nz"]
    } else {
        &["x", "y", "z"]
    };
    for axis in axes {
        let _ = writeln!(header, "property {ty} {axis}");
    }
    header.push_str("end_header\n");
    let values_per_point = axes.len();
    let rows = cloud.points().iter().enumerate().map(|(i, p)| {
        let n = cloud
            .normals()
            .and_then(|ns| ns.get(i))
            .copied()
            .unwrap_or_default();
        [p.x, p.y, p.z, n.x, n.y, n.z]
    });
    let mut out = header.into_bytes();
    match encoding {
        PlyEncoding::Ascii => {
            let mut body = String::with_capacity(cloud.len() * values_per_point * 12);
            for row in rows {
                for (k, v) in row[..values_per_point].iter().enumerate() {
                    let sep = if k + 1 == values_per_point { '\n' } else { ' ' };
                    let _ = match scalar {
                        PlyScalar::Float => write!(body, "{}{sep}", *v as f32),
                        PlyScalar::Double => write!(body, "{v}{sep}"),
                    };
                }
            }
            out.extend_from_slice(body.as_bytes());
        }
        PlyEncoding::BinaryLittleEndian | PlyEncoding::BinaryBigEndian => {
            let big = encoding == PlyEncoding::BinaryBigEndian;
            let size = match scalar {
                PlyScalar::Float => 4,
                PlyScalar::Double => 8,
            };
            out.reserve(cloud.len() * values_per_point * size);
            for row in rows {
                for v in &row[..values_per_point] {
                    match (scalar, big) {
                        (PlyScalar::Float, false) => {
                            out.extend_from_slice(&(*v as f32).to_le_bytes())
                        }
                        (PlyScalar::Float, true) => {
                            out.extend_from_slice(&(*v as f32).to_be_bytes())
                        }
                        (PlyScalar::Double, false) => out.extend_from_slice(&v.to_le_bytes()),
                        (PlyScalar::Double, true) => out.extend_from_slice(&v.to_be_bytes()),
                    }
                }
            }
        }
    }
    out
}
