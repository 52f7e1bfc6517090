//! Sample sources for `ftafm analyse`, read in pieces (never a whole file): NumPy `.npy`,
//! WAV (through `hound`) and raw little-endian int16/float32 (a file or standard input).

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use super::npy::{self, Dtype};

/// The file format (`--format`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// From the extension: .npy, .wav; standard input (`-`) needs raw-i16 or raw-f32.
    Auto,
    Npy,
    Wav,
    /// Raw little-endian int16, channels interleaved; needs --sample-rate.
    RawI16,
    /// Raw little-endian float32, channels interleaved; needs --sample-rate.
    RawF32,
}

enum Kind {
    Npy {
        r: BufReader<File>,
        dtype: Dtype,
    },
    Wav {
        r: hound::WavReader<BufReader<File>>,
        float: bool,
        bits: u16,
    },
    Raw {
        r: Box<dyn Read>,
        dtype: Dtype,
    },
}

/// An open recording: its channels, sample rate (if the file has one) and length.
pub struct Source {
    /// The file's name as given, for messages.
    pub name: String,
    /// Channels per sample time.
    pub channels: usize,
    /// Sample rate in the file's header (Hz), WAV only.
    pub sample_rate: Option<f64>,
    /// Sample times in the file, where known (not for standard input).
    pub frames: Option<u64>,
    /// What one unit of the values read is: "file units", or "full scale (±1)" for WAV
    /// integers.
    pub units: &'static str,
    /// Sample times read so far.
    pub read: u64,
    kind: Kind,
    bytes: Vec<u8>,
}

impl Source {
    /// Opens `path` (`-`: standard input) as `format`; `channels` is the count for raw
    /// input (the others have it in their header).
    pub fn open(path: &Path, format: Format, channels: usize) -> Result<Self, String> {
        let name = path.display().to_string();
        let fail = |e: &dyn std::fmt::Display| format!("{name}: {e}");
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let stdin = path.as_os_str() == "-";
        let format = match (format, ext.as_deref()) {
            (Format::Auto, _) if stdin => {
                return Err(
                    "-: standard input has no header: give --format raw-i16 or raw-f32 and \
                     --sample-rate"
                        .to_owned(),
                );
            }
            (Format::Auto, Some("npy")) => Format::Npy,
            (Format::Auto, Some("wav")) => Format::Wav,
            (Format::Auto, _) => {
                return Err(format!(
                    "{name}: cannot tell the format from the extension: give --format \
                     (npy, wav, raw-i16, raw-f32)"
                ));
            }
            (f, _) => f,
        };
        if stdin && matches!(format, Format::Npy | Format::Wav) {
            return Err("-: standard input is read as raw-i16 or raw-f32 only".to_owned());
        }
        let open = || File::open(path).map_err(|e| fail(&e));
        let (kind, channels, sample_rate, frames, units) = match format {
            Format::Npy => {
                let mut r = BufReader::with_capacity(1 << 20, open()?);
                let h = npy::read_header(&mut r).map_err(|e| fail(&e))?;
                let channels = h.shape.get(1).copied().unwrap_or(1) as usize;
                if channels == 0 {
                    return Err(fail(&"the array has 0 channels (shape (n, 0))"));
                }
                let len = std::fs::metadata(path).map_err(|e| fail(&e))?.len();
                let want = h.shape[0] * channels as u64 * h.dtype.size() as u64;
                if len - h.data_offset.min(len) < want {
                    return Err(fail(&format_args!(
                        "truncated: the header says {} samples × {channels} channels ({want} \
                         bytes of data), the file holds {} bytes of data",
                        h.shape[0],
                        len.saturating_sub(h.data_offset)
                    )));
                }
                let kind = Kind::Npy { r, dtype: h.dtype };
                (kind, channels, None, Some(h.shape[0]), "file units")
            }
            Format::Wav => {
                let r = hound::WavReader::new(BufReader::with_capacity(1 << 20, open()?))
                    .map_err(|e| fail(&format_args!("not a WAV file this reader takes: {e}")))?;
                let spec = r.spec();
                let float = spec.sample_format == hound::SampleFormat::Float;
                if !(float && spec.bits_per_sample == 32
                    || !float && matches!(spec.bits_per_sample, 8 | 16 | 24 | 32))
                {
                    return Err(fail(&format_args!(
                        "{}-bit {} samples: the reader takes PCM 16, 24 or 32-bit and IEEE \
                         float 32-bit",
                        spec.bits_per_sample,
                        if float { "float" } else { "integer" }
                    )));
                }
                let frames = u64::from(r.duration());
                let units = if float {
                    "file units"
                } else {
                    "full scale (±1)"
                };
                let kind = Kind::Wav {
                    r,
                    float,
                    bits: spec.bits_per_sample,
                };
                (
                    kind,
                    usize::from(spec.channels),
                    Some(f64::from(spec.sample_rate)),
                    Some(frames),
                    units,
                )
            }
            Format::RawI16 | Format::RawF32 => {
                let dtype = if format == Format::RawI16 {
                    Dtype::I16
                } else {
                    Dtype::F32
                };
                let (r, frames): (Box<dyn Read>, _) = if stdin {
                    (
                        Box::new(BufReader::with_capacity(1 << 20, std::io::stdin())),
                        None,
                    )
                } else {
                    let len = std::fs::metadata(path).map_err(|e| fail(&e))?.len();
                    let frame = (dtype.size() * channels) as u64;
                    if len % frame != 0 {
                        return Err(fail(&format_args!(
                            "{len} bytes is not a whole number of {channels}-channel samples \
                             of {} bytes: truncated, or the wrong --format or --channels",
                            dtype.size()
                        )));
                    }
                    (
                        Box::new(BufReader::with_capacity(1 << 20, open()?)),
                        Some(len / frame),
                    )
                };
                (Kind::Raw { r, dtype }, channels, None, frames, "file units")
            }
            Format::Auto => unreachable!("resolved above"),
        };
        if frames == Some(0) {
            return Err(fail(&"the file holds no samples"));
        }
        Ok(Self {
            name,
            channels,
            sample_rate,
            frames,
            units,
            read: 0,
            kind,
            bytes: Vec::new(),
        })
    }

