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
//! interpolated linearly. On the coupled engine they set the surface the integrated tip
//! meets (its position and the region's Hertz stiffness), so topography steps, feedback
//! transients and inclusion edges are simulated, not interpolated.

use std::f64::consts::{PI, TAU};
use std::sync::Arc;

use rustfft::num_complex::Complex64;

use super::coupled::CoupledKernel;
use super::plan::{PlanError, SynthPlan, TURN};
use super::pulse::{PulseKernel, PulseTrain};
use super::raster::{PixelId, Raster};
use super::synthesizer::Output;
use crate::config::{FeedbackSettings, Material, ScanSettings, Settings};
use crate::model;
use crate::physics::spectrum::{cut_cosine_train, photodiode_transfer};
use crate::physics::{Cantilever, Elastic, SampleMap};
use crate::timebase::phase_to_radians;

/// Distance grid of the tap tables: this fraction of the free amplitude per step (0.5 nm
/// at 30 nm).
const TABLE_STEP: f64 = 1.0 / 60.0;

/// The cut-cosine tap force of one region as a function of the distance from the tip's rest
/// position to the region's surface.
#[derive(Clone, Debug)]
pub struct TapTable {
    /// Distance of entry 0 (m).
    first: f64,
    /// Distance step (m).
    step: f64,
    /// The pulse train at each distance; F = 0 where the tip does not reach the surface.
    trains: Vec<PulseTrain>,
}

impl TapTable {
    /// The tap force at `distance` (m): linear between entries, the end entries beyond.
    pub fn at(&self, distance: f64) -> PulseTrain {
        let last = self.trains.len() - 1;
        let u = ((distance - self.first) / self.step).clamp(0.0, last as f64);
        let i = (u.floor() as usize).min(last.saturating_sub(1));
        let f = u - i as f64;
        let (a, b) = (&self.trains[i], &self.trains[(i + 1).min(last)]);
        if a.max_force == 0.0 || b.max_force == 0.0 {
            // Contact begins between the two: take the nearer rather than blend a pulse
            // with no pulse.
            return if f < 0.5 { *a } else { *b };
        }
        let dphase = (b.centre_phase - a.centre_phase + PI).rem_euclid(TAU) - PI;
        PulseTrain {
            max_force: a.max_force + f * (b.max_force - a.max_force),
            tau: a.tau + f * (b.tau - a.tau),
            centre_phase: a.centre_phase + f * dphase,
        }
    }

    /// The distances of the grid (m).
    pub fn distances(&self) -> impl Iterator<Item = f64> + '_ {
        (0..self.trains.len()).map(|i| self.first + i as f64 * self.step)
    }
}

/// What the tables depend on: a scan change that leaves these alone reuses them.
#[derive(Clone, Debug, PartialEq)]
struct TableKey {
    cantilever: crate::config::CantileverSettings,
    tip: Material,
    drive: crate::config::DriveSettings,
    distance: f64,
    materials: Vec<(f64, f64)>,
}

/// One [`TapTable`] per region of the sample map.
#[derive(Debug)]
pub struct TapTables {
    key: TableKey,
    /// Per region, in [`SampleMap::regions`] order.
    pub regions: Vec<TapTable>,
    /// Grid points whose 1-DOF solve failed (filled from the nearest neighbour).
    pub failed: usize,
}

impl TapTables {
    fn build(settings: &Settings, cantilever: &Cantilever, map: &SampleMap, key: TableKey) -> Self {
        let d0 = settings.surface.distance;
        let a_free = settings.drive.free_amplitude;
        let step = a_free * TABLE_STEP;
        let lower = (0.25 * d0).max(d0 - 0.5 * a_free);
        let j_lo = ((lower - d0) / step).floor() as i64;
        let j_hi = ((a_free - d0) / step).ceil() as i64 + 2;
        let first = d0 + j_lo as f64 * step;
        let count = (j_hi - j_lo + 1) as usize;
        let solve_region = |material: Elastic| -> (TapTable, usize) {
            let mut s = settings.clone();
            let sample = Material {
                youngs_modulus: material.youngs_modulus,
                poisson: material.poisson,
            };
            let mut trains: Vec<Option<PulseTrain>> = (0..count)
                .map(|i| {
                    s.surface.distance = first + i as f64 * step;
                    let solution = model::impact_oscillator(&s, cantilever, sample).solve();
                    solution.ok().map(|sol| {
                        if sol.in_contact() {
                            PulseTrain {
                                max_force: sol.max_force,
                                tau: sol.contact_time_ratio,
                                centre_phase: sol.pulse_phase,
                            }
                        } else {
                            PulseTrain {
                                max_force: 0.0,
                                tau: 0.0,
                                centre_phase: 0.0,
                            }
                        }
                    })
                })
                .collect();
            let failed = trains.iter().filter(|t| t.is_none()).count();
            // Fill failures from the nearest solved neighbour.
            let solved: Vec<(usize, PulseTrain)> = trains
                .iter()
                .enumerate()
                .filter_map(|(i, t)| t.map(|t| (i, t)))
                .collect();
            for (i, slot) in trains.iter_mut().enumerate() {
                if slot.is_none() {
                    *slot = solved
                        .iter()
                        .min_by_key(|(j, _)| j.abs_diff(i))
                        .map(|(_, t)| *t);
                }
            }
            let trains = trains
                .into_iter()
                .map(|t| {
                    t.unwrap_or(PulseTrain {
                        max_force: 0.0,
                        tau: 0.0,
                        centre_phase: 0.0,
                    })
                })
                .collect();
            (
                TapTable {
                    first,
                    step,
                    trains,
                },
                failed,
            )
        };
        // Regions in parallel: ~0.1 s each on one core.
        let materials: Vec<Elastic> = map.regions().iter().map(|r| r.material).collect();
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let chunk = materials.len().div_ceil(threads).max(1);
        let results: Vec<(TapTable, usize)> = std::thread::scope(|scope| {
            let handles: Vec<_> = materials
                .chunks(chunk)
                .map(|part| {
                    let solve = &solve_region;
                    scope.spawn(move || part.iter().map(|m| solve(*m)).collect::<Vec<_>>())
                })
                .collect();
            handles
                .into_iter()
                .flat_map(|h| h.join().expect("tap table thread"))
                .collect()
        });
        let failed = results.iter().map(|(_, f)| f).sum();
        Self {
            key,
            regions: results.into_iter().map(|(t, _)| t).collect(),
            failed,
        }
    }
}

