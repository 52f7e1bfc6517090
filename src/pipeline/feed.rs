//! Samples from outside the process (`/source/kind = "stream"`): a client's frames go into
//! the [`SampleInlet`] (off the real-time threads, under its lock), the synthesiser thread
//! takes them out through the [`FeedReader`] (lock-free) and passes them on to the DSP
//! thread in the place of synthesised blocks.
//!
//! ```text
//! session ──frame──► SampleInlet ══ samples (SPSC) ══► FeedReader (synth thread) ──► sample ring
//!                               ══ gaps (SPSC) ═════►
//! ```
//!
//! A frame names the index of its first sample in the writer's own count, so that what
//! the writer lost on its way (a digitiser's overrun, a dropped packet) arrives as a gap:
//! the chain's sample index and drive phase move on by the gap, the DSP restarts its
//! filters there (a discontinuity, counted), and the gap is counted. A frame that finds
//! the feed full is dropped whole, counted, and becomes a gap of its length, so the
//! stream's time stays true. Nothing is ever waited for on the real-time side.

use std::sync::Arc;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use ringbuf::traits::{Consumer, Observer, Producer, Split};
use ringbuf::{HeapCons, HeapProd, HeapRb};

use super::counters::Counters;

/// The magic at the start of every frame: "FTS1" (ftafm samples, layout 1).
pub const FRAME_MAGIC: [u8; 4] = *b"FTS1";
/// Bytes of a frame's header before its samples.
pub const FRAME_HEADER_BYTES: usize = 40;
/// Gaps queued between the writer and the reader: more than any burst of lost frames
/// before the reader takes them (one a frame at most).
const GAP_SLOTS: usize = 4096;

/// The sample type of a frame's samples, all little-endian.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleType {
    /// 16-bit two's-complement integers (code 1), a digitiser's ADC codes.
    I16,
    /// 32-bit IEEE floats (code 2).
    F32,
    /// 64-bit IEEE floats (code 3).
    F64,
}

impl SampleType {
    fn from_code(code: u16) -> Option<Self> {
        match code {
            1 => Some(Self::I16),
            2 => Some(Self::F32),
            3 => Some(Self::F64),
            _ => None,
        }
    }

    /// Bytes a sample.
    pub fn size(self) -> usize {
        match self {
            Self::I16 => 2,
            Self::F32 => 4,
            Self::F64 => 8,
        }
    }
}

/// A frame's header ([`FRAME_HEADER_BYTES`] bytes, little-endian): magic `FTS1`, sample type
/// (u16: 1 int16, 2 float32, 3 float64), reserved u16 (0), id (u64, echoed in the reply),
/// sample rate (f64, Hz), scale (f64, m per unit of the samples), index of the frame's
/// first sample in the writer's count (u64); then the samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameHeader {
    /// The writer's tag for the frame, echoed in its reply.
    pub id: u64,
    /// The samples' type.
    pub sample_type: SampleType,
    /// The sample rate the writer says the samples were taken at (Hz).
    pub sample_rate: f64,
    /// Metres per unit of the samples (m).
    pub scale: f64,
    /// Index of the frame's first sample in the writer's count.
    pub first_index: u64,
}

/// Why a frame was refused; nothing of it entered the chain.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FrameError {
    /// The bytes are not a frame.
    #[error("{0}")]
    Malformed(String),
    /// The frame does not fit the running chain.
    #[error("{0}")]
    Refused(String),
}