    /// Reads up to `max` sample times into `out` (cleared; channels interleaved, as f64);
    /// returns how many were read, 0 at the end. A file shorter than its header says is an
    /// error, as is a partial sample at the end of raw input.
    pub fn read(&mut self, out: &mut Vec<f64>, max: usize) -> Result<usize, String> {
        out.clear();
        let want = match self.frames {
            Some(total) => max.min((total - self.read) as usize),
            None => max,
        };
        if want == 0 {
            return Ok(0);
        }
        let values = want * self.channels;
        let name = &self.name;
        match &mut self.kind {
            Kind::Npy { r, dtype } => {
                let n = dtype.size() * values;
                self.bytes.resize(n, 0);
                r.read_exact(&mut self.bytes)
                    .map_err(|e| format!("{name}: reading at sample {}: {e}", self.read))?;
                decode(*dtype, &self.bytes, out);
            }
            Kind::Raw { r, dtype } => {
                let n = dtype.size() * values;
                self.bytes.resize(n, 0);
                let mut got = 0;
                while got < n {
                    match r.read(&mut self.bytes[got..]) {
                        Ok(0) => break,
                        Ok(k) => got += k,
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                        Err(e) => return Err(format!("{name}: {e}")),
                    }
                }
                let frame = dtype.size() * self.channels;
                if got % frame != 0 {
                    return Err(format!(
                        "{name}: the input ends inside a sample ({} bytes after sample {}): \
                         truncated, or the wrong --format or --channels",
                        got % frame,
                        self.read + (got / frame) as u64
                    ));
                }
                decode(*dtype, &self.bytes[..got], out);
            }
            Kind::Wav { r, float, bits } => {
                let at = self.read;
                let err = |e: hound::Error| format!("{name}: reading at sample {at}: {e}");
                if *float {
                    for s in r.samples::<f32>().take(values) {
                        out.push(f64::from(s.map_err(err)?));
                    }
                } else {
                    let full = f64::from(1u32 << (*bits - 1));
                    for s in r.samples::<i32>().take(values) {
                        out.push(f64::from(s.map_err(err)?) / full);
                    }
                }
                if out.len() < values {
                    return Err(format!(
                        "{name}: truncated: the data chunk ends at sample {} of {}",
                        at + (out.len() / self.channels) as u64,
                        self.frames.unwrap_or(0)
                    ));
                }
            }
        }
        let frames = out.len() / self.channels;
        self.read += frames as u64;
        Ok(frames)
    }
}

fn decode(dtype: Dtype, bytes: &[u8], out: &mut Vec<f64>) {
    match dtype {
        Dtype::I16 => out.extend(
            bytes
                .chunks_exact(2)
                .map(|b| f64::from(i16::from_le_bytes([b[0], b[1]]))),
        ),
        Dtype::I32 => out.extend(
            bytes
                .chunks_exact(4)
                .map(|b| f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]]))),
        ),
        Dtype::F32 => out.extend(
            bytes
                .chunks_exact(4)
                .map(|b| f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))),
        ),
        Dtype::F64 => out.extend(
            bytes
                .chunks_exact(8)
                .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes"))),
        ),
    }
}
