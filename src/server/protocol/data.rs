//! Data messages: JSON text and the binary framing (see `docs/protocol.md`, "Binary frames").

use crate::imaging::ImageLine;
use crate::inversion::ForceEstimate;
use crate::pipeline::{DemodFrame, ScopeBuffer, SpectrumBuffer};
use crate::server::status::StatusReport;

use super::StreamKind;
use super::json::JsonBuf;

/// First four bytes of every binary message.
pub const BINARY_MAGIC: [u8; 4] = *b"FTAF";

/// Version of the binary layout, in bytes 4–5 of the header.
pub const BINARY_VERSION: u16 = 1;

/// Size of the binary header (bytes).
pub const BINARY_HEADER_BYTES: usize = 40;

/// Size of one demodulator record in a binary `demods` message (bytes).
pub const DEMOD_RECORD_BYTES: usize = 40;

/// A decoded binary header.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BinaryHeader {
    /// Layout version ([`BINARY_VERSION`] for this server).
    pub version: u16,
    /// Which stream.
    pub stream: StreamKind,
    /// The stream's message counter.
    pub seq: u64,
    /// Simulated time of the newest sample reflected (s).
    pub t: f64,
    /// Unix time (ns) at which that sample was synthesised.
    pub t_synth_ns: u64,
    /// Records (demods), magnitudes (spectrum), samples (scope) or JSON bytes (status).
    pub count: u32,
}

impl BinaryHeader {
    /// Payload size (bytes after the header) this header announces.
    pub fn payload_bytes(&self) -> usize {
        let count = self.count as usize;
        match self.stream {
            StreamKind::Demods => count * DEMOD_RECORD_BYTES,
            StreamKind::Spectrum => 8 + 4 * count,
            StreamKind::Scope => 24 + 4 * count,
            StreamKind::Status | StreamKind::Force | StreamKind::Image | StreamKind::Sweep => count,
        }
    }
}

/// Reads the header of a binary message: `None` when it is shorter than
/// [`BINARY_HEADER_BYTES`], the magic is wrong or the stream code unknown. The version is
/// returned as found (check it); reserved bytes are ignored.
pub fn decode_header(bytes: &[u8]) -> Option<BinaryHeader> {
    let header = bytes.get(..BINARY_HEADER_BYTES)?;
    if header[..4] != BINARY_MAGIC {
        return None;
    }
    let u16_at = |i: usize| u16::from_le_bytes([header[i], header[i + 1]]);
    let u32_at = |i: usize| {
        u32::from_le_bytes(
            header[i..i + 4]
                .try_into()
                .expect("4 bytes of a 40-byte slice"),
        )
    };
    let u64_at = |i: usize| {
        u64::from_le_bytes(
            header[i..i + 8]
                .try_into()
                .expect("8 bytes of a 40-byte slice"),
        )
    };
    Some(BinaryHeader {
        version: u16_at(4),
        stream: StreamKind::from_code(header[6])?,
        seq: u64_at(8),
        t: f64::from_bits(u64_at(16)),
        t_synth_ns: u64_at(24),
        count: u32_at(32),
    })
}

/// `{"stream":"demods","seq":n,"t":s,"t_synth_ns":ns,"demods":[{"index":0,"harmonic":1,
/// "x":m,"y":m,"r":m,"phase":rad},…]}` with `r = hypot(x, y)` and `phase = atan2(y, x)`.
pub fn demods_json(seq: u64, frame: &DemodFrame) -> String {
    let values = frame.values();
    let mut out = JsonBuf::with_capacity(96 + values.len() * 140);
    json_header(&mut out, StreamKind::Demods, seq, frame.t, frame.t_synth_ns);
    out.raw(",\"demods\":[");
    for (i, v) in values.iter().enumerate() {
        out.raw(if i == 0 {
            "{\"index\":"
        } else {
            ",{\"index\":"
        });
        out.u64(u64::from(v.index));
        out.raw(",\"harmonic\":");
        out.u64(u64::from(v.harmonic));
        out.raw(",\"x\":");
        out.f64(v.x);
        out.raw(",\"y\":");
        out.f64(v.y);
        out.raw(",\"r\":");
        out.f64(v.r());
        out.raw(",\"phase\":");
        out.f64(v.phase());
        out.raw("}");
    }
    out.raw("]}");
    out.into_string()
}

