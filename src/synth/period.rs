//! What the loops run once a drive period share (the scan's feedback,
//! [`super::scan`], and the PID units, [`super::pids`]): where the next update falls, and
//! the boxcar demodulator's mixing sum.

use rustfft::num_complex::Complex64;

/// Samples from phase word `phase` until the drive phase first passes `target` (at least 1):
/// where a loop run once per drive period (the scan's, the PID units') next updates.
pub(super) fn samples_until(phase: u64, target: u64, word: u64) -> u64 {
    let words = target.wrapping_sub(phase).wrapping_sub(1);
    (u128::from(words) / u128::from(word.max(1))) as u64 + 1
}

/// Σ sₙ·ρ0·rⁿ over the samples sₙ of `piece`: a boxcar demodulator's sum, with the mixing
/// phasor ρ0 = e^{−iθ} and its step r = `step` per sample. Four interleaved phasors (each
/// stepping by r⁴) make four independent chains of multiply–adds, which a core runs in
/// parallel where one chain would wait on each product in turn.
pub(super) fn mix(piece: &[f64], rho0: Complex64, step: Complex64) -> Complex64 {
    let step2 = step * step;
    let step4 = step2 * step2;
    let mut rho = [rho0, rho0 * step, rho0 * step2, rho0 * step2 * step];
    let mut acc = [Complex64::new(0.0, 0.0); 4];
    let mut chunks = piece.chunks_exact(4);
    for chunk in &mut chunks {
        for lane in 0..4 {
            acc[lane] += rho[lane] * chunk[lane];
            rho[lane] *= step4;
        }
    }
    let mut tail = rho[0];
    let mut sum = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for &s in chunks.remainder() {
        sum += tail * s;
        tail *= step;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The interleaved mixing sum against the terms summed one by one, at every length's
    /// remainder.
    #[test]
    fn mix_is_the_sum() {
        let rho0 = Complex64::from_polar(1.0, 0.3);
        let step = Complex64::from_polar(1.0, -0.0271);
        for len in [0usize, 1, 3, 4, 5, 97, 100, 4096] {
            let piece: Vec<f64> = (0..len).map(|n| (n as f64 * 0.37).sin() + 0.1).collect();
            let mut direct = Complex64::new(0.0, 0.0);
            for (n, &s) in piece.iter().enumerate() {
                direct += rho0 * step.powu(n as u32) * s;
            }
            let mixed = mix(&piece, rho0, step);
            assert!(
                (mixed - direct).norm() < 1e-11 * (len as f64).max(1.0),
                "{len}: {mixed} against {direct}"
            );
        }
    }
}
