//! The DSP stage's configuration and state, built off the real-time thread from the
//! settings: the lock-in bank and the sliding spectrum.

use crate::config::{Oscillator, Settings, SpectrumWindow};
use crate::dsp::Oscillator as Reference;
use crate::dsp::{
    Demodulator, DspError, LockInBank, LockInSample, MAX_DEMODULATORS, SPLIT_LANES,
    SlidingSpectrum, SpectrumConfig, Window,
};
use crate::timebase::PREDECIMATION;

use super::dsp_team::DspTeam;
use super::frames::{DemodFrame, DemodValue};
use super::scope::{ScopeCapture, ScopeConfig};

/// Most DSP threads (`/dsp/threads`): the bank splits into at most this many shards of
/// [`SPLIT_LANES`] lanes or more.
pub const MAX_DSP_THREADS: usize = MAX_DEMODULATORS / SPLIT_LANES;
const _: () = assert!(MAX_DSP_THREADS == crate::config::MAX_DSP_THREADS as usize);
/// Input samples per hand-off to the workers: the shards' output buffers hold what this
/// many samples can produce.
const PIECE: usize = 4096;

/// Where the DSP stage's outputs go: the DSP thread's frame queues, or a test's lists.
pub trait DspSink {
    /// One demodulator output at stream sample `index`; outputs come in time order, and
    /// within one time in demodulator order.
    fn demod(&mut self, index: u64, value: DemodValue);
    /// One spectrum ending at stream sample `index`: `bin_width` (Hz) and the magnitudes.
    fn spectrum<I: ExactSizeIterator<Item = f64>>(&mut self, index: u64, bin_width: f64, bins: I);
}

/// Threads the DSP stage runs on for `/dsp/threads`: the value itself from 1 up; 0 (auto)
/// is 1 on a machine with 2 cores or fewer (the synthesiser and the DSP thread take one
/// each) and otherwise one more for each core beyond two, at most 4.
pub fn dsp_threads(settings: &Settings) -> usize {
    match settings.dsp.threads {
        0 => {
            let cores = std::thread::available_parallelism().map_or(1, usize::from);
            1 + cores.saturating_sub(2).min(3)
        }
        n => (n as usize).min(MAX_DSP_THREADS),
    }
}

/// Lock-in bank plus sliding spectrum, with the mapping from their own sample counts to
/// the stream's sample index.
pub struct DspPlan {
    /// Input sample rate (Hz).
    pub sample_rate: f64,
    /// The lock-in bank, split into shards (one per DSP thread, [`LockInBank::split`]).
    bank: Vec<LockInBank>,
    /// Each shard's outputs of the current piece (with more than one shard).
    outputs: Vec<Vec<LockInSample>>,
    spectrum: Option<SlidingSpectrum>,
    pub(crate) scope: Option<ScopeCapture>,
    /// Stream index of the bank's sample 0.
    bank_offset: u64,
    /// Stream index of the spectrum's sample 0.
    spectrum_offset: u64,
    /// The settings epoch this plan belongs to: the DSP thread takes it up with the first
    /// block of that epoch (`BlockHeader::epoch`).
    pub(crate) epoch: u64,
    /// What the bank was built from: a plan built from the same takes over the running
    /// bank (its filters' state) instead of starting from zero. The second excitation's
    /// frequency counts only while a demodulator reads it.
    bank_key: (f64, Option<f64>, Vec<Demodulator>, usize),
}

