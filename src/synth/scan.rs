//! The scan in the synthesiser: the tip moves over the sample map along the [`Raster`], the
//! material and surface height under it set the tap force, and the amplitude feedback (a PI
//! controller, as in every tapping-mode AFM) moves the sample to hold the photodiode
//! amplitude at the drive frequency at its setpoint.
//!
//! Once per drive period, at the drive phase opposite the pulse (so a pulse is never cut):
//! the feedback's own demodulator (a one-period boxcar of the photodiode samples, ADC and
//! noise included, mixed with the drive phase) gives the amplitude; the PI controller updates
//! the distance; then the region under the tip and the distance minus its height set the
//! tap force. On the paper engine they pick the cut cosine (F, τ, phase) from that region's
//! table of 1-DOF solutions, built off the real-time thread over a grid of distances and
//! interpolated linearly ([`super::scan_plan`]). On the coupled engine they set the surface
//! the integrated tip meets (its position and the region's Hertz stiffness), so topography
//! steps, feedback transients and inclusion edges are simulated, not interpolated.

use std::f64::consts::TAU;

use rustfft::num_complex::Complex64;

use super::coupled::CoupledKernel;
use super::period::{mix, samples_until};
use super::pids::ScanLoops;
use super::plan::SynthPlan;
use super::pulse::PulseKernel;
use super::raster::{PixelId, Raster};
use super::scan_plan::ScanPlan;
use super::synthesizer::{Output, SynthState};
use crate::timebase::{TWO_POW_64, phase_to_radians};

/// The feedback's and the topography's record of one pixel, from the synthesiser.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PixelTopography {
    /// The raster's generation.
    pub generation: u32,
    /// The pixel.
    pub pixel: PixelId,
    /// Mean distance the controller set, minus `/surface/distance` (m): the height image.
    pub height: f64,
    /// Mean amplitude the feedback's demodulator read (m, photodiode, peak).
    pub amplitude: f64,
    /// Mean frequency of the second excitation (Hz) while it drives: under mode 2's PLL
    /// the resonance it tracks, so less `/drive2/frequency` the pixel's Δf₂.
    pub frequency2: Option<f64>,
    /// Drive periods averaged.
    pub periods: u32,
}

/// The mutable side of a scan: raster position, controller, tap force. Owned by the
/// synthesiser thread; built off it (the pulse kernel has room for every mode).
#[derive(Clone, Debug)]
pub struct ScanRuntime {
    /// The running raster, if a scan runs.
    pub raster: Option<Raster>,
    generation: u32,
    /// Controller output: distance from the tip's rest position to the base surface (m).
    pub distance: f64,
    integral: f64,
    /// Amplitude read over the last drive period (m).
    pub amplitude: f64,
    /// Region under the tip.
    pub region: usize,
    /// Its surface height (m above the base).
    region_height: f64,
    pulse: PulseKernel,
    /// The coupled engine's kernel with the surface under the tip (a copy of the plan's;
    /// its distance and stiffness follow the scan).
    coupled: Option<CoupledKernel>,
    acc: Complex64,
    acc_count: u32,
    /// First sample of the period in progress, and of the next.
    period_start: u64,
    next_update: u64,
    /// Zero of the height channel: `/surface/distance` of the plan (m).
    distance_zero: f64,
    /// Pixel being accumulated and its sums.
    pixel: Option<PixelId>,
    sum_distance: f64,
    sum_amplitude: f64,
    sum_frequency2: f64,
    /// Whether the second excitation drove in the pixel's periods.
    frequency2: bool,
    periods: u32,
}

impl ScanRuntime {
    /// An idle runtime for `plan`'s sample period.
    pub fn new(plan: &SynthPlan) -> Self {
        Self {
            raster: None,
            generation: 0,
            distance: 0.0,
            integral: 0.0,
            amplitude: 0.0,
            region: 0,
            region_height: 0.0,
            pulse: PulseKernel::idle(plan.h),
            coupled: None,
            acc: Complex64::new(0.0, 0.0),
            acc_count: 0,
            period_start: 0,
            next_update: 0,
            distance_zero: 0.0,
            pixel: None,
            sum_distance: 0.0,
            sum_amplitude: 0.0,
            sum_frequency2: 0.0,
            frequency2: false,
            periods: 0,
        }
    }

