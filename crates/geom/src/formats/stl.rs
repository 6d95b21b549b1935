//! STL, ascii and binary.
//!
//! Binary STL is read and written with stl_io. Ascii STL is parsed here instead, for two reasons:
//! stl_io's ascii errors carry no line number (the contract is that every error names the line),
//! and it parses ascii coordinates as `f32`, which would throw away the digits a CAD export
//! writes. Also, stl_io decides ascii versus binary by a leading `"solid "`, which many binary
//! exporters put in their 80-byte header; the choice is made here instead (a binary file's size
//! is exactly 84 + 50 × its facet count), and such a header is blanked before stl_io sees it.
//!
//! Vertices shared by facets (equal coordinates, bit for bit) are merged into one. Facet normals
//! in the file are ignored: [`Mesh`] derives them from the vertex order.

use rustc_hash::FxHashMap;
use std::io::Cursor;
use std::path::Path as FsPath;

use super::text::{Lines, truncate};
use crate::error::{GeomError, Location, Result};
use crate::math::Point3;
use crate::mesh::Mesh;

const HEADER_BYTES: usize = 80;
const COUNT_END: usize = HEADER_BYTES + 4;
const FACET_BYTES: usize = 50;

/// Merges equal vertices and collects triangles.
#[derive(Default)]
struct Builder {
    vertices: Vec<Point3>,
    index_of: FxHashMap<[u64; 3], u32>,
    triangles: Vec<[u32; 3]>,
}

impl Builder {
    fn vertex(&mut self, p: Point3) -> u32 {
        let key = [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
        let next = self.vertices.len();
        *self.index_of.entry(key).or_insert_with(|| {
            self.vertices.push(p);
            // At most 3 × (number of facets) vertices, and facets are counted by a u32.
            next as u32
        })
    }

    fn into_mesh(self, name: &FsPath) -> Result<Mesh> {
        if self.triangles.is_empty() {
            return Err(GeomError::parse(name, Location::End, "no facets"));
        }
        Mesh::new(self.vertices, self.triangles).map_err(|e| super::in_file(name, e))
    }
}

fn facet_count(bytes: &[u8]) -> Option<u32> {
    let count: [u8; 4] = bytes.get(HEADER_BYTES..COUNT_END)?.try_into().ok()?;
    Some(u32::from_le_bytes(count))
}

fn is_exact_binary(bytes: &[u8]) -> bool {
    facet_count(bytes).is_some_and(|n| {
        (COUNT_END as u64) + (FACET_BYTES as u64) * u64::from(n) == bytes.len() as u64
    })
}

fn starts_with_solid(bytes: &[u8]) -> bool {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    bytes[start..].starts_with(b"solid")
}

pub(super) fn parse(bytes: &[u8], name: &FsPath) -> Result<Mesh> {
    if !is_exact_binary(bytes) && starts_with_solid(bytes) {
        parse_ascii(bytes, name)
    } else {
        parse_binary(bytes, name)
    }
}

fn parse_binary(bytes: &[u8], name: &FsPath) -> Result<Mesh> {
    let Some(count) = facet_count(bytes) else {
        return Err(GeomError::parse(
            name,
            Location::Header,
            format!(
                "a binary STL needs an {COUNT_END}-byte header, the file has {} bytes",
                bytes.len()
            ),
        ));
    };
    let count = count as usize;
    let body = bytes.len() - COUNT_END;
    let found = body / FACET_BYTES;
    if found < count {
        return Err(GeomError::parse(
            name,
            Location::Element(found),
            format!(
                "truncated: the header declares {count} facets, the file holds {found} \
                 ({} bytes, {} needed)",
                bytes.len(),
                COUNT_END as u64 + FACET_BYTES as u64 * count as u64
            ),
        ));
    }
    if body != count * FACET_BYTES {
        return Err(GeomError::parse(
            name,
            Location::Byte((COUNT_END + count * FACET_BYTES) as u64),
            format!(
                "{} bytes follow the {count} facets the header declares",
                body - count * FACET_BYTES
            ),
        ));
    }
    // stl_io takes a header starting "solid " for ascii: blank it (its content is free text).
    let blanked;
    let input = if bytes.starts_with(b"solid") {
        let mut copy = bytes.to_vec();
        copy[..HEADER_BYTES].fill(0);
        blanked = copy;
        &blanked[..]
    } else {
        bytes
    };
    let mut cursor = Cursor::new(input);
    let reader = stl_io::create_stl_reader(&mut cursor)
        .map_err(|e| GeomError::parse(name, Location::Header, format!("stl_io: {e}")))?;
    let mut builder = Builder {
        vertices: Vec::with_capacity(count / 2 + 3),
        index_of: FxHashMap::with_capacity_and_hasher(count / 2 + 3, Default::default()),
        triangles: Vec::with_capacity(count),
    };
    for (index, facet) in reader.enumerate() {
        let facet = facet.map_err(|e| {
            GeomError::parse(
                name,
                Location::Element(index),
                format!("facet {index}: stl_io: {e}"),
            )
        })?;
        let mut tri = [0; 3];
        for (corner, v) in tri.iter_mut().zip(facet.vertices.iter()) {
            let p = Point3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]));
            if !p.coords.iter().all(|c| c.is_finite()) {
                return Err(GeomError::parse(
                    name,
                    Location::Element(index),
                    format!(
                        "facet {index}: vertex ({}, {}, {}) is not finite",
                        p.x, p.y, p.z
                    ),
                ));
            }
            *corner = builder.vertex(p);
        }
        builder.triangles.push(tri);
    }
    builder.into_mesh(name)
}