impl FrameHeader {
    /// Reads a frame's header and its samples' bytes; checks the layout, not the values.
    pub fn parse(bytes: &[u8]) -> Result<(Self, &[u8]), FrameError> {
        let bad = |m: String| Err(FrameError::Malformed(m));
        if bytes.len() < FRAME_HEADER_BYTES {
            return bad(format!(
                "a sample frame has a {FRAME_HEADER_BYTES}-byte header (docs/protocol.md, \
                 \"Streaming samples in\"); this binary frame has {} bytes",
                bytes.len()
            ));
        }
        if bytes[..4] != FRAME_MAGIC {
            return bad(format!(
                "a sample frame starts with the magic \"FTS1\", not {:?}",
                String::from_utf8_lossy(&bytes[..4])
            ));
        }
        let u16_at = |i: usize| u16::from_le_bytes([bytes[i], bytes[i + 1]]);
        let u64_at = |i: usize| u64::from_le_bytes(bytes[i..i + 8].try_into().unwrap_or([0; 8]));
        let code = u16_at(4);
        let Some(sample_type) = SampleType::from_code(code) else {
            return bad(format!(
                "sample type {code} is not one of 1 (int16), 2 (float32), 3 (float64)"
            ));
        };
        if u16_at(6) != 0 {
            return bad(format!(
                "the header's reserved field (bytes 6-7) must be 0, not {}",
                u16_at(6)
            ));
        }
        let header = FrameHeader {
            id: u64_at(8),
            sample_type,
            sample_rate: f64::from_bits(u64_at(16)),
            scale: f64::from_bits(u64_at(24)),
            first_index: u64_at(32),
        };
        let data = &bytes[FRAME_HEADER_BYTES..];
        if data.is_empty() || !data.len().is_multiple_of(sample_type.size()) {
            return bad(format!(
                "a frame of {:?} samples carries a whole number of {}-byte samples, at least \
                 one; this one has {} bytes after the header",
                sample_type,
                sample_type.size(),
                data.len()
            ));
        }
        if !(header.scale.is_finite() && header.scale != 0.0) {
            return bad(format!(
                "the scale (m per unit of the samples) must be finite and non-zero, not {}",
                header.scale
            ));
        }
        Ok((header, data))
    }

    /// Writes this header before `data` (the samples' bytes): a frame.
    pub fn frame(&self, data: &[u8]) -> Vec<u8> {
        let code: u16 = match self.sample_type {
            SampleType::I16 => 1,
            SampleType::F32 => 2,
            SampleType::F64 => 3,
        };
        let mut out = Vec::with_capacity(FRAME_HEADER_BYTES + data.len());
        out.extend_from_slice(&FRAME_MAGIC);
        out.extend_from_slice(&code.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(&self.id.to_le_bytes());
        out.extend_from_slice(&self.sample_rate.to_le_bytes());
        out.extend_from_slice(&self.scale.to_le_bytes());
        out.extend_from_slice(&self.first_index.to_le_bytes());
        out.extend_from_slice(data);
        out
    }
}

/// What became of a frame the inlet took.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct FrameReceipt {
    /// Samples that entered the feed.
    pub accepted: u64,
    /// Samples dropped because the feed was full (the chain is behind the writer): they
    /// become a gap in the stream.
    pub dropped: u64,
    /// Samples the writer skipped before this frame (its first index beyond the next
    /// expected one): a gap in the stream.
    pub gap: u64,
    /// Samples the feed has room for after this frame.
    pub room: u64,
    /// The writer's index of the next sample expected.
    pub next_index: u64,
}

/// The inlet's side of the feed, under its lock.
struct Writer {
    samples: HeapProd<f64>,
    gaps: HeapProd<Gap>,
    /// Samples pushed (the reader's position is counted in the same units).
    written: u64,
    /// The writer's index of the next sample, once a frame has come.
    expected: Option<u64>,
    /// The connection writing, if one is.
    client: Option<u64>,
    /// A gap waiting for room in the gap queue (merged with the next).
    held_gap: u64,
    /// Scratch for one frame's samples in metres (kept, so a frame allocates nothing).
    scratch: Vec<f64>,
}

/// A mark in the stream, after `at` samples written: `len` samples missing, or a new stream
/// whose first sample has the writer's index `start`.
#[derive(Clone, Copy, Debug)]
struct Gap {
    at: u64,
    len: u64,
    start: Option<u64>,
}

/// The writing end of the feed: a client's frames in, under a lock (off the real-time
/// threads).
pub struct SampleInlet {
    writer: Mutex<Writer>,
    /// Whether `/source/kind` is `stream`: frames are refused otherwise.
    accepting: AtomicBool,
    sample_rate: f64,
    counters: Arc<Counters>,
    capacity: usize,
}

/// The reading end of the feed, on the synthesiser thread. Lock-free and allocation-free.
pub(crate) struct FeedReader {
    samples: HeapCons<f64>,
    gaps: HeapCons<Gap>,
    /// Samples taken (in the writer's `written` units).
    taken: u64,
}

