//! What a scan needs, built off the real-time thread from the settings ([`ScanPlan`]): the
//! sample map, the Hertz stiffness of the tip on each region, the amplitude the feedback
//! holds, the drive phase at which the tap force is updated and, on the paper engine, the
//! tap tables ([`TapTables`]): per region, the cut-cosine tap force of the 1-DOF solution
//! over a grid of distances, interpolated linearly. The synthesiser's side of a running
//! scan (raster, feedback, the tap force following the sample) is [`super::scan`]'s.

use std::f64::consts::{PI, TAU};
use std::sync::Arc;

use rustfft::num_complex::Complex64;

use super::pulse::PulseTrain;
use crate::config::{FeedbackSettings, Material, ScanSettings, Settings};
use crate::model;
use crate::physics::spectrum::{cut_cosine_train, photodiode_transfer};
use crate::physics::{Cantilever, Elastic, SampleMap};
use crate::timebase::TWO_POW_64;

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
    ) -> Self {
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
        let update_phase = ((centre / TAU).rem_euclid(1.0) * TWO_POW_64) as u64 ^ (1 << 63);
        Self {
            settings: settings.scan.clone(),
            feedback: settings.feedback.clone(),
            map,
            tables,
            stiffness,
            setpoint,
            base_distance: settings.surface.distance,
            max_distance: 2.0 * settings.drive.free_amplitude.max(settings.surface.distance),
            update_phase,
        }
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