impl DspPlan {
    /// Builds the bank and spectrum of `settings` (plans FFTs, allocates every buffer).
    pub fn new(settings: &Settings) -> Result<Self, DspError> {
        let fs = settings.synth.sample_rate;
        let demods = demodulators(settings);
        let threads = dsp_threads(settings);
        let drive2 = demods
            .iter()
            .any(|d| d.enable && d.oscillator == Reference::Drive2)
            .then_some(settings.drive2.frequency);
        let bank = LockInBank::with_drive2(
            fs,
            settings.drive.frequency,
            settings.drive2.frequency,
            &demods,
        )?
        .split(threads)?;
        let outputs = if bank.len() > 1 {
            let per_lane = PIECE / PREDECIMATION + 1;
            bank.iter()
                .map(|shard| Vec::with_capacity(shard.lanes() * per_lane))
                .collect()
        } else {
            Vec::new()
        };
        let spectrum = if settings.spectrum.enable {
            let hop =
                usize::try_from(samples_between(fs, settings.spectrum.rate)).unwrap_or(usize::MAX);
            Some(SlidingSpectrum::new(SpectrumConfig {
                sample_rate: fs,
                size: settings.spectrum.size as usize,
                hop,
                window: window(settings.spectrum.window),
            })?)
        } else {
            None
        };
        let scope = settings.scope.enable.then(|| {
            ScopeCapture::new(ScopeConfig {
                length: settings.scope.length as usize,
                decimation: settings.scope.decimation as usize,
                hop: samples_between(fs, settings.scope.rate),
            })
        });
        Ok(Self {
            sample_rate: fs,
            bank,
            outputs,
            spectrum,
            scope,
            bank_offset: 0,
            spectrum_offset: 0,
            epoch: 0,
            bank_key: (settings.drive.frequency, drive2, demods, threads),
        })
    }

    /// Bins per spectrum frame (0 without a spectrum).
    pub fn spectrum_bins(&self) -> usize {
        self.spectrum.as_ref().map_or(0, |s| s.bin_count())
    }

    /// Takes over `old`'s running lock-in bank when this plan's is built from the same
    /// settings, so that a change elsewhere (the spectrum, the scope, another node of the
    /// plan) does not restart every demodulator's filter from zero. A swap: nothing is
    /// allocated or freed (the real-time thread calls this).
    pub(crate) fn inherit_bank(&mut self, old: &mut DspPlan) {
        if self.bank_key == old.bank_key {
            std::mem::swap(&mut self.bank, &mut old.bank);
        }
    }

    /// Shards of the lock-in bank: the threads it runs on, given as many in the team.
    pub fn shards(&self) -> usize {
        self.bank.len()
    }

    /// The stream continues at `index` (a new plan, or after an overrun): map the bank's and
    /// the spectrum's own counts onto it.
    pub(crate) fn restart(&mut self, index: u64) {
        // Every shard has taken the same samples.
        self.bank_offset = index - self.bank[0].samples_processed();
        if let Some(s) = &mut self.spectrum {
            // A spectrum frame must not straddle a gap.
            s.reset();
            self.spectrum_offset = index;
        }
        if let Some(s) = &mut self.scope {
            s.restart();
        }
    }

    /// Input samples between a decimated sample's centre and the input sample that
    /// completes it.
    pub(crate) fn group_delay(&self) -> u64 {
        self.bank[0].group_delay() as u64
    }

    /// The boxcar demodulation of every enabled demodulator since the last call, into
    /// `frame`'s values (its length set); returns the decimated samples averaged.
    pub(crate) fn take_pixel(&mut self, frame: &mut DemodFrame) -> u32 {
        frame.len = 0;
        let mut samples = 0;
        // Shards hold consecutive demodulators: shard by shard is index order.
        for shard in &mut self.bank {
            samples = shard.take_integrals(|demod, harmonic, oscillator, x, y| {
                if frame.len < frame.values.len() {
                    frame.values[frame.len] = DemodValue {
                        index: demod as u8,
                        harmonic,
                        oscillator: setting(oscillator),
                        x,
                        y,
                    };
                    frame.len += 1;
                }
            });
        }
        samples
    }

    /// Locks the reference of the demodulators on the drive to the synthesiser's drive for
    /// the next sample (those on `/drive2` keep theirs: a PLL moves the drive alone).
    pub(crate) fn align(&mut self, phase: u64, frequency_word: u64) {
        for shard in &mut self.bank {
            shard.align_drive(phase, frequency_word);
        }
    }

    /// Locks the reference of the demodulators on oscillator `"drive2"` to the second
    /// excitation for the next sample: `phase2` its phase word of that sample and
    /// `frequency_word2` its step per sample (2^64 = one period), as in
    /// [`BlockHeader`](super::BlockHeader). The DSP thread calls it at every block;
    /// before [`process_block`](Self::process_block) it does the same for a caller with
    /// demodulators on `"drive2"`. Real-time safe.
    pub fn align_drive2(&mut self, phase2: u64, frequency_word2: u64) {
        for shard in &mut self.bank {
            shard.align_drive2(phase2, frequency_word2);
        }
    }

