//! What one measuring period records: the force samples, the work terms and the force's
//! Fourier coefficients.

use rustfft::num_complex::Complex64;

use super::CoupledError;
use super::period_map::{CONTACT_STEP_MEASURE, PeriodMap};

/// Harmonics of the force summed on the integrator's points; beyond, by FFT.
pub(super) const DENSE_HARMONICS: usize = 64;
/// Points per period of the force's FFT for the harmonics beyond [`DENSE_HARMONICS`]: the
/// grid step is T/65536, and the interpolant's content that folds onto harmonic j ≤ 1024
/// comes from harmonics ≥ 64 512, ~10⁻⁴ of the 1024th's.
pub(super) const FFT_POINTS: usize = 1 << 16;
/// Gauss–Legendre nodes on [−1, 1] and their weights, 4 points.
const GAUSS_LEGENDRE_4: [(f64, f64); 4] = [
    (-0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
    (-0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
    (0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
    (0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
];

/// Two-sided Fourier coefficients c_j = (1/T)∫g e^{−ijΩt}dt, j = 0..=harmonics, of the force
/// recorded at `samples` (t, g, δ) in one period [0, T), linear between them and zero before
/// the first and after the last (the record starts and ends where g vanishes, and between
/// contacts its points are where g = 0 and g ≈ 0⁺), by the FFT of that on a uniform grid.
pub(super) fn fft_coefficients(
    samples: &[(f64, f64, f64)],
    t_period: f64,
    harmonics: usize,
) -> Vec<Complex64> {
    let n = FFT_POINTS;
    let mut grid = vec![0.0; n];
    if let (Some(first), Some(last)) = (samples.first(), samples.last()) {
        let mut i = 0;
        for (m, g) in grid.iter_mut().enumerate() {
            let t = m as f64 * t_period / n as f64;
            if t < first.0 || t > last.0 {
                continue;
            }
            while i + 1 < samples.len() && samples[i + 1].0 < t {
                i += 1;
            }
            let (a, b) = (samples[i], samples[(i + 1).min(samples.len() - 1)]);
            *g = if b.0 > a.0 {
                a.1 + (b.1 - a.1) * (t - a.0) / (b.0 - a.0)
            } else {
                a.1
            };
        }
    }
    let mut planner = realfft::RealFftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(n);
    let mut spectrum = fft.make_output_vec();
    // A length that is the plan's and a grid of it cannot fail.
    fft.process(&mut grid, &mut spectrum)
        .expect("the FFT's buffers have its length");
    spectrum
        .into_iter()
        .take(harmonics + 1)
        .map(|x| x / n as f64)
        .collect()
}

/// What a period's integration reports (when measuring).
#[derive(Default)]
pub(super) struct Record {
    /// (t, g, δ) at every point in contact.
    pub(super) force: Vec<(f64, f64, f64)>,
    /// Time (s) of the steps with the tip in contact at either end, the contact's share of
    /// the period wherever in it the contact falls (across t = 0 too).
    pub(super) contact_time: f64,
    /// The work terms' trapezoid sums over the whole period.
    pub(super) drive_work: f64,
    pub(super) damping_work: f64,
    pub(super) contact_work: f64,
    pub(super) base_contact_work: f64,
    pub(super) coefficients: Vec<Complex64>,
    /// The previous point and its power terms.
    pub(super) last: Option<(f64, Powers)>,
}

/// (drive power, damping power, g·ż, g·u̇, g, δ) at one point.
pub(super) type Powers = (f64, f64, f64, f64, f64, f64);

impl PeriodMap<'_> {
    /// The measuring period from `h`: the record, with force coefficients up to `harmonics`
    /// — by Gauss–Legendre on each integrator step up to [`DENSE_HARMONICS`], and
    /// beyond by the FFT of the force on a uniform grid of [`FFT_POINTS`] (interpolated
    /// linearly between those points): hundreds of harmonics (for the aliases) at the cost
    /// of one FFT rather than a multiplication per harmonic per point.
    pub(super) fn measure_period(
        &self,
        h: &[f64],
        harmonics: usize,
    ) -> Result<Record, CoupledError> {
        let dense = harmonics.min(DENSE_HARMONICS);
        let mut record = Record {
            coefficients: vec![Complex64::new(0.0, 0.0); dense + 1],
            ..Record::default()
        };
        self.integrate(h, CONTACT_STEP_MEASURE, Some(&mut record))?;
        if harmonics > dense {
            let beyond = fft_coefficients(&record.force, self.t_period, harmonics);
            record
                .coefficients
                .extend_from_slice(&beyond[dense + 1..=harmonics]);
        }
        Ok(record)
    }

    /// The power terms at (t, h).
    pub(super) fn powers(&self, t: f64, h: &[f64]) -> Powers {
        let e = self.phasor(t);
        let (_, ubase_v) = self.base(e);
        let udd = -self.u * self.p.drive_omega.powi(2) * e.im;
        let delta = self.indentation(t, h);
        let g = self.p.force(delta);
        let mut drive = 0.0;
        let mut damping = 0.0;
        let mut tip_v = ubase_v;
        for (n, m) in self.p.modes.iter().enumerate() {
            let (_, v0) = self.free_mode(n, e);
            let v = v0 + h[2 * n + 1];
            let mass = m.stiffness / (m.omega * m.omega);
            drive += -mass * m.participation * udd * v;
            damping += mass * 2.0 * m.gamma * m.omega * v * v;
            tip_v += m.tip_value * v;
        }
        (drive, damping, g * tip_v, g * ubase_v, g, delta)
    }

    /// Adds one integrator step's share of the force's Fourier coefficients,
    /// (1/T)∫g e^{−ikΩt}dt over [t0, t1], by 4-point Gauss–Legendre quadrature on the step's
    /// own Dormand–Prince solution from (t0, `h0`): exact for polynomials of degree 7, so the
    /// smooth adhesive pull over the long steps out of contact (up to T/4000) is integrated
    /// to the integrator's tolerance at every harmonic, where a trapezoid on the step's ends
    /// was off by ~1 % at H30. The nodes' forces join the force record before the step's end
    /// point (the FFT beyond [`DENSE_HARMONICS`] and the peak and width read them).
    pub(super) fn add_step_coefficients(&self, r: &mut Record, t0: f64, h0: &[f64], t1: f64) {
        let (half, mid) = (0.5 * (t1 - t0), 0.5 * (t0 + t1));
        let w = self.p.drive_omega;
        for (x, weight) in GAUSS_LEGENDRE_4 {
            let t = mid + half * x;
            let h = self.dp_step(t0, h0, t - t0).0;
            let delta = self.indentation(t, &h);
            let g = self.p.force(delta);
            if g == 0.0 {
                continue;
            }
            r.force.push((t, g, delta.max(0.0)));
            let scale = weight * half * g / self.t_period;
            // e^{−ikΩt} by powers of e^{−iΩt}, re-anchored every 64 harmonics: hundreds of
            // harmonics (for the aliases) cost multiplications, not sines.
            let step = Complex64::from_polar(1.0, -w * t);
            let mut e = Complex64::new(1.0, 0.0);
            for (k, c) in r.coefficients.iter_mut().enumerate() {
                if k > 0 && k % 64 == 0 {
                    e = Complex64::from_polar(1.0, -(k as f64) * w * t);
                }
                *c += scale * e;
                e *= step;
            }
        }
    }

    /// Adds the point (t, h) to the record: the work terms' trapezoid sums from the previous
    /// point, the contact time, and the force sample. The force's Fourier coefficients come
    /// from [`PeriodMap::add_step_coefficients`].
    pub(super) fn accumulate(&self, r: &mut Record, t: f64, h: &[f64]) {
        let now = self.powers(t, h);
        if let Some((t0, before)) = r.last.take() {
            let dt = t - t0;
            r.drive_work += 0.5 * dt * (before.0 + now.0);
            r.damping_work += 0.5 * dt * (before.1 + now.1);
            r.contact_work += 0.5 * dt * (before.2 + now.2);
            r.base_contact_work += 0.5 * dt * (before.3 + now.3);
            if before.5 > 0.0 || now.5 > 0.0 {
                r.contact_time += dt;
            }
        }
        if now.4 != 0.0 || r.force.last().is_some_and(|l| l.1 != 0.0) {
            r.force.push((t, now.4, now.5.max(0.0)));
        }
        r.last = Some((t, now));
    }
}

/// The force record as one period that starts at its smallest force: the samples before it
/// move to the end, a period later, so a pulse that straddles t = 0 (and T) is one stretch.
pub(super) fn from_minimum(samples: &[(f64, f64, f64)], t_period: f64) -> Vec<(f64, f64, f64)> {
    let Some(k) = samples
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.1.total_cmp(&b.1.1))
        .map(|(i, _)| i)
    else {
        return Vec::new();
    };
    samples[k..]
        .iter()
        .copied()
        .chain(samples[..k].iter().map(|&(t, g, d)| (t + t_period, g, d)))
        .collect()
}

/// FWHM (s) of the force samples (t, g, δ), by linear interpolation at the half maximum.
pub(super) fn full_width_at_half_maximum(samples: &[(f64, f64, f64)], peak: f64) -> f64 {
    if peak <= 0.0 || samples.len() < 2 {
        return 0.0;
    }
    let half = 0.5 * peak;
    let mut rise = None;
    let mut fall = None;
    for w in samples.windows(2) {
        let ((t0, g0, _), (t1, g1, _)) = (w[0], w[1]);
        if rise.is_none() && g0 < half && g1 >= half {
            rise = Some(t0 + (half - g0) / (g1 - g0) * (t1 - t0));
        }
        if rise.is_some() && g0 >= half && g1 < half {
            fall = Some(t0 + (g0 - half) / (g0 - g1) * (t1 - t0));
        }
    }
    match (rise, fall) {
        (Some(r), Some(f)) if f > r => f - r,
        _ => 0.0,
    }
}
