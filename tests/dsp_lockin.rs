//! The multi-harmonic lock-in bank: calibration, phase reference, separation of harmonics
//! (the pre-decimator's aliasing argument checked numerically), no drift, filter response.

use std::f64::consts::{PI, TAU};

use ftafm::dsp::PREDECIMATION_ORDER;
use ftafm::dsp::{Demodulator, LockInBank, LockInSample, MAX_DEMODULATORS, Predecimator};
use ftafm::timebase::PREDECIMATION;

const FS: f64 = 10e6;

/// `Σ A_k cos(2π k f m/f_s + φ_k)` for samples `start .. start + out.len()`, the phase
/// computed in f64 independently of the bank's integer accumulator (error ≲ 10⁻⁹ rad at
/// m = 10⁸).
fn tones(out: &mut [f64], start: u64, drive: f64, parts: &[(u32, f64, f64)]) {
    let r = drive / FS;
    for (i, x) in out.iter_mut().enumerate() {
        let cycles = ((start + i as u64) as f64 * r).fract();
        *x = parts
            .iter()
            .map(|&(k, a, phi)| a * (TAU * (k as f64 * cycles).fract() + phi).cos())
            .sum();
    }
}

fn tone_signal(len: usize, drive: f64, parts: &[(u32, f64, f64)]) -> Vec<f64> {
    let mut x = vec![0.0; len];
    tones(&mut x, 0, drive, parts);
    x
}

/// The last output of every demodulator after processing `input`.
fn last_outputs(bank: &mut LockInBank, input: &[f64]) -> Vec<Option<LockInSample>> {
    let mut last = vec![None; MAX_DEMODULATORS];
    bank.process(input, |s| last[s.demod] = Some(s));
    last
}

/// Wrapped phase difference (rad).
fn phase_error(a: f64, b: f64) -> f64 {
    (a - b + PI).rem_euclid(TAU) - PI
}

fn banks(fd: f64, demods: &[Demodulator]) -> Vec<LockInBank> {
    let fast = LockInBank::new(FS, fd, demods).unwrap();
    let portable = LockInBank::new(FS, fd, demods)
        .unwrap()
        .with_portable_kernel();
    vec![fast, portable]
}

#[test]
fn a_pure_tone_reads_its_amplitude_and_phase() {
    let harmonics = [1u32, 2, 7, 17, 32];
    let demods: Vec<Demodulator> = harmonics
        .iter()
        .map(|&k| Demodulator::new(k, 4, 100e-6, 1e3))
        .collect();
    let mut worst = (0.0f64, 0.0f64);
    for fd in [100e3, 100.0123e3, 137e3] {
        for (case, phi) in [-3.0, -1.0, 0.0, 0.4, 2.5].into_iter().enumerate() {
            for (lane, &k) in harmonics.iter().enumerate() {
                // One tone per run: the others must read (almost) nothing.
                let amp = 1e-9 * (1.0 + case as f64);
                let x = tone_signal(60_000, fd, &[(k, amp, phi)]);
                for mut bank in banks(fd, &demods) {
                    let out = last_outputs(&mut bank, &x);
                    let s = out[lane].unwrap();
                    let rel = s.r() / amp - 1.0;
                    let dphi = phase_error(s.phase(), phi);
                    worst = (worst.0.max(rel.abs()), worst.1.max(dphi.abs()));
                    assert!(
                        rel.abs() < 1e-4,
                        "k {k} f {fd} φ {phi}: R {} vs {amp}",
                        s.r()
                    );
                    assert!(
                        dphi.abs() < 1e-4,
                        "k {k} f {fd} φ {phi}: phase {}",
                        s.phase()
                    );
                    assert!((s.x - amp * phi.cos()).abs() < 1e-4 * amp);
                    assert!((s.y - amp * phi.sin()).abs() < 1e-4 * amp);
                }
            }
        }
    }
    println!(
        "worst relative amplitude error {:.1e}, phase error {:.1e} rad",
        worst.0, worst.1
    );
}

