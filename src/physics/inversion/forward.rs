//! What the lock-in reads for a given tip force: the light-lever transfer (Eq. 9) and the
//! aliases of the harmonics above the Nyquist frequency.
//!
//! The photodiode signal is sampled at f_s with no anti-alias filter in front of the ADC
//! (the instrument synthesises the sampled signal exactly), so harmonic j of the drive f
//! shows up wherever j·f folds to. The lock-in at harmonic k mixes the samples with
//! e^{−ikθ[m]}, θ[m] = 2πfm/f_s, and keeps what is at 0 Hz: the component c_j·e^{ijθ} lands
//! there when (j − k)·f/f_s is an integer, and its conjugate c̄_j·e^{−ijθ} when
//! (j + k)·f/f_s is. So for two-sided photodiode coefficients S_j = T(jΩ)·c_j the lock-in
//! reads
//!
//! S_k^read = Σ_{j ≥ 0, (j−k)f/f_s ∈ ℤ} S_j + Σ_{j > 0, (j+k)f/f_s ∈ ℤ} S̄_j,
//!
//! which is S_k alone for f_s → ∞. With the default 10 MS/s and 100 kHz (f_s/f = 100), the
//! 17th harmonic also receives the 83rd, 117th, 183rd, … and the 29th the 71st, whose
//! light-lever signal is larger than its own (the 29th is near the pulse's spectral zero and
//! the 71st is lifted by mode 5): dividing the reading by T(kΩ) alone biases the force
//! coefficient there by up to 100 %. A harmonic whose fold lands near but not exactly on
//! k·f beats slowly through the lock-in instead of adding a constant; such near misses
//! (relative offset below 10⁻⁹ counts as exact) are not modelled.

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

use super::InversionError;
use crate::physics::beam::Cantilever;
use crate::physics::spectrum::photodiode_transfer;

/// Highest harmonic j summed in the aliases. The light-lever signal of a harmonic falls at
/// least as 1/j⁴ beyond the last mode and the pulse (the transfer as 1/j², the cut cosine's
/// coefficients as 1/j²), so the tail beyond j = 1024 is below 2·10⁻⁵ of the smallest
/// harmonic read at the default settings (checked against the lock-in itself in the tests).
pub const ALIAS_HARMONICS: usize = 1024;

/// One harmonic that reaches a demodulator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AliasTerm {
    /// Harmonic j of the drive.
    pub harmonic: usize,
    /// Whether it arrives conjugated (folded from the other side of a multiple of f_s).
    pub conjugate: bool,
    /// Light-lever transfer T(jΩ) (m/N).
    pub transfer: Complex64,
}

/// What the lock-in at one harmonic reads.
#[derive(Clone, Debug, PartialEq)]
struct Reading {
    harmonic: usize,
    transfer: Complex64,
    /// Every harmonic other than k itself that lands on k.
    aliases: Vec<AliasTerm>,
}

/// The forward model of the measurement: for each demodulated harmonic, the light-lever
/// transfer of the harmonic itself and the harmonics aliased onto it. Built once (it
/// evaluates the transfer function a few thousand times), used for every estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct LockInModel {
    cantilever: Cantilever,
    drive_frequency: f64,
    sample_rate: Option<f64>,
    readings: Vec<Reading>,
    /// T(jΩ) for j = 0..=[`super::MAX_AUTO_HARMONIC`] (series and aliases).
    transfers: Vec<Complex64>,
}

/// Two-sided coefficient c_j (N) of the cut-cosine pulse train of peak `max_force`, ratio
/// `tau`, centred at drive phase `pulse_phase` (rad).
pub fn cut_cosine_phasor(max_force: f64, tau: f64, pulse_phase: f64, j: usize) -> Complex64 {
    super::two_harmonic::cut_cosine_value(max_force, tau, j)
        * Complex64::from_polar(1.0, -(j as f64) * pulse_phase)
}

