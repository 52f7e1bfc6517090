//! The lock-in's reference for a recording: a sinusoid's frequency and phase measured from
//! samples (the excitation channel, or the signal's own fundamental), as an external
//! reference input or a PLL would lock to it.

use std::f64::consts::TAU;

use realfft::RealFftPlanner;

/// Longest stretch the spectrum's first estimate looks at (samples).
pub const MAX_FIT_SAMPLES: usize = 1 << 20;
/// Segments whose phases the refinement fits a line to.
const SEGMENTS: usize = 16;

/// A sinusoid A·cos(2πf·n/f_s + φ) fitted to samples.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Fit {
    /// Frequency (Hz).
    pub frequency: f64,
    /// Phase at the first sample (rad), cosine convention.
    pub phase: f64,
    /// Amplitude, peak (units of the samples).
    pub amplitude: f64,
    /// RMS of the segments' phases about the fitted line (rad): how steady the tone is.
    pub phase_residual: f64,
    /// Samples the fit used.
    pub samples: usize,
}

/// Phasor Σ w[n]·x[n]·e^{−iωn} over `x` whose first sample is sample `start`, ω in
/// rad/sample, w a Hann window over `x`: it keeps other tones (the harmonics) from leaking
/// in over a stretch that is not a whole number of their periods.
fn phasor(x: &[f64], omega: f64, start: usize) -> (f64, f64) {
    let (mut re, mut im) = (0.0, 0.0);
    let step = TAU / x.len() as f64;
    // The rotation is re-anchored every 1024 samples so its rounding does not accumulate.
    for (b, block) in x.chunks(1024).enumerate() {
        let n0 = (start + b * 1024) as f64;
        let (s0, c0) = (omega * n0).sin_cos();
        let (ds, dc) = omega.sin_cos();
        let (mut c, mut s) = (c0, s0);
        for (j, &v) in block.iter().enumerate() {
            let v = v * (0.5 - 0.5 * (step * ((b * 1024 + j) as f64 + 0.5)).cos());
            re += v * c;
            im -= v * s;
            (c, s) = (c * dc - s * ds, s * dc + c * ds);
        }
    }
    (re, im)
}

/// Fits the strongest tone of `x` (sampled at `fs`, Hz), within 10 % of `near` (Hz) if
/// given: the Hann-windowed spectrum's peak, interpolated, then refined by a line through
/// the phases of [`SEGMENTS`] stretches (a phase-stable fit). At most
/// [`MAX_FIT_SAMPLES`] samples are used.
pub fn fit(x: &[f64], fs: f64, near: Option<f64>) -> Result<Fit, String> {
    let len = x.len().min(MAX_FIT_SAMPLES);
    if len < 256 {
        return Err(format!(
            "{len} samples are too few to measure the reference (at least 256)"
        ));
    }
    let x = &x[..len];
    let n = 1usize << len.ilog2();
    let mut buf: Vec<f64> = x[..n]
        .iter()
        .enumerate()
        .map(|(j, v)| v * (0.5 - 0.5 * (TAU * j as f64 / n as f64).cos()))
        .collect();
    let fft = RealFftPlanner::<f64>::new().plan_fft_forward(n);
    let mut spec = fft.make_output_vec();
    fft.process(&mut buf, &mut spec)
        .expect("sizes from the plan");
    let mag: Vec<f64> = spec.iter().map(|c| c.norm().max(1e-300).ln()).collect();
    let bin = fs / n as f64;
    let (lo, hi) = match near {
        Some(f) => (
            ((0.9 * f / bin).floor() as usize).max(1),
            ((1.1 * f / bin).ceil() as usize + 1).min(mag.len() - 1),
        ),
        None => (2, mag.len() - 1),
    };
    if lo + 1 >= hi {
        return Err(format!(
            "no spectrum bins near {} Hz below the Nyquist frequency {} Hz",
            near.unwrap_or(0.0),
            fs / 2.0
        ));
    }
    let k = (lo..hi)
        .max_by(|&a, &b| mag[a].total_cmp(&mag[b]))
        .expect("a non-empty range");
    let (a, b, c) = (mag[k - 1], mag[k], mag[k + 1]);
    let denom = a - 2.0 * b + c;
    let delta = if denom.abs() > 0.0 {
        (0.5 * (a - c) / denom).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    let mut frequency = (k as f64 + delta) * bin;
    let seg = len / SEGMENTS;
    let centres: Vec<f64> = (0..SEGMENTS)
        .map(|j| (j * seg) as f64 + (seg as f64 - 1.0) / 2.0)
        .collect();
    let mut residual = 0.0;
    for _ in 0..4 {
        let omega = TAU * frequency / fs;
        let mut phases: Vec<f64> = Vec::with_capacity(SEGMENTS);
        for j in 0..SEGMENTS {
            let (re, im) = phasor(&x[j * seg..(j + 1) * seg], omega, j * seg);
            let mut p = im.atan2(re);
            if let Some(&prev) = phases.last() {
                p = prev + (p - prev + std::f64::consts::PI).rem_euclid(TAU) - std::f64::consts::PI;
            }
            phases.push(p);
        }
        let (mc, mp) = (
            centres.iter().sum::<f64>() / SEGMENTS as f64,
            phases.iter().sum::<f64>() / SEGMENTS as f64,
        );
        let sxx: f64 = centres.iter().map(|c| (c - mc).powi(2)).sum();
        let sxy: f64 = centres
            .iter()
            .zip(&phases)
            .map(|(c, p)| (c - mc) * (p - mp))
            .sum();
        let slope = sxy / sxx;
        residual = (centres
            .iter()
            .zip(&phases)
            .map(|(c, p)| (p - mp - slope * (c - mc)).powi(2))
            .sum::<f64>()
            / SEGMENTS as f64)
            .sqrt();
        frequency += slope * fs / TAU;
    }
    let omega = TAU * frequency / fs;
    let (re, im) = phasor(x, omega, 0);
    // The Hann window's sum.
    let gain = len as f64 / 2.0;
    Ok(Fit {
        frequency,
        phase: im.atan2(re),
        amplitude: 2.0 * re.hypot(im) / gain,
        phase_residual: residual,
        samples: len,
    })
}

/// Phase word (2^64 = one cycle, as [`crate::timebase`]) of `phase` (rad).
pub fn phase_word(phase: f64) -> u64 {
    let cycles = (phase / TAU).rem_euclid(1.0);
    (cycles * 18_446_744_073_709_551_616.0).round() as u128 as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tone_between_bins_is_found_to_a_fraction_of_a_millihertz() {
        let (fs, f, phi) = (2e6, 73_456.789, 1.234);
        let x: Vec<f64> = (0..200_000)
            .map(|n| {
                0.7 * (TAU * f * n as f64 / fs + phi).cos()
                    + 0.1 * (TAU * 3.0 * f * n as f64 / fs).cos()
            })
            .collect();
        let fit = fit(&x, fs, None).unwrap();
        assert!((fit.frequency - f).abs() < 1e-3, "{}", fit.frequency);
        assert!((fit.phase - phi).abs() < 1e-5, "{}", fit.phase);
        assert!((fit.amplitude - 0.7).abs() < 1e-4, "{}", fit.amplitude);
        let near = super::fit(&x, fs, Some(3.0 * f)).unwrap();
        assert!(
            (near.frequency - 3.0 * f).abs() < 1e-2,
            "{}",
            near.frequency
        );
        assert_eq!(phase_word(std::f64::consts::PI), 1 << 63);
    }
}