#[test]
fn harmonic_zero_reads_the_mean() {
    let demods = [
        Demodulator::new(0, 4, 100e-6, 1e3),
        Demodulator::new(1, 4, 100e-6, 1e3),
    ];
    for mean in [-2e-9, 3e-9] {
        let mut x = tone_signal(60_000, 100.0123e3, &[(1, 20e-9, 0.3)]);
        x.iter_mut().for_each(|v| *v += mean);
        for mut bank in banks(100.0123e3, &demods) {
            let out = last_outputs(&mut bank, &x);
            let s = out[0].unwrap();
            assert!((s.x / mean - 1.0).abs() < 1e-4, "{s:?}");
            assert!(s.y.abs() < 1e-12 * 20e-9, "{s:?}");
            assert!((s.r() - mean.abs()).abs() < 1e-4 * mean.abs());
            let fundamental = out[1].unwrap();
            assert!((fundamental.r() / 20e-9 - 1.0).abs() < 1e-4);
        }
    }
}

/// Amplitudes of the multi-tone test signal: 20 nm fundamental, 0.01–0.2 nm harmonics.
fn harmonic_amplitude(k: u32) -> f64 {
    if k == 1 {
        20e-9
    } else {
        (0.01 + 0.19 * ((k * 7) % 31) as f64 / 30.0) * 1e-9
    }
}

/// Drive frequencies for the aliasing check: commensurate with f_s, incommensurate, and an
/// adversarial one where 18·f_drive lands 10 Hz from 4·f_s/D, so that the fundamental's
/// image in the harmonic-17 channel (at −18·f_drive) folds to 10 Hz after decimation,
/// where no low-pass can remove it: only the pre-decimator's null does.
const DRIVES: [f64; 4] = [100e3, 100.0123e3, 137e3, (2.5e6 + 10.0) / 18.0];

#[test]
fn harmonics_of_a_multi_tone_signal_separate() {
    let demods: Vec<Demodulator> = (1..=32)
        .map(|k| Demodulator::new(k, 4, 100e-6, 1e3))
        .collect();
    let parts: Vec<(u32, f64, f64)> = (1..=32)
        .map(|k| (k, harmonic_amplitude(k), 0.37 * k as f64))
        .collect();
    for fd in DRIVES {
        let x = tone_signal(160_000, fd, &parts);
        for mut bank in banks(fd, &demods) {
            let out = last_outputs(&mut bank, &x);
            let mut worst = (0.0f64, 0);
            for (i, &(k, amp, phi)) in parts.iter().enumerate() {
                let s = out[i].unwrap();
                let rel = s.r() / amp - 1.0;
                if rel.abs() > worst.0 {
                    worst = (rel.abs(), k);
                }
                assert!(rel.abs() < 5e-3, "f {fd} k {k}: R {} vs {amp}", s.r());
                assert!(phase_error(s.phase(), phi).abs() < 5e-3, "f {fd} k {k}");
            }
            println!(
                "drive {fd:.4} Hz ({}): worst harmonic error {:.1e} (k = {})",
                bank.kernel(),
                worst.0,
                worst.1
            );
        }
    }
}

#[test]
fn the_fundamental_does_not_leak_into_the_harmonics() {
    let demods: Vec<Demodulator> = (2..=32)
        .map(|k| Demodulator::new(k, 4, 100e-6, 1e3))
        .collect();
    for fd in DRIVES {
        let x = tone_signal(160_000, fd, &[(1, 20e-9, 0.5)]);
        let mut bank = LockInBank::new(FS, fd, &demods).unwrap();
        let out = last_outputs(&mut bank, &x);
        let leak: Vec<f64> = out.iter().flatten().map(|s| s.r() / 20e-9).collect();
        let k17 = leak[15];
        let worst = leak.iter().cloned().fold(0.0, f64::max);
        println!("drive {fd:.4} Hz: leak into k=17 {k17:.1e}, worst over k=2..32 {worst:.1e}");
        assert!(k17 < 5e-6, "drive {fd}: {k17:e}");
        assert!(worst < 5e-6, "drive {fd}: {worst:e}");
    }
}

#[test]
fn the_adversarial_drive_folds_an_image_onto_a_cic_null() {
    // The adversarial drive really is adversarial: the fundamental's image in channel 17
    // folds to 10 Hz, where a 100 µs low-pass passes essentially everything, so the
    // suppression seen above is the CIC null's doing.
    let fd = DRIVES[3];
    let image = 18.0 * fd;
    let p = Predecimator {
        factor: PREDECIMATION,
        order: PREDECIMATION_ORDER,
    };
    let folded = image - 4.0 * FS / PREDECIMATION as f64;
    assert!((folded - 10.0).abs() < 1e-6);
    assert!(p.magnitude(image, FS) < 1e-20);
}

