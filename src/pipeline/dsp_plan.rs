//! The DSP stage's configuration and state, built off the real-time thread from the
//! settings: the lock-in bank and the sliding spectrum.

use crate::config::{Settings, SpectrumWindow};
use crate::dsp::{Demodulator, DspError, LockInBank, SlidingSpectrum, SpectrumConfig, Window};

use super::dsp_worker::Emitter;
use super::frames::{DemodFrame, DemodValue};
use super::scope::{ScopeCapture, ScopeConfig};

/// Lock-in bank plus sliding spectrum, with the mapping from their own sample counts to
/// the stream's sample index.
pub struct DspPlan {
    /// Input sample rate (Hz).
    pub sample_rate: f64,
    bank: LockInBank,
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
    /// bank (its filters' state) instead of starting from zero.
    bank_key: (f64, Vec<Demodulator>),
}

impl DspPlan {
    /// Builds the bank and spectrum of `settings` (plans FFTs, allocates every buffer).
    pub fn new(settings: &Settings) -> Result<Self, DspError> {
        let fs = settings.synth.sample_rate;
        let demods = demodulators(settings);
        let bank = LockInBank::new(fs, settings.drive.frequency, &demods)?;
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
            spectrum,
            scope,
            bank_offset: 0,
            spectrum_offset: 0,
            epoch: 0,
            bank_key: (settings.drive.frequency, demods),
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

    /// The stream continues at `index` (a new plan, or after an overrun): map the bank's and
    /// the spectrum's own counts onto it.
    pub(crate) fn restart(&mut self, index: u64) {
        self.bank_offset = index - self.bank.samples_processed();
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
        self.bank.group_delay() as u64
    }

    /// The boxcar demodulation of every enabled demodulator since the last call, into
    /// `frame`'s values (its length set); returns the decimated samples averaged.
    pub(crate) fn take_pixel(&mut self, frame: &mut DemodFrame) -> u32 {
        frame.len = 0;
        self.bank.take_integrals(|demod, harmonic, x, y| {
            if frame.len < frame.values.len() {
                frame.values[frame.len] = DemodValue {
                    index: demod as u8,
                    harmonic,
                    x,
                    y,
                };
                frame.len += 1;
            }
        })
    }

    /// Locks the lock-in reference to the synthesiser's drive for the next sample.
    pub(crate) fn align(&mut self, phase: u64, frequency_word: u64) {
        self.bank.align_drive(phase, frequency_word);
    }

    pub(crate) fn process(&mut self, input: &[f64], emit: &mut Emitter<'_>) {
        let offset = self.bank_offset;
        self.bank.process(input, |s| {
            emit.demod(
                offset + s.sample_index,
                DemodValue {
                    index: s.demod as u8,
                    harmonic: s.harmonic,
                    x: s.x,
                    y: s.y,
                },
            )
        });
        if let Some(spectrum) = &mut self.spectrum {
            let offset = self.spectrum_offset;
            let size = spectrum.config().size as u64;
            spectrum.process(input, |f| {
                let newest = offset + f.start_index + size - 1;
                emit.spectrum(newest, f.bin_width, f.bins.iter().map(|c| c.norm()));
            });
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
        })
        .collect()
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