/// Header, then per demodulator: index u32, harmonic u32, x, y, r, phase as f64.
pub fn demods_binary(seq: u64, frame: &DemodFrame) -> Vec<u8> {
    let values = frame.values();
    let count = count_of(values.len());
    let values = &values[..count as usize];
    let mut out = Vec::with_capacity(BINARY_HEADER_BYTES + values.len() * DEMOD_RECORD_BYTES);
    binary_header(
        &mut out,
        StreamKind::Demods,
        seq,
        frame.t,
        frame.t_synth_ns,
        count,
    );
    for v in values {
        out.extend_from_slice(&u32::from(v.index).to_le_bytes());
        out.extend_from_slice(&v.harmonic.to_le_bytes());
        for x in [v.x, v.y, v.r(), v.phase()] {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    out
}

/// `{"stream":"spectrum","seq":n,"t":s,"t_synth_ns":ns,"bin_width":Hz,"magnitudes":[…]}`.
pub fn spectrum_json(seq: u64, s: &SpectrumBuffer) -> String {
    let mut out = JsonBuf::with_capacity(128 + s.magnitudes.len() * 14);
    json_header(&mut out, StreamKind::Spectrum, seq, s.t, s.t_synth_ns);
    out.raw(",\"bin_width\":");
    out.f64(s.bin_width);
    out.raw(",\"magnitudes\":");
    f32_array(&mut out, &s.magnitudes);
    out.raw("}");
    out.into_string()
}

/// Header, then bin_width f64, then `count` f32 magnitudes.
pub fn spectrum_binary(seq: u64, s: &SpectrumBuffer) -> Vec<u8> {
    let count = count_of(s.magnitudes.len());
    let magnitudes = &s.magnitudes[..count as usize];
    let mut out = Vec::with_capacity(BINARY_HEADER_BYTES + 8 + 4 * magnitudes.len());
    binary_header(
        &mut out,
        StreamKind::Spectrum,
        seq,
        s.t,
        s.t_synth_ns,
        count,
    );
    out.extend_from_slice(&s.bin_width.to_le_bytes());
    extend_f32(&mut out, magnitudes);
    out
}

/// `{"stream":"scope","seq":n,"t":s,"t_synth_ns":ns,"dt":s,"start_phase":rad,
/// "phase_step":rad,"samples":[…]}`.
pub fn scope_json(seq: u64, s: &ScopeBuffer) -> String {
    let mut out = JsonBuf::with_capacity(160 + s.samples.len() * 14);
    json_header(&mut out, StreamKind::Scope, seq, s.t, s.t_synth_ns);
    out.raw(",\"dt\":");
    out.f64(s.dt);
    out.raw(",\"start_phase\":");
    out.f64(s.start_phase);
    out.raw(",\"phase_step\":");
    out.f64(s.phase_step);
    out.raw(",\"samples\":");
    f32_array(&mut out, &s.samples);
    out.raw("}");
    out.into_string()
}

/// Header, then dt, start_phase, phase_step as f64, then `count` f32 samples.
pub fn scope_binary(seq: u64, s: &ScopeBuffer) -> Vec<u8> {
    let count = count_of(s.samples.len());
    let samples = &s.samples[..count as usize];
    let mut out = Vec::with_capacity(BINARY_HEADER_BYTES + 24 + 4 * samples.len());
    binary_header(&mut out, StreamKind::Scope, seq, s.t, s.t_synth_ns, count);
    for x in [s.dt, s.start_phase, s.phase_step] {
        out.extend_from_slice(&x.to_le_bytes());
    }
    extend_f32(&mut out, samples);
    out
}

/// `{"stream":"status","seq":n,"t":s,"t_synth_ns":ns,…}` with every field of the
/// [`StatusReport`] at the top level (nested ones, like `counters`, stay objects).
pub fn status_json(seq: u64, t: f64, t_synth_ns: u64, status: &StatusReport) -> String {
    let mut out = JsonBuf::with_capacity(1024);
    json_header(&mut out, StreamKind::Status, seq, t, t_synth_ns);
    // Serialise the report as an object, then splice it in: its `{` becomes the `,` after
    // the header (or, if it is empty, `{}` becomes the closing `}`).
    let start = out.len();
    out.serialize(status);
    if out.tail(start) == b"{}" {
        out.truncate(start);
        out.raw("}");
    } else {
        debug_assert_eq!(out.tail(start).first(), Some(&b'{'));
        out.set_ascii(start, b',');
    }
    out.into_string()
}

/// Header, then `count` bytes of UTF-8: the same JSON object as [`status_json`].
pub fn status_binary(seq: u64, t: f64, t_synth_ns: u64, status: &StatusReport) -> Vec<u8> {
    let json = status_json(seq, t, t_synth_ns, status);
    let count = count_of(json.len());
    let json = &json.as_bytes()[..count as usize];
    let mut out = Vec::with_capacity(BINARY_HEADER_BYTES + json.len());
    binary_header(&mut out, StreamKind::Status, seq, t, t_synth_ns, count);
    out.extend_from_slice(json);
    out
}

/// `{"stream":"force","seq":n,"t":s,"t_synth_ns":ns,…}` with every field of the
/// [`ForceEstimate`] at the top level.
pub fn force_json(seq: u64, estimate: &ForceEstimate) -> String {
    let mut out = JsonBuf::with_capacity(256 + estimate.waveform.len() * 24);
    json_header(
        &mut out,
        StreamKind::Force,
        seq,
        estimate.t,
        estimate.t_synth_ns,
    );
    let start = out.len();
    out.serialize(estimate);
    out.set_ascii(start, b',');
    out.into_string()
}

/// Header, then `count` bytes of UTF-8: the same JSON object as [`force_json`].
pub fn force_binary(seq: u64, estimate: &ForceEstimate) -> Vec<u8> {
    let json = force_json(seq, estimate);
    let count = count_of(json.len());
    let json = &json.as_bytes()[..count as usize];
    let mut out = Vec::with_capacity(BINARY_HEADER_BYTES + json.len());
    binary_header(
        &mut out,
        StreamKind::Force,
        seq,
        estimate.t,
        estimate.t_synth_ns,
        count,
    );
    out.extend_from_slice(json);
    out
}

/// `{"stream":"image","seq":n,"t":s,"t_synth_ns":ns,"generation":g,"frame":f,"line":l,
/// "pixels":P,"size":m,"line_rate":Hz,"direction":"trace","units":{…},"channels":{…}}`:
/// one finished trace line, every channel an array of `pixels` values (`null`: missing).
pub fn image_json(seq: u64, line: &ImageLine) -> String {
    let values: usize = line.channels.iter().map(|(_, _, v)| v.len()).sum();
    let mut out = JsonBuf::with_capacity(512 + values * 24);
    json_header(&mut out, StreamKind::Image, seq, line.t, line.t_synth_ns);
    out.raw(",\"generation\":");
    out.u64(line.generation.into());
    out.raw(",\"frame\":");
    out.u64(line.frame);
    out.raw(",\"line\":");
    out.u64(line.line.into());
    out.raw(",\"pixels\":");
    out.u64(line.pixels.into());
    out.raw(",\"size\":");
    out.f64(line.size);
    out.raw(",\"line_rate\":");
    out.f64(line.line_rate);
    out.raw(",\"direction\":\"trace\",\"units\":{");
    for (i, (name, unit, _)) in line.channels.iter().enumerate() {
        if i > 0 {
            out.raw(",");
        }
        out.string(name);
        out.raw(":");
        out.string(unit);
    }
    out.raw("},\"channels\":{");
    for (i, (name, _, data)) in line.channels.iter().enumerate() {
        if i > 0 {
            out.raw(",");
        }
        out.string(name);
        out.raw(":[");
        for (j, v) in data.iter().enumerate() {
            if j > 0 {
                out.raw(",");
            }
            out.f64(*v);
        }
        out.raw("]");
    }
    out.raw("}}");
    out.into_string()
}

/// A stream whose binary payload is its JSON message: the header, then `count` bytes of
/// UTF-8 (the sweep).
pub fn json_binary(stream: StreamKind, seq: u64, t: f64, t_synth_ns: u64, json: &str) -> Vec<u8> {
    let count = count_of(json.len());
    let json = &json.as_bytes()[..count as usize];
    let mut out = Vec::with_capacity(BINARY_HEADER_BYTES + json.len());
    binary_header(&mut out, stream, seq, t, t_synth_ns, count);
    out.extend_from_slice(json);
    out
}

/// Header, then `count` bytes of UTF-8: the same JSON object as [`image_json`].
pub fn image_binary(seq: u64, line: &ImageLine) -> Vec<u8> {
    let json = image_json(seq, line);
    let count = count_of(json.len());
    let json = &json.as_bytes()[..count as usize];
    let mut out = Vec::with_capacity(BINARY_HEADER_BYTES + json.len());
    binary_header(
        &mut out,
        StreamKind::Image,
        seq,
        line.t,
        line.t_synth_ns,
        count,
    );
    out.extend_from_slice(json);
    out
}

fn json_header(out: &mut JsonBuf, stream: StreamKind, seq: u64, t: f64, t_synth_ns: u64) {
    out.raw("{\"stream\":\"");
    out.raw(stream.name());
    out.raw("\",\"seq\":");
    out.u64(seq);
    out.raw(",\"t\":");
    out.f64(t);
    out.raw(",\"t_synth_ns\":");
    out.u64(t_synth_ns);
}

fn f32_array(out: &mut JsonBuf, values: &[f32]) {
    out.raw("[");
    for (i, &x) in values.iter().enumerate() {
        if i > 0 {
            out.raw(",");
        }
        out.f32(x);
    }
    out.raw("]");
}

fn binary_header(
    out: &mut Vec<u8>,
    stream: StreamKind,
    seq: u64,
    t: f64,
    t_synth_ns: u64,
    count: u32,
) {
    out.extend_from_slice(&BINARY_MAGIC);
    out.extend_from_slice(&BINARY_VERSION.to_le_bytes());
    out.push(stream.code());
    out.push(0);
    out.extend_from_slice(&seq.to_le_bytes());
    out.extend_from_slice(&t.to_le_bytes());
    out.extend_from_slice(&t_synth_ns.to_le_bytes());
    out.extend_from_slice(&count.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    debug_assert_eq!(out.len(), BINARY_HEADER_BYTES);
}

fn extend_f32(out: &mut Vec<u8>, values: &[f32]) {
    for x in values {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

/// The header's `count` field; a payload beyond u32::MAX entries (never reached: buffers
/// are far smaller) is cut to what the header can announce.
fn count_of(len: usize) -> u32 {
    u32::try_from(len).unwrap_or(u32::MAX)
}