#[test]
fn no_phase_drift_over_1e8_samples() {
    // Incommensurate drive; a harmonic too, where any drift would be 17 times larger.
    let fd = 100.0123e3;
    let parts = [(1, 10e-9, 0.7), (17, 0.1e-9, -2.1)];
    let demods = [
        Demodulator::new(1, 4, 100e-6, 1e3),
        Demodulator::new(17, 4, 100e-6, 1e3),
    ];
    let mut bank = LockInBank::new(FS, fd, &demods).unwrap();
    let total: u64 = 100_000_000;
    let block = 1 << 16;
    let mut x = vec![0.0; block];
    let mut first = [None; 2];
    let mut last = [None; 2];
    let mut start = 0u64;
    while start < total {
        let n = (total - start).min(block as u64) as usize;
        tones(&mut x[..n], start, fd, &parts);
        bank.process(&x[..n], |s| {
            // The first output after the filter settled (2 ms), and the last one.
            if s.sample_index > 20_000 && first[s.demod].is_none() {
                first[s.demod] = Some(s);
            }
            last[s.demod] = Some(s);
        });
        start += n as u64;
    }
    assert_eq!(bank.samples_processed(), total);
    for (i, &(k, amp, phi)) in parts.iter().enumerate() {
        let (a, b) = (first[i].unwrap(), last[i].unwrap());
        let early = phase_error(a.phase(), phi);
        let late = phase_error(b.phase(), phi);
        println!(
            "k {k}: phase error {early:.1e} rad at sample {}, {late:.1e} rad at sample {}",
            a.sample_index, b.sample_index
        );
        assert!(b.sample_index > total - 20_000);
        assert!(late.abs() < 1e-6, "k {k}: {late:e}");
        assert!((b.r() / amp - 1.0).abs() < 1e-6);
    }
}

#[test]
fn changing_the_drive_frequency_keeps_the_phase() {
    // The synthesiser's drive changes frequency with a continuous phase at sample m1; the
    // bank is told at the same sample and must read the same phase after settling.
    let (f1, f2) = (100e3, 100.7e3);
    let m1 = 50_000usize;
    let total = 120_000usize;
    let phi = 0.9;
    let (k, amp) = (3u32, 1e-9);
    let theta1 = f1 / FS * m1 as f64; // drive phase at m1 in cycles
    let x: Vec<f64> = (0..total)
        .map(|m| {
            let cycles = if m < m1 {
                f1 / FS * m as f64
            } else {
                theta1 + f2 / FS * (m - m1) as f64
            };
            amp * (TAU * (k as f64 * cycles).fract() + phi).cos()
        })
        .collect();
    let demods = [Demodulator::new(k, 4, 50e-6, 10e3)];
    for mut bank in banks(f1, &demods) {
        let mut before = None;
        bank.process(&x[..m1], |s| before = Some(s));
        let phase_word = bank.drive().phase();
        bank.set_drive_frequency(f2).unwrap();
        assert_eq!(
            bank.drive().phase(),
            phase_word,
            "no phase jump in the accumulator"
        );
        let mut outputs = Vec::new();
        bank.process(&x[m1..], |s| outputs.push(s));
        let before = before.unwrap();
        assert!(phase_error(before.phase(), phi).abs() < 1e-6);
        // Throughout the change the reading stays put: the phase never jumps, the
        // amplitude dips only through the ≤ 30-sample window straddling the change.
        for s in &outputs {
            assert!(phase_error(s.phase(), phi).abs() < 1e-3, "{s:?}");
            assert!((s.r() / amp - 1.0).abs() < 1e-2, "{s:?}");
        }
        let after = outputs.last().unwrap();
        assert!(phase_error(after.phase(), phi).abs() < 1e-6);
        assert!((after.r() / amp - 1.0).abs() < 1e-6);
    }
}