    /// One block of the stream as the DSP thread processes it, for tests and benchmarks:
    /// the reference locked to the drive (`phase`, the phase word of the block's first
    /// sample, and `frequency_word`, as in [`BlockHeader`](super::BlockHeader)), then the
    /// bank and the spectrum over `input`, the bank's shards on `team`'s workers. The
    /// stream starts at index 0 with the plan's first block and must continue without gaps.
    /// Demodulators on `"drive2"` keep the reference of the last
    /// [`align_drive2`](Self::align_drive2) (from `/drive2/frequency`, phase 0 at sample 0,
    /// without one).
    pub fn process_block<S: DspSink>(
        &mut self,
        team: &mut DspTeam,
        phase: u64,
        frequency_word: u64,
        input: &[f64],
        sink: &mut S,
    ) {
        self.align(phase, frequency_word);
        self.process(input, team, sink);
    }

    /// The bank and the spectrum over `input`. With one shard all on this thread; with more,
    /// in pieces of at most [`PIECE`] samples, each handed to `team` (shards 1 … on its
    /// workers, shard 0 and the spectrum here) and the shards' outputs then merged in time
    /// order, shard by shard within one time: the order one bank gives.
    pub(crate) fn process<S: DspSink>(&mut self, input: &[f64], team: &mut DspTeam, sink: &mut S) {
        let offset = self.bank_offset;
        let value = |s: &LockInSample| DemodValue {
            index: s.demod as u8,
            harmonic: s.harmonic,
            oscillator: setting(s.oscillator),
            x: s.x,
            y: s.y,
        };
        let spectrum_offset = self.spectrum_offset;
        let spectrum = |spectrum: &mut Option<SlidingSpectrum>, piece: &[f64], sink: &mut S| {
            if let Some(spectrum) = spectrum {
                let size = spectrum.config().size as u64;
                spectrum.process(piece, |f| {
                    let newest = spectrum_offset + f.start_index + size - 1;
                    sink.spectrum(newest, f.bin_width, f.bins.iter().map(|c| c.norm()));
                });
            }
        };
        if let [bank] = self.bank.as_mut_slice() {
            bank.process(input, |s| sink.demod(offset + s.sample_index, value(&s)));
            spectrum(&mut self.spectrum, input, sink);
            return;
        }
        for piece in input.chunks(PIECE) {
            let sp = &mut self.spectrum;
            let out = &mut *sink;
            team.run(&mut self.bank, &mut self.outputs, piece, || {
                spectrum(sp, piece, out)
            });
            let mut heads = [0usize; MAX_DSP_THREADS];
            loop {
                let next = self
                    .outputs
                    .iter()
                    .zip(&heads)
                    .filter_map(|(out, &h)| out.get(h).map(|s| s.sample_index))
                    .min();
                let Some(index) = next else { break };
                for (out, head) in self.outputs.iter().zip(&mut heads) {
                    while let Some(s) = out.get(*head).filter(|s| s.sample_index == index) {
                        sink.demod(offset + index, value(s));
                        *head += 1;
                    }
                }
            }
        }
    }
}

/// Longest hop between frames, in samples: 2^53, 28 years at 10 MS/s. Hops are added to
/// sample indices on the DSP thread, so one near `u64::MAX` would wrap them (and a wrapped
/// index sends a frame loop round for ever); 2^53 also keeps every hop exact in an `f64`.
pub(crate) const MAX_HOP: u64 = 1 << 53;

/// Input samples between frames at `rate` (Hz) for input at `sample_rate` (Hz): the nearest
/// whole number, at least 1 and at most [`MAX_HOP`], whatever the two are (a rate of 5e-324
/// makes the quotient infinite, a NaN makes it NaN: both give the longest hop).
pub(crate) fn samples_between(sample_rate: f64, rate: f64) -> u64 {
    let hop = (sample_rate / rate).round();
    if hop.is_nan() || hop >= MAX_HOP as f64 {
        MAX_HOP
    } else if hop >= 1.0 {
        hop as u64
    } else {
        1
    }
}

/// The lock-in bank's demodulators for `/demods/...`, in index order; one out of band
/// ([`Settings::demod_active`]) is disabled.
pub fn demodulators(settings: &Settings) -> Vec<Demodulator> {
    settings
        .demods
        .iter()
        .enumerate()
        .map(|(i, d)| Demodulator {
            enable: settings.demod_active(i),
            harmonic: d.harmonic,
            order: d.order,
            time_constant: d.timeconstant,
            output_rate: d.rate,
            oscillator: match d.oscillator {
                Oscillator::Drive => Reference::Drive,
                Oscillator::Drive2 => Reference::Drive2,
            },
        })
        .collect()
}

