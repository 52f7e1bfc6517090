//! The live bimodal AM-FM estimate (the `bimodal` stream, docs/loops.md): the sample's
//! modulus and the indentation from what the loops of bimodal AFM read, frame by frame.
//!
//! Mode 1 is read off the demodulator frame (the first demodulator at harmonic 1 of
//! `"drive"`): its amplitude A1 = A01·|s1|/|s01| and phase lag φ1 = π/2 − arg(s1/s01)
//! against the free lever's reading s01 at the settings in force
//! ([`crate::synth::plan::free_reading`]), A01 = `/drive/free_amplitude`. Mode 2's frequency
//! shift is mode 2's PLL's (the enabled unit on the phase of harmonic 1 of `"drive2"`
//! driving `drive2_frequency`): the output of its update in force at the frame's sample
//! (the newest update at or before it, [`PllHistory`]) less `/drive2/frequency`, which the
//! user sets at the free resonance. [`crate::physics::bimodal::estimate`] turns them into ⟨F⟩,
//! ⟨k_ts⟩, d and E*; the sample's Young's modulus follows from E* with the tip's.
//!
//! A frame synthesised before the settings in force, no PLL update at or before the
//! frame, or a PLL update made under other settings gives no estimate: the message says
//! why, so nothing stale passes as current. The message names the update it paired the
//! frame with (`pll_sample`, `pll_age`).

use std::f64::consts::FRAC_PI_2;

use rustfft::num_complex::Complex64;
use serde_json::{Value, json};

use super::Current;
use crate::config::{Oscillator, PidInput, PidTarget, Settings};
use crate::physics::bimodal::{self, BimodalError, BimodalEstimate, BimodalLever, BimodalReading};
use crate::pipeline::{DemodFrame, PidUpdate};

/// What the estimate needs of one epoch's settings, computed once per epoch.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// The settings epoch it is for.
    pub epoch: u64,
    /// The simulated time (s) from which the stream runs under those settings.
    t: Option<f64>,
    /// The sample rate (S/s) under them.
    rate: f64,
    /// The lever's constants, or why the estimate cannot be made at these settings.
    setup: Result<BimodalSetup, String>,
}

/// What the bimodal expressions need of one set of settings: the lever's constants, the
/// free lever's reading at f1 and mode 2's PLL. The `bimodal` stream's and the scan's
/// bimodal channels' one calibration.
#[derive(Clone, Debug)]
pub struct BimodalSetup {
    lever: BimodalLever,
    /// The free lever's reading at harmonic 1 of the drive (m, X + iY).
    free1: Complex64,
    /// `/drive/free_amplitude` (m).
    free_amplitude: f64,
    /// N of mode 2's PLL `/pids/N`.
    pll: usize,
    /// `/drive2/frequency` (Hz): the centre Δf2 is taken from.
    centre2: f64,
    /// The tip's 1/E contribution (1 − ν_t²)/E_t and the sample's 1 − ν_s².
    tip_term: f64,
    sample_poisson_term: f64,
}

impl Calibration {
    /// The calibration for `current`'s settings.
    pub fn of(current: &Current) -> Self {
        Self {
            epoch: current.epoch,
            t: current.t,
            rate: current.settings.synth.sample_rate,
            setup: BimodalSetup::of(&current.settings),
        }
    }