#[test]
fn droop_is_compensated_for_a_tone_off_the_harmonic() {
    // A tone 5 kHz above harmonic 4 reads A·|H_lowpass(5 kHz)| (the low-pass's exact
    // discrete response); the CIC alone would read 4·10⁻⁴ low at this offset.
    let fd = 100.0123e3;
    let offset = 5e3;
    let (k, amp) = (4u32, 1e-9);
    let demod = Demodulator::new(k, 8, 20e-6, 625e3);
    let mut bank = LockInBank::new(FS, fd, &[demod]).unwrap();
    let lp = bank.low_pass(0).unwrap();
    let r = (k as f64 * fd + offset) / FS;
    let x: Vec<f64> = (0..100_000)
        .map(|m| amp * (TAU * (m as f64 * r).fract()).cos())
        .collect();
    let mut readings = Vec::new();
    bank.process(&x, |s| readings.push(s.r()));
    // Discrete response of the cascade at the decimated rate.
    let w = TAU * offset / bank.decimated_rate();
    let a = lp.alpha();
    let section = a / ((1.0 - (1.0 - a) * w.cos()).hypot((1.0 - a) * w.sin()));
    let expected = amp * section.powi(8);
    let settled = &readings[readings.len() - 100..];
    let worst = settled
        .iter()
        .map(|r| (r / expected - 1.0).abs())
        .fold(0.0, f64::max);
    let p = Predecimator {
        factor: PREDECIMATION,
        order: PREDECIMATION_ORDER,
    };
    let uncompensated = 1.0 - p.magnitude(offset, FS);
    println!("relative error {worst:.1e}; uncompensated CIC droop {uncompensated:.1e}");
    assert!(uncompensated > 4e-4);
    assert!(worst < 2e-5, "{worst:e}");
}

#[test]
fn step_response_of_every_order_through_the_bank() {
    // A tone switched on at sample m0: R follows the n-section step response, timed from
    // the step (at m0 − ½, between samples) plus the pre-decimator's group delay, with the
    // cascade's half-sample lead per section at the decimated rate (see `LowPass`).
    let fd = 137e3;
    let (k, amp, phi) = (2u32, 1e-9, 0.2);
    let tau = 500e-6;
    let m0 = 10_007usize;
    for order in 1..=8u32 {
        let len = m0 + (20.0 * order as f64 * tau * FS) as usize;
        let mut x = tone_signal(len, fd, &[(k, amp, phi)]);
        x[..m0].fill(0.0);
        let mut bank = LockInBank::new(FS, fd, &[Demodulator::new(k, order, tau, 625e3)]).unwrap();
        let delay = bank.group_delay() as f64;
        let lp = bank.low_pass(0).unwrap();
        let d = PREDECIMATION as f64;
        let mut worst: f64 = 0.0;
        bank.process(&x, |s| {
            let t =
                (s.sample_index as f64 - delay - (m0 as f64 - 0.5) + order as f64 * d / 2.0) / FS;
            worst = worst.max((s.r() / amp - lp.step_response(t)).abs());
        });
        println!("order {order}: worst |R/A − S(t)| = {worst:.1e}");
        assert!(worst < 1e-3, "order {order}: {worst:e}");
    }
}

