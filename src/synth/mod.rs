//! Photodiode synthesis on the real-time thread: every flexural mode as an exactly
//! discretised oscillator, driven at the base and by the tap force, with thermal,
//! detector and ADC noise, and the ADC's anti-alias filter ([`adc`]). [`SynthPlan`] is built off the real-time thread; its
//! [`process`](SynthPlan::process) fills blocks without allocating, locking or blocking.

pub mod adc;
pub mod coupled;
pub mod digitiser;
pub mod drive;
mod lanes;
pub mod modal;
pub mod noise_pages;
pub mod normals;
mod period;
pub(crate) mod phasor;
pub mod pid_plan;
pub mod pids;
pub mod plan;
pub mod pulse;
pub mod raster;
pub mod scan;
pub mod scan_plan;
pub mod synthesizer;
pub mod window;

pub use adc::{Adc, AdcHistory, WindowSample};
pub use coupled::{CoupledKernel, CoupledTrace, DEFAULT_SUBSTEP_BUDGET, DEFAULT_SUBSTEPS};
pub use digitiser::{Digitiser, DigitiserInput};
pub use drive::{Drive, ReferenceChange};
pub use pid_plan::{PidPlan, PidUnitPlan};
pub use pids::{
    PENDING_REFERENCES, PLL_LOCK_PHASE, PLL_LOCK_UPDATES, PidReading, PidRuntime, PidSums,
    ScanLoops,
};
pub use plan::{BOLTZMANN, PlanError, SynthPlan, TapForce};
pub use pulse::PulseTrain;
pub use raster::{PixelId, Raster};
pub use scan::{PixelTopography, ScanRuntime};
pub use scan_plan::{ScanPlan, TapTable, TapTables, sample_map};
pub use synthesizer::{SynthCounters, SynthState};