/// The sample map of the settings: `/sample` as the base, enabled `/inclusions/N` on it in
/// index order.
pub fn sample_map(settings: &Settings) -> SampleMap {
    use crate::config::InclusionShape;
    use crate::physics::{Outline, Region};
    let mut map = SampleMap::uniform(model::elastic(settings.sample));
    for inc in settings.inclusions.iter().filter(|i| i.enable) {
        let outline = match inc.shape {
            InclusionShape::Disc => Outline::Disc {
                x: inc.x,
                y: inc.y,
                radius: 0.5 * inc.width,
            },
            InclusionShape::Rectangle => Outline::Rectangle {
                x: inc.x,
                y: inc.y,
                half_width: 0.5 * inc.width,
                half_length: 0.5 * inc.length,
            },
        };
        map.add(
            outline,
            Region {
                material: Elastic {
                    youngs_modulus: inc.youngs_modulus,
                    poisson: inc.poisson,
                },
                height: inc.height,
            },
        );
    }
    map
}

/// Everything a running scan needs, built off the real-time thread.
#[derive(Clone, Debug)]
pub struct ScanPlan {
    /// `/scan/...`.
    pub settings: ScanSettings,
    /// `/feedback/...`.
    pub feedback: FeedbackSettings,
    /// The sample.
    pub map: SampleMap,
    /// Tap force per region over distance (the paper engine's; `None` on the coupled
    /// engine).
    pub tables: Option<Arc<TapTables>>,
    /// Hertz prefactor κ_eff·√R of the tip on each region (N/m^{3/2}), in
    /// [`SampleMap::regions`] order: the coupled engine's contact.
    pub stiffness: Vec<f64>,
    /// Amplitude the feedback holds (m, photodiode, peak): `/feedback/setpoint`, or the
    /// steady amplitude at `/surface/distance` over the base when that is 0.
    pub setpoint: f64,
    /// `/surface/distance` (m): where the controller starts, and the zero of the height.
    pub base_distance: f64,
    /// The controller's output stays within [0, this] (m).
    pub max_distance: f64,
    /// Drive phase word at which the tap force is updated: opposite the pulse.
    pub update_phase: u64,
}

impl ScanPlan {
    /// The plan for `settings`. On the paper engine (`base` = [`ScanBase::Paper`]) it
    /// reuses `cache` when the physics it was built for is the same (a change of the raster
    /// or the gains then costs nothing), else solves the 1-DOF problem over the distance
    /// grid for every region (~0.1 s per region per core); the coupled engine needs no
    /// tables.
    pub fn new(
        settings: &Settings,
        cantilever: &Cantilever,
        base: ScanBase,
        cache: Option<&Arc<TapTables>>,
    ) -> Result<Self, PlanError> {
        let map = sample_map(settings);
        let stiffness = map
            .regions()
            .iter()
            .map(|r| {
                let material = Material {
                    youngs_modulus: r.material.youngs_modulus,
                    poisson: r.material.poisson,
                };
                model::impact_oscillator(settings, cantilever, material)
                    .contact
                    .stiffness_coefficient()
            })
            .collect();
        let (setpoint, centre, tables) = match base {
            ScanBase::Paper {
                drive_signal,
                drive_frequency,
                train,
            } => {
                let tables = Self::tables(settings, cantilever, &map, cache);
                let omega = 2.0 * PI * drive_frequency;
                let tap = train.map_or(Complex64::new(0.0, 0.0), |t| {
                    let c1 = cut_cosine_train(t.max_force, t.tau, t.centre_phase, 1)[1];
                    photodiode_transfer(cantilever, omega) * c1 * 2.0
                });
                let centre = train.map_or(PI, |t| t.centre_phase);
                ((drive_signal + tap).norm(), centre, Some(tables))
            }
            ScanBase::Coupled {
                amplitude,
                force_phase,
            } => (amplitude, force_phase.unwrap_or(PI), None),
        };
        let setpoint = if settings.feedback.setpoint > 0.0 {
            settings.feedback.setpoint
        } else {
            setpoint
        };
        let update_phase = ((centre / TAU).rem_euclid(1.0) * TURN) as u64 ^ (1 << 63);
        Ok(Self {
            settings: settings.scan.clone(),
            feedback: settings.feedback.clone(),
            map,
            tables,
            stiffness,
            setpoint,
            base_distance: settings.surface.distance,
            max_distance: 2.0 * settings.drive.free_amplitude.max(settings.surface.distance),
            update_phase,
        })
    }

