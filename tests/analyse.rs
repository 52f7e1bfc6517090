//! `ftafm analyse` on files: the synthesiser's own signal written by `record-signal` and
//! analysed gives the DSP plan's outputs on the same samples bit for bit, and the same
//! force estimates; an excitation channel or the signal's own fundamental as the reference;
//! a WAV written by another library; bad files refused with what is wrong.

use std::f64::consts::{FRAC_PI_2, TAU};
use std::path::{Path, PathBuf};

use ftafm::analyse::{self, Format, Options, Output};
use ftafm::config::{Engine, Settings, default_settings};
use ftafm::inversion::ForceEstimator;
use ftafm::pipeline::{BLOCK_SAMPLES, DemodFrame, DemodValue, DspPlan, DspSink, DspTeam};
use ftafm::synth::{SynthPlan, SynthState};

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ftafm-analyse-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The paper engine: its estimator's table is built in a tenth of a second.
fn settings() -> Settings {
    let mut s = default_settings();
    s.synth.engine = Engine::Paper;
    s.synth.realtime = false;
    s.dsp.threads = 1;
    s
}

fn options(file: &Path) -> Options {
    Options {
        file: file.to_owned(),
        format: Format::Auto,
        channels: 1,
        signal_channel: 0,
        sample_rate: None,
        reference_channel: None,
        drive_frequency: None,
        reference2_channel: None,
        drive2_frequency: None,
        invols: None,
        metres: false,
        out: None,
        progress: false,
    }
}

/// Demodulator frames as the DSP thread's emitter collects them.
#[derive(Default)]
struct Frames {
    frames: Vec<DemodFrame>,
    current: Option<DemodFrame>,
}

impl DspSink for Frames {
    fn demod(&mut self, index: u64, value: DemodValue) {
        if self
            .current
            .as_ref()
            .is_some_and(|f| f.sample_index != index)
        {
            self.frames.push(self.current.take().unwrap());
        }
        let f = self.current.get_or_insert_with(|| {
            let mut f = DemodFrame::empty();
            f.sample_index = index;
            f
        });
        f.values[f.len] = value;
        f.len += 1;
    }

    fn spectrum<I: ExactSizeIterator<Item = f64>>(&mut self, _: u64, _: f64, _: I) {}
}

fn bits(frames: &[DemodFrame]) -> Vec<(u64, u8, u32, u64, u64)> {
    frames
        .iter()
        .flat_map(|f| {
            f.values().iter().map(|v| {
                (
                    f.sample_index,
                    v.index,
                    v.harmonic,
                    v.x.to_bits(),
                    v.y.to_bits(),
                )
            })
        })
        .collect()
}

/// Runs the analysis and keeps its frames and estimates.
fn analysed(
    settings: &Settings,
    opts: &Options,
) -> (analyse::Summary, Vec<DemodFrame>, Vec<[f64; 6]>) {
    let (mut frames, mut force) = (Vec::new(), Vec::new());
    let mut keep = |o: Output<'_>| match o {
        Output::Demods(f) => frames.push(*f),
        Output::Force(e) => force.push([
            e.max_force,
            e.max_force_sigma,
            e.youngs_modulus,
            e.youngs_modulus_sigma,
            e.contact_time_ratio,
            e.contact_time_ratio_sigma,
        ]),
    };
    let summary = analyse::analyse_with(settings, opts, Some(&mut keep)).unwrap();
    (summary, frames, force)
}

