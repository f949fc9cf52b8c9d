//! NumPy `.npy` and `.npz` files: a small reader (plus a writer for tests and tools).
//!
//! Supported: format versions 1, 2 and 3; every numeric dtype NumPy writes for real
//! numbers (`b1`, `i1`/`u1`, `i2`/`u2`, `i4`/`u4`, `i8`/`u8`, `f2`, `f4`, `f8`) in either
//! byte order; C and Fortran order (Fortran arrays are transposed to C order on load);
//! `.npz` archives (stored or deflated) through the `zip` crate. Everything else
//! (complex, strings, records, objects/pickles, truncated data, trailing bytes) is a
//! clear error, never a guess.
//!
//! Why hand-written: the crates measured (2026-11) fail on exactly the hostile headers
//! this reader must refuse: `npyz` 0.9.1 panics ("attempt to multiply with overflow",
//! in `NpyFile::new`) on a header whose shape product overflows `u64` in debug builds
//! and wraps it to an empty array in release; `ndarray-npy` 0.9 aborts the process
//! allocating 8 TiB for a header that claims 2^40 `f8` values over a 64-byte body.
//! Here every size is computed with checked arithmetic and compared with the bytes
//! actually present before anything is allocated (see `tests/fuzz_loaders.rs`).
//!
//! Invariant: an [`NpyArray`] holds exactly `shape.iter().product()` values, converted
//! to `f64` in C (row-major) order; the original dtype is kept in [`NpyArray::dtype`].

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use super::DataError;

const MAGIC: &[u8] = b"\x93NUMPY";

/// Largest `.npy` entry of an `.npz` archive read into memory (camera archives and test
/// fixtures are kilobytes to megabytes; a larger entry is a corrupt or hostile file).
pub const MAX_NPZ_ENTRY_BYTES: u64 = 1 << 30;

/// Element type of an array as stored in the file (its byte order is undone on load).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DType {
    Bool,
    I1,
    U1,
    I2,
    U2,
    I4,
    U4,
    I8,
    U8,
    F2,
    F4,
    F8,
}

impl DType {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            DType::Bool | DType::I1 | DType::U1 => 1,
            DType::I2 | DType::U2 | DType::F2 => 2,
            DType::I4 | DType::U4 | DType::F4 => 4,
            DType::I8 | DType::U8 | DType::F8 => 8,
        }
    }

    /// NumPy's type code without byte order (`f8`, `u1`, ...).
    fn from_code(code: &str) -> Option<DType> {
        Some(match code {
            "b1" | "?" => DType::Bool,
            "i1" => DType::I1,
            "u1" => DType::U1,
            "i2" => DType::I2,
            "u2" => DType::U2,
            "i4" => DType::I4,
            "u4" => DType::U4,
            "i8" => DType::I8,
            "u8" => DType::U8,
            "f2" => DType::F2,
            "f4" => DType::F4,
            "f8" => DType::F8,
            _ => return None,
        })
    }

    /// One element from exactly `self.size()` little-endian bytes.
    fn decode_le(self, b: &[u8]) -> f64 {
        let a = |n: usize| -> [u8; 8] {
            let mut out = [0u8; 8];
            out[..n].copy_from_slice(&b[..n]);
            out
        };
        match self {
            DType::Bool => f64::from(u8::from(b[0] != 0)),
            DType::I1 => f64::from(b[0] as i8),
            DType::U1 => f64::from(b[0]),
            DType::I2 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            DType::U2 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            DType::F2 => f64::from(half::f16::from_le_bytes([b[0], b[1]])),
            DType::I4 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            DType::U4 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            DType::F4 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            DType::I8 => i64::from_le_bytes(a(8)) as f64,
            DType::U8 => u64::from_le_bytes(a(8)) as f64,
            DType::F8 => f64::from_le_bytes(a(8)),
        }
    }
}

/// A dense array read from a `.npy` file, values converted to `f64`.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    pub shape: Vec<usize>,
    pub dtype: DType,
    /// Row-major values; `data.len() == shape.iter().product()`.
    pub data: Vec<f64>,
}

impl NpyArray {
    /// The shape as NumPy prints it, e.g. `(20, 17)` or `(5,)`.
    pub fn shape_string(&self) -> String {
        shape_string(&self.shape)
    }

