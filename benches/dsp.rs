//! DSP throughput on one core, in input samples per second (goal: the 32-demodulator bank
//! and the sliding spectrum together at ≥ 30 MS/s, three times the 10 MS/s real-time rate);
//! and the DSP stage (`DspPlan`) on one thread against the bank split over two
//! (`/dsp/threads`), which needs two free cores to show a gain.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ftafm::dsp::{
    Demodulator, LockInBank, MAX_DEMODULATORS, SlidingSpectrum, SpectrumConfig, Window,
};

const SAMPLE_RATE: f64 = 10e6;
const DRIVE: f64 = 100.0123e3;
const BLOCK: usize = 4096;

/// A tapping-mode-like photodiode signal: 20 nm fundamental, small harmonics, a little noise.
fn signal(len: usize) -> Vec<f64> {
    let mut seed = 0x9E37_79B9_7F4A_7C15u64;
    (0..len)
        .map(|m| {
            let theta = std::f64::consts::TAU * DRIVE * m as f64 / SAMPLE_RATE;
            let mut s = 20e-9 * theta.cos();
            for k in 2..=32 {
                s += 0.1e-9 / k as f64 * (k as f64 * theta + 0.1 * k as f64).cos();
            }
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            s + 1e-12 * ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5)
        })
        .collect()
}

fn bank(order: u32) -> LockInBank {
    let demods: Vec<Demodulator> = (0..MAX_DEMODULATORS as u32)
        .map(|i| Demodulator::new(i + 1, order, 100e-6, 10e3))
        .collect();
    LockInBank::new(SAMPLE_RATE, DRIVE, &demods).expect("valid bank")
}

fn spectrum(size: usize, hop: usize) -> SlidingSpectrum {
    SlidingSpectrum::new(SpectrumConfig {
        sample_rate: SAMPLE_RATE,
        size,
        hop,
        window: Window::BlackmanHarris,
    })
    .expect("valid spectrum")
}

/// Blocks of a long signal, cycled, so the caches see fresh input as they would live.
struct Feed {
    data: Vec<f64>,
    next: usize,
}

impl Feed {
    fn new() -> Self {
        Self {
            data: signal(BLOCK * 64),
            next: 0,
        }
    }

    fn block(&mut self) -> &[f64] {
        let start = self.next * BLOCK;
        self.next = (self.next + 1) % 64;
        &self.data[start..start + BLOCK]
    }
}

fn lockin(c: &mut Criterion) {
    let mut group = c.benchmark_group("lockin_bank");
    group.throughput(Throughput::Elements(BLOCK as u64));
    let variants = [
        ("32_demods_order4", bank(4)),
        ("32_demods_order4_avx2", bank(4).with_avx2_kernel()),
        ("32_demods_order8", bank(8)),
        ("32_demods_order4_portable", bank(4).with_portable_kernel()),
    ];
    for (name, mut b) in variants {
        let mut feed = Feed::new();
        group.bench_function(name, |bencher| {
            bencher.iter(|| {
                let mut acc = 0.0;
                b.process(feed.block(), |s| acc += s.x);
                black_box(acc)
            })
        });
    }
    group.finish();
}

fn sliding_spectrum(c: &mut Criterion) {
    let mut group = c.benchmark_group("sliding_spectrum");
    group.throughput(Throughput::Elements(BLOCK as u64));
    for (size, hop) in [(4096, 1024), (4096, 4096), (16384, 4096)] {
        let mut s = spectrum(size, hop);
        let mut feed = Feed::new();
        group.bench_function(format!("n{size}_hop{hop}"), |bencher| {
            bencher.iter(|| {
                let mut acc = 0.0;
                s.process(feed.block(), |f| acc += f.bins[1].re);
                black_box(acc)
            })
        });
    }
    group.finish();
}

fn together(c: &mut Criterion) {
    let mut group = c.benchmark_group("lockin_and_spectrum");
    group.throughput(Throughput::Elements(BLOCK as u64));
    // The spectrum as a stress (N = 4096 every 1024 samples), and as the defaults run it
    // (N = 32768, ten a second: every 10^6 samples at 10 MS/s).
    let variants = [
        ("32_demods_order4_n4096_hop1024", bank(4), (4096, 1024)),
        (
            "32_demods_order4_n4096_hop1024_avx2",
            bank(4).with_avx2_kernel(),
            (4096, 1024),
        ),
        (
            "32_demods_order4_n4096_hop1024_portable",
            bank(4).with_portable_kernel(),
            (4096, 1024),
        ),
        (
            "32_demods_order4_default_spectrum",
            bank(4),
            (32768, (SAMPLE_RATE / 10.0) as usize),
        ),
    ];
    for (name, mut b, (size, hop)) in variants {
        let mut s = spectrum(size, hop);
        let mut feed = Feed::new();
        group.bench_function(name, |bencher| {
            bencher.iter(|| {
                let block = feed.block();
                let mut acc = 0.0;
                b.process(block, |o| acc += o.x);
                s.process(block, |f| acc += f.bins[1].re);
                black_box(acc)
            })
        });
    }
    group.finish();
}

fn threads(c: &mut Criterion) {
    use ftafm::config::default_settings;
    use ftafm::pipeline::{DemodValue, DspPlan, DspSink, DspTeam};

    struct Sum(f64);
    impl DspSink for Sum {
        fn demod(&mut self, _: u64, v: DemodValue) {
            self.0 += v.x;
        }
        fn spectrum<I: ExactSizeIterator<Item = f64>>(&mut self, _: u64, _: f64, mut bins: I) {
            self.0 += bins.nth(1).unwrap_or(0.0);
        }
    }

    let mut group = c.benchmark_group("dsp_threads");
    group.throughput(Throughput::Elements(BLOCK as u64));
    for threads in [1, 2] {
        let mut settings = default_settings();
        settings.dsp.threads = threads;
        settings.drive.frequency = DRIVE;
        settings.spectrum.size = 4096;
        // One spectrum every 1024 samples (above the node's range; the plan takes it).
        settings.spectrum.rate = SAMPLE_RATE / 1024.0;
        for (i, d) in settings.demods.iter_mut().enumerate() {
            *d = ftafm::config::DemodSettings {
                enable: true,
                harmonic: i as u32 + 1,
                order: 4,
                timeconstant: 100e-6,
                rate: 10e3,
                oscillator: Default::default(),
            };
        }
        let mut plan = DspPlan::new(&settings).expect("valid plan");
        assert_eq!(plan.shards(), threads as usize);
        let mut team = DspTeam::spawn(plan.shards() - 1, false).expect("worker threads");
        let word = ftafm::timebase::frequency_word(DRIVE, SAMPLE_RATE).expect("valid drive");
        let mut feed = Feed::new();
        let mut first = 0u64;
        group.bench_function(
            format!("32_demods_order4_n4096_hop1024_{threads}_thread"),
            |bencher| {
                bencher.iter(|| {
                    let mut sum = Sum(0.0);
                    let block = feed.block();
                    let phase = word.wrapping_mul(first);
                    plan.process_block(&mut team, phase, word, block, &mut sum);
                    first += block.len() as u64;
                    black_box(sum.0)
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, lockin, sliding_spectrum, together, threads);
criterion_main!(benches);