    /// The `bimodal` message's fields for `frame` (after the envelope), with `pll` the PLL
    /// unit's ([`pll_unit`](Self::pll_unit)) update in force at the frame's sample
    /// ([`PllHistory::at`]).
    pub fn fields(&self, frame: &DemodFrame, pll: Option<PidUpdate>) -> Value {
        let mut fields = json!({ "epoch": self.epoch });
        match self.reading(frame, pll) {
            Ok((reading, setup, pll)) => {
                fields["amplitude1"] = json!(reading.amplitude);
                fields["phase_lag1"] = json!(reading.phase_lag);
                fields["frequency_shift2"] = json!(reading.frequency_shift);
                fields["pll_unit"] = json!(setup.pll);
                fields["pll_limited"] = json!(pll.limited);
                fields["pll_sample"] = json!(pll.sample);
                fields["pll_age"] =
                    json!(frame.sample_index.saturating_sub(pll.sample) as f64 / self.rate);
                match setup.values(&reading) {
                    Ok(v) => {
                        let e = v.estimate;
                        fields["mean_force"] = json!(e.mean_force);
                        fields["mean_stiffness"] = json!(e.mean_stiffness);
                        fields["indentation"] = json!(e.indentation);
                        fields["reduced_modulus"] = json!(e.reduced_modulus);
                        fields["short_tap_indentation"] = json!(e.short_tap_indentation);
                        fields["short_tap_modulus"] = json!(e.short_tap_modulus);
                        fields["youngs_modulus"] = json!(v.youngs_modulus);
                        fields["reason"] = Value::Null;
                    }
                    Err(e) => fields["reason"] = json!(e.to_string()),
                }
            }
            Err(reason) => fields["reason"] = json!(reason),
        }
        for key in [
            "amplitude1",
            "phase_lag1",
            "frequency_shift2",
            "pll_unit",
            "pll_limited",
            "pll_sample",
            "pll_age",
            "mean_force",
            "mean_stiffness",
            "indentation",
            "reduced_modulus",
            "short_tap_indentation",
            "short_tap_modulus",
            "youngs_modulus",
        ] {
            if fields.get(key).is_none() {
                fields[key] = Value::Null;
            }
        }
        fields
    }

    /// Whether it knew when the settings took effect in the stream (a calibration made
    /// before the synthesiser said is made again once it has).
    pub fn t_known(&self) -> bool {
        self.t.is_some()
    }

    /// N of mode 2's PLL at these settings, if there is one.
    pub fn pll_unit(&self) -> Option<usize> {
        self.setup.as_ref().ok().map(|s| s.pll)
    }

    fn reading(
        &self,
        frame: &DemodFrame,
        pll: Option<PidUpdate>,
    ) -> Result<(BimodalReading, &BimodalSetup, PidUpdate), String> {
        let setup = self.setup.as_ref().map_err(Clone::clone)?;
        if self.t.is_none_or(|t| frame.t < t) {
            return Err(format!(
                "the frame at t = {} s was synthesised before the settings of epoch {}",
                frame.t, self.epoch
            ));
        }
        let h1 = frame
            .values()
            .iter()
            .find(|v| v.on_drive() && v.harmonic == 1)
            .ok_or("no demodulator at harmonic 1 of \"drive\" is enabled: mode 1 is read there")?;
        let pll = pll.ok_or_else(|| {
            format!(
                "/pids/{} has made no update at or before the frame at t = {} s (sample {})",
                setup.pll, frame.t, frame.sample_index
            )
        })?;
        if pll.epoch != self.epoch {
            return Err(format!(
                "/pids/{} has made no update under the settings of epoch {} at or before the \
                 frame at t = {} s (the one in force then, at sample {}, ran under epoch {})",
                setup.pll, self.epoch, frame.t, pll.sample, pll.epoch
            ));
        }
        let reading = setup.reading(Complex64::new(h1.x, h1.y), pll.output);
        Ok((reading, setup, pll))
    }
}

/// Mode 2's PLL updates the hub has seen, oldest first: the frames come from the DSP thread
/// behind the synthesiser (up to the sample ring's length, 0.5 s of signal, when it runs
/// free), whose latest update is then past them, so a frame is paired with the update in
/// force at its sample, the newest at or before it. The hub records the unit's latest
/// update at each of its passes (at least one a millisecond); the history keeps the last
/// [`PLL_HISTORY`] distinct ones.
#[derive(Clone, Debug, Default)]
pub struct PllHistory {
    /// The unit the updates are of.
    unit: Option<usize>,
    /// The updates, their samples increasing.
    updates: std::collections::VecDeque<PidUpdate>,
}

/// Updates a [`PllHistory`] keeps (seconds of passes a millisecond apart).
pub const PLL_HISTORY: usize = 4096;

