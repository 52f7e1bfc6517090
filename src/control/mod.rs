//! Closed-loop control as pure maths: the discrete PID controller the real-time chain's
//! loops (`/pids/N/*`, LabOne's shape) are built from, the linear models of the loops it
//! will close (the PLL and the amplitude loop), their step responses, and an advisor that
//! sets the gains for a target bandwidth. No threads, no I/O; a layer beside `physics`,
//! depending on nothing else in the crate.
//!
//! The PID runs live in the synthesiser as the `/pids/N/*` units (`synth::pids`); the
//! advisor advises them through the op `pid_advise` (the PLL's plant
//! [`Plant::Resonator`], the units' demodulator [`Demodulator::pid_unit`]).

pub mod advisor;
pub mod loop_model;
pub mod pid;
pub mod step;

pub use advisor::{Advice, AdvisorError, Kind, advise};
pub use loop_model::{Demodulator, Gains, LoopModel, ModelError, Plant};
pub use pid::{Pid, PidError, PidSettings};
pub use step::{StepError, StepMetrics, StepTrace, discrete_step, model_step};
