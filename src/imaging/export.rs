//! Image files AFM users open directly: Gwyddion Simple Field (`.gsf`) and NumPy (`.npy`).
//! Pure functions from an image (row 0 at the top) to bytes.

/// One channel of a finished frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageChannel {
    /// Channel name (`height`, `h17`, …).
    pub name: String,
    /// SI unit of the values (`m`, `rad`, `Pa`, `N`, `1`).
    pub unit: &'static str,
    /// `pixels × pixels` values, row-major, row 0 at the top; NaN where a pixel is missing.
    pub data: Vec<f64>,
}

/// Gwyddion Simple Field 1.0: a text header of `key = value` lines, NUL padding to a
/// multiple of 4 bytes (at least one NUL), then `xres × yres` little-endian f32 values,
/// row-major, first row at the top. `size` is the side of the square image (m).
pub fn gsf(channel: &ImageChannel, pixels: u32, size: f64, origin: (f64, f64)) -> Vec<u8> {
    let unit = match channel.unit {
        "1" => "",
        u => u,
    };
    let mut header = format!(
        "Gwyddion Simple Field 1.0\nXRes = {pixels}\nYRes = {pixels}\nXReal = {size:e}\nYReal = {size:e}\nXOffset = {:e}\nYOffset = {:e}\nXYUnits = m\nZUnits = {unit}\nTitle = {}\n",
        origin.0, origin.1, channel.name
    )
    .into_bytes();
    let pad = 4 - header.len() % 4;
    header.extend(std::iter::repeat_n(0u8, pad));
    header.reserve(channel.data.len() * 4);
    for v in &channel.data {
        header.extend_from_slice(&(*v as f32).to_le_bytes());
    }
    header
}

/// NumPy `.npy` version 1.0: magic, header length, a Python dict literal describing a
/// little-endian f64 array of shape (pixels, pixels) in C order, padded with spaces and a
/// newline to a multiple of 64 bytes, then the data, row 0 at the top.
pub fn npy(channel: &ImageChannel, pixels: u32) -> Vec<u8> {
    let dict =
        format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({pixels}, {pixels}), }}");
    let unpadded = 10 + dict.len() + 1;
    let total = unpadded.div_ceil(64) * 64;
    let mut out = Vec::with_capacity(total + channel.data.len() * 8);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&((total - 10) as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out.extend(std::iter::repeat_n(b' ', total - unpadded));
    out.push(b'\n');
    for v in &channel.data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel() -> ImageChannel {
        ImageChannel {
            name: "h17".into(),
            unit: "m",
            data: (0..9).map(|i| i as f64 * 1e-12).collect(),
        }
    }

    #[test]
    fn gsf_has_its_header_padding_and_data() {
        let bytes = gsf(&channel(), 3, 1e-6, (-5e-7, -5e-7));
        let nul = bytes.iter().position(|&b| b == 0).unwrap();
        let header = std::str::from_utf8(&bytes[..nul]).unwrap();
        assert!(header.starts_with("Gwyddion Simple Field 1.0\n"));
        for line in [
            "XRes = 3",
            "YRes = 3",
            "XReal = 1e-6",
            "XYUnits = m",
            "ZUnits = m",
            "Title = h17",
        ] {
            assert!(header.lines().any(|l| l == line), "{line} in {header}");
        }
        let data_start = bytes.len() - 9 * 4;
        assert_eq!(data_start % 4, 0);
        assert!(data_start > nul && bytes[nul..data_start].iter().all(|&b| b == 0));
        let last = f32::from_le_bytes(bytes[bytes.len() - 4..].try_into().unwrap());
        assert_eq!(last, 8e-12f32);
    }

    #[test]
    fn npy_header_is_aligned_and_describes_the_array() {
        let bytes = npy(&channel(), 3);
        assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
        let len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + len) % 64, 0);
        let header = std::str::from_utf8(&bytes[10..10 + len]).unwrap();
        assert!(header.contains("'descr': '<f8'") && header.contains("'shape': (3, 3)"));
        assert!(header.ends_with('\n'));
        assert_eq!(bytes.len(), 10 + len + 72);
        let v = f64::from_le_bytes(bytes[10 + len + 8..10 + len + 16].try_into().unwrap());
        assert_eq!(v, 1e-12);
    }
}