impl PllHistory {
    /// Records `update`, unit `unit`'s latest: a new unit starts the history afresh; an
    /// update already recorded (the same sample) is not recorded again, and one before the
    /// newest (the stream restarted) replaces the history.
    pub fn record(&mut self, unit: usize, update: PidUpdate) {
        if self.unit != Some(unit) {
            self.unit = Some(unit);
            self.updates.clear();
        }
        if let Some(newest) = self.updates.back() {
            if newest.sample == update.sample {
                return;
            }
            if update.sample < newest.sample {
                self.updates.clear();
            }
        }
        if self.updates.capacity() < PLL_HISTORY {
            self.updates.reserve_exact(PLL_HISTORY - self.updates.len());
        }
        if self.updates.len() == PLL_HISTORY {
            self.updates.pop_front();
        }
        self.updates.push_back(update);
    }

    /// The update of unit `unit` in force at sample `sample`: the newest recorded at or
    /// before it; `None` if none is (or the history is of another unit).
    pub fn at(&self, unit: usize, sample: u64) -> Option<PidUpdate> {
        if self.unit != Some(unit) {
            return None;
        }
        let after = self.updates.partition_point(|u| u.sample <= sample);
        after
            .checked_sub(1)
            .and_then(|i| self.updates.get(i))
            .copied()
    }
}

/// The bimodal channels of one reading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BimodalValues {
    /// The expressions' ⟨F⟩, ⟨k_ts⟩, d and E*.
    pub estimate: BimodalEstimate,
    /// The sample's Young's modulus from E* and the tip's (Pa); `None` where E* exceeds
    /// what the tip alone allows.
    pub youngs_modulus: Option<f64>,
}

impl BimodalSetup {
    /// The constants of `s`, or why there is no estimate at them.
    pub fn of(s: &Settings) -> Result<Self, String> {
        setup(s)
    }

    /// The reading of mode 1's phasor `s1` at harmonic 1 of the drive (m, X + iY) and of
    /// mode 2's frequency `frequency2` (Hz, the PLL's output).
    pub fn reading(&self, s1: Complex64, frequency2: f64) -> BimodalReading {
        BimodalReading {
            free_amplitude: self.free_amplitude,
            amplitude: self.free_amplitude * s1.norm() / self.free1.norm(),
            // A lead of the tapping lever over the free one is a smaller lag.
            phase_lag: FRAC_PI_2 - (s1 / self.free1).arg(),
            frequency_shift: frequency2 - self.centre2,
        }
    }

    /// The bimodal expressions on `reading`.
    pub fn values(&self, reading: &BimodalReading) -> Result<BimodalValues, BimodalError> {
        let estimate = bimodal::estimate(&self.lever, reading)?;
        let sample = 1.0 / estimate.reduced_modulus - self.tip_term;
        Ok(BimodalValues {
            estimate,
            youngs_modulus: (sample > 0.0).then(|| self.sample_poisson_term / sample),
        })
    }
}

