//! Real-time signal processing blocks: lock-in demodulators and the sliding spectrum.
//! Blocks take preallocated state and never allocate, lock, log or block in `process`.
