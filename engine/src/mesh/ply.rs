//! PLY files (Turk's polygon format) as bytes: [`mesh_to_ply`] and [`points_to_ply`]
//! write binary little-endian files with `float x y z`, `float nx ny nz` (when the mesh
//! has normals), `uchar red green blue` (when it has colours) and, for meshes,
//! `list uchar int vertex_indices`; [`read_ply`] reads binary little-endian and ASCII
//! files with any scalar types, polygon faces (fan-triangulated) and extra elements or
//! properties (skipped). Big-endian files are refused with a message saying so.

use glam::Vec3;

use super::{MeshError, TriMesh};

fn header(mesh: &TriMesh, faces: bool) -> String {
    let mut h = format!("ply\nformat binary_little_endian 1.0\ncomment written by edgenerf\nelement vertex {}\n", mesh.positions.len());
    h += "property float x\nproperty float y\nproperty float z\n";
    if !mesh.normals.is_empty() {
        h += "property float nx\nproperty float ny\nproperty float nz\n";
    }
    if !mesh.colors.is_empty() {
        h += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    }
    if faces {
        h += &format!("element face {}\nproperty list uchar int vertex_indices\n", mesh.triangles.len());
    }
    h + "end_header\n"
}

fn encode(mesh: &TriMesh, faces: bool) -> Result<Vec<u8>, MeshError> {
    mesh.check()?;
    let mut out = header(mesh, faces).into_bytes();
    for (i, p) in mesh.positions.iter().enumerate() {
        let mut floats = p.to_array().to_vec();
        if let Some(n) = mesh.normals.get(i) {
            floats.extend(n.to_array());
        }
        for f in floats {
            out.extend(f.to_le_bytes());
        }
        if let Some(c) = mesh.colors.get(i) {
            out.extend(c);
        }
    }
    if faces {
        for t in &mesh.triangles {
            out.push(3);
            for i in t {
                out.extend((*i as i32).to_le_bytes());
            }
        }
    }
    Ok(out)
}

/// A mesh as a binary little-endian PLY file (vertices and triangles).
pub fn mesh_to_ply(mesh: &TriMesh) -> Result<Vec<u8>, MeshError> {
    encode(mesh, true)
}

