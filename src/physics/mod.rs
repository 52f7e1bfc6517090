//! Pure maths of the paper (Stark & Heckl 2000): beam modes, contact mechanics, the 1-DOF
//! impact oscillator, spectra and transfer functions. No threads, no I/O.

pub mod beam;
pub mod bimodal;
pub mod contact;
pub mod coupled;
pub mod fm;
pub mod impact;
pub mod inversion;
pub mod sample_map;
pub mod spectrum;

pub use beam::{Cantilever, Mode};
pub use contact::{Adhesion, Elastic, HertzContact};
pub use coupled::{
    Branch, Continuation, CoupledError, CoupledOrbit, CoupledProblem, Jump, MAX_PERIODS,
    SearchLimits,
};
pub use impact::{ImpactOscillator, ImpactSolution, SolveOptions};
pub use sample_map::{Outline, Region, SampleMap};
pub use spectrum::Harmonic;