#[test]
fn the_synthesisers_signal_analysed_from_a_file_gives_the_live_lock_in_bit_for_bit() {
    let s = settings();
    let d = dir("round-trip");
    let samples = 400_000; // 40 ms at 10 MS/s: 40 frames at the default 1 kHz.
    // The live chain's DSP stage on the synthesiser's blocks, as the DSP thread runs it.
    let plan = SynthPlan::new(&s).unwrap();
    let mut state = SynthState::steady(&plan, s.synth.seed);
    let mut dsp = DspPlan::new(&s).unwrap();
    let mut team = DspTeam::none();
    let mut live = Frames::default();
    let mut signal = Vec::with_capacity(samples);
    while signal.len() < samples {
        let len = BLOCK_SAMPLES.min(samples - signal.len());
        let phase = plan.output_phase(state.phase());
        let mut block = vec![0.0; len];
        plan.process(&mut state, &mut block);
        dsp.process_block(&mut team, phase, plan.frequency_word, &block, &mut live);
        signal.extend(block);
    }
    let live_frames = live.frames;
    assert!(live_frames.len() >= 39, "{} frames", live_frames.len());

    let file = d.join("signal.npy");
    let rec = analyse::record::record_signal(&s, samples as u64, &file, true).unwrap();
    assert_eq!(rec.samples, samples as u64);
    // The file holds the synthesiser's samples bit for bit (and the drive's cosine).
    let bytes = std::fs::read(&file).unwrap();
    let h = analyse::npy::read_header(&mut &bytes[..]).unwrap();
    assert_eq!(h.shape, vec![samples as u64, 2]);
    let data = &bytes[h.data_offset as usize..];
    for (i, v) in signal.iter().enumerate().step_by(997) {
        let at = i * 16;
        assert_eq!(
            f64::from_le_bytes(data[at..at + 8].try_into().unwrap()).to_bits(),
            v.to_bits()
        );
    }

    let out = d.join("out");
    let mut opts = options(&file);
    opts.out = Some(out.clone());
    let (summary, frames, force) = analysed(&s, &opts);
    assert_eq!(summary.reference.source, "sidecar");
    assert_eq!(summary.samples, samples as u64);
    // The outputs that left the live chain before the end of the stream: the analysis
    // flushes its last frame at the end, the live sink still holds it.
    assert_eq!(bits(&frames[..live_frames.len()]), bits(&live_frames));
    for f in ["demods.npy", "spectrum.npy", "force.npy", "summary.json"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let demods = std::fs::read(out.join("demods.npy")).unwrap();
    let rows = summary.demod_frames as usize;
    let row = 8 + 8 + 4 * 8 * s.demods.len() + 4 * s.demods.len();
    assert_eq!(rows, frames.len());
    assert_eq!(demods.len() % 64, (rows * row) % 64, "header padded to 64");

    // The force estimates: those of the daemon's estimator on the live frames.
    let mut est = ForceEstimator::new(&s).unwrap().expect("an estimator");
    let settle = summary.force.as_ref().unwrap().settle_from;
    let mut expected = Vec::new();
    for f in &live_frames {
        let mut f = *f;
        f.t = f.sample_index as f64 / s.synth.sample_rate;
        if f.t >= settle
            && let Some(Ok(e)) = est.push(&f)
        {
            expected.push(e.max_force);
        }
    }
    assert!(expected.len() >= 20, "{} estimates", expected.len());
    let got: Vec<f64> = force.iter().map(|e| e[0]).collect();
    assert_eq!(got[..expected.len()], expected[..]);
    // Within their stated standard deviations of their mean.
    let mean = got.iter().sum::<f64>() / got.len() as f64;
    for e in &force {
        assert!(
            e[1] > 0.0 && (e[0] - mean).abs() < 4.0 * e[1],
            "{e:?} vs {mean}"
        );
        assert!((e[2] - s.sample.youngs_modulus).abs() < 4.0 * e[3], "{e:?}");
    }

    // The excitation channel as the reference: its phase measured, not known exactly.
    let mut opts = options(&file);
    opts.reference_channel = Some(1);
    opts.metres = true;
    let (summary, by_channel, _) = analysed(&s, &opts);
    let fit = summary.reference.fit.unwrap();
    assert!((fit.frequency - s.drive.frequency).abs() < 1e-3, "{fit:?}");
    assert_eq!(by_channel.len(), frames.len());
    // The signal's fundamental as the reference (a PLL): harmonic 1 reads phase 0.
    let mut opts = options(&file);
    opts.drive_frequency = Some(s.drive.frequency * 1.001);
    opts.metres = true;
    let (summary, by_signal, _) = analysed(&s, &opts);
    assert_eq!(summary.reference.source, "signal");
    for ((a, b), c) in frames.iter().zip(&by_channel).zip(&by_signal).skip(10) {
        for ((x, y), z) in a.values().iter().zip(b.values()).zip(c.values()) {
            assert!((x.r() - y.r()).abs() <= 1e-6 * x.r() + 1e-15, "{x:?} {y:?}");
            let dphi = (x.phase() - y.phase() + TAU / 2.0).rem_euclid(TAU) - TAU / 2.0;
            assert!(dphi.abs() < 1e-3 * f64::from(x.harmonic), "{x:?} {y:?}");
            // The fundamental's fit is as good as the signal's noise allows: equal to a part in
            // 10⁴, or within 0.01 pm for harmonics at the noise floor.
            assert!((x.r() - z.r()).abs() <= 1e-4 * x.r() + 1e-14, "{x:?} {z:?}");
        }
        let h1 = c.values()[0];
        assert!(h1.phase().abs() < 1e-3, "{h1:?}");
    }
    std::fs::remove_dir_all(&d).ok();
}

/// Two-channel 16-bit WAV written by `hound`: the signal (two tones) and the excitation.
fn write_wav(path: &Path, fs: u32, f: f64, seconds: f64) {
    let spec = hound::WavSpec {
        channels: 2,
        sample_rate: fs,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(path, spec).unwrap();
    for n in 0..(seconds * f64::from(fs)) as usize {
        let theta = TAU * f * n as f64 / f64::from(fs);
        let sig = 0.5 * (theta + 0.3).cos() + 0.1 * (3.0 * theta - 1.0).cos();
        for v in [sig, 0.8 * theta.cos()] {
            w.write_sample((v * 32767.0).round() as i16).unwrap();
        }
    }
    w.finalize().unwrap();
}

#[test]
fn a_wav_written_by_another_library_gives_each_tones_amplitude_and_phase() {
    let d = dir("wav");
    let file = d.join("tones.wav");
    let (fs, f) = (1_000_000, 10_123.4);
    write_wav(&file, fs, f, 0.1);
    let mut s = default_settings();
    s.inversion.enable = false;
    s.dsp.threads = 1;
    let mut opts = options(&file);
    opts.reference_channel = Some(1);
    opts.invols = Some(1.0);
    let (summary, frames, _) = analysed(&s, &opts);
    assert_eq!(summary.sample_rate, 1e6);
    assert_eq!(summary.sample_rate_from, "the WAV header");
    assert!(summary.why_no_force.is_some());
    let fit = summary.reference.fit.unwrap();
    assert!((fit.frequency - f).abs() < 1e-3, "{fit:?}");
    assert!((fit.amplitude - 0.8).abs() < 1e-3, "{fit:?}");
    assert!(frames.len() >= 90, "{} frames", frames.len());
    // Quantised to 16 bits (±1.5e-5 of full scale): the lock-in's outputs once settled.
    for frame in &frames[20..] {
        for v in frame.values() {
            let (r, phase) = match v.harmonic {
                1 => (0.5, 0.3),
                3 => (0.1, -1.0),
                _ => (0.0, 0.0),
            };
            assert!((v.r() - r).abs() < 2e-4, "{v:?}");
            if r > 0.0 {
                assert!((v.phase() - phase).abs() < 2e-3, "{v:?}");
            }
        }
    }
    std::fs::remove_dir_all(&d).ok();
}

/// Two excitations recorded beside the signal (a bimodal experiment): channel 1 holds the
/// first, channel 2 the second at an unrelated frequency and phase. With
/// `--reference2-channel` (looked for near `/drive2/frequency`) the demodulators on `drive2`
/// read the signal's tone at f2 against it: its amplitude and its phase less the
/// excitation's; with `--drive2-frequency` alone the signal's own tone is the reference
/// (phase 0). Bad values are refused by name.
#[test]
fn a_second_excitation_channel_is_the_reference_of_the_demodulators_on_drive2() {
    let d = dir("drive2");
    let file = d.join("bimodal.wav");
    let (fs, f1, f2, psi) = (1_000_000u32, 10_123.4, 63_456.7, -2.1);
    let spec = hound::WavSpec {
        channels: 3,
        sample_rate: fs,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(&file, spec).unwrap();
    for n in 0..(0.1 * f64::from(fs)) as usize {
        let t = n as f64 / f64::from(fs);
        let (a, b) = (TAU * f1 * t, TAU * f2 * t + psi);
        let sig = 0.5 * (a + 0.3).cos() + 0.2 * (b + 0.7).cos();
        for v in [sig, 0.8 * a.cos(), 0.6 * b.cos()] {
            w.write_sample((v * 32767.0).round() as i16).unwrap();
        }
    }
    w.finalize().unwrap();
    let mut s = default_settings();
    s.inversion.enable = false;
    s.dsp.threads = 1;
    s.drive2.frequency = 63e3;
    s.demods[1].harmonic = 1;
    s.demods[1].oscillator = ftafm::config::Oscillator::Drive2;
    let mut opts = options(&file);
    opts.invols = Some(1.0);
    opts.reference_channel = Some(1);
    opts.reference2_channel = Some(2);
    let check = |frames: &[DemodFrame], second: (f64, f64)| {
        assert!(frames.len() >= 90, "{} frames", frames.len());
        for frame in &frames[20..] {
            for v in frame.values() {
                let (r, phase) = match (v.index, v.harmonic) {
                    (1, _) => second,
                    (_, 1) => (0.5, 0.3),
                    _ => continue,
                };
                assert!((v.r() - r).abs() < 2e-4, "{v:?}");
                assert!((v.phase() - phase).abs() < 2e-3, "{v:?}");
            }
        }
    };
    let (summary, frames, _) = analysed(&s, &opts);
    let r2 = summary.reference2.clone().unwrap();
    let fit = r2.fit.unwrap();
    assert_eq!(r2.source, "channel 2");
    assert!((fit.frequency - f2).abs() < 1e-3, "{fit:?}");
    assert!((fit.amplitude - 0.6).abs() < 1e-3, "{fit:?}");
    check(&frames, (0.2, 0.7));
    // The signal's own tone near --drive2-frequency.
    opts.reference2_channel = None;
    opts.drive2_frequency = Some(63e3);
    let (summary, frames, _) = analysed(&s, &opts);
    assert_eq!(summary.reference2.unwrap().source, "signal");
    check(&frames, (0.2, 0.0));
    // Refusals, naming the flag.
    for (channel, f, says) in [
        (
            Some(0),
            None,
            "--reference2-channel must differ from --signal-channel",
        ),
        (Some(3), None, "--reference2-channel 3"),
        (
            None,
            Some(6e5),
            "--drive2-frequency must be finite, > 0 and below half",
        ),
    ] {
        opts.reference2_channel = channel;
        opts.drive2_frequency = f;
        let e = analyse::analyse_with(&s, &opts, None).unwrap_err();
        assert!(e.contains(says), "{e}");
    }
    std::fs::remove_dir_all(&d).ok();
}

/// A WAV that SoX synthesised (`sox … synth`: two sines, the second a quarter period on,
/// mixed down to one 16-bit channel): data this project did not write, by a tool that has
/// its own idea of a sine's phase. The reference is refined from the signal (its
/// fundamental, SoX's `sin`, is the reference's cosine a quarter period on), so the
/// fundamental reads phase 0 and the third harmonic, sin(3θ + π/2) = cos(3θ_ref + 3π/2),
/// reads −π/2. SoX is installed by `.ci/run`; without it the test fails, saying so.
#[test]
fn a_wav_synthesised_by_sox_gives_each_tones_amplitude_and_phase() {
    let d = dir("sox");
    let file = d.join("sox.wav");
    let made = std::process::Command::new("sox")
        .args([
            "-D", "-r", "1000000", "-c", "2", "-n", "-b", "16", "-c", "1",
        ])
        .arg(&file)
        .args(["synth", "0.2", "sine", "10000", "sine", "30000", "0", "25"])
        .args(["remix", "1v0.5,2v0.2"])
        .status()
        .unwrap_or_else(|e| panic!("sox is needed for this test (apt-get install sox): {e}"));
    assert!(made.success(), "sox failed: {made}");
    let mut s = default_settings();
    s.inversion.enable = false;
    s.dsp.threads = 1;
    let mut opts = options(&file);
    opts.drive_frequency = Some(10e3);
    opts.invols = Some(1.0);
    let (summary, frames, _) = analysed(&s, &opts);
    assert_eq!(summary.sample_rate_from, "the WAV header");
    let fit = summary.reference.fit.unwrap();
    assert!((fit.frequency - 1e4).abs() < 1e-6, "{fit:?}");
    // SoX's sine is a few µrad off its nominal phase (its single-precision synthesis).
    assert!((fit.phase + FRAC_PI_2).abs() < 2e-5, "{fit:?}");
    assert!(frames.len() >= 190, "{} frames", frames.len());
    // 16-bit quantisation (±1.5e-5 of full scale): the lock-in's outputs once settled.
    for frame in &frames[20..] {
        for v in frame.values() {
            let (r, phase) = match v.harmonic {
                1 => (0.5, 0.0),
                3 => (0.2, -FRAC_PI_2),
                _ => (0.0, 0.0),
            };
            assert!((v.r() - r).abs() < 2e-4, "{v:?}");
            if r > 0.0 {
                assert!((v.phase() - phase).abs() < 2e-3, "{v:?}");
            }
        }
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn bad_files_are_refused_naming_the_file_and_what_is_wrong() {
    let d = dir("bad");
    let s = settings();
    let err = |file: &Path, tweak: &dyn Fn(&mut Options)| -> String {
        let mut opts = options(file);
        opts.sample_rate = Some(1e6);
        opts.drive_frequency = Some(1e4);
        opts.metres = true;
        tweak(&mut opts);
        let e = analyse::analyse(&s, &opts).unwrap_err();
        assert!(
            e.contains(&file.display().to_string()) || e.starts_with("--"),
            "{e}"
        );
        e
    };
    let none = |_: &mut Options| {};
    let empty = d.join("empty.npy");
    std::fs::write(&empty, b"").unwrap();
    assert!(err(&empty, &none).contains("too short"));
    let empty_wav = d.join("empty.wav");
    std::fs::write(&empty_wav, b"").unwrap();
    assert!(err(&empty_wav, &none).contains("not a WAV"));
    // A WAV whose header has no data chunk.
    let mut nodata = b"RIFF\x24\x00\x00\x00WAVEfmt \x10\x00\x00\x00\x01\x00\x01\x00".to_vec();
    nodata.extend(1_000_000u32.to_le_bytes());
    nodata.extend(2_000_000u32.to_le_bytes());
    nodata.extend([2, 0, 16, 0]);
    let nodata_wav = d.join("nodata.wav");
    std::fs::write(&nodata_wav, &nodata).unwrap();
    let e = err(&nodata_wav, &none);
    assert!(e.contains("not a WAV") || e.contains("no samples"), "{e}");
    // A truncated .npy: the header promises more than the file holds.
    let good = d.join("good.npy");
    let tone: Vec<f64> = (0..20_000).map(|n| (TAU * 0.01 * n as f64).cos()).collect();
    analyse::npy::write_f64(&good, &[tone.len()], &tone).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let truncated = d.join("truncated.npy");
    std::fs::write(&truncated, &bytes[..bytes.len() - 8]).unwrap();
    assert!(err(&truncated, &none).contains("truncated"));
    // A NaN sample.
    let mut nan = tone.clone();
    nan[12_345] = f64::NAN;
    let nan_file = d.join("nan.npy");
    analyse::npy::write_f64(&nan_file, &[nan.len()], &nan).unwrap();
    let e = err(&nan_file, &none);
    assert!(e.contains("sample 12345") && e.contains("NaN"), "{e}");
    // Channels that do not match: a column that is not there, raw bytes not whole samples.
    let e = err(&good, &|o: &mut Options| o.signal_channel = 1);
    assert!(e.contains("1 channel"), "{e}");
    let raw = d.join("odd.raw");
    std::fs::write(&raw, [0u8; 10]).unwrap();
    let e = err(&raw, &|o: &mut Options| {
        o.format = Format::RawI16;
        o.channels = 2;
    });
    assert!(e.contains("not a whole number"), "{e}");
    // No scale, no reference, no rate.
    let e = err(&good, &|o: &mut Options| o.metres = false);
    assert!(e.contains("--invols"), "{e}");
    let e = err(&good, &|o: &mut Options| o.drive_frequency = None);
    assert!(e.contains("--reference-channel"), "{e}");
    let e = err(&good, &|o: &mut Options| o.sample_rate = None);
    assert!(e.contains("--sample-rate"), "{e}");
    // The good file goes through.
    let mut opts = options(&good);
    opts.sample_rate = Some(1e6);
    opts.drive_frequency = Some(1e4);
    opts.metres = true;
    let mut s = s.clone();
    s.inversion.enable = false;
    assert_eq!(analyse::analyse(&s, &opts).unwrap().samples, 20_000);
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn the_commands_record_and_analyse_through_files_and_standard_input() {
    use std::io::Write;
    use std::process::{Command, Stdio};
    let d = dir("cli");
    let config = d.join("paper.toml");
    std::fs::write(&config, "[synth]\nengine = \"paper\"\n").unwrap();
    let file = d.join("sig.npy");
    let bin = env!("CARGO_BIN_EXE_ftafm");
    let cfg = config.to_str().unwrap();
    let out = Command::new(bin)
        .args([
            "--config",
            cfg,
            "record-signal",
            "--seconds",
            "0.02",
            "--out",
        ])
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = Command::new(bin)
        .args(["--config", cfg, "analyse", "--json"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["samples"], 200_000);
    assert_eq!(json["reference"]["source"], "sidecar");
    assert_eq!(json["demod_frames"], 20);
    // The same samples as raw float32 on standard input, the fundamental as the reference.
    let bytes = std::fs::read(&file).unwrap();
    let h = analyse::npy::read_header(&mut &bytes[..]).unwrap();
    let raw: Vec<u8> = bytes[h.data_offset as usize..]
        .chunks_exact(8)
        .flat_map(|b| (f64::from_le_bytes(b.try_into().unwrap()) as f32).to_le_bytes())
        .collect();
    let mut child = Command::new(bin)
        .args(["--config", cfg, "analyse", "-", "--format", "raw-f32"])
        .args([
            "--sample-rate",
            "1e7",
            "--drive-frequency",
            "1e5",
            "--units",
            "m",
        ])
        .args(["--json"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(&raw).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["samples"], 200_000);
    assert_eq!(json["reference"]["source"], "signal");
    // Bad flags exit 2, bad files 1, each with its message.
    let out = Command::new(bin)
        .args(["analyse", "--units", "V"])
        .arg(&file)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("allowed value is \"m\""));
    let out = Command::new(bin)
        .args(["analyse", "-", "--units", "m"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--format raw-i16 or raw-f32"));
    std::fs::remove_dir_all(&d).ok();
}