/// A point cloud (the mesh's vertices with their normals and colours, no face
/// element) as a binary little-endian PLY file.
pub fn points_to_ply(mesh: &TriMesh) -> Result<Vec<u8>, MeshError> {
    encode(mesh, false)
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Result<Scalar, MeshError> {
        Ok(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            other => return Err(MeshError::Ply(format!("unknown property type {other:?}"))),
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }
}

struct Property {
    name: String,
    /// `Some(count type)` for a list property.
    list: Option<Scalar>,
    ty: Scalar,
}

struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

/// Where values come from: binary little-endian bytes or ASCII tokens.
enum Source<'a> {
    Binary { data: &'a [u8], at: usize },
    Ascii { tokens: std::str::SplitAsciiWhitespace<'a> },
}

impl Source<'_> {
    fn next(&mut self, ty: Scalar) -> Result<f64, MeshError> {
        match self {
            Source::Binary { data, at } => {
                let n = ty.size();
                let b = data.get(*at..*at + n).ok_or_else(|| MeshError::Ply("the file ends before its last element (truncated?)".into()))?;
                *at += n;
                Ok(match ty {
                    Scalar::I8 => b[0] as i8 as f64,
                    Scalar::U8 => b[0] as f64,
                    Scalar::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
                    Scalar::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
                    Scalar::I32 => i32::from_le_bytes(b.try_into().unwrap()) as f64,
                    Scalar::U32 => u32::from_le_bytes(b.try_into().unwrap()) as f64,
                    Scalar::F32 => f32::from_le_bytes(b.try_into().unwrap()) as f64,
                    Scalar::F64 => f64::from_le_bytes(b.try_into().unwrap()),
                })
            }
            Source::Ascii { tokens } => {
                let t = tokens.next().ok_or_else(|| MeshError::Ply("the file ends before its last element (truncated?)".into()))?;
                t.parse::<f64>().map_err(|_| MeshError::Ply(format!("{t:?} is not a number")))
            }
        }
    }
}

/// Reads a PLY file's `vertex` element (`x y z`, optional `nx ny nz` and
/// `red green blue`: 8-bit as stored, floats in `[0, 1]` scaled by 255) and its
/// `face` element (`vertex_indices` or `vertex_index`; polygons fan-triangulated).
pub fn read_ply(bytes: &[u8]) -> Result<TriMesh, MeshError> {
    let end = b"end_header";
    let pos = bytes.windows(end.len()).position(|w| w == end).ok_or_else(|| MeshError::Ply("no end_header line: not a PLY file".into()))?;
    let mut body = pos + end.len();
    while body < bytes.len() && bytes[body] != b'\n' {
        body += 1;
    }
    body += 1;
    let head = std::str::from_utf8(&bytes[..pos]).map_err(|_| MeshError::Ply("the header is not text".into()))?;
    let mut lines = head.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err(MeshError::Ply("the file does not start with \"ply\"".into()));
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, _] => format = Some(f.to_string()),
            ["element", name, n] => {
                let count = n.parse().map_err(|_| MeshError::Ply(format!("element {name}: bad count {n:?}")))?;
                elements.push(Element { name: name.to_string(), count, props: Vec::new() });
            }
            ["property", "list", c, t, name] => {
                let e = elements.last_mut().ok_or_else(|| MeshError::Ply("a property before any element".into()))?;
                e.props.push(Property { name: name.to_string(), list: Some(Scalar::parse(c)?), ty: Scalar::parse(t)? });
            }
            ["property", t, name] => {
                let e = elements.last_mut().ok_or_else(|| MeshError::Ply("a property before any element".into()))?;
                e.props.push(Property { name: name.to_string(), list: None, ty: Scalar::parse(t)? });
            }
            ["comment", ..] | ["obj_info", ..] | [] => {}
            _ => return Err(MeshError::Ply(format!("unexpected header line {line:?}"))),
        }
    }
    let mut src = match format.as_deref() {
        Some("binary_little_endian") => Source::Binary { data: bytes, at: body },
        Some("ascii") => Source::Ascii {
            tokens: std::str::from_utf8(&bytes[body.min(bytes.len())..])
                .map_err(|_| MeshError::Ply("an ASCII PLY body that is not text".into()))?
                .split_ascii_whitespace(),
        },
        Some(f) => return Err(MeshError::Ply(format!("format {f} is not supported; convert the file to binary_little_endian or ascii (e.g. with meshlab or trimesh)"))),
        None => return Err(MeshError::Ply("no format line in the header".into())),
    };
    let mut mesh = TriMesh::default();
    for e in &elements {
        let idx = |n: &str| e.props.iter().position(|p| p.name == n && p.list.is_none());
        let xyz = [idx("x"), idx("y"), idx("z")];
        let nrm = [idx("nx"), idx("ny"), idx("nz")];
        let rgb = [idx("red"), idx("green"), idx("blue")];
        let faces = e.props.iter().position(|p| p.list.is_some() && (p.name == "vertex_indices" || p.name == "vertex_index"));
        if e.name == "vertex" && xyz.iter().any(Option::is_none) {
            return Err(MeshError::Ply("the vertex element has no x, y, z properties".into()));
        }
        // A file's element counts come from its header: grow as values arrive.
        let mut values = vec![0.0f64; e.props.len()];
        let mut list = Vec::new();
        for _ in 0..e.count {
            for (k, p) in e.props.iter().enumerate() {
                match p.list {
                    None => values[k] = src.next(p.ty)?,
                    Some(ct) => {
                        let n = src.next(ct)?;
                        if !(0.0..=1e6).contains(&n) {
                            return Err(MeshError::Ply(format!("a list of {n} entries in element {}", e.name)));
                        }
                        list.clear();
                        for _ in 0..n as usize {
                            list.push(src.next(p.ty)?);
                        }
                        if Some(k) == faces && e.name == "face" && list.len() >= 3 {
                            let to_index = |v: f64| {
                                if v >= 0.0 && v < u32::MAX as f64 { Ok(v as u32) } else { Err(MeshError::Ply(format!("vertex index {v} out of range"))) }
                            };
                            let first = to_index(list[0])?;
                            for w in list[1..].windows(2) {
                                mesh.triangles.push([first, to_index(w[0])?, to_index(w[1])?]);
                            }
                        }
                    }
                }
            }
            if e.name == "vertex" {
                let get = |i: Option<usize>| values[i.unwrap()] as f32;
                mesh.positions.push(Vec3::new(get(xyz[0]), get(xyz[1]), get(xyz[2])));
                if nrm.iter().all(Option::is_some) {
                    mesh.normals.push(Vec3::new(get(nrm[0]), get(nrm[1]), get(nrm[2])));
                }
                if rgb.iter().all(Option::is_some) {
                    mesh.colors.push(rgb.map(|i| {
                        let i = i.unwrap();
                        let v = if e.props[i].ty.is_float() { values[i] * 255.0 } else { values[i] };
                        v.round().clamp(0.0, 255.0) as u8
                    }));
                }
            }
        }
    }
    mesh.check().map_err(|e| MeshError::Ply(e.to_string()))?;
    Ok(mesh)
}