    /// Follows a change of plan at sample `index`. A new or
    /// changed raster starts at `index`; the controller keeps its output across changes of
    /// gains or setpoint (bumpless) and starts at `/surface/distance` when a scan starts.
    /// Allocation-free.
    pub fn retarget(&mut self, old: &SynthPlan, new: &SynthPlan, index: u64) {
        let Some(scan) = &new.scan else {
            self.raster = None;
            self.pixel = None;
            return;
        };
        // A copy: fixed-size lanes, no allocation.
        self.coupled.clone_from(&new.coupled);
        let was = old.scan.as_ref();
        let restart = self.raster.is_none()
            || was.is_none_or(|w| w.settings != scan.settings || w.map != scan.map);
        self.distance_zero = scan.base_distance;
        if self.raster.is_none() {
            self.distance = scan.base_distance;
            self.integral = scan.base_distance;
            self.amplitude = scan.setpoint;
        }
        if restart {
            self.generation = self.generation.wrapping_add(1);
            self.raster = Some(Raster::new(
                &scan.settings,
                new.sample_rate,
                new.drive_frequency,
                index,
                self.generation,
            ));
            self.pixel = None;
            self.sum_distance = 0.0;
            self.sum_amplitude = 0.0;
            self.sum_frequency2 = 0.0;
            self.periods = 0;
        }
        // A fresh period starts here: the boxcar restarts and the force is set at once.
        self.acc = Complex64::new(0.0, 0.0);
        self.acc_count = 0;
        self.period_start = index;
        self.next_update = index;
    }
}

impl SynthPlan {
    /// Fills `out` with the next samples of a running scan (see the module docs), handing
    /// each finished pixel's topography to `pixel`. With `loops`, the PID units run beside
    /// the scan (bimodal AFM's mode-2 loops beside the scan's feedback; with
    /// `/feedback/enable` off, a unit on the surface distance is the feedback and loops on
    /// the drive may run too), each at its own update, their updates and reference changes
    /// handed to the sinks in `loops`. Allocation-free, lock-free. Without a scan in the
    /// plan it is [`process`](Self::process).
    pub fn process_scan(
        &self,
        state: &mut SynthState,
        rt: &mut ScanRuntime,
        mut loops: Option<ScanLoops<'_>>,
        out: &mut [f64],
        pixel: &mut impl FnMut(PixelTopography),
    ) {
        let (Some(scan), Some(raster)) = (&self.scan, rt.raster) else {
            self.process(state, out);
            return;
        };
        if let Some(l) = &mut loops {
            l.runtime.begin(self, state);
        }
        let word = self.frequency_word;
        let step = Complex64::from_polar(1.0, -(word as f64) / TWO_POW_64 * TAU);
        let mut done = 0;
        while done < out.len() {
            let index = state.sample_index();
            if index >= rt.next_update {
                // The second excitation and the surface in force over the period just
                // ended: the loops' where they move them.
                let (drive2, distance) = match &loops {
                    Some(l) => (l.runtime.drive2(), l.runtime.held_distance()),
                    None => (self.drive2, None),
                };
                let from_loops = FromLoops {
                    frequency2: drive2.map(|d| d.word as f64 / TWO_POW_64 * self.sample_rate),
                    distance,
                };
                self.update(scan, &raster, state.phase(), index, from_loops, rt, pixel);
            }
            let mut until = rt.next_update;
            if let Some(l) = &mut loops {
                if index >= l.runtime.next_update() {
                    self.update_pids(state, index, l.runtime, &mut l.reading, &mut l.reference);
                }
                until = until.min(l.runtime.next_update());
            }
            let n = ((until - index) as usize).min(out.len() - done);
            let segment = &mut out[done..done + n];
            let phase = state.phase();
            match (&mut loops, &rt.coupled) {
                (Some(l), Some(under_tip)) => {
                    // One kernel: the loops' (it carries the excitations they move) with the
                    // surface under the tip: the region's, at the distance a unit sets from
                    // its update on, else the scan's feedback.
                    let distance = match l.runtime.held_distance() {
                        Some(d) => d - rt.region_height,
                        None => under_tip.distance,
                    };
                    l.runtime.set_surface(distance, under_tip.stiffness);
                    let (drive, drive2, coupled) = l.runtime.drives();
                    self.process_with(
                        drive,
                        drive2,
                        None,
                        coupled,
                        state,
                        Output::Samples(segment),
                    );
                }
                (None, Some(coupled)) => self.process_with(
                    &self.drive,
                    self.drive2.as_ref(),
                    None,
                    Some(coupled),
                    state,
                    Output::Samples(segment),
                ),
                (_, None) => self.process_with(
                    &self.drive,
                    None,
                    Some(&rt.pulse),
                    None,
                    state,
                    Output::Samples(segment),
                ),
            }
            if let Some(l) = &mut loops {
                l.runtime.demodulate(segment, index);
            }
            // The feedback's demodulator: Σ s·e^{−iθ} over the period.
            let rho = Complex64::from_polar(1.0, -phase_to_radians(phase));
            rt.acc += mix(segment, rho, step);
            rt.acc_count += n as u32;
            done += n;
        }
    }

