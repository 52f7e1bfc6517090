//! The header the synthesiser sends with every block of samples: where the block sits in
//! the stream and the exact drive phase, so the DSP's reference stays locked to it, and
//! how to finish its samples.

/// Describes one block of samples in the sample ring.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlockHeader {
    /// Index of the block's first sample.
    pub index: u64,
    /// Samples in the block.
    pub len: u32,
    /// Drive phase word of the first sample (2^64 = one period).
    pub phase: u64,
    /// Drive phase words per sample.
    pub frequency_word: u64,
    /// `/drive2`'s phase word of the first sample and its phase words per sample: the
    /// reference of the demodulators on oscillator `"drive2"` (whether or not it drives).
    pub phase2: u64,
    pub frequency_word2: u64,
    /// Unix time (ns) when the block's newest sample was synthesised.
    pub t_synth_ns: u64,
    /// The raster of the scan in progress, if one runs.
    pub raster: Option<crate::synth::Raster>,
    /// The settings epoch in force from this block on ([`Pipeline::apply`]'s count): the
    /// DSP thread takes up a plan of this epoch with this block, so a change of the
    /// synthesis and of the lock-in lands on one sample boundary.
    ///
    /// [`Pipeline::apply`]: super::Pipeline::apply
    pub epoch: u64,
    /// How the DSP thread finishes the block's window samples into samples; `None`: the
    /// synthesiser finished them (a scan's feedback reads them), and the ring holds them in
    /// the window samples' `grid`.
    pub digitise: Option<crate::synth::DigitiserInput>,
    /// How many changes of the lock-in's reference fall in the block (a PID unit moving the
    /// drive frequency: a PLL), in the reference ring in order, each at its sample.
    pub references: u32,
    /// The PID units' running sums after the block ([`crate::synth::PidSums`]): the demod
    /// frames of the block carry them, so a mean of the loops over frames is one of the
    /// same stretch of the stream.
    pub pids: [crate::synth::PidSums; crate::config::PID_COUNT],
}

/// Unix time in ns now.
pub fn unix_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}
