//! Pure maths of the paper (Stark & Heckl 2000): beam modes, contact mechanics, the 1-DOF
//! impact oscillator, spectra and transfer functions. No threads, no I/O.