/// A feed of `capacity` samples for a chain at `sample_rate` (S/s).
pub(crate) fn feed(
    capacity: usize,
    sample_rate: f64,
    counters: Arc<Counters>,
) -> (SampleInlet, FeedReader) {
    let (samples_in, samples_out) = HeapRb::<f64>::new(capacity).split();
    let (gaps_in, gaps_out) = HeapRb::<Gap>::new(GAP_SLOTS).split();
    (
        SampleInlet {
            writer: Mutex::new(Writer {
                samples: samples_in,
                gaps: gaps_in,
                written: 0,
                expected: None,
                client: None,
                held_gap: 0,
                scratch: Vec::new(),
            }),
            accepting: AtomicBool::new(false),
            sample_rate,
            counters,
            capacity,
        },
        FeedReader {
            samples: samples_out,
            gaps: gaps_out,
            taken: 0,
        },
    )
}

impl SampleInlet {
    /// Takes frames from now on (`/source/kind` became `stream`), a new stream: the next
    /// frame may start at any index. Or refuses them.
    pub(crate) fn accept(&self, on: bool) {
        // Under the writer's lock: once this returns `false`, no frame enters.
        let Ok(mut w) = self.writer.lock() else {
            return;
        };
        let was = self.accepting.swap(on, Ordering::AcqRel);
        if on && !was {
            w.expected = None;
            w.client = None;
        }
    }

    /// Whether frames are taken (`/source/kind` is `stream`).
    pub fn accepting(&self) -> bool {
        self.accepting.load(Ordering::Acquire)
    }

    /// The connection `client` has gone: another may stream, and its first frame starts a
    /// new stream.
    pub fn release(&self, client: u64) {
        if let Ok(mut w) = self.writer.lock()
            && w.client == Some(client)
        {
            w.client = None;
            w.expected = None;
        }
    }

    /// Samples the feed holds (s/s of the chain's rate: not yet taken by the chain).
    pub fn fill(&self) -> usize {
        self.writer
            .lock()
            .map(|w| w.samples.occupied_len())
            .unwrap_or(0)
    }

    /// The feed's capacity (samples).
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Takes the frame `bytes` from connection `client`: checks it against the running
    /// chain, converts its samples to metres and queues them, or drops them whole if the
    /// feed has no room (a gap). On error nothing changes.
    pub fn push_frame(
        &self,
        client: u64,
        bytes: &[u8],
    ) -> Result<(FrameHeader, FrameReceipt), FrameError> {
        let (header, data) = FrameHeader::parse(bytes)?;
        let refuse = |m: String| Err(FrameError::Refused(m));
        if header.sample_rate != self.sample_rate {
            return refuse(format!(
                "the frame's sample rate {} Hz is not the chain's /synth/sample_rate {} Hz \
                 (fixed while running: start the daemon with the stream's rate)",
                header.sample_rate, self.sample_rate
            ));
        }
        let mut guard = self
            .writer
            .lock()
            .map_err(|_| FrameError::Refused("the sample feed is unusable".into()))?;
        let w = &mut *guard;
        if !self.accepting() {
            return refuse(
                "samples are taken only while /source/kind is \"stream\"; set it first".into(),
            );
        }
        if let Some(other) = w.client
            && other != client
        {
            return refuse(format!(
                "another connection (client {other}) is streaming samples; one stream at a time"
            ));
        }
        let n = (data.len() / header.sample_type.size()) as u64;
        let gap = match w.expected {
            Some(next) if header.first_index < next => {
                return refuse(format!(
                    "the frame starts at sample {} but sample {next} is next: frames go \
                     forward and do not overlap",
                    header.first_index
                ));
            }
            Some(next) => header.first_index - next,
            None => 0,
        };
        w.scratch.clear();
        let scale = header.scale;
        match header.sample_type {
            SampleType::I16 => w.scratch.extend(
                data.chunks_exact(2)
                    .map(|b| f64::from(i16::from_le_bytes([b[0], b[1]])) * scale),
            ),
            SampleType::F32 => w.scratch.extend(
                data.chunks_exact(4)
                    .map(|b| f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])) * scale),
            ),
            SampleType::F64 => w.scratch.extend(
                data.chunks_exact(8)
                    .map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8])) * scale),
            ),
        }
        if let Some(i) = w.scratch.iter().position(|x| !x.is_finite()) {
            return refuse(format!(
                "sample {} of the frame (stream index {}) is not a finite number",
                i,
                header.first_index + i as u64
            ));
        }
        // A new stream's first frame marks its start (its reference phase is the drive's at
        // the writer's index); one that finds no slot is refused, so nothing is out of place.
        if w.expected.is_none() {
            let start = Gap {
                at: w.written,
                len: 0,
                start: Some(header.first_index),
            };
            if w.gaps.try_push(start).is_err() {
                return refuse("the feed's queue of marks is full; send again".into());
            }
            w.held_gap = 0;
        }
        w.client = Some(client);
        w.expected = Some(header.first_index + n);
        // A gap (with one held back for want of a slot) goes ahead of the samples; a frame
        // whose gap finds no slot is dropped with it, so no gap is ever out of place.
        let pending = gap + w.held_gap;
        let fits = w.samples.vacant_len() as u64 >= n && (pending == 0 || w.gaps.vacant_len() > 0);
        let mut accepted = 0;
        if fits {
            if pending > 0 {
                let _ = w.gaps.try_push(Gap {
                    at: w.written,
                    len: pending,
                    start: None,
                });
                w.held_gap = 0;
            }
            let Writer {
                samples, scratch, ..
            } = w;
            samples.push_slice(scratch);
            w.written += n;
            accepted = n;
        } else {
            w.held_gap = pending + n;
            let gap = Gap {
                at: w.written,
                len: w.held_gap,
                start: None,
            };
            if w.gaps.try_push(gap).is_ok() {
                w.held_gap = 0;
            }
        }
        let dropped = n - accepted;
        Counters::add(&self.counters.stream_frames, 1);
        Counters::add(&self.counters.stream_samples, accepted);
        Counters::add(&self.counters.stream_gap_samples, gap);
        Counters::add(&self.counters.stream_dropped_samples, dropped);
        Ok((
            header,
            FrameReceipt {
                accepted,
                dropped,
                gap,
                room: w.samples.vacant_len() as u64,
                next_index: header.first_index + n,
            },
        ))
    }
}