#[test]
fn white_noise_through_the_bank_gives_the_analytic_enbw() {
    // White noise of variance σ² mixed with 2cos(kθ) is white with variance 2σ², density
    // 4σ²/f_s one-sided, so var(X) = var(Y) = 4σ²·ENBW/f_s.
    let mut seed = 0x1234_5678_9ABC_DEF1u64;
    let mut uniform = move || {
        seed ^= seed >> 12;
        seed ^= seed << 25;
        seed ^= seed >> 27;
        ((seed.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let enbw_target = 2e3;
    for order in [1u32, 2, 4, 8] {
        // τ for a 2 kHz ENBW at this order.
        let tau = ftafm::dsp::LowPass::new(order, 1.0, 1.0).unwrap().enbw() / enbw_target;
        let mut bank =
            LockInBank::new(FS, 100.0123e3, &[Demodulator::new(5, order, tau, 20e3)]).unwrap();
        let enbw = bank.low_pass(0).unwrap().enbw();
        let (mut n, mut sxx, mut syy) = (0usize, 0.0, 0.0);
        let settle = (20.0 * order as f64 * tau * FS) as u64;
        let mut x = vec![0.0; 1 << 16];
        for _ in 0..150 {
            for pair in x.chunks_exact_mut(2) {
                let r = (-2.0 * uniform().ln()).sqrt();
                let (s, c) = (TAU * uniform()).sin_cos();
                pair[0] = r * c;
                pair[1] = r * s;
            }
            bank.process(&x, |s| {
                if s.sample_index > settle {
                    n += 1;
                    sxx += s.x * s.x;
                    syy += s.y * s.y;
                }
            });
        }
        let expected = 4.0 * enbw / FS;
        let rel = (sxx + syy) / (2.0 * n as f64) / expected - 1.0;
        println!("order {order}: var(X,Y) / (4σ²·ENBW/f_s) − 1 = {rel:+.2e}");
        assert!(rel.abs() < 0.08, "order {order}: {rel:e}");
    }
}

#[test]
fn outputs_do_not_depend_on_the_block_size_and_kernels_agree() {
    let fd = 100.0123e3;
    let demods: Vec<Demodulator> = (0..20)
        .map(|i| Demodulator::new(i, 1 + i % 8, 30e-6, 100e3 / (1 + i % 3) as f64))
        .collect();
    let parts: Vec<(u32, f64, f64)> = (0..20)
        .map(|k| (k, 1e-9 * (k + 1) as f64, 0.1 * k as f64))
        .collect();
    let x = tone_signal(50_000, fd, &parts);
    let run = |bank: &mut LockInBank, block: usize| {
        let mut out = Vec::new();
        for chunk in x.chunks(block) {
            bank.process(chunk, |s| out.push(s));
        }
        out
    };
    let reference = run(&mut LockInBank::new(FS, fd, &demods).unwrap(), 50_000);
    for block in [1, 15, 16, 17, 4096, 5000] {
        let out = run(&mut LockInBank::new(FS, fd, &demods).unwrap(), block);
        assert_eq!(out, reference, "block {block}");
    }
    let portable = run(
        &mut LockInBank::new(FS, fd, &demods)
            .unwrap()
            .with_portable_kernel(),
        999,
    );
    assert_eq!(portable.len(), reference.len());
    for (a, b) in portable.iter().zip(&reference) {
        assert_eq!((a.demod, a.sample_index), (b.demod, b.sample_index));
        assert!((a.x - b.x).abs() < 1e-12 * 20e-9 && (a.y - b.y).abs() < 1e-12 * 20e-9);
    }
}

#[test]
fn outputs_arrive_at_the_realised_rate_with_sample_indices() {
    let demods = [
        Demodulator::new(1, 4, 1e-4, 1e3),
        Demodulator {
            enable: false,
            ..Demodulator::new(2, 4, 1e-4, 1e3)
        },
        Demodulator::new(3, 4, 1e-4, 3e3),
        Demodulator::new(4, 4, 1e-4, 1e9), // clamps to the decimated rate
    ];
    let mut bank = LockInBank::new(FS, 100e3, &demods).unwrap();
    assert_eq!(bank.output_rate(0), Some(1e3));
    assert_eq!(bank.output_rate(1), None);
    assert_eq!(bank.output_rate(2), Some(625e3 / 208.0));
    assert_eq!(bank.output_rate(3), Some(625e3));
    let mut indices = vec![Vec::new(); 4];
    bank.process(&vec![0.0; 100_000], |s| {
        indices[s.demod].push(s.sample_index)
    });
    assert!(indices[1].is_empty());
    let d = PREDECIMATION as u64;
    assert_eq!(
        indices[0],
        (1..=10).map(|i| i * 625 * d - 1).collect::<Vec<_>>()
    );
    assert_eq!(indices[2][0], 208 * d - 1);
    assert_eq!(indices[3].len(), 100_000 / d as usize);
}

#[test]
fn bad_settings_are_rejected() {
    let ok = Demodulator::new(1, 4, 1e-4, 1e3);
    assert!(LockInBank::new(FS, 1e5, &[ok; 32]).is_ok());
    assert!(LockInBank::new(FS, 1e5, &[ok; 33]).is_err());
    assert!(LockInBank::new(0.0, 1e5, &[ok]).is_err());
    assert!(LockInBank::new(FS, f64::NAN, &[ok]).is_err());
    for bad in [
        Demodulator { order: 0, ..ok },
        Demodulator { order: 9, ..ok },
        Demodulator {
            time_constant: 0.0,
            ..ok
        },
        Demodulator {
            time_constant: f64::INFINITY,
            ..ok
        },
        Demodulator {
            output_rate: -1.0,
            ..ok
        },
    ] {
        let err = LockInBank::new(FS, 1e5, &[ok, bad]).unwrap_err();
        assert!(err.to_string().starts_with("demodulator 1:"), "{err}");
    }
    // An empty bank is valid and just counts samples.
    let mut empty = LockInBank::new(FS, 1e5, &[]).unwrap();
    empty.process(&[0.0; 100], |_| panic!("no demodulators, no output"));
    assert_eq!(empty.samples_processed(), 100);
}
