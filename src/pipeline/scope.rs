//! The scope: every 1/`/scope/rate` seconds, `/scope/length` consecutive photodiode samples
//! (every `/scope/decimation`-th), with the drive phase at the first one so a client can
//! subtract harmonics (the paper's Fig. 4).

use crate::timebase::phase_to_radians;

use super::block::BlockHeader;
use super::frames::ScopeBuffer;

/// Longest trace (samples); the pool's buffers are allocated this long once.
pub const MAX_SCOPE_SAMPLES: usize = 65_536;

/// Scope settings for one DSP plan.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScopeConfig {
    /// Samples per trace.
    pub length: usize,
    /// Keep every Nth sample.
    pub decimation: usize,
    /// Input samples between trace starts.
    pub hop: u64,
}

/// Capture state: where the current (or next) trace starts.
#[derive(Debug)]
pub(crate) struct ScopeCapture {
    pub config: ScopeConfig,
    /// Stream index of the first sample of the trace being filled, or of the next one.
    start: Option<u64>,
}

impl ScopeCapture {
    pub fn new(config: ScopeConfig) -> Self {
        Self {
            config,
            start: None,
        }
    }

    /// Feeds `samples`, which start at stream index `first` and belong to the block of
    /// `header`. `current` is the trace being filled; `take` supplies an empty buffer when a
    /// trace starts (`None`: no buffer free, the trace is skipped — `take` counts it);
    /// full traces go to `give`. Traces never overlap (hop ≥ length × decimation).
    #[allow(clippy::too_many_arguments)]
    pub fn feed(
        &mut self,
        header: &BlockHeader,
        first: u64,
        samples: &[f64],
        sample_rate: f64,
        current: &mut Option<ScopeBuffer>,
        take: &mut impl FnMut() -> Option<ScopeBuffer>,
        give: &mut impl FnMut(ScopeBuffer),
    ) {
        let c = self.config;
        let dec = c.decimation as u64;
        let end = first + samples.len() as u64;
        loop {
            let start = *self.start.get_or_insert(first);
            if current.is_none() {
                if start >= end {
                    return;
                }
                if start < first {
                    // The stream jumped past the planned start: begin here instead.
                    self.start = Some(first);
                    continue;
                }
                let Some(mut buf) = take() else {
                    self.start = Some(start.saturating_add(c.hop));
                    continue;
                };
                buf.samples.clear();
                let words = header
                    .phase
                    .wrapping_add(header.frequency_word.wrapping_mul(start - header.index));
                buf.start_phase = phase_to_radians(words);
                buf.phase_step = phase_to_radians(header.frequency_word.wrapping_mul(dec));
                buf.dt = dec as f64 / sample_rate;
                *current = Some(buf);
            }
            let buf = current.as_mut().expect("a trace is being filled");
            let mut index = start + buf.samples.len() as u64 * dec;
            while index < end && buf.samples.len() < c.length {
                buf.samples.push(samples[(index - first) as usize] as f32);
                index += dec;
            }
            if buf.samples.len() < c.length {
                return;
            }
            let mut full = current.take().expect("a trace is being filled");
            full.sample_index = index - dec;
            full.t = full.sample_index as f64 / sample_rate;
            full.t_synth_ns = header.t_synth_ns;
            give(full);
            // Saturating: a wrapped start would lie before the stream and be taken for a
            // jump, and the loop would go round for ever on the real-time thread.
            self.start = Some(start.saturating_add(c.hop));
        }
    }

    /// Forget the position (after a gap in the stream; the caller drops a partial trace).
    pub fn restart(&mut self) {
        self.start = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn buffer() -> ScopeBuffer {
        ScopeBuffer::with_capacity(16)
    }

    /// The longest hop (a rate of 5e-324 Hz) gives one trace and then none, and every
    /// block returns: the next start saturates instead of wrapping to before the stream.
    #[test]
    fn the_longest_hop_neither_wraps_nor_spins() {
        let mut capture = ScopeCapture::new(ScopeConfig {
            length: 16,
            decimation: 1,
            hop: u64::MAX,
        });
        let samples = [0.5; 64];
        let (mut current, mut traces, mut taken) = (None, 0, 0);
        for block in 0..100u64 {
            let header = BlockHeader {
                index: block * 64,
                len: 64,
                phase: 0,
                frequency_word: 1 << 60,
                phase2: 0,
                frequency_word2: 0,
                t_synth_ns: 0,
                raster: None,
                epoch: 0,
                digitise: None,
                references: 0,
                pids: Default::default(),
            };
            capture.feed(
                &header,
                header.index,
                &samples,
                1e6,
                &mut current,
                &mut || {
                    taken += 1;
                    (taken < 1000).then(buffer)
                },
                &mut |_| traces += 1,
            );
        }
        assert_eq!(traces, 1);
        assert_eq!(taken, 1);
    }
}
