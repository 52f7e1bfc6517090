//! NumPy `.npy` files, version 1.0/2.0: the header parse of the reader and a writer that
//! streams rows and fills the row count in at the end (so nothing is held in memory).

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::Path;

/// Element types the reader takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dtype {
    I16,
    I32,
    F32,
    F64,
}

impl Dtype {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            Dtype::I16 => 2,
            Dtype::I32 | Dtype::F32 => 4,
            Dtype::F64 => 8,
        }
    }
}

/// What a `.npy` header says: the element type, the shape, and where the data begins.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    pub dtype: Dtype,
    pub shape: Vec<u64>,
    /// Bytes from the start of the file to the first element.
    pub data_offset: u64,
}

/// Reads and checks the header at the start of `r`; the error says what is wrong and what
/// the reader takes.
pub fn read_header(r: &mut impl Read) -> Result<Header, String> {
    let mut magic = [0u8; 8];
    r.read_exact(&mut magic)
        .map_err(|_| "too short for a .npy file (no 8-byte magic)".to_owned())?;
    if &magic[..6] != b"\x93NUMPY" {
        return Err("not a .npy file (its magic is not \\x93NUMPY)".to_owned());
    }
    let (len, prefix) = match magic[6] {
        1 => {
            let mut b = [0u8; 2];
            r.read_exact(&mut b).map_err(|_| "truncated .npy header")?;
            (u64::from(u16::from_le_bytes(b)), 10)
        }
        2 | 3 => {
            let mut b = [0u8; 4];
            r.read_exact(&mut b).map_err(|_| "truncated .npy header")?;
            (u64::from(u32::from_le_bytes(b)), 12)
        }
        v => {
            return Err(format!(
                ".npy format version {v} is not supported (1, 2 or 3)"
            ));
        }
    };
    if len > 1 << 20 {
        return Err(format!(".npy header of {len} bytes: not a plain array"));
    }
    let mut text = vec![0u8; len as usize];
    r.read_exact(&mut text)
        .map_err(|_| "truncated .npy header".to_owned())?;
    let text = String::from_utf8_lossy(&text);
    let field = |key: &str| -> Result<String, String> {
        let at = text
            .find(&format!("'{key}'"))
            .ok_or_else(|| format!(".npy header has no '{key}'"))?;
        let rest = text[at + key.len() + 2..].trim_start();
        let rest = rest
            .strip_prefix(':')
            .ok_or_else(|| format!(".npy header: no ':' after '{key}'"))?
            .trim_start();
        let end = if rest.starts_with('(') {
            rest.find(')').map(|i| i + 1)
        } else {
            rest.find([',', '}'])
        }
        .ok_or_else(|| format!(".npy header: '{key}' has no end"))?;
        Ok(rest[..end].trim().to_owned())
    };
    let descr = field("descr")?;
    let descr = descr.trim_matches(|c| c == '\'' || c == '"');
    let dtype = match descr {
        "<i2" => Dtype::I16,
        "<i4" => Dtype::I32,
        "<f4" => Dtype::F32,
        "<f8" => Dtype::F64,
        other => {
            return Err(format!(
                "element type {other:?} is not supported: little-endian int16, int32, float32 \
                 or float64 ('<i2', '<i4', '<f4', '<f8'; convert with arr.astype)"
            ));
        }
    };
    if field("fortran_order")? != "False" {
        return Err(
            "Fortran-order arrays are not supported: save a C-order array (np.ascontiguousarray)"
                .to_owned(),
        );
    }
    let shape = field("shape")?;
    let shape: Vec<u64> = shape
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<u64>()
                .map_err(|_| format!(".npy shape {shape}: not integers"))
        })
        .collect::<Result<_, _>>()?;
    if !(1..=2).contains(&shape.len()) {
        return Err(format!(
            "a {}-D array: the reader takes 1-D (one channel) or 2-D (samples × channels)",
            shape.len()
        ));
    }
    Ok(Header {
        dtype,
        shape,
        data_offset: prefix + len,
    })
}

/// A `.npy` file written row by row: the header is written with room for the final row
/// count and rewritten by [`finish`](Self::finish).
pub struct NpyWriter {
    out: BufWriter<File>,
    descr: String,
    /// Shape after the first axis, as NumPy writes it (e.g. `""` or `", 2049"`).
    tail: String,
    rows: u64,
    header_len: usize,
}

