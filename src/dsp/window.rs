//! Spectral windows for the sliding spectrum: cosine sums in their periodic (DFT-even) form.

use std::f64::consts::TAU;

/// A window for [`SlidingSpectrum`](super::SlidingSpectrum).
///
/// All are cosine sums `w[j] = Σ_m (−1)^m a_m cos(2π m j / N)`, j = 0…N−1, in the periodic
/// form, so a tone exactly on a bin leaks into no bin outside the main lobe.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Window {
    /// Boxcar: narrowest main lobe, −13 dB side lobes, scallop loss 36 %.
    Rectangular,
    /// Hann (raised cosine): −31 dB side lobes, scallop loss 15 %.
    #[default]
    Hann,
    /// Four-term Blackman–Harris (Harris 1978): −92 dB side lobes, scallop loss 9.1 %.
    BlackmanHarris,
    /// Flat-top HFT95 (Heinzel, Rüdiger & Schilling 2002): −95 dB side lobes, scallop loss
    /// below 0.06 %, so any tone's peak bin reads its amplitude within 10⁻³.
    FlatTop,
}

impl Window {
    /// Every window, for tests and menus.
    pub const ALL: [Window; 4] = [
        Window::Rectangular,
        Window::Hann,
        Window::BlackmanHarris,
        Window::FlatTop,
    ];

    /// Cosine-sum coefficients a_m (unnormalised; only ratios matter once calibrated).
    pub const fn coefficients(self) -> &'static [f64] {
        match self {
            Window::Rectangular => &[1.0],
            Window::Hann => &[0.5, 0.5],
            Window::BlackmanHarris => &[0.35875, 0.48829, 0.14128, 0.01168],
            Window::FlatTop => &[1.0, 1.9383379, 1.3045202, 0.4028270, 0.0350665],
        }
    }

    /// Window value at sample `j` of a window of length `len`.
    pub fn value(self, j: usize, len: usize) -> f64 {
        let x = TAU * j as f64 / len as f64;
        self.coefficients()
            .iter()
            .enumerate()
            .map(|(m, a)| {
                let sign = if m % 2 == 0 { 1.0 } else { -1.0 };
                sign * a * (m as f64 * x).cos()
            })
            .sum()
    }

    /// Fill `out` with the window of length `out.len()`.
    pub fn fill(self, out: &mut [f64]) {
        let len = out.len();
        for (j, w) in out.iter_mut().enumerate() {
            *w = self.value(j, len);
        }
    }

    /// Magnitude of the window's transform at `offset` bins from its centre, relative to
    /// the centre (1 at 0): the reading of a tone `offset` bins from the bin it is read in.
    /// Evaluated for a window of `len` samples.
    pub fn response(self, offset: f64, len: usize) -> f64 {
        let (mut re, mut im, mut sum) = (0.0, 0.0, 0.0);
        for j in 0..len {
            let w = self.value(j, len);
            let (s, c) = (TAU * offset * j as f64 / len as f64).sin_cos();
            re += w * c;
            im -= w * s;
            sum += w;
        }
        re.hypot(im) / sum
    }

    /// Scallop loss (1): the fraction of a tone's amplitude lost, at worst, in its peak bin,
    /// which is when the tone lies half-way between two bins: `1 − response(½)`.
    pub fn scallop_loss(self, len: usize) -> f64 {
        1.0 - self.response(0.5, len)
    }

    /// Equivalent noise bandwidth in bins: `N Σw² / (Σw)²` (1 for the boxcar).
    pub fn enbw_bins(self, len: usize) -> f64 {
        let (mut s1, mut s2) = (0.0, 0.0);
        for j in 0..len {
            let w = self.value(j, len);
            s1 += w;
            s2 += w * w;
        }
        len as f64 * s2 / (s1 * s1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scallop_losses_match_the_literature() {
        let n = 1024;
        let expect = [
            (Window::Rectangular, 0.3634),
            (Window::Hann, 0.1514),
            (Window::BlackmanHarris, 0.0910),
        ];
        for (w, loss) in expect {
            assert!((w.scallop_loss(n) - loss).abs() < 2e-3, "{w:?}");
        }
        assert!(Window::FlatTop.scallop_loss(n).abs() < 1e-3);
    }

    #[test]
    fn flat_top_is_flat_across_the_bin() {
        for i in 0..=50 {
            let r = Window::FlatTop.response(i as f64 / 100.0, 512);
            assert!((r - 1.0).abs() < 1e-3, "offset {i}/100: {r}");
        }
    }

    #[test]
    fn enbw_in_bins() {
        assert!((Window::Rectangular.enbw_bins(256) - 1.0).abs() < 1e-12);
        assert!((Window::Hann.enbw_bins(256) - 1.5).abs() < 1e-12);
        assert!((Window::BlackmanHarris.enbw_bins(256) - 2.0044).abs() < 1e-3);
    }
}