/// The setting a demodulator's reference stands for, for the values it hands out.
fn setting(reference: Reference) -> Oscillator {
    match reference {
        Reference::Drive => Oscillator::Drive,
        Reference::Drive2 => Oscillator::Drive2,
    }
}

fn window(w: SpectrumWindow) -> Window {
    match w {
        SpectrumWindow::Rectangular => Window::Rectangular,
        SpectrumWindow::Hann => Window::Hann,
        SpectrumWindow::BlackmanHarris => Window::BlackmanHarris,
        SpectrumWindow::FlatTop => Window::FlatTop,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_name_their_oscillator_and_drive2_values_read_the_second_tone() {
        // Demodulator 1 on /drive2 at harmonic 1, the rest on the drive; a tone of each,
        // in blocks whose headers' phases advance as the synthesiser's do.
        struct Last([Option<DemodValue>; 4]);
        impl DspSink for Last {
            fn demod(&mut self, _: u64, v: DemodValue) {
                self.0[usize::from(v.index)] = Some(v);
            }
            fn spectrum<I: ExactSizeIterator<Item = f64>>(&mut self, _: u64, _: f64, _: I) {}
        }
        let mut s = crate::config::default_settings();
        s.synth.realtime = false;
        s.spectrum.enable = false;
        s.scope.enable = false;
        s.dsp.threads = 1;
        s.drive2.frequency = 626.689e3;
        for (i, d) in s.demods.iter_mut().enumerate() {
            d.enable = i < 4;
            d.harmonic = 1;
            d.timeconstant = 100e-6;
            d.order = 4;
        }
        s.demods[1].oscillator = Oscillator::Drive2;
        let fs = s.synth.sample_rate;
        let word = crate::timebase::frequency_word(s.drive.frequency, fs).unwrap();
        let word2 = crate::timebase::frequency_word(s.drive2.frequency, fs).unwrap();
        let mut plan = DspPlan::new(&s).unwrap();
        let mut team = DspTeam::spawn(0, false).unwrap();
        let mut last = Last([None; 4]);
        let (a, b, phi) = (2e-8, 5e-10, 0.7);
        for block in 0..60u64 {
            let first = block * 4096;
            let x: Vec<f64> = (first..first + 4096)
                .map(|m| {
                    let t1 = crate::timebase::phase_to_radians(word.wrapping_mul(m));
                    let t2 = crate::timebase::phase_to_radians(word2.wrapping_mul(m));
                    a * t1.cos() + b * (t2 + phi).cos()
                })
                .collect();
            plan.align_drive2(word2.wrapping_mul(first), word2);
            plan.process_block(&mut team, word.wrapping_mul(first), word, &x, &mut last);
        }
        let [Some(d0), Some(d1), ..] = last.0 else {
            panic!("no outputs")
        };
        assert_eq!(
            (d0.oscillator, d1.oscillator),
            (Oscillator::Drive, Oscillator::Drive2)
        );
        assert!(d0.on_drive() && !d1.on_drive());
        assert!(
            (d0.x - a).abs() < 1e-6 * a && d0.y.abs() < 1e-6 * a,
            "{d0:?}"
        );
        let (x, y) = (b * phi.cos(), b * phi.sin());
        assert!(
            (d1.x - x).abs() < 1e-6 * b && (d1.y - y).abs() < 1e-6 * b,
            "{d1:?}"
        );
    }

    #[test]
    fn hops_stay_between_one_sample_and_the_longest() {
        assert_eq!(samples_between(2e6, 20.0), 100_000);
        assert_eq!(samples_between(2e6, 3e6), 1);
        for rate in [5e-324, 1e-300, 1e-13, 0.0, f64::NAN, -1.0] {
            let hop = samples_between(2e6, rate);
            assert!(hop == MAX_HOP || hop == 1, "{rate}: {hop}");
        }
        assert_eq!(samples_between(2e6, 5e-324), MAX_HOP);
        assert_eq!(samples_between(2e6, f64::NAN), MAX_HOP);
    }
}