    /// Checks the shape against a pattern where `None` matches any length.
    /// The error names `path` and `what` (e.g. the array name inside an `.npz`).
    pub fn expect_shape(
        &self,
        path: &Path,
        what: &str,
        pattern: &[Option<usize>],
    ) -> Result<(), DataError> {
        let ok = self.shape.len() == pattern.len()
            && self
                .shape
                .iter()
                .zip(pattern)
                .all(|(&s, p)| p.is_none_or(|p| p == s));
        if ok {
            return Ok(());
        }
        let expected: Vec<String> = pattern
            .iter()
            .map(|p| p.map_or_else(|| "N".to_string(), |p| p.to_string()))
            .collect();
        Err(DataError::Npy {
            path: path.to_path_buf(),
            message: format!(
                "{what} has shape {}, expected ({}); the file is not in the expected layout",
                self.shape_string(),
                expected.join(", ")
            ),
        })
    }

    /// Row `i` of a 2-D array.
    pub fn row(&self, i: usize) -> &[f64] {
        let cols = self.shape.get(1).copied().unwrap_or(1);
        &self.data[i * cols..(i + 1) * cols]
    }
}

fn shape_string(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Parses the bytes of a `.npy` file. Errors are plain messages; callers add the path.
pub fn parse_npy(bytes: &[u8]) -> Result<NpyArray, String> {
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err("not a .npy file (missing the \\x93NUMPY magic)".into());
    }
    let major = bytes[6];
    let (header_len, header_start): (usize, usize) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            let b = bytes.get(8..12).ok_or("truncated .npy header")?;
            (u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize, 12)
        }
        v => {
            return Err(format!(
                "unsupported .npy format version {v} (1, 2 and 3 are supported)"
            ));
        }
    };
    let header_end = header_start
        .checked_add(header_len)
        .filter(|&end| end <= bytes.len())
        .ok_or_else(|| format!("truncated .npy header (it claims {header_len} bytes, the file holds {})", bytes.len()))?;
    let header = &bytes[header_start..header_end];
    let header = std::str::from_utf8(header).map_err(|_| "the .npy header is not text")?;
    let Header { dtype, big_endian, fortran, shape } = parse_header(header)?;
    // A header can claim any shape: the byte count must not overflow (it wrapped and
    // passed the size check before, then failed allocating with "capacity overflow").
    let body = &bytes[header_end..];
    let count = shape.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
    let expected = count.and_then(|n| n.checked_mul(dtype.size())).ok_or_else(|| {
        format!("header claims shape {}, more bytes than memory can hold (corrupt file)", shape_string(&shape))
    })?;
    if body.len() != expected {
        let what = if body.len() < expected { "truncated or corrupt file" } else { "trailing bytes: corrupt file" };
        return Err(format!(
            "data section holds {} bytes but shape {} of {dtype:?} needs {expected} ({what})",
            body.len(),
            shape_string(&shape)
        ));
    }
    let size = dtype.size();
    let mut element = [0u8; 8];
    let mut data: Vec<f64> = body
        .chunks_exact(size)
        .map(|c| {
            element[..size].copy_from_slice(c);
            if big_endian {
                element[..size].reverse();
            }
            dtype.decode_le(&element[..size])
        })
        .collect();
    if fortran && shape.len() > 1 {
        data = fortran_to_c(&data, &shape);
    }
    Ok(NpyArray { shape, dtype, data })
}

/// Reorders the values of a Fortran-order (first index fastest) array into C order.
fn fortran_to_c(data: &[f64], shape: &[usize]) -> Vec<f64> {
    let mut out = Vec::with_capacity(data.len());
    // Walk C order with a multi-index; the Fortran offset is sum(i_k * prod(shape[..k])).
    let mut strides = Vec::with_capacity(shape.len());
    let mut s = 1usize;
    for &d in shape {
        strides.push(s);
        s *= d;
    }
    let mut index = vec![0usize; shape.len()];
    for _ in 0..data.len() {
        out.push(data[index.iter().zip(&strides).map(|(i, s)| i * s).sum::<usize>()]);
        for k in (0..shape.len()).rev() {
            index[k] += 1;
            if index[k] < shape[k] {
                break;
            }
            index[k] = 0;
        }
    }
    out
}