    /// The paper engine's tap tables for `settings`: `cache` when it fits, else built.
    fn tables(
        settings: &Settings,
        cantilever: &Cantilever,
        map: &SampleMap,
        cache: Option<&Arc<TapTables>>,
    ) -> Arc<TapTables> {
        let key = TableKey {
            cantilever: settings.cantilever.clone(),
            tip: settings.tip,
            drive: settings.drive.clone(),
            distance: settings.surface.distance,
            materials: map
                .regions()
                .iter()
                .map(|r| (r.material.youngs_modulus, r.material.poisson))
                .collect(),
        };
        match cache {
            Some(t) if t.key == key => t.clone(),
            _ => Arc::new(TapTables::build(settings, cantilever, map, key)),
        }
    }
}

/// What a scan starts from: the tip's steady state over the base at `/surface/distance`,
/// as the engine computes it.
#[derive(Clone, Copy, Debug)]
pub enum ScanBase {
    /// The paper engine: the free photodiode response and the 1-DOF tap force.
    Paper {
        /// Steady drive response of the photodiode: Re[Ŝ e^{iθ}] (m).
        drive_signal: Complex64,
        /// Drive frequency (Hz).
        drive_frequency: f64,
        /// The cut cosine of the 1-DOF solution, if the tip touches the base.
        train: Option<PulseTrain>,
    },
    /// The coupled engine, from its own periodic orbit.
    Coupled {
        /// Photodiode amplitude at the drive frequency (m, peak).
        amplitude: f64,
        /// Drive phase of the largest tip force (rad), if the tip touches the base.
        force_phase: Option<f64>,
    },
}

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
            self.periods = 0;
        }
        // A fresh period starts here: the boxcar restarts and the force is set at once.
        self.acc = Complex64::new(0.0, 0.0);
        self.acc_count = 0;
        self.period_start = index;
        self.next_update = index;
    }
}

/// Samples from phase word `phase` until the drive phase first passes `target` (at least 1).
fn samples_until(phase: u64, target: u64, word: u64) -> u64 {
    let words = target.wrapping_sub(phase).wrapping_sub(1);
    (u128::from(words) / u128::from(word.max(1))) as u64 + 1
}

impl SynthPlan {
    /// Fills `out` with the next samples of a running scan (see the module docs), handing
    /// each finished pixel's topography to `pixel`. Allocation-free, lock-free. Without a
    /// scan in the plan it is [`process`](Self::process).
    pub fn process_scan(
        &self,
        state: &mut super::SynthState,
        rt: &mut ScanRuntime,
        out: &mut [f64],
        pixel: &mut impl FnMut(PixelTopography),
    ) {
        let (Some(scan), Some(raster)) = (&self.scan, rt.raster) else {
            self.process(state, out);
            return;
        };
        let word = self.frequency_word;
        let step = Complex64::from_polar(1.0, -(word as f64) / TURN * TAU);
        let mut done = 0;
        while done < out.len() {
            let index = state.sample_index();
            if index >= rt.next_update {
                self.update(scan, &raster, state.phase(), index, rt, pixel);
            }
            let n = ((rt.next_update - index) as usize).min(out.len() - done);
            let segment = &mut out[done..done + n];
            let phase = state.phase();
            match &rt.coupled {
                Some(coupled) => {
                    self.process_with(None, Some(coupled), state, Output::Samples(segment))
                }
                None => self.process_with(Some(&rt.pulse), None, state, Output::Samples(segment)),
            }
            // The feedback's demodulator: Σ s·e^{−iθ} over the period.
            let mut rho = Complex64::from_polar(1.0, -phase_to_radians(phase));
            let mut acc = rt.acc;
            for &s in segment.iter() {
                acc += rho * s;
                rho *= step;
            }
            rt.acc = acc;
            rt.acc_count += n as u32;
            done += n;
        }
    }

    /// Once per drive period: amplitude, controller, pixel bookkeeping, tap force.
    fn update(
        &self,
        scan: &ScanPlan,
        raster: &Raster,
        phase: u64,
        index: u64,
        rt: &mut ScanRuntime,
        pixel: &mut impl FnMut(PixelTopography),
    ) {
        let fb = &scan.feedback;
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
                rt.periods += 1;
            }
            if fb.enable {
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
                periods: self.periods,
            });
        }
        self.sum_distance = 0.0;
        self.sum_amplitude = 0.0;
        self.periods = 0;
    }
}