/// Header bytes including magic, padded to a multiple of 64 with room for any u64 count.
fn header_bytes(descr: &str, rows: u64, tail: &str, len: Option<usize>) -> Vec<u8> {
    let dict = format!("{{'descr': {descr}, 'fortran_order': False, 'shape': ({rows},{tail}), }}");
    // Room for a 20-digit count whatever the current one.
    let min = 10 + dict.len() + 1 + 24;
    let total = len.unwrap_or(min.div_ceil(64) * 64);
    let mut h = b"\x93NUMPY\x01\x00".to_vec();
    h.extend_from_slice(&((total - 10) as u16).to_le_bytes());
    h.extend_from_slice(dict.as_bytes());
    h.resize(total - 1, b' ');
    h.push(b'\n');
    h
}

impl NpyWriter {
    /// Creates `path` for rows of NumPy type `descr` (its repr, e.g. `'<f8'` or
    /// `[('t', '<f8'), ...]`) and trailing shape `tail` (e.g. `""` or `" 2049"`).
    pub fn create(path: &Path, descr: &str, tail: &str) -> std::io::Result<Self> {
        let mut out = BufWriter::new(File::create(path)?);
        let tail = if tail.is_empty() {
            String::new()
        } else {
            format!(" {}", tail.trim())
        };
        let h = header_bytes(descr, 0, &tail, None);
        out.write_all(&h)?;
        Ok(Self {
            out,
            descr: descr.to_owned(),
            tail,
            rows: 0,
            header_len: h.len(),
        })
    }

    /// Appends one row's bytes (little-endian, laid out as `descr`).
    pub fn row(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.rows += 1;
        self.out.write_all(bytes)
    }

    /// Rows written.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// Writes the final row count into the header and closes the file.
    pub fn finish(mut self) -> std::io::Result<u64> {
        let h = header_bytes(&self.descr, self.rows, &self.tail, Some(self.header_len));
        self.out.seek(SeekFrom::Start(0))?;
        self.out.write_all(&h)?;
        self.out.flush()?;
        Ok(self.rows)
    }
}

/// Writes a whole 1-D or 2-D float64 array (`shape`, C order) to `path`.
pub fn write_f64(path: &Path, shape: &[usize], data: &[f64]) -> std::io::Result<()> {
    let tail = shape[1..]
        .iter()
        .map(|n| n.to_string())
        .collect::<Vec<_>>()
        .join(", ");
    let mut w = NpyWriter::create(path, "'<f8'", &tail)?;
    let per_row = shape[1..].iter().product::<usize>().max(1);
    let mut bytes = Vec::with_capacity(per_row * 8);
    for row in data.chunks(per_row) {
        bytes.clear();
        for v in row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        w.row(&bytes)?;
    }
    w.finish()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_array_reads_back_with_its_shape() {
        let dir = std::env::temp_dir().join(format!("ftafm-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.npy");
        let data: Vec<f64> = (0..6).map(f64::from).collect();
        write_f64(&path, &[3, 2], &data).unwrap();
        let mut f = File::open(&path).unwrap();
        let h = read_header(&mut f).unwrap();
        assert_eq!(h.dtype, Dtype::F64);
        assert_eq!(h.shape, vec![3, 2]);
        assert_eq!(h.data_offset % 64, 0);
        let mut rest = Vec::new();
        f.read_to_end(&mut rest).unwrap();
        assert_eq!(rest.len(), 48);
        assert_eq!(f64::from_le_bytes(rest[40..48].try_into().unwrap()), 5.0);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn unsupported_headers_are_refused_with_what_is_allowed() {
        let mut h = header_bytes("'>f8'", 4, "", None);
        h.extend([0u8; 32]);
        let e = read_header(&mut &h[..]).unwrap_err();
        assert!(e.contains("'<f8'"), "{e}");
        let e = read_header(&mut &b"hello world"[..]).unwrap_err();
        assert!(e.contains("magic"), "{e}");
        let h = header_bytes("'<f4'", 4, " 2, 3", None);
        assert!(read_header(&mut &h[..]).unwrap_err().contains("3-D"));
    }
}
