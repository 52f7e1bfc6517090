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

/// Size of a time point's own header in a batched `demods` message: seq u64, t f64,
/// t_synth_ns u64 (bytes).
pub const POINT_HEADER_BYTES: usize = 24;

/// Byte 7 of the header: the payload's layout. 0: the stream's own; 1: batched `demods`.
const LAYOUT_BATCHED: u8 = 1;

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
    /// Records (demods), magnitudes (spectrum), samples (scope) or JSON bytes (status);
    /// time points in a batched `demods` message.
    pub count: u32,
    /// For a batched `demods` message (a subscription with `batch` > 1): the records of
    /// each time point. `None` in every other message.
    pub batched_records: Option<u32>,
}

impl BinaryHeader {
    /// Payload size (bytes after the header) this header announces.
    pub fn payload_bytes(&self) -> usize {
        let count = self.count as usize;
        if let Some(records) = self.batched_records {
            // Saturating: a header read off the wire may announce anything.
            let point = (records as usize)
                .saturating_mul(DEMOD_RECORD_BYTES)
                .saturating_add(POINT_HEADER_BYTES);
            return count.saturating_mul(point);
        }
        match self.stream {
            StreamKind::Demods => count * DEMOD_RECORD_BYTES,
            StreamKind::Spectrum => 8 + 4 * count,
            StreamKind::Scope => 24 + 4 * count,
            StreamKind::Status
            | StreamKind::Force
            | StreamKind::Image
            | StreamKind::Sweep
            | StreamKind::Bimodal
            | StreamKind::Pids => count,
        }
    }
}

/// Reads the header of a binary message: `None` when it is shorter than
/// [`BINARY_HEADER_BYTES`], the magic is wrong or the stream code unknown. The version is
/// returned as found (check it); reserved bytes are ignored.
///
/// A batched `demods` message (byte 7 = 1) has `batched_records`; read its points with
/// [`batched_points`].
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
    let stream = StreamKind::from_code(header[6])?;
    Some(BinaryHeader {
        version: u16_at(4),
        stream,
        seq: u64_at(8),
        t: f64::from_bits(u64_at(16)),
        t_synth_ns: u64_at(24),
        count: u32_at(32),
        batched_records: (header[7] == LAYOUT_BATCHED && stream == StreamKind::Demods)
            .then(|| u32_at(36)),
    })
}

/// One time point of a batched `demods` message.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BatchedPoint<'a> {
    /// The point's own `seq` in the stream.
    pub seq: u64,
    /// Simulated time of the point (s).
    pub t: f64,
    /// Unix time (ns) at which its newest sample was synthesised.
    pub t_synth_ns: u64,
    /// Its demodulator records, [`DEMOD_RECORD_BYTES`] each, as in an unbatched message.
    pub records: &'a [u8],
}

/// The time points of a batched `demods` message, oldest first; `None` when `bytes` is
/// not one or its length is not what the header announces.
pub fn batched_points(bytes: &[u8]) -> Option<Vec<BatchedPoint<'_>>> {
    let header = decode_header(bytes)?;
    let records = header.batched_records? as usize;
    if header.stream != StreamKind::Demods
        || bytes.len() != BINARY_HEADER_BYTES + header.payload_bytes()
    {
        return None;
    }
    let size = POINT_HEADER_BYTES + records * DEMOD_RECORD_BYTES;
    let u64_at = |p: &[u8], i: usize| u64::from_le_bytes(p[i..i + 8].try_into().expect("8 bytes"));
    Some(
        bytes[BINARY_HEADER_BYTES..]
            .chunks_exact(size)
            .map(|p| BatchedPoint {
                seq: u64_at(p, 0),
                t: f64::from_bits(u64_at(p, 8)),
                t_synth_ns: u64_at(p, 16),
                records: &p[POINT_HEADER_BYTES..],
            })
            .collect(),
    )
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
    let count = count_of(frame.values().len());
    let mut out = Vec::with_capacity(BINARY_HEADER_BYTES + count as usize * DEMOD_RECORD_BYTES);
    binary_header(
        &mut out,
        StreamKind::Demods,
        seq,
        frame.t,
        frame.t_synth_ns,
        count,
    );
    demod_records(&mut out, frame);
    out
}

/// The records of one demods frame, as in [`demods_binary`].
fn demod_records(out: &mut Vec<u8>, frame: &DemodFrame) {
    let values = frame.values();
    for v in &values[..count_of(values.len()) as usize] {
        out.extend_from_slice(&u32::from(v.index).to_le_bytes());
        out.extend_from_slice(&v.harmonic.to_le_bytes());
        for x in [v.x, v.y, v.r(), v.phase()] {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
}

/// One time point of a batched `demods` message: seq, t and t_synth_ns, then the records
/// as in [`demods_binary`]. [`DemodBatch`] gathers them into a message.
pub fn demods_point(seq: u64, frame: &DemodFrame) -> Vec<u8> {
    let mut out =
        Vec::with_capacity(POINT_HEADER_BYTES + frame.values().len() * DEMOD_RECORD_BYTES);
    out.extend_from_slice(&seq.to_le_bytes());
    out.extend_from_slice(&frame.t.to_le_bytes());
    out.extend_from_slice(&frame.t_synth_ns.to_le_bytes());
    demod_records(&mut out, frame);
    out
}

/// A batched `demods` message being gathered for one client: time points with the same
/// number of records, behind room for the header.
#[derive(Debug, Default)]
pub struct DemodBatch {
    bytes: Vec<u8>,
    points: u32,
    records: u32,
    last: (u64, f64, u64),
}

impl DemodBatch {
    /// Time points gathered.
    pub fn points(&self) -> u32 {
        self.points
    }

    /// Records per point of the points gathered (0 when empty).
    pub fn records(&self) -> u32 {
        self.records
    }

    /// Adds a point made by [`demods_point`].
    pub fn push(&mut self, point: &[u8]) {
        let records = ((point.len() - POINT_HEADER_BYTES) / DEMOD_RECORD_BYTES) as u32;
        if self.points == 0 {
            self.bytes.clear();
            self.bytes.resize(BINARY_HEADER_BYTES, 0);
            self.records = records;
        }
        debug_assert_eq!(records, self.records, "a batch's points have equal records");
        let u64_at = |i: usize| u64::from_le_bytes(point[i..i + 8].try_into().expect("8 bytes"));
        self.last = (u64_at(0), f64::from_bits(u64_at(8)), u64_at(16));
        self.bytes.extend_from_slice(point);
        self.points += 1;
    }

    /// The message of the points gathered (the header's seq, t and t_synth_ns are the
    /// newest point's), leaving the batch empty; `None` if it was.
    pub fn take(&mut self) -> Option<Vec<u8>> {
        if self.points == 0 {
            return None;
        }
        let (seq, t, t_synth_ns) = self.last;
        let mut header = Vec::with_capacity(BINARY_HEADER_BYTES);
        binary_header(
            &mut header,
            StreamKind::Demods,
            seq,
            t,
            t_synth_ns,
            self.points,
        );
        header[7] = LAYOUT_BATCHED;
        header[36..40].copy_from_slice(&self.records.to_le_bytes());
        self.bytes[..BINARY_HEADER_BYTES].copy_from_slice(&header);
        self.points = 0;
        Some(std::mem::take(&mut self.bytes))
    }
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
    out.raw(",\"epoch\":");
    out.u64(line.epoch);
    out.raw(if line.stale {
        ",\"stale\":true"
    } else {
        ",\"stale\":false"
    });
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