impl FeedReader {
    /// The next piece of the stream for a block of at most `max` samples: `Start(i)` where a
    /// new stream starts at the writer's index `i`, `Skip(n)` where `n` samples are
    /// missing, `Samples(n)` where [`take`](Self::take) gives `n` (≥ 1), or `None` where
    /// nothing is there yet.
    pub(crate) fn next(&mut self, max: usize) -> Option<Piece> {
        if let Some(gap) = self.gaps.first().copied()
            && gap.at <= self.taken
        {
            let _ = self.gaps.try_pop();
            return Some(match gap.start {
                Some(index) => Piece::Start(index),
                None => Piece::Skip(gap.len),
            });
        }
        let mut n = self.samples.occupied_len().min(max) as u64;
        if let Some(gap) = self.gaps.first() {
            n = n.min(gap.at - self.taken);
        }
        (n > 0).then_some(Piece::Samples(n as usize))
    }

    /// Moves the next `out.len()` samples (m) into `out`, as [`next`](Self::next) said were
    /// there.
    pub(crate) fn take(&mut self, out: &mut [f64]) {
        let got = self.samples.pop_slice(out);
        self.taken += got as u64;
    }

    /// Throws away what the feed holds (the source is no longer a stream); how many samples.
    pub(crate) fn discard(&mut self) -> u64 {
        let n = self.samples.skip(usize::MAX) as u64;
        self.taken += n;
        while self.gaps.try_pop().is_some() {}
        n
    }
}

