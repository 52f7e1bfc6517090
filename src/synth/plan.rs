//! Everything the synthesiser needs, computed off the real-time thread from the settings:
//! the modal kernels, the drive's steady response, the tap-force pulse from the 1-DOF
//! solution, and the noise levels. Immutable once built; the real-time loop only reads it.

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

use super::adc::{self, Adc};
use super::coupled::{CoupledKernel, Refinement};
use super::drive::{Drive, ReferenceChange};
use super::modal::ModalKernel;
use super::pid_plan::PidPlan;
use super::pulse::{PulseKernel, PulseTrain};
use super::scan_plan::{ScanBase, ScanPlan, TapTables};
use super::window::{ModeWindow, Moments};
use crate::config::{Engine, Oscillator, Settings, SourceKind};
use crate::model;
use crate::physics::beam::{BeamError, MAX_MODES};
use crate::physics::impact::ImpactError;
use crate::physics::{Cantilever, ImpactSolution};
use crate::timebase::{TWO_POW_64, WordError, frequency_word};
use std::sync::Arc;

/// Boltzmann's constant (J/K).
pub const BOLTZMANN: f64 = 1.380_649e-23;

/// Why a plan cannot be built from the settings.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// The cantilever is not buildable.
    #[error(transparent)]
    Beam(#[from] BeamError),
    /// The 1-DOF tapping problem has no solution we could find.
    #[error("1-DOF tapping solution: {0}")]
    Impact(#[from] ImpactError),
    /// The drive frequency cannot be represented.
    #[error(transparent)]
    Drive(#[from] WordError),
    /// A PID unit's settings that its controller refuses (`model::check_pids` names the
    /// node first).
    #[error(transparent)]
    Pid(#[from] crate::control::PidError),
}

/// The tap force the synthesiser applies, from the 1-DOF solution (paper engine).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TapForce {
    /// The cut-cosine pulse train.
    pub train: PulseTrain,
    /// θ of the 1-DOF solution (degrees).
    pub phase_shift_deg: f64,
    /// Fundamental amplitude of the 1-DOF tip motion (m).
    pub tapping_amplitude: f64,
    /// Maximum indentation (m).
    pub max_indentation: f64,
}

impl TapForce {
    fn from_solution(s: &ImpactSolution) -> Self {
        Self {
            train: PulseTrain {
                max_force: s.max_force,
                tau: s.contact_time_ratio,
                centre_phase: s.pulse_phase,
            },
            phase_shift_deg: s.phase_shift_deg(),
            tapping_amplitude: s.tapping_amplitude,
            max_indentation: s.max_indentation,
        }
    }
}

/// The synthesiser's immutable configuration.
#[derive(Clone, Debug)]
pub struct SynthPlan {
    /// Sample rate (Hz).
    pub sample_rate: f64,
    /// Sample period h (s).
    pub h: f64,
    /// Drive phase words per sample.
    pub frequency_word: u64,
    /// Realised drive frequency f_s·word/2^64 (Hz).
    pub drive_frequency: f64,
    /// The cantilever.
    pub cantilever: Cantilever,
    pub(crate) modes: Vec<ModalKernel>,
    /// The drive `/drive/*` configure: its steady responses, and the loop's constants.
    pub drive: Drive,
    /// The second excitation (`/drive2/*`), where it drives: its steady responses beside
    /// the first's. The coupled engine only.
    pub drive2: Option<Drive>,
    /// `/drive2/frequency`'s phase words per sample, whether or not it drives: the
    /// reference of the demodulators on it (0 where it is not below the Nyquist frequency).
    pub frequency_word2: u64,
    pub(crate) pulse: Option<PulseKernel>,
    /// The engine (`/synth/engine`).
    pub engine: Engine,
    /// The coupled engine's kernel, when it is the engine: the tap force then comes from
    /// the tip position sample by sample and `pulse` and `tap` are `None`.
    pub coupled: Option<CoupledKernel>,
    /// The paper engine's tap force (the 1-DOF solution), if the tip touches the sample.
    pub tap: Option<TapForce>,
    /// Standard deviation of the held thermal input of each mode (m/s²).
    pub(crate) thermal_sigma: Vec<f64>,
    /// Standard deviation of the detector noise per sample (m).
    pub detector_sigma: f64,
    /// ADC, if quantisation is on.
    pub adc: Option<Adc>,
    /// The ADC's anti-alias filter ([`adc`]): its grid taps, or none to sample directly.
    pub(crate) anti_alias: Option<[f64; adc::GRID_TAPS]>,
    /// The window's weights of the tap force's moments (α, β summed over the modes).
    pub(crate) force_window: (f64, f64),
    /// Per-mode constants laid out for the hot loop.
    pub(crate) lanes: Lanes,
    /// Seed of the noise generator (`/synth/seed`).
    pub seed: u64,
    /// The scan, when `/scan/enable` is on: the tip moves over the sample map under the
    /// amplitude feedback ([`process_scan`](Self::process_scan)).
    pub scan: Option<ScanPlan>,
    /// The PID units (`/pids/N/*`): with one enabled the synthesiser runs them
    /// ([`process_pids`](Self::process_pids)).
    pub pids: PidPlan,
    /// Where the chain's samples come from (`/source/kind`): with a stream the synthesiser
    /// thread passes the streamed samples on instead of synthesising, and keeps the sample
    /// index and the drive phase running ([`SynthState::skip`](super::SynthState::skip)).
    pub source: SourceKind,
    /// The settings epoch this plan belongs to (set by the pipeline when it queues the
    /// plan): the synthesiser takes it up once that epoch is published, with the block it
    /// stamps with it.
    pub epoch: u64,
    /// The outputs whose nodes the change that made this plan wrote, [`PidTarget::bit`]
    /// each (set by the pipeline, [`PidTarget::written`]): a unit that no longer runs on
    /// one gives it back to its node even where the node's value is unchanged.
    ///
    /// [`PidTarget::bit`]: crate::config::PidTarget::bit
    /// [`PidTarget::written`]: crate::config::PidTarget::written
    pub release: u64,
}

/// Per-mode constants as structure of arrays, zero past the plan's modes.
#[derive(Clone, Debug, Default)]
pub(crate) struct Lanes {
    /// e^{λh}, real and imaginary parts.
    pub a_re: [f64; MAX_MODES],
    pub a_im: [f64; MAX_MODES],
    /// Photodiode metres per unit of Im q.
    pub lever: [f64; MAX_MODES],
    /// Thermal input per standard normal deviate: σ·∫₀ʰe^{λ(h−s)}ds, real and imaginary.
    pub noise_re: [f64; MAX_MODES],
    pub noise_im: [f64; MAX_MODES],
    /// The ADC's window ([`super::window`]): the knot functional κ per unit of Re q and
    /// of Im q at a grid sample.
    pub knot_re: [f64; MAX_MODES],
    pub knot_im: [f64; MAX_MODES],
    /// κ at the sample's midpoint per unit of Re q, of Im q and of the thermal deviate at
    /// the sample's start (the midpoint's state is e^{λh/2}·q + σ·∫₀^{h/2}e^{λ(h/2−s)}ds·ξ).
    pub mid_re: [f64; MAX_MODES],
    pub mid_im: [f64; MAX_MODES],
    pub mid_noise: [f64; MAX_MODES],
    /// The held thermal input's part of the window centred on a grid sample, per deviate
    /// of the sample it starts and of the one before; of the window on a midpoint.
    pub grid_noise: [f64; MAX_MODES],
    pub grid_noise_before: [f64; MAX_MODES],
    pub mid_input_noise: [f64; MAX_MODES],
    /// κ at the midpoint per newton-second of a kick at the sample's start.
    pub mid_kick: [f64; MAX_MODES],
    /// Where neither the sample nor the one before has a tap force, the windows are
    /// functionals of the grid sample's state and the deviates alone: the grid sample's
    /// window per unit of Re q, Im q, this sample's deviate and the last one's; the
    /// midpoint's per unit of Re q, Im q and this sample's deviate.
    pub free_grid_re: [f64; MAX_MODES],
    pub free_grid_im: [f64; MAX_MODES],
    pub free_grid_noise: [f64; MAX_MODES],
    pub free_grid_noise_before: [f64; MAX_MODES],
    pub free_mid_re: [f64; MAX_MODES],
    pub free_mid_im: [f64; MAX_MODES],
    pub free_mid_noise: [f64; MAX_MODES],
    /// κ at the last midpoint from the grid sample's state, where the last sample had no
    /// tap force: per unit of Re q, Im q and of the last sample's deviate.
    pub back_re: [f64; MAX_MODES],
    pub back_im: [f64; MAX_MODES],
    pub back_noise: [f64; MAX_MODES],
}

impl Lanes {
    fn new(modes: &[ModalKernel], thermal_sigma: &[f64], h: f64) -> Self {
        let mut l = Self::default();
        for (m, (k, sigma)) in modes.iter().zip(thermal_sigma).enumerate() {
            l.a_re[m] = k.propagator.re;
            l.a_im[m] = k.propagator.im;
            l.lever[m] = k.lever_gain;
            l.noise_re[m] = k.hold_gain.re * sigma;
            l.noise_im[m] = k.hold_gain.im * sigma;
            let w = ModeWindow::new(k, h);
            l.knot_re[m] = w.knot_re;
            l.knot_im[m] = w.knot_im;
            let half = (k.lambda * (0.5 * h)).exp();
            (l.mid_re[m], l.mid_im[m]) = w.of(half);
            l.mid_noise[m] = w.knot(((half - 1.0) / k.lambda) * sigma);
            let (start, mid, end) = Moments::held(*sigma, h).weigh(w.alpha, w.beta, h);
            l.grid_noise[m] = start;
            l.mid_input_noise[m] = mid;
            l.grid_noise_before[m] = end;
            l.mid_kick[m] = l.mid_re[m] * k.force_gain;
            // Free samples: q at the midpoint is e·q + σ·g·ξ (e = e^{λh/2}, g = (e − 1)/λ),
            // so the last midpoint is (q − σ·g·ξ′)/e. The second differences 1/e − 2 + e and
            // 1 − 2e + e² are written as sinh² to keep their digits.
            let x = k.lambda * (0.5 * h);
            let sh = (x * 0.5).sinh();
            let g = (half - 1.0) / k.lambda;
            let (gr, gi) = w.of(4.0 * sh * sh);
            l.free_grid_re[m] = gr;
            l.free_grid_im[m] = gi;
            l.free_grid_noise[m] = w.knot(g * sigma) + start;
            l.free_grid_noise_before[m] = -w.knot(g / half * sigma) + end;
            let (mr, mi) = w.of(4.0 * half * sh * sh);
            l.free_mid_re[m] = mr;
            l.free_mid_im[m] = mi;
            // σ·κ(hold − 2g) with hold − 2g = (e − 1)²/λ.
            l.free_mid_noise[m] = w.knot(4.0 * half * sh * sh / k.lambda * sigma) + mid;
            let (br, bi) = w.of(1.0 / half);
            l.back_re[m] = br;
            l.back_im[m] = bi;
            l.back_noise[m] = -w.knot(g / half * sigma);
        }
        l
    }
}

/// The ADC window's weights of the tap force's moments, summed over the modes it drives
/// ([`super::window::Moments::weigh`]).
fn force_window(modes: &[ModalKernel], h: f64) -> (f64, f64) {
    modes.iter().fold((0.0, 0.0), |(alpha, beta), k| {
        let w = ModeWindow::new(k, h);
        (alpha + w.alpha * k.force_gain, beta + w.beta * k.force_gain)
    })
}

impl SynthPlan {
    /// Builds the plan for `settings`; solves the 1-DOF tapping problem (a few ms), and with
    /// a scan the tap tables of every region (~0.1 s each).
    pub fn new(settings: &Settings) -> Result<Self, PlanError> {
        Self::with_tables(settings, None)
    }

    /// As [`new`](Self::new), reusing `tables` when they fit the settings' physics.
    pub fn with_tables(
        settings: &Settings,
        tables: Option<&Arc<TapTables>>,
    ) -> Result<Self, PlanError> {
        let engine = settings.synth.engine;
        let cantilever = model::cantilever(settings)?;
        let sample_rate = settings.synth.sample_rate;
        let h = 1.0 / sample_rate;
        let word = frequency_word(settings.drive.frequency, sample_rate)?;
        let drive_frequency = word as f64 / TWO_POW_64 * sample_rate;
        let omega = 2.0 * PI * drive_frequency;
        let modes: Vec<ModalKernel> = cantilever
            .modes
            .iter()
            .map(|m| ModalKernel::new(m, h))
            .collect();

        let drive = Drive::with_free_amplitude(
            &cantilever,
            sample_rate,
            word,
            settings.drive.free_amplitude,
        );
        let drive_response = &drive.response[..cantilever.modes.len()];
        let drive_signal = drive.signal;
        let frequency_word2 = frequency_word(settings.drive2.frequency, sample_rate).unwrap_or(0);
        let drive2 = (settings.drive2.enable && engine == Engine::Coupled).then(|| {
            Drive::with_free_amplitude(
                &cantilever,
                sample_rate,
                frequency_word2,
                settings.drive2.free_amplitude,
            )
        });

        let tap = match engine {
            Engine::Paper => {
                let solution =
                    model::impact_oscillator(settings, &cantilever, settings.sample).solve()?;
                solution
                    .in_contact()
                    .then(|| TapForce::from_solution(&solution))
            }
            Engine::Coupled => None,
        };
        let pulse = tap.map(|t| PulseKernel::new(&t.train, h, word, &modes));

        let noise = &settings.noise;
        let thermal_sigma: Vec<f64> = cantilever
            .modes
            .iter()
            .zip(&modes)
            .map(|(m, k)| {
                if noise.enable && noise.temperature > 0.0 {
                    // Equipartition: ⟨Y²⟩ = k_B·T/Kn, with Y = Im q/ω_d.
                    let variance = BOLTZMANN * noise.temperature / m.stiffness;
                    (variance * k.omega_d * k.omega_d / k.held_noise_gain()).sqrt()
                } else {
                    0.0
                }
            })
            .collect();
        // One-sided density ρ over the band 0..f_s/2: variance ρ²·f_s/2 per sample.
        let detector_sigma = if noise.enable {
            noise.detector_density * (sample_rate / 2.0).sqrt()
        } else {
            0.0
        };
        let adc = (noise.enable && noise.adc_bits > 0).then(|| {
            let lsb = 2.0 * noise.adc_range / 2f64.powi(noise.adc_bits as i32);
            Adc {
                lsb,
                range: noise.adc_range,
                codes_per_metre: 1.0 / lsb,
            }
        });
        let lanes = Lanes::new(&modes, &thermal_sigma, h);
        let force_window = force_window(&modes, h);
        let coupled = (engine == Engine::Coupled).then(|| {
            let contact = model::impact_oscillator(settings, &cantilever, settings.sample).contact;
            let mut kernel = CoupledKernel::new(
                &cantilever.modes,
                h,
                omega,
                drive_response,
                drive.base_amplitude,
                settings.surface.distance,
                &contact,
                model::adhesion(settings),
                &thermal_sigma,
                settings.synth.contact_substeps as usize,
                settings.synth.substep_budget,
            );
            kernel.set_second_drive(&cantilever.modes, h, drive2.as_ref());
            kernel
        });
        let scan = settings.scan.enable.then(|| {
            let base = match &coupled {
                Some(kernel) => {
                    let (amplitude, force_phase) = kernel.orbit_reading(
                        &cantilever.modes,
                        drive_response,
                        h,
                        &lanes.lever,
                        drive_signal,
                    );
                    ScanBase::Coupled {
                        amplitude,
                        force_phase,
                    }
                }
                None => ScanBase::Paper {
                    drive_signal,
                    drive_frequency,
                    train: tap.map(|t| t.train),
                },
            };
            ScanPlan::new(settings, &cantilever, base, tables)
        });
        let pids = PidPlan::new(
            settings,
            coupled.as_ref().map(|c| c.free_tip),
            drive.base_amplitude,
            drive2.as_ref().map(|d| d.base_amplitude),
        )?;
        Ok(Self {
            scan,
            pids,
            lanes,
            seed: settings.synth.seed,
            sample_rate,
            h,
            frequency_word: word,
            drive_frequency,
            cantilever,
            modes,
            drive,
            drive2,
            frequency_word2,
            pulse,
            engine,
            coupled,
            tap,
            thermal_sigma,
            detector_sigma,
            adc,
            anti_alias: settings.synth.anti_alias.then(adc::grid_taps),
            force_window,
            source: settings.source.kind,
            epoch: 0,
            release: 0,
        })
    }

    /// Drive phase word at which the sample synthesised at drive phase `phase` was taken:
    /// `phase` itself, or the ADC filter's delay before it ([`adc::delayed_phase`]).
    pub fn output_phase(&self, phase: u64) -> u64 {
        self.output_phase_at(phase, self.frequency_word)
    }

    /// [`output_phase`](Self::output_phase) for a drive of `word` words per sample.
    pub fn output_phase_at(&self, phase: u64, word: u64) -> u64 {
        if self.anti_alias.is_some() {
            adc::delayed_phase(phase, word)
        } else {
            phase
        }
    }

    /// The lock-in's reference of `oscillator` after it changes to `word` words per sample
    /// at sample `index`, its phase `phase`: the samples taken under the new frequency
    /// begin ⌈D⌉ samples on (D the ADC filter's delay; 0 without it), at the phase the
    /// oscillator had D samples before.
    pub(crate) fn reference_change(
        &self,
        oscillator: Oscillator,
        phase: u64,
        index: u64,
        word: u64,
    ) -> ReferenceChange {
        let lag = if self.anti_alias.is_some() {
            adc::DELAY_HALF_SAMPLES.div_ceil(2)
        } else {
            0
        };
        ReferenceChange {
            oscillator,
            index: index + lag,
            phase: self.output_phase_at(phase.wrapping_add(word.wrapping_mul(lag)), word),
            word,
        }
    }

    /// Gain of the ADC's anti-alias filter at `frequency` f/f_s, its delay removed (1 for
    /// every frequency without the filter): what the samples hold of a component at f.
    pub fn front_end_gain(&self, frequency: f64) -> f64 {
        self.anti_alias
            .as_ref()
            .map_or(1.0, |taps| adc::gain(taps, frequency))
    }

    /// The photodiode's free (no contact) steady drive response: Re[Ŝ·e^{iθ}] at drive
    /// phase θ (m).
    pub fn free_signal(&self) -> Complex64 {
        self.drive.signal
    }

    /// Each mode's steady drive response, Y_n = Re[Ŷ_n e^{iθ}] (m).
    pub(crate) fn drive_response(&self) -> &[Complex64] {
        &self.drive.response[..self.modes.len()]
    }

    /// Number of modes synthesised.
    pub fn mode_count(&self) -> usize {
        self.modes.len()
    }

    /// Steady-state modal states at drive phase `theta` (rad) under the tap force alone:
    /// q_n = Σ_k (ikΩ − λ̄n)·Y_{n,k}·e^{ikθ} with Y_{n,k} = gain·c_k·Hn(kΩ)/ωn², summed over
    /// |k| ≤ 4096 (the terms fall off like 1/k³ past the pulse's bandwidth). With the
    /// coupled engine: its own periodic orbit ([`CoupledKernel::steady_state`]), and the
    /// sub-step count its taps settled on (the default with the paper engine).
    pub(crate) fn tap_steady_state(&self, theta: f64) -> (Vec<Complex64>, Refinement) {
        if let Some(coupled) = &self.coupled {
            let (q, refinement) =
                coupled.steady_state(&self.cantilever.modes, self.drive_response(), self.h, theta);
            return (q[..self.modes.len()].to_vec(), refinement);
        }
        let Some(tap) = self.tap else {
            return (
                vec![Complex64::new(0.0, 0.0); self.modes.len()],
                Refinement::default(),
            );
        };
        let omega = 2.0 * PI * self.drive_frequency;
        let train = tap.train;
        let kmax = 4096;
        let coefficients = crate::physics::spectrum::cut_cosine_train(
            train.max_force,
            train.tau,
            train.centre_phase,
            kmax,
        );
        let q = self
            .cantilever
            .modes
            .iter()
            .zip(&self.modes)
            .map(|(mode, kernel)| {
                let lambda_bar = kernel.lambda.conj();
                let mut q = Complex64::new(0.0, 0.0);
                for (k, c) in coefficients.iter().enumerate() {
                    // Both signs of k: c_{−k} = conj(c_k).
                    for sign in [1.0, -1.0] {
                        if k == 0 && sign < 0.0 {
                            continue;
                        }
                        let kk = sign * k as f64;
                        let ck = if sign > 0.0 { *c } else { c.conj() };
                        let y = ck * kernel.force_gain * mode.transfer(kk * omega)
                            / (mode.omega * mode.omega);
                        q += (Complex64::new(0.0, kk * omega) - lambda_bar)
                            * y
                            * Complex64::from_polar(1.0, kk * theta);
                    }
                }
                q
            })
            .collect();
        (q, Refinement::default())
    }
}

/// What a demodulator at harmonic 1 reads (X + iY, m) of the free lever at `settings`' drive:
/// [`SynthPlan::free_signal`] through the ADC's front end, without building a plan (no
/// orbit, no tables: cheap enough for every `status`). `None` for settings no plan accepts.
pub fn free_reading(settings: &Settings) -> Option<Complex64> {
    free_reading_of(settings, Oscillator::Drive)
}

/// [`free_reading`] of either excitation alone: what a demodulator at harmonic 1 of
/// `oscillator` reads of the free lever driven by it at its `/drive/*` or `/drive2/*`
/// frequency and free amplitude (whether or not `/drive2/enable` is set).
pub fn free_reading_of(settings: &Settings, oscillator: Oscillator) -> Option<Complex64> {
    let cantilever = model::cantilever(settings).ok()?;
    let sample_rate = settings.synth.sample_rate;
    let (frequency, free_amplitude) = match oscillator {
        Oscillator::Drive => (settings.drive.frequency, settings.drive.free_amplitude),
        Oscillator::Drive2 => (settings.drive2.frequency, settings.drive2.free_amplitude),
    };
    let word = frequency_word(frequency, sample_rate).ok()?;
    let drive = Drive::with_free_amplitude(&cantilever, sample_rate, word, free_amplitude);
    let gain = if settings.synth.anti_alias {
        adc::gain(&adc::grid_taps(), drive.frequency / sample_rate)
    } else {
        1.0
    };
    Some(drive.signal * gain)
}