/// Two-sided coefficients c_j (N), j = 0..=jmax, of the cut-cosine pulse train of peak
/// `max_force`, ratio `tau`, centred at drive phase `pulse_phase` (rad):
/// (2Fτ/π)·cos(πτj)/(1 − 4τ²j²)·e^{−ijφ}, the cosines and phasors by recurrence
/// (re-anchored every 64 terms, so rounding stays at ~10⁻¹⁵), the removable singularity
/// 2τj = 1 by [`super::cut_cosine_shape`]. Agrees with [`cut_cosine_phasor`] term by term.
pub fn cut_cosine_spectrum(
    max_force: f64,
    tau: f64,
    pulse_phase: f64,
    jmax: usize,
) -> Vec<Complex64> {
    let scale = 2.0 * max_force * tau / PI;
    let shape_step = Complex64::from_polar(1.0, PI * tau);
    let phase_step = Complex64::from_polar(1.0, -pulse_phase);
    let (mut shape_rot, mut phase_rot) = (Complex64::new(1.0, 0.0), Complex64::new(1.0, 0.0));
    (0..=jmax)
        .map(|j| {
            let jf = j as f64;
            if j % 64 == 0 {
                shape_rot = Complex64::from_polar(1.0, PI * tau * jf);
                phase_rot = Complex64::from_polar(1.0, -pulse_phase * jf);
            } else {
                shape_rot *= shape_step;
                phase_rot *= phase_step;
            }
            let w = 2.0 * tau * jf;
            let shape = if (w - 1.0).abs() < 1e-2 {
                super::cut_cosine_shape(w).0
            } else {
                shape_rot.re / (1.0 - w * w)
            };
            phase_rot * (scale * shape)
        })
        .collect()
}

impl LockInModel {
    /// The model for demodulators at `harmonics` (duplicates are ignored) on `cantilever`
    /// driven at `drive_frequency` (Hz), the signal sampled at `sample_rate` (Hz; `None`:
    /// no aliasing, as with an ideal anti-alias filter or an analogue lock-in).
    ///
    /// # Errors
    /// [`InversionError::InvalidDriveFrequency`] for a drive frequency that is not positive
    /// and finite, [`InversionError::InvalidSampleRate`] likewise for the sample rate.
    pub fn new(
        cantilever: &Cantilever,
        drive_frequency: f64,
        sample_rate: Option<f64>,
        harmonics: &[usize],
    ) -> Result<Self, InversionError> {
        if !(drive_frequency.is_finite() && drive_frequency > 0.0) {
            return Err(InversionError::InvalidDriveFrequency(drive_frequency));
        }
        if let Some(fs) = sample_rate
            && !(fs.is_finite() && fs > 0.0)
        {
            return Err(InversionError::InvalidSampleRate(fs));
        }
        let omega = 2.0 * PI * drive_frequency;
        let transfer = |j: usize| photodiode_transfer(cantilever, j as f64 * omega);
        let mut ks: Vec<usize> = harmonics.to_vec();
        ks.sort_unstable();
        ks.dedup();
        // Transfer of every harmonic a series or an alias sum needs, computed once.
        let table: Vec<Complex64> = (0..=super::MAX_AUTO_HARMONIC.max(ALIAS_HARMONICS))
            .map(transfer)
            .collect();
        let readings = ks
            .iter()
            .map(|&k| {
                let mut aliases = Vec::new();
                if let Some(fs) = sample_rate {
                    let ratio = drive_frequency / fs;
                    let lands = |offset: f64| {
                        let cycles = offset * ratio;
                        (cycles - cycles.round()).abs() <= 1e-9 * ratio
                    };
                    for (j, &t) in table.iter().enumerate().take(ALIAS_HARMONICS + 1) {
                        if j != k && lands(j as f64 - k as f64) {
                            aliases.push(AliasTerm {
                                harmonic: j,
                                conjugate: false,
                                transfer: t,
                            });
                        }
                        if j > 0 && lands(j as f64 + k as f64) {
                            aliases.push(AliasTerm {
                                harmonic: j,
                                conjugate: true,
                                transfer: t,
                            });
                        }
                    }
                }
                Reading {
                    harmonic: k,
                    transfer: table.get(k).copied().unwrap_or_else(|| transfer(k)),
                    aliases,
                }
            })
            .collect();
        Ok(Self {
            cantilever: cantilever.clone(),
            drive_frequency,
            sample_rate,
            readings,
            transfers: table,
        })
    }