/// Where the ascii parser is in the grammar.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Before `solid`.
    Start,
    /// Expecting `facet` or `endsolid`.
    Solid,
    /// Expecting `outer loop`.
    Facet,
    /// Expecting `vertex` (the count so far) or `endloop`.
    Loop(usize),
    /// Expecting `endfacet`.
    EndFacet,
    /// After `endsolid`: only another `solid` may follow.
    Done,
}

fn parse_ascii(bytes: &[u8], name: &FsPath) -> Result<Mesh> {
    let mut builder = Builder::default();
    let mut state = State::Start;
    let mut corners = [0u32; 3];
    let mut facet_line = 0;
    for (line_no, raw) in Lines::new(bytes) {
        let at = Location::Line(line_no);
        let err = |message: String| GeomError::parse(name, at, message);
        let line = std::str::from_utf8(raw).map_err(|_| {
            err(format!(
                "not text, yet the file starts with \"solid\": neither ascii STL nor a binary STL \
                 whose size matches its facet count ({} bytes; the header's count needs {})",
                bytes.len(),
                facet_count(bytes).map_or_else(
                    || "84 or more".to_owned(),
                    |n| (COUNT_END as u64 + FACET_BYTES as u64 * u64::from(n)).to_string()
                )
            ))
        })?;
        let tokens: Vec<&str> = line.split_ascii_whitespace().take(5).collect();
        let Some(&keyword) = tokens.first() else {
            continue;
        };
        state = match (state, keyword) {
            (State::Start | State::Done, "solid") => State::Solid,
            (State::Solid, "facet") => {
                facet_line = line_no;
                State::Facet
            }
            (State::Solid, "endsolid") => State::Done,
            (State::Facet, "outer") if tokens.get(1) == Some(&"loop") => State::Loop(0),
            (State::Loop(k), "vertex") => {
                if k == 3 {
                    return Err(err(format!(
                        "a fourth vertex in the facet of line {facet_line}: STL facets are \
                         triangles"
                    )));
                }
                let [_, x, y, z] = tokens.as_slice() else {
                    return Err(err("expected \"vertex X Y Z\"".to_owned()));
                };
                let mut c = [0.0; 3];
                for (value, (token, axis)) in c.iter_mut().zip([(x, "x"), (y, "y"), (z, "z")]) {
                    *value = super::text::parse_finite(token, name, at, axis)?;
                }
                corners[k] = builder.vertex(Point3::new(c[0], c[1], c[2]));
                State::Loop(k + 1)
            }
            (State::Loop(3), "endloop") => {
                builder.triangles.push(corners);
                State::EndFacet
            }
            (State::Loop(k), "endloop") => {
                return Err(err(format!(
                    "the facet of line {facet_line} has {k} vertices, needs 3"
                )));
            }
            (State::EndFacet, "endfacet") => State::Solid,
            (state, other) => {
                let expected = match state {
                    State::Start => "solid",
                    State::Solid => "facet or endsolid",
                    State::Facet => "outer loop",
                    State::Loop(3) => "endloop",
                    State::Loop(_) => "vertex",
                    State::EndFacet => "endfacet",
                    State::Done => "nothing or another solid",
                };
                return Err(err(format!(
                    "expected {expected}, found {:?}",
                    truncate(other)
                )));
            }
        };
    }
    if state != State::Done {
        return Err(GeomError::parse(
            name,
            Location::End,
            format!(
                "the file ends inside a solid after {} complete facets (no endsolid: truncated?)",
                builder.triangles.len()
            ),
        ));
    }
    builder.into_mesh(name)
}

pub(super) fn encode(mesh: &Mesh) -> Result<Vec<u8>> {
    if u32::try_from(mesh.triangles().len()).is_err() {
        return Err(GeomError::invalid(
            "mesh",
            format!(
                "{} triangles: binary STL counts facets in a u32",
                mesh.triangles().len()
            ),
        ));
    }
    let vertices = mesh.vertices();
    let to_f32 = |p: &Point3| {
        // STL stores f32: rounding to the nearest is the format's precision.
        stl_io::Vertex::new([p.x as f32, p.y as f32, p.z as f32])
    };
    let triangles: Vec<stl_io::Triangle> = mesh
        .triangles()
        .iter()
        .enumerate()
        .map(|(t, tri)| {
            let n = mesh.face_normal(t).unwrap_or_default();
            stl_io::Triangle {
                normal: stl_io::Normal::new([n.x as f32, n.y as f32, n.z as f32]),
                // Mesh::new checked every index.
                vertices: tri.map(|i| to_f32(&vertices[i as usize])),
            }
        })
        .collect();
    let mut out = Vec::with_capacity(COUNT_END + FACET_BYTES * triangles.len());
    stl_io::write_stl(&mut out, triangles.iter())
        .map_err(|e| GeomError::invalid("mesh", format!("stl_io could not encode: {e}")))?;
    Ok(out)
}