/// What [`FeedReader::next`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Piece {
    /// A new stream, whose next sample has this index in the writer's count.
    Start(u64),
    /// Samples missing from the stream.
    Skip(u64),
    /// Samples ready.
    Samples(usize),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(first_index: u64, samples: &[f64]) -> Vec<u8> {
        let data: Vec<u8> = samples.iter().flat_map(|x| x.to_le_bytes()).collect();
        FrameHeader {
            id: 7,
            sample_type: SampleType::F64,
            sample_rate: 1e6,
            scale: 2.0,
            first_index,
        }
        .frame(&data)
    }

    fn inlet(capacity: usize) -> (SampleInlet, FeedReader) {
        let (inlet, reader) = feed(capacity, 1e6, Arc::new(Counters::default()));
        inlet.accept(true);
        (inlet, reader)
    }

    #[test]
    fn samples_arrive_scaled_and_in_order_with_the_gaps_where_they_were() {
        let (inlet, mut reader) = inlet(64);
        let (_, r) = inlet.push_frame(1, &frame(10, &[1.0, 2.0, 3.0])).unwrap();
        assert_eq!((r.accepted, r.gap, r.dropped, r.next_index), (3, 0, 0, 13));
        // Samples 13 and 14 lost on the way.
        let (_, r) = inlet.push_frame(1, &frame(15, &[4.0, 5.0])).unwrap();
        assert_eq!((r.accepted, r.gap, r.next_index), (2, 2, 17));
        assert_eq!(reader.next(100), Some(Piece::Start(10)));
        assert_eq!(reader.next(100), Some(Piece::Samples(3)));
        let mut out = [0.0; 3];
        reader.take(&mut out);
        assert_eq!(out, [2.0, 4.0, 6.0]);
        assert_eq!(reader.next(100), Some(Piece::Skip(2)));
        assert_eq!(reader.next(1), Some(Piece::Samples(1)));
        let mut one = [0.0];
        reader.take(&mut one);
        assert_eq!(one, [8.0]);
        assert_eq!(reader.next(100), Some(Piece::Samples(1)));
        reader.take(&mut one);
        assert_eq!(one, [10.0]);
        assert_eq!(reader.next(100), None);
    }

    #[test]
    fn a_frame_that_finds_the_feed_full_is_dropped_whole_and_becomes_a_gap() {
        let (inlet, mut reader) = inlet(4);
        inlet.push_frame(1, &frame(0, &[1.0, 1.0, 1.0])).unwrap();
        let (_, r) = inlet.push_frame(1, &frame(3, &[2.0, 2.0])).unwrap();
        assert_eq!((r.accepted, r.dropped), (0, 2));
        let mut out = [0.0; 3];
        assert_eq!(reader.next(100), Some(Piece::Start(0)));
        assert_eq!(reader.next(100), Some(Piece::Samples(3)));
        reader.take(&mut out);
        let (_, r) = inlet.push_frame(1, &frame(5, &[3.0])).unwrap();
        assert_eq!((r.accepted, r.dropped, r.gap), (1, 0, 0));
        assert_eq!(reader.next(100), Some(Piece::Skip(2)));
        assert_eq!(reader.next(100), Some(Piece::Samples(1)));
    }

    #[test]
    fn bad_frames_are_refused_and_change_nothing() {
        let (inlet, mut reader) = inlet(64);
        inlet.push_frame(1, &frame(0, &[1.0])).unwrap();
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (b"FTS1".to_vec(), "40-byte header"),
            (
                {
                    let mut f = frame(1, &[1.0]);
                    f[0] = b'X';
                    f
                },
                "magic",
            ),
            (
                {
                    let mut f = frame(1, &[1.0]);
                    f[4] = 9;
                    f
                },
                "sample type 9",
            ),
            (
                {
                    let mut f = frame(1, &[1.0]);
                    f.pop();
                    f
                },
                "whole number",
            ),
            (frame(0, &[1.0]), "frames go forward"),
            (frame(1, &[f64::NAN]), "not a finite number"),
            (
                {
                    let mut f = frame(1, &[1.0]);
                    f[16..24].copy_from_slice(&2e6f64.to_le_bytes());
                    f
                },
                "not the chain's /synth/sample_rate",
            ),
            (
                {
                    let mut f = frame(1, &[1.0]);
                    f[24..32].copy_from_slice(&0f64.to_le_bytes());
                    f
                },
                "scale",
            ),
        ];
        for (bytes, says) in cases {
            let e = inlet.push_frame(1, &bytes).unwrap_err().to_string();
            assert!(e.contains(says), "{says}: {e}");
        }
        let e = inlet.push_frame(2, &frame(1, &[1.0])).unwrap_err();
        assert!(e.to_string().contains("another connection"), "{e}");
        assert_eq!(reader.next(100), Some(Piece::Start(0)));
        assert_eq!(reader.next(100), Some(Piece::Samples(1)));
        let mut out = [0.0];
        reader.take(&mut out);
        assert_eq!(reader.next(100), None);
        inlet.release(1);
        assert!(inlet.push_frame(2, &frame(0, &[1.0])).is_ok());
        inlet.accept(false);
        let e = inlet.push_frame(2, &frame(1, &[1.0])).unwrap_err();
        assert!(e.to_string().contains("/source/kind"), "{e}");
    }
}