    /// The model seen through a front end of real gain `gain(f/f_s)` (its delay removed)
    /// before the sampler, e.g. the ADC's anti-alias filter: each demodulated harmonic's
    /// transfer and each alias's is scaled by the gain at its own frequency (f/f_s of the
    /// harmonic, before folding). Without a sample rate it changes nothing.
    /// [`transfer_any`](Self::transfer_any) stays the light lever's alone.
    #[must_use]
    pub fn with_front_end(mut self, gain: impl Fn(f64) -> f64) -> Self {
        let Some(fs) = self.sample_rate else {
            return self;
        };
        let ratio = self.drive_frequency / fs;
        for r in &mut self.readings {
            r.transfer *= gain(r.harmonic as f64 * ratio);
            for a in &mut r.aliases {
                a.transfer *= gain(a.harmonic as f64 * ratio);
            }
        }
        self
    }

    /// The cantilever.
    pub fn cantilever(&self) -> &Cantilever {
        &self.cantilever
    }

    /// Drive frequency (Hz).
    pub fn drive_frequency(&self) -> f64 {
        self.drive_frequency
    }

    /// Sample rate of the signal (Hz), if aliasing is modelled.
    pub fn sample_rate(&self) -> Option<f64> {
        self.sample_rate
    }

    /// The demodulated harmonics, ascending.
    pub fn harmonics(&self) -> impl Iterator<Item = usize> + '_ {
        self.readings.iter().map(|r| r.harmonic)
    }

    fn reading(&self, k: usize) -> Option<&Reading> {
        self.readings
            .binary_search_by_key(&k, |r| r.harmonic)
            .ok()
            .map(|i| &self.readings[i])
    }

    /// Light-lever transfer T(kΩ) (m/N) of demodulated harmonic `k`.
    pub fn transfer(&self, k: usize) -> Option<Complex64> {
        self.reading(k).map(|r| r.transfer)
    }

    /// Light-lever transfer T(kΩ) (m/N) of any harmonic `k` (tabulated up to
    /// [`super::MAX_AUTO_HARMONIC`], computed beyond).
    pub fn transfer_any(&self, k: usize) -> Complex64 {
        self.transfers.get(k).copied().unwrap_or_else(|| {
            photodiode_transfer(&self.cantilever, k as f64 * 2.0 * PI * self.drive_frequency)
        })
    }

    /// The harmonics other than `k` that reach the demodulator at `k` (empty without a
    /// sample rate or for a harmonic not in the model).
    pub fn aliases(&self, k: usize) -> &[AliasTerm] {
        self.reading(k).map_or(&[], |r| &r.aliases)
    }

    /// The aliased part of what the demodulator at `k` reads (two-sided, m) for force
    /// coefficients `force(j)` (N): Σ T(jΩ)·c_j over the aliases, conjugated where folded.
    pub fn aliased(&self, k: usize, force: impl Fn(usize) -> Complex64) -> Complex64 {
        self.aliases(k)
            .iter()
            .map(|a| {
                let s = a.transfer * force(a.harmonic);
                if a.conjugate { s.conj() } else { s }
            })
            .sum()
    }

    /// [`Self::aliased`] for force coefficients given as a spectrum `force[j]` (N), which
    /// must reach [`ALIAS_HARMONICS`] (terms beyond its end count as zero).
    pub fn aliased_spectrum(&self, k: usize, force: &[Complex64]) -> Complex64 {
        self.aliased(k, |j| force.get(j).copied().unwrap_or_default())
    }

    /// What the demodulator at `k` reads (two-sided S_k, m; the lock-in's X + iY is twice
    /// this for k ≥ 1) for force coefficients `force(j)` (N); `None` for a harmonic not in
    /// the model.
    pub fn read(&self, k: usize, force: impl Fn(usize) -> Complex64) -> Option<Complex64> {
        let r = self.reading(k)?;
        Some(r.transfer * force(k) + self.aliased(k, force))
    }
}