    /// Once per drive period: amplitude, controller, pixel bookkeeping, tap force.
    #[allow(clippy::too_many_arguments)]
    fn update(
        &self,
        scan: &ScanPlan,
        raster: &Raster,
        phase: u64,
        index: u64,
        from_loops: FromLoops,
        rt: &mut ScanRuntime,
        pixel: &mut impl FnMut(PixelTopography),
    ) {
        let fb = &scan.feedback;
        let frequency2 = from_loops.frequency2;
        if let Some(distance) = from_loops.distance {
            // A PID unit is the feedback.
            rt.distance = distance;
        }
        if rt.acc_count > 0 {
            let n = f64::from(rt.acc_count);
            rt.amplitude = 2.0 * rt.acc.norm() / n;
            // The period just ended belongs to the pixel it started in.
            if let Some(id) = raster.pixel_at(rt.period_start) {
                if rt.pixel.is_some_and(|p| p.serial != id.serial) {
                    rt.flush_pixel(raster.generation, pixel);
                }
                rt.pixel = Some(id);
                rt.sum_distance += rt.distance;
                rt.sum_amplitude += rt.amplitude;
                rt.frequency2 = frequency2.is_some();
                rt.sum_frequency2 += frequency2.unwrap_or(0.0);
                rt.periods += 1;
            }
            if from_loops.distance.is_some() {
                rt.integral = rt.distance;
            } else if fb.enable {
                let error = scan.setpoint - rt.amplitude;
                rt.integral =
                    (rt.integral + fb.integral * error * n * self.h).clamp(0.0, scan.max_distance);
                rt.distance = (rt.integral + fb.proportional * error).clamp(0.0, scan.max_distance);
            } else {
                rt.distance = scan.base_distance;
                rt.integral = scan.base_distance;
            }
        }
        rt.acc = Complex64::new(0.0, 0.0);
        rt.acc_count = 0;
        rt.period_start = index;
        rt.next_update = index + samples_until(phase, scan.update_phase, self.frequency_word);

        let (x, y) = raster.position(index);
        rt.region = scan.map.region_at(x, y);
        let region = &scan.map.regions()[rt.region];
        rt.region_height = region.height;
        let distance = rt.distance - region.height;
        if let Some(coupled) = &mut rt.coupled {
            coupled.distance = distance;
            coupled.stiffness = scan.stiffness[rt.region];
        } else if let Some(tables) = &scan.tables {
            let train = tables.regions[rt.region].at(distance);
            rt.pulse
                .retune(&train, self.h, self.frequency_word, &self.modes);
        }
    }
}

/// What the PID units beside a scan set over the period just ended.
#[derive(Clone, Copy, Debug)]
struct FromLoops {
    /// The second excitation's frequency (Hz), while it drives.
    frequency2: Option<f64>,
    /// The surface distance (m), where a unit drives it: the scan's feedback then.
    distance: Option<f64>,
}

impl ScanRuntime {
    fn flush_pixel(&mut self, generation: u32, sink: &mut impl FnMut(PixelTopography)) {
        if let Some(id) = self.pixel
            && self.periods > 0
        {
            let n = f64::from(self.periods);
            sink(PixelTopography {
                generation,
                pixel: id,
                height: self.sum_distance / n - self.distance_zero,
                amplitude: self.sum_amplitude / n,
                frequency2: self.frequency2.then(|| self.sum_frequency2 / n),
                periods: self.periods,
            });
        }
        self.sum_distance = 0.0;
        self.sum_amplitude = 0.0;
        self.sum_frequency2 = 0.0;
        self.periods = 0;
    }
}
