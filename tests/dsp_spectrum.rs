//! The sliding spectrum: amplitude calibration, scallop loss per window, phase, framing.

use std::f64::consts::{PI, TAU};

use ftafm::dsp::{SlidingSpectrum, SpectrumConfig, Window};

const FS: f64 = 10e6;

fn spectrum(size: usize, hop: usize, window: Window) -> SlidingSpectrum {
    SlidingSpectrum::new(SpectrumConfig {
        sample_rate: FS,
        size,
        hop,
        window,
    })
    .unwrap()
}

fn tone(len: usize, f: f64, amp: f64, phase: f64) -> Vec<f64> {
    let r = f / FS;
    (0..len)
        .map(|m| amp * (TAU * (m as f64 * r).fract() + phase).cos())
        .collect()
}

/// The first frame of `x`: (peak bin, its complex value), plus the whole magnitude list.
fn first_frame(s: &mut SlidingSpectrum, x: &[f64]) -> Vec<ftafm::dsp::Complex<f64>> {
    let mut bins = None;
    s.process(x, |f| {
        if bins.is_none() {
            bins = Some(f.bins.to_vec());
        }
    });
    bins.expect("a frame")
}

fn peak(bins: &[ftafm::dsp::Complex<f64>]) -> (usize, ftafm::dsp::Complex<f64>) {
    let (i, c) = bins
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.norm().total_cmp(&b.1.norm()))
        .unwrap();
    (i, *c)
}

#[test]
fn a_tone_on_a_bin_reads_its_amplitude_and_phase_with_every_window() {
    let n = 4096;
    for window in Window::ALL {
        let mut s = spectrum(n, n, window);
        for (bin, amp, phase) in [
            (100usize, 20e-9, 0.3),
            (417, 1e-10, -2.0),
            (2000, 5e-9, 3.0),
        ] {
            let f = bin as f64 * s.bin_width();
            let bins = first_frame(&mut s, &tone(n, f, amp, phase));
            let (i, c) = peak(&bins);
            assert_eq!(i, bin, "{window:?}");
            assert!(
                (c.norm() / amp - 1.0).abs() < 1e-10,
                "{window:?}: {} vs {amp}",
                c.norm()
            );
            assert!(
                (c.arg() - phase).abs() < 1e-9,
                "{window:?}: phase {}",
                c.arg()
            );
        }
    }
}

#[test]
fn flat_top_reads_any_tone_within_1e3() {
    let n = 4096;
    let mut s = spectrum(n, n, Window::FlatTop);
    let mut worst: f64 = 0.0;
    for i in 0..=40 {
        // From on-bin to half-way between bins 300 and 301, and beyond.
        let f = (300.0 + i as f64 / 40.0 * 0.75) * s.bin_width();
        let bins = first_frame(&mut s, &tone(n, f, 1e-9, 0.7));
        let (_, c) = peak(&bins);
        worst = worst.max((c.norm() / 1e-9 - 1.0).abs());
    }
    println!("flat-top: worst amplitude error {worst:.1e}");
    assert!(worst < 1e-3, "{worst:e}");
}

#[test]
fn other_windows_read_low_by_at_most_their_scallop_loss() {
    let n = 4096;
    for window in [Window::Rectangular, Window::Hann, Window::BlackmanHarris] {
        let mut s = spectrum(n, n, window);
        let loss = window.scallop_loss(n);
        let mut lowest: f64 = 1.0;
        for i in 0..=20 {
            let offset = i as f64 / 40.0; // 0 … ½ bin
            let f = (1000.0 + offset) * s.bin_width();
            let bins = first_frame(&mut s, &tone(n, f, 1.0, 0.0));
            let (_, c) = peak(&bins);
            let reading = c.norm();
            // Between the window's own response at this offset and 1, up to the leakage of
            // the tone's mirror image at −f (far side lobes: tiny but for the boxcar).
            let expected = window.response(offset, n);
            let leak = if window == Window::Rectangular {
                1e-3
            } else {
                1e-6
            };
            assert!(
                (reading - expected).abs() < leak,
                "{window:?} at +{offset}: {reading}"
            );
            assert!(reading > 1.0 - loss - leak && reading < 1.0 + leak);
            lowest = lowest.min(reading);
        }
        println!("{window:?}: lowest reading {lowest:.4}, scallop loss {loss:.4}");
        assert!((1.0 - lowest - loss).abs() < 2e-3);
    }
}

#[test]
fn dc_and_nyquist_are_calibrated() {
    let n = 1024;
    let mut s = spectrum(n, n, Window::Hann);
    let x: Vec<f64> = (0..n)
        .map(|m| 0.25 + 0.5 * if m % 2 == 0 { 1.0 } else { -1.0 })
        .collect();
    let bins = first_frame(&mut s, &x);
    assert!((bins[0].re - 0.25).abs() < 1e-12);
    assert!((bins[n / 2].re - 0.5).abs() < 1e-12);
    assert!((bins[n / 2].im).abs() < 1e-12);
}

#[test]
fn the_phase_refers_to_the_first_sample_of_each_frame() {
    // Frames every 1000 samples of a tone on bin 64: the phase at the frame start advances
    // by 2π·f·hop/f_s from one frame to the next.
    let (n, hop) = (2048usize, 1000usize);
    let mut s = spectrum(n, hop, Window::BlackmanHarris);
    let bin = 64;
    let f = bin as f64 * s.bin_width();
    let x = tone(20_000, f, 1.0, 0.0);
    let mut frames = Vec::new();
    s.process(&x, |fr| frames.push((fr.start_index, fr.bins[bin])));
    assert_eq!(frames.len(), (20_000 - n) / hop + 1);
    for (start, c) in frames {
        let expected = (TAU * (start as f64 * f / FS).fract() + PI).rem_euclid(TAU) - PI;
        let err = (c.arg() - expected + PI).rem_euclid(TAU) - PI;
        assert!(
            err.abs() < 1e-9,
            "frame at {start}: {} vs {expected}",
            c.arg()
        );
        assert!((c.norm() - 1.0).abs() < 1e-9);
    }
}

#[test]
fn framing_and_rates() {
    let s = spectrum(4096, 1024, Window::Hann);
    assert_eq!(s.output_rate(), FS / 1024.0);
    assert_eq!(s.bin_width(), FS / 4096.0);
    assert_eq!(s.bin_count(), 2049);
    assert_eq!(s.bin_frequency(10), 10.0 * FS / 4096.0);
    // A hop larger than the frame skips samples; frames still come every hop.
    let mut sparse = spectrum(256, 1000, Window::Hann);
    let mut starts = Vec::new();
    for chunk in vec![0.0; 10_000].chunks(333) {
        sparse.process(chunk, |f| starts.push(f.start_index));
    }
    assert_eq!(starts, (0..10).map(|i| i * 1000).collect::<Vec<u64>>());
    assert!(
        SlidingSpectrum::new(SpectrumConfig {
            sample_rate: FS,
            size: 1,
            hop: 1,
            window: Window::Hann
        })
        .is_err()
    );
    assert!(
        SlidingSpectrum::new(SpectrumConfig {
            sample_rate: FS,
            size: 64,
            hop: 0,
            window: Window::Hann
        })
        .is_err()
    );
    // Odd sizes work too (no Nyquist bin).
    let mut odd = spectrum(1001, 1001, Window::FlatTop);
    let f = 50.0 * odd.bin_width();
    let bins = first_frame(&mut odd, &tone(1001, f, 2.0, 0.0));
    assert_eq!(bins.len(), 501);
    assert!((bins[50].norm() - 2.0).abs() < 1e-9);
}
