//! Image files AFM users open directly: Gwyddion Simple Field (`.gsf`) and NumPy (`.npy`,
//! with a companion `.json`). Pure functions from an image (row 0 at the top) and its
//! [`Metadata`] to bytes.

use std::time::{SystemTime, UNIX_EPOCH};

use serde_json::{Map, Value, json};

use super::ImageFrame;

/// What a file says about how it was made: ftafm's version, when, which frame, and every
/// setting of the instrument (node path → value, as `list` gives them).
#[derive(Clone, Debug, PartialEq)]
pub struct Metadata {
    /// ftafm's version.
    pub version: &'static str,
    /// When the file was made, UTC, ISO 8601 (`2026-11-24T20:15:03Z`).
    pub date: String,
    /// The scan's generation (bumps when its settings change) and frame number.
    pub generation: u32,
    pub frame: u64,
    /// Every node of the settings when the frame finished.
    pub settings: Vec<(String, Value)>,
}

impl Metadata {
    /// The metadata of `frame`, made at `now`.
    pub fn of(frame: &ImageFrame, now: SystemTime) -> Self {
        Self {
            version: env!("CARGO_PKG_VERSION"),
            date: iso8601_utc(now),
            generation: frame.generation,
            frame: frame.frame,
            settings: frame
                .settings
                .nodes()
                .into_iter()
                .map(|n| (n.path, n.value))
                .collect(),
        }
    }
}

/// `2026-11-24T20:15:03Z` for `t` (whole seconds, UTC; the epoch for times before it).
pub fn iso8601_utc(t: SystemTime) -> String {
    let secs = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let (days, rest) = (secs / 86_400, secs % 86_400);
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm, proleptic Gregorian).
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rest / 3600,
        rest / 60 % 60,
        rest % 60
    )
}

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
/// The metadata follow as further `key = value` lines, which Gwyddion shows as the
/// channel's metadata: `ftafm.version`, `ftafm.date`, `ftafm.generation`, `ftafm.frame`,
/// and one `ftafm:/node/path = value` per setting (JSON values).
pub fn gsf(
    channel: &ImageChannel,
    pixels: u32,
    size: f64,
    origin: (f64, f64),
    meta: &Metadata,
) -> Vec<u8> {
    let unit = match channel.unit {
        "1" => "",
        u => u,
    };
    let mut text = format!(
        "Gwyddion Simple Field 1.0\nXRes = {pixels}\nYRes = {pixels}\nXReal = {size:e}\nYReal = {size:e}\nXOffset = {:e}\nYOffset = {:e}\nXYUnits = m\nZUnits = {unit}\nTitle = {}\n",
        origin.0, origin.1, channel.name
    );
    text.push_str(&format!(
        "ftafm.version = {}\nftafm.date = {}\nftafm.generation = {}\nftafm.frame = {}\n",
        meta.version, meta.date, meta.generation, meta.frame
    ));
    for (path, value) in &meta.settings {
        // JSON has no raw newlines, and a header line must not hold one.
        text.push_str(&format!("ftafm:{path} = {value}\n"));
    }
    let mut header = text.into_bytes();
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

/// The `.npy` file's companion `.json`: what NumPy's header cannot say (the channel's unit,
/// the pixel size and origin, the metadata).
pub fn npy_companion(
    channel: &ImageChannel,
    pixels: u32,
    size: f64,
    origin: (f64, f64),
    meta: &Metadata,
) -> String {
    let settings: Map<String, Value> = meta.settings.iter().cloned().collect();
    let doc = json!({
        "channel": channel.name,
        "unit": channel.unit,
        "shape": [pixels, pixels],
        "row_0": "top (largest y)",
        "size_m": size,
        "origin_m": [origin.0, origin.1],
        "pixel_m": size / f64::from(pixels.max(1)),
        "ftafm_version": meta.version,
        "date": meta.date,
        "generation": meta.generation,
        "frame": meta.frame,
        "settings": settings,
    });
    serde_json::to_string_pretty(&doc).expect("plain values") + "\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta() -> Metadata {
        Metadata {
            version: "9.9.9",
            date: "2026-11-24T20:15:03Z".into(),
            generation: 2,
            frame: 5,
            settings: vec![
                ("/sample/youngs_modulus".into(), json!(129e9)),
                ("/synth/engine".into(), json!("paper")),
            ],
        }
    }

    #[test]
    fn dates_are_iso_8601_utc() {
        let at = |s: u64| iso8601_utc(UNIX_EPOCH + std::time::Duration::from_secs(s));
        assert_eq!(at(0), "1970-01-01T00:00:00Z");
        // 2000-02-29 (a leap day of a century leap year) 12:34:56.
        assert_eq!(at(951_827_696), "2000-02-29T12:34:56Z");
        assert_eq!(at(1_795_551_303), "2026-11-24T20:15:03Z");
    }

    #[test]
    fn the_companion_json_carries_unit_geometry_and_settings() {
        let text = npy_companion(&channel(), 3, 1e-6, (-5e-7, -5e-7), &meta());
        let v: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["unit"], "m");
        assert_eq!(v["shape"], json!([3, 3]));
        assert_eq!(v["date"], "2026-11-24T20:15:03Z");
        assert_eq!(v["ftafm_version"], "9.9.9");
        assert_eq!(v["settings"]["/sample/youngs_modulus"], 129e9);
    }

    fn channel() -> ImageChannel {
        ImageChannel {
            name: "h17".into(),
            unit: "m",
            data: (0..9).map(|i| i as f64 * 1e-12).collect(),
        }
    }

    #[test]
    fn gsf_has_its_header_padding_and_data() {
        let bytes = gsf(&channel(), 3, 1e-6, (-5e-7, -5e-7), &meta());
        let nul = bytes.iter().position(|&b| b == 0).unwrap();
        let header = std::str::from_utf8(&bytes[..nul]).unwrap();
        assert!(header.starts_with("Gwyddion Simple Field 1.0\n"));
        for line in [
            "XRes = 3",
            "YRes = 3",
            "XReal = 1e-6",
            "XYUnits = m",
            "ZUnits = m",
            "ftafm.version = 9.9.9",
            "ftafm.date = 2026-11-24T20:15:03Z",
            "ftafm.frame = 5",
            "ftafm:/sample/youngs_modulus = 129000000000.0",
            "ftafm:/synth/engine = \"paper\"",
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