/// What the header dict says.
struct Header {
    dtype: DType,
    big_endian: bool,
    fortran: bool,
    shape: Vec<usize>,
}

/// Parses the Python dict literal of the header: `descr`, `fortran_order`, `shape`.
fn parse_header(header: &str) -> Result<Header, String> {
    let descr = dict_value(header, "descr")?;
    let descr = descr
        .strip_prefix('\'')
        .and_then(|d| d.split('\'').next())
        .or_else(|| descr.strip_prefix('"').and_then(|d| d.split('"').next()))
        .ok_or_else(|| format!("cannot read 'descr' in header {header:?} (structured arrays are not supported)"))?;
    let unsupported = || {
        format!(
            "dtype '{descr}' is not supported (expected a number: bool, int, uint or float of 1 to 8 bytes); \
             convert with a.astype('<f8')"
        )
    };
    let (order, code) = match descr.split_at_checked(1) {
        Some((o @ ("<" | ">" | "|" | "="), code)) => (o, code),
        _ => ("=", descr),
    };
    let dtype = DType::from_code(code).ok_or_else(unsupported)?;
    let big_endian = order == ">" || (order == "=" && cfg!(target_endian = "big"));
    let fortran = match dict_value(header, "fortran_order")? {
        v if v.starts_with("True") => true,
        v if v.starts_with("False") => false,
        _ => return Err(format!("cannot read 'fortran_order' in header {header:?}")),
    };
    let shape_src = dict_value(header, "shape")?;
    let inner = shape_src
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| format!("cannot read 'shape' in header {header:?}"))?;
    let shape = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.trim_end_matches('L').parse::<usize>())
        .collect::<Result<Vec<_>, _>>()
        .map_err(|_| format!("cannot read 'shape' in header {header:?}"))?;
    Ok(Header { dtype, big_endian, fortran, shape })
}

/// The text right after `'key':` in the header dict (leading spaces skipped).
fn dict_value<'a>(header: &'a str, key: &str) -> Result<&'a str, String> {
    let pos = header
        .find(&format!("'{key}'"))
        .or_else(|| header.find(&format!("\"{key}\"")))
        .ok_or_else(|| format!("header has no '{key}' entry: {header:?}"))?;
    let rest = header[pos + key.len() + 2..].trim_start();
    rest.strip_prefix(':')
        .map(str::trim_start)
        .ok_or_else(|| format!("cannot read '{key}' in header {header:?}"))
}

/// Reads a `.npy` file.
pub fn read_npy(path: &Path) -> Result<NpyArray, DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    parse_npy(&bytes).map_err(|message| DataError::Npy {
        path: path.to_path_buf(),
        message,
    })
}