/// The constants of `s`, or why there is no estimate at them.
fn setup(s: &Settings) -> Result<BimodalSetup, String> {
    if !s.drive2.enable {
        return Err(
            "the second excitation is off (/drive2/enable): bimodal AFM reads mode 2's PLL on it"
                .to_owned(),
        );
    }
    let pll = s
        .pids
        .iter()
        .position(|p| {
            p.enable
                && p.oscillator == Oscillator::Drive2
                && p.input == PidInput::Phase
                && p.harmonic == 1
                && p.output == PidTarget::Drive2Frequency
        })
        .ok_or(
            "no PID unit is mode 2's PLL (enabled, input \"phase\", harmonic 1 of oscillator \
             \"drive2\", output \"drive2_frequency\")",
        )?;
    let cantilever = crate::model::cantilever(s).map_err(|e| e.to_string())?;
    let (Some(m1), Some(m2)) = (cantilever.modes.first(), cantilever.modes.get(1)) else {
        return Err("the lever has no second mode".to_owned());
    };
    let free1 = crate::synth::plan::free_reading(s)
        .filter(|z| z.norm() > 0.0)
        .ok_or("the free lever's reading at these settings is not defined")?;
    Ok(BimodalSetup {
        lever: BimodalLever {
            k1: m1.tip_stiffness(),
            q1: m1.q,
            k2: m2.tip_stiffness(),
            f2: s.drive2.frequency,
            tip_radius: s.cantilever.tip_radius,
        },
        free1,
        free_amplitude: s.drive.free_amplitude,
        pll,
        centre2: s.drive2.frequency,
        tip_term: (1.0 - s.tip.poisson * s.tip.poisson) / s.tip.youngs_modulus,
        sample_poisson_term: 1.0 - s.sample.poisson * s.sample.poisson,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn update(sample: u64) -> PidUpdate {
        PidUpdate {
            sample,
            epoch: 1,
            output: sample as f64,
            updates: sample / 10,
            ..PidUpdate::default()
        }
    }

    /// A frame is paired with the update in force at its sample, never a later one; the
    /// ring forgets the oldest, and another unit or a restart starts it afresh.
    #[test]
    fn the_pll_history_gives_the_update_in_force_at_a_sample() {
        let mut h = PllHistory::default();
        assert_eq!(h.at(1, 100), None);
        for s in [10, 20, 20, 30] {
            h.record(1, update(s));
        }
        assert_eq!(h.at(1, 5), None, "none at or before");
        assert_eq!(h.at(1, 10).map(|u| u.sample), Some(10));
        assert_eq!(h.at(1, 29).map(|u| u.sample), Some(20));
        assert_eq!(h.at(1, 1000).map(|u| u.sample), Some(30));
        assert_eq!(h.at(2, 1000), None, "another unit");
        for s in 4..(PLL_HISTORY as u64 + 4) {
            h.record(1, update(10 * s));
        }
        assert_eq!(h.at(1, 35), None, "the oldest forgotten");
        assert_eq!(h.at(1, 45).map(|u| u.sample), Some(40));
        h.record(1, update(15));
        assert_eq!(h.at(1, 1000).map(|u| u.sample), Some(15), "a restart");
        h.record(2, update(500));
        assert_eq!(h.at(1, 1000), None);
        assert_eq!(h.at(2, 1000).map(|u| u.sample), Some(500));
    }

    /// The message names the update it paired the frame with, and says when there is none
    /// at or before the frame.
    #[test]
    fn the_fields_name_the_pll_update_or_its_absence() {
        let mut s = crate::config::default_settings();
        s.drive2.enable = true;
        s.pids[1].enable = true;
        s.pids[1].oscillator = Oscillator::Drive2;
        s.pids[1].input = PidInput::Phase;
        s.pids[1].harmonic = 1;
        s.pids[1].output = PidTarget::Drive2Frequency;
        s.demods[0].enable = true;
        s.demods[0].harmonic = 1;
        s.demods[0].oscillator = Oscillator::Drive;
        let c = Calibration {
            epoch: 1,
            t: Some(0.0),
            rate: 1000.0,
            setup: BimodalSetup::of(&s),
        };
        assert_eq!(c.pll_unit(), Some(1), "{:?}", c.setup);
        let mut frame = DemodFrame::empty();
        frame.sample_index = 250;
        frame.t = 0.25;
        frame.len = 1;
        frame.values[0].harmonic = 1;
        frame.values[0].oscillator = Oscillator::Drive;
        frame.values[0].x = 1e-9;
        let none = c.fields(&frame, None);
        let reason = none["reason"].as_str().unwrap();
        assert!(reason.contains("at or before the frame"), "{reason}");
        assert!(none["pll_sample"].is_null() && none["pll_age"].is_null());
        let mut pll = update(200);
        pll.output = s.drive2.frequency + 100.0;
        let some = c.fields(&frame, Some(pll));
        assert_eq!(some["pll_sample"], 200, "{some}");
        assert_eq!(some["pll_age"].as_f64(), Some(0.05), "{some}");
        let shift = some["frequency_shift2"].as_f64().unwrap();
        assert!((shift - 100.0).abs() < 1e-6, "{some}");
        pll.epoch = 0;
        let other = c.fields(&frame, Some(pll));
        let reason = other["reason"].as_str().unwrap();
        assert!(
            reason.contains("epoch 1") && reason.contains("epoch 0"),
            "{reason}"
        );
    }
}