/// Serialises a C-order little-endian `f64` array as `.npy` (format version 1).
/// Panics if `data.len()` is not the product of `shape` (a caller bug).
pub fn npy_bytes_f64(shape: &[usize], data: &[f64]) -> Vec<u8> {
    assert_eq!(
        shape.iter().product::<usize>(),
        data.len(),
        "npy_bytes_f64: shape does not match data"
    );
    let mut header = format!(
        "{{'descr': '<f8', 'fortran_order': False, 'shape': {}, }}",
        shape_string(shape)
    );
    // Pad so that magic + version + length + header (with its newline) is a multiple of 64.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 8);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Writes a C-order `f64` array as a `.npy` file.
pub fn write_npy_f64(path: &Path, shape: &[usize], data: &[f64]) -> Result<(), DataError> {
    std::fs::write(path, npy_bytes_f64(shape, data)).map_err(|e| DataError::io(path, e))
}

/// Writes `f64` arrays as an uncompressed `.npz` archive (what `np.savez` writes).
pub fn write_npz_f64(path: &Path, arrays: &[(&str, &[usize], &[f64])]) -> Result<(), DataError> {
    let bad = |e: zip::result::ZipError| DataError::Npy {
        path: path.to_path_buf(),
        message: format!("cannot write archive: {e}"),
    };
    let file = std::fs::File::create(path).map_err(|e| DataError::io(path, e))?;
    let mut zip = zip::ZipWriter::new(std::io::BufWriter::new(file));
    let options =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    for (name, shape, data) in arrays {
        zip.start_file(format!("{name}.npy"), options)
            .map_err(bad)?;
        std::io::Write::write_all(&mut zip, &npy_bytes_f64(shape, data))
            .map_err(|e| DataError::io(path, e))?;
    }
    let mut inner = zip.finish().map_err(bad)?;
    std::io::Write::flush(&mut inner).map_err(|e| DataError::io(path, e))
}

/// All arrays of a `.npz` archive, by name (without the `.npy` suffix).
#[derive(Clone, Debug)]
pub struct Npz {
    path: PathBuf,
    arrays: BTreeMap<String, NpyArray>,
}

impl Npz {
    /// Reads every array of the archive at `path`.
    pub fn read(path: &Path) -> Result<Npz, DataError> {
        let bad = |message: String| DataError::Npy {
            path: path.to_path_buf(),
            message,
        };
        let file = std::fs::File::open(path).map_err(|e| DataError::io(path, e))?;
        let mut archive = zip::ZipArchive::new(std::io::BufReader::new(file))
            .map_err(|e| bad(format!("not a valid .npz (zip) archive: {e}")))?;
        let mut arrays = BTreeMap::new();
        for i in 0..archive.len() {
            let mut entry = archive
                .by_index(i)
                .map_err(|e| bad(format!("cannot read archive entry {i}: {e}")))?;
            let name = entry.name().to_string();
            let Some(key) = name.strip_suffix(".npy") else {
                continue;
            };
            // The entry's size is the archive's claim: read no more than the cap (a
            // hostile size must not reserve memory, a zip bomb must not fill it).
            if entry.size() > MAX_NPZ_ENTRY_BYTES {
                return Err(bad(format!(
                    "{name} claims {} bytes, more than the {MAX_NPZ_ENTRY_BYTES} this reader accepts (corrupt archive?)",
                    entry.size()
                )));
            }
            let mut bytes = Vec::new();
            (&mut entry)
                .take(MAX_NPZ_ENTRY_BYTES + 1)
                .read_to_end(&mut bytes)
                .map_err(|e| bad(format!("cannot read {name}: {e}")))?;
            if bytes.len() as u64 > MAX_NPZ_ENTRY_BYTES {
                return Err(bad(format!("{name} decompresses to more than {MAX_NPZ_ENTRY_BYTES} bytes (corrupt archive?)")));
            }
            let array = parse_npy(&bytes).map_err(|m| bad(format!("{name}: {m}")))?;
            arrays.insert(key.to_string(), array);
        }
        Ok(Npz {
            path: path.to_path_buf(),
            arrays,
        })
    }

    /// The archive's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Array `name`, or `None`.
    pub fn get(&self, name: &str) -> Option<&NpyArray> {
        self.arrays.get(name)
    }

    /// Array `name`, or an error that names the archive and the missing key.
    pub fn require(&self, name: &str) -> Result<&NpyArray, DataError> {
        self.get(name).ok_or_else(|| DataError::Npy {
            path: self.path.clone(),
            message: format!(
                "the archive has no array '{name}' (it holds {} arrays)",
                self.arrays.len()
            ),
        })
    }

    /// Names of all arrays, sorted.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.arrays.keys().map(String::as_str)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Builds a version-`major` `.npy` byte string from a header dict and raw data.
    fn hand_built(major: u8, dict: &str, body: &[u8]) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        out.extend_from_slice(&[major, 0]);
        let header = format!("{dict}   \n");
        if major == 1 {
            out.extend_from_slice(&(header.len() as u16).to_le_bytes());
        } else {
            out.extend_from_slice(&(header.len() as u32).to_le_bytes());
        }
        out.extend_from_slice(header.as_bytes());
        out.extend_from_slice(body);
        out
    }

    #[test]
    fn reads_hand_built_v1_f4() {
        let body: Vec<u8> = [1.5f32, -2.0, 3.25, 4.0, 5.0, 6.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let bytes = hand_built(
            1,
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }",
            &body,
        );
        let a = parse_npy(&bytes).unwrap();
        assert_eq!(a.shape, vec![2, 3]);
        assert_eq!(a.dtype, DType::F4);
        assert_eq!(a.data, vec![1.5, -2.0, 3.25, 4.0, 5.0, 6.0]);
        assert_eq!(a.row(1), &[4.0, 5.0, 6.0]);
    }

    #[test]
    fn reads_v2_v3_and_integers() {
        let body: Vec<u8> = [7i64, -8].iter().flat_map(|v| v.to_le_bytes()).collect();
        let a = parse_npy(&hand_built(
            2,
            "{'descr': '<i8', 'fortran_order': False, 'shape': (2,), }",
            &body,
        ))
        .unwrap();
        assert_eq!(
            (a.shape.clone(), a.data.clone()),
            (vec![2], vec![7.0, -8.0])
        );
        let body: Vec<u8> = [3i32].iter().flat_map(|v| v.to_le_bytes()).collect();
        let a = parse_npy(&hand_built(
            3,
            "{'descr': '<i4', 'fortran_order': False, 'shape': (), }",
            &body,
        ))
        .unwrap();
        assert_eq!((a.shape.clone(), a.data.clone()), (vec![], vec![3.0]));
    }

    #[test]
    fn a_header_claiming_a_huge_shape_is_an_error_not_an_overflow() {
        // 4 * 2^62 * 4 bytes wraps to 0 in 64 bits: an empty body passed the size check.
        let header = "{'descr': '<f4', 'fortran_order': False, 'shape': (4611686018427387904, 4), }";
        let e = parse_npy(&hand_built(1, header, &[])).unwrap_err();
        assert!(e.contains("more bytes than memory can hold"), "{e}");
    }

    #[test]
    fn writer_round_trips() {
        let data: Vec<f64> = (0..34).map(|i| i as f64 * 0.5 - 3.0).collect();
        let bytes = npy_bytes_f64(&[2, 17], &data);
        assert_eq!(
            bytes.len() % 64,
            (34 * 8) % 64,
            "header is padded to 64 bytes"
        );
        let a = parse_npy(&bytes).unwrap();
        assert_eq!(
            (a.shape, a.dtype, a.data),
            (vec![2, 17], DType::F8, data.clone())
        );

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.npz");
        write_npz_f64(
            &path,
            &[
                ("poses", &[2, 17], &data),
                ("eye", &[2, 2], &[1.0, 0.0, 0.0, 1.0]),
            ],
        )
        .unwrap();
        let npz = Npz::read(&path).unwrap();
        assert_eq!(npz.names().collect::<Vec<_>>(), ["eye", "poses"]);
        assert_eq!(npz.require("poses").unwrap().data, data);
        let msg = npz.require("world_mat_0").unwrap_err().to_string();
        assert!(
            msg.contains("a.npz") && msg.contains("world_mat_0"),
            "{msg}"
        );
    }

    #[test]
    fn reads_every_numeric_dtype_in_either_byte_order() {
        let v1 = "{'descr': 'D', 'fortran_order': False, 'shape': (2,), }";
        let cases: [(&str, Vec<u8>, [f64; 2]); 8] = [
            ("|u1", vec![3, 250], [3.0, 250.0]),
            ("|i1", vec![3, 0xff], [3.0, -1.0]),
            ("|b1", vec![0, 1], [0.0, 1.0]),
            ("<u2", [7u16, 65535].iter().flat_map(|v| v.to_le_bytes()).collect(), [7.0, 65535.0]),
            (">i2", [-7i16, 300].iter().flat_map(|v| v.to_be_bytes()).collect(), [-7.0, 300.0]),
            ("<f2", [0x3c00u16, 0xc000].iter().flat_map(|v| v.to_le_bytes()).collect(), [1.0, -2.0]),
            (">f8", [0.25f64, -3.5].iter().flat_map(|v| v.to_be_bytes()).collect(), [0.25, -3.5]),
            (">u4", [1u32, 4_000_000_000].iter().flat_map(|v| v.to_be_bytes()).collect(), [1.0, 4e9]),
        ];
        for (descr, body, want) in cases {
            let a = parse_npy(&hand_built(1, &v1.replace('D', descr), &body)).unwrap_or_else(|e| panic!("{descr}: {e}"));
            assert_eq!(a.data, want, "{descr}");
        }
    }

    #[test]
    fn fortran_order_is_transposed_to_c_order() {
        // The 2x3 array [[1, 2, 3], [4, 5, 6]] stored column by column.
        let body: Vec<u8> = [1.0f64, 4.0, 2.0, 5.0, 3.0, 6.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        let a = parse_npy(&hand_built(1, "{'descr': '<f8', 'fortran_order': True, 'shape': (2, 3), }", &body)).unwrap();
        assert_eq!((a.shape.clone(), a.data.clone()), (vec![2, 3], vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]));
        // 2x2x2: element (i, j, k) at Fortran offset i + 2j + 4k holds 100i + 10j + k.
        let mut f = [0.0f64; 8];
        for (i, j, k) in (0..8).map(|n| (n / 4, (n / 2) % 2, n % 2)) {
            f[i + 2 * j + 4 * k] = (100 * i + 10 * j + k) as f64;
        }
        let body: Vec<u8> = f.iter().flat_map(|v| v.to_le_bytes()).collect();
        let a = parse_npy(&hand_built(2, "{'descr': '<f8', 'fortran_order': True, 'shape': (2, 2, 2), }", &body)).unwrap();
        assert_eq!(a.data, [0.0, 1.0, 10.0, 11.0, 100.0, 101.0, 110.0, 111.0]);
    }

    #[test]
    fn rejects_unsupported_layouts() {
        let body = [0u8; 8];
        for descr in ["<U2", "<c16", "|O", "<M8[s]"] {
            let dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': (1,), }}");
            let err = parse_npy(&hand_built(1, &dict, &body)).unwrap_err();
            assert!(err.contains("not supported") && err.contains(descr), "{descr}: {err}");
        }
        let err = parse_npy(&hand_built(
            1,
            "{'descr': [('a', '<f8')], 'fortran_order': False, 'shape': (1,), }",
            &body,
        ));
        assert!(err.unwrap_err().contains("structured"));
        let err = parse_npy(&hand_built(
            1,
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2,), }",
            &body,
        ));
        assert!(err.unwrap_err().contains("truncated"));
        let err = parse_npy(&hand_built(
            1,
            "{'descr': '<f4', 'fortran_order': False, 'shape': (1,), }",
            &body,
        ));
        assert!(err.unwrap_err().contains("trailing bytes"));
        // A header length past the end of the file (v2: a u32 length).
        let mut bytes = hand_built(2, "{'descr': '<f8', 'fortran_order': False, 'shape': (1,), }", &body);
        bytes[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(parse_npy(&bytes).unwrap_err().contains("truncated .npy header"));
        assert!(
            parse_npy(b"PK\x03\x04 not npy")
                .unwrap_err()
                .contains("magic")
        );
    }

    #[test]
    fn npz_entries_claiming_more_than_the_cap_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.npz");
        write_npz_f64(&path, &[("x", &[2], &[1.0, 2.0])]).unwrap();
        // Patch the uncompressed size in the local header and the central directory.
        let mut bytes = std::fs::read(&path).unwrap();
        let size = npy_bytes_f64(&[2], &[1.0, 2.0]).len() as u32;
        let mut patched = 0;
        for sig in [&b"PK\x03\x04"[..], &b"PK\x01\x02"[..]] {
            let at = bytes.windows(4).position(|w| w == sig).unwrap();
            let off = at + if sig[2] == 3 { 22 } else { 24 };
            assert_eq!(u32::from_le_bytes(bytes[off..off + 4].try_into().unwrap()), size);
            bytes[off..off + 4].copy_from_slice(&u32::MAX.to_le_bytes());
            patched += 1;
        }
        assert_eq!(patched, 2);
        std::fs::write(&path, &bytes).unwrap();
        let msg = Npz::read(&path).unwrap_err().to_string();
        assert!(msg.contains("a.npz") && msg.contains("x.npy") && msg.contains("claims"), "{msg}");
    }

    #[test]
    fn shape_check_names_path() {
        let a = NpyArray {
            shape: vec![20, 15],
            dtype: DType::F8,
            data: vec![0.0; 300],
        };
        assert!(
            a.expect_shape(Path::new("x.npy"), "poses", &[None, Some(15)])
                .is_ok()
        );
        let msg = a
            .expect_shape(Path::new("x.npy"), "poses", &[None, Some(17)])
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("x.npy") && msg.contains("(20, 15)") && msg.contains("(N, 17)"),
            "{msg}"
        );
    }
}
