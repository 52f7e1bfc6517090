//! The configuration layer as a library: the embedded default, partial overlays, errors that
//! name the key, the node registry with `get`/`set`, and that the docs list every node.

use std::collections::BTreeSet;

use ftafm::config::{
    ConfigError, DEFAULT_TOML, Engine, FeedbackSettings, InclusionSettings, InclusionShape,
    InversionMethod, InversionSettings, Kind, NodeError, ScanSettings, Settings, SpectrumWindow,
    default_settings, load, load_str, registry,
};
use proptest::prelude::*;
use serde_json::{Value, json};

/// The message of the error a config text gives.
fn error_of(overlay: &str) -> String {
    match load_str(overlay, "test.toml") {
        Ok(_) => panic!("accepted:\n{overlay}"),
        Err(e) => e.to_string(),
    }
}

/// Asserts `message` contains every one of `parts`.
fn assert_mentions(message: &str, parts: &[&str]) {
    for part in parts {
        assert!(message.contains(part), "{message:?} lacks {part:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// The embedded default

#[test]
fn default_is_the_papers_silicon_case() {
    let s = default_settings();
    s.validate().unwrap();
    assert_eq!(s.cantilever.f1, 100e3);
    assert_eq!(s.cantilever.k, 20.0);
    assert_eq!(s.cantilever.q, [100.0, 417.0, 340.0, 200.0, 26.0]);
    assert_eq!(s.cantilever.extra_modes, 0);
    assert_eq!(s.cantilever.tip_radius, 10e-9);
    for material in [s.tip, s.sample] {
        assert_eq!(material.youngs_modulus, 129e9);
        assert_eq!(material.poisson, 0.28);
    }
    assert_eq!(s.drive.frequency, 100e3);
    assert_eq!(s.drive.free_amplitude, 30e-9);
    assert_eq!(s.surface.distance, 20e-9);
    assert_eq!(s.synth.sample_rate, 10e6);
    assert_eq!(s.synth.engine, Engine::Coupled);
    assert_eq!(s.synth.seed, 1);
    assert!(s.synth.realtime);
    assert!(s.noise.enable);
    assert_eq!(s.noise.temperature, 300.0);
    assert_eq!(s.noise.detector_density, 1e-13);
    assert_eq!(s.noise.adc_bits, 16);
    assert_eq!(s.noise.adc_range, 100e-9);
    assert!(s.spectrum.enable);
    assert_eq!(s.spectrum.size, 32768);
    assert_eq!(s.spectrum.window, SpectrumWindow::BlackmanHarris);
    assert_eq!(s.spectrum.rate, 10.0);
    assert!(s.scope.enable);
    assert_eq!(s.scope.length, 2000);
    assert_eq!(s.scope.decimation, 1);
    assert_eq!(s.scope.rate, 20.0);
    assert!(s.server.allowed_origins.is_empty());
    assert_eq!(s.server.max_clients, 128);
    assert_eq!(s.server.client_queue, 1024);
    assert_eq!(s.server.stall_timeout, 60.0);
    assert_eq!(
        s.inversion,
        InversionSettings {
            enable: true,
            method: InversionMethod::Full,
            harmonic_a: 6,
            harmonic_b: 17,
            averaging: 1,
            points: 256,
        }
    );
    assert_eq!(
        s.scan,
        ScanSettings {
            enable: false,
            size: 1e-6,
            pixels: 64,
            line_rate: 2.0,
            x: 0.0,
            y: 0.0,
        }
    );
    // The feedback holds the amplitude at /surface/distance; its gains are tuned in the
    // default file, so only their ranges are asserted here.
    assert!(s.feedback.enable);
    assert_eq!(s.feedback.setpoint, 0.0);
    assert!((0.0..=10.0).contains(&s.feedback.proportional));
    assert!(s.feedback.integral > 0.0 && s.feedback.integral <= 1e6);
    // Inclusion 0: the paper's 10 % softer inhomogeneity, a flat disc a third of the scan
    // size across at the centre of the scan area; the rest are disabled silicon.
    assert_eq!(s.inclusions.len(), 8);
    assert_eq!(
        s.inclusions[0],
        InclusionSettings {
            enable: true,
            shape: InclusionShape::Disc,
            x: 0.0,
            y: 0.0,
            width: 333.3e-9,
            length: 333.3e-9,
            height: 0.0,
            youngs_modulus: 116.1e9,
            relative_modulus: 0.9,
            poisson: 0.28,
        }
    );
    assert!((s.inclusions[0].width - s.scan.size / 3.0).abs() < 1e-10);
    assert!((s.inclusions[0].youngs_modulus / s.sample.youngs_modulus - 0.9).abs() < 1e-3);
    for inclusion in &s.inclusions[1..] {
        assert_eq!(
            *inclusion,
            InclusionSettings {
                enable: false,
                shape: InclusionShape::Disc,
                x: 0.0,
                y: 0.0,
                width: 100e-9,
                length: 100e-9,
                height: 0.0,
                youngs_modulus: 129e9,
                relative_modulus: 1.0,
                poisson: 0.28,
            }
        );
    }
    // Each pixel of the default scan lasts 390 drive periods (at least 10 are required), a
    // frame 32 s.
    let pixel = 1.0 / (2.0 * f64::from(s.scan.pixels) * s.scan.line_rate);
    assert_eq!((pixel * s.drive.frequency).floor(), 390.0);
    assert_eq!(f64::from(s.scan.pixels) / s.scan.line_rate, 32.0);
    assert_eq!(s.demods.len(), 32);
    for (n, demod) in s.demods.iter().enumerate() {
        assert!(demod.enable);
        assert_eq!(demod.harmonic as usize, n + 1);
        assert_eq!(demod.order, 4);
        assert_eq!(demod.timeconstant, 5e-4);
        assert_eq!(demod.rate, 1000.0);
    }
}

#[test]
fn no_file_means_the_default() {
    assert_eq!(load(None).unwrap(), default_settings());
    assert_eq!(load_str("", "empty.toml").unwrap(), default_settings());
    assert_eq!(
        load_str(DEFAULT_TOML, "default.toml").unwrap(),
        default_settings()
    );
}

#[test]
fn settings_serialise_to_toml_that_loads_back() {
    // The demodulator bank is written as the index-keyed table the files use.
    let text = toml::to_string(&default_settings()).unwrap();
    assert!(text.contains("[demods.31]"), "{text}");
    assert_eq!(
        load_str(&text, "roundtrip.toml").unwrap(),
        default_settings()
    );
    let json = serde_json::to_value(default_settings()).unwrap();
    assert_eq!(json["demods"]["3"]["harmonic"], json!(4));
    assert_eq!(json["server"]["allowed_origins"], json!([]));
    assert_eq!(json["inversion"]["method"], json!("full"));
    assert_eq!(json["inversion"]["harmonic_b"], json!(17));
    // Tables keep the tree's order: [inversion] after [server], before the bank.
    let at = |table: &str| {
        text.find(table)
            .unwrap_or_else(|| panic!("{table}: {text}"))
    };
    assert!(at("[server]") < at("[inversion]") && at("[inversion]") < at("[scan]"));
    assert!(at("[scan]") < at("[feedback]") && at("[feedback]") < at("[inclusions.0]"));
    assert!(at("[inclusions.7]") < at("[demods.0]"));
    assert_eq!(json["inclusions"]["0"]["shape"], json!("disc"));
    assert_eq!(json["inclusions"]["0"]["youngs_modulus"], json!(116.1e9));
    assert_eq!(json["scan"]["pixels"], json!(64));
    assert_eq!(json["feedback"]["setpoint"], json!(0.0));
    // Shapes are written by name and come back.
    let mut s = default_settings();
    s.inclusions[5].shape = InclusionShape::Rectangle;
    s.inclusions[5].enable = true;
    let text = toml::to_string(&s).unwrap();
    assert!(text.contains("shape = \"rectangle\""), "{text}");
    assert_eq!(load_str(&text, "roundtrip.toml").unwrap(), s);
    let mut s = default_settings();
    s.inversion.method = InversionMethod::TwoHarmonic;
    let text = toml::to_string(&s).unwrap();
    assert!(text.contains("method = \"two_harmonic\""), "{text}");
    assert_eq!(load_str(&text, "roundtrip.toml").unwrap(), s);
    // A list of origins is a TOML array of strings, and comes back the same.
    let mut s = default_settings();
    s.server.allowed_origins = vec!["http://localhost:3000".into(), "https://lab.example".into()];
    let text = toml::to_string(&s).unwrap();
    assert!(
        text.contains(r#"allowed_origins = ["http://localhost:3000", "https://lab.example"]"#),
        "{text}"
    );
    assert_eq!(load_str(&text, "roundtrip.toml").unwrap(), s);
}

/// Every seed `set` accepts is saved so that it loads again: TOML's integers end at
/// 2⁶³ − 1, so a larger seed is written as the string of its digits, which a file (and so
/// `--config` and `load_settings`) may give; smaller ones stay integers.
#[test]
fn the_largest_seed_is_saved_and_loaded_again() {
    for seed in [u64::MAX, 1 << 63, (1 << 63) - 1, 0] {
        let mut s = default_settings();
        s.set("/synth/seed", &json!(seed)).unwrap();
        let text = ftafm::config::settings_toml(&s).unwrap();
        let written = if seed > i64::MAX as u64 {
            format!("seed = \"{seed}\"")
        } else {
            format!("seed = {seed}")
        };
        assert!(text.contains(&written), "{written}: {text}");
        let back = load_str(&text, "saved.toml").unwrap_or_else(|e| panic!("{seed}: {e}"));
        assert_eq!(back.synth.seed, seed);
        assert_eq!(back, s);
        // serde alone (the complete file, as the embedded default is read) agrees.
        assert_eq!(toml::from_str::<Settings>(&text).unwrap(), s);
    }
    // Only a value beyond TOML's integers may be a string; nothing else is taken for one.
    for (text, shown) in [
        ("[synth]\nseed = \"12\"\n", "\"12\""),
        (
            "[synth]\nseed = \"18446744073709551616\"\n",
            "18446744073709551616",
        ),
        (
            "[synth]\nseed = \"+9223372036854775808\"\n",
            "+9223372036854775808",
        ),
    ] {
        assert_mentions(&error_of(text), &["/synth/seed", shown, "wrong type"]);
    }
}

// ---------------------------------------------------------------------------------------------
// Overlays

#[test]
fn partial_overlay_changes_only_what_it_names() {
    let s = load_str(
        "[sample]\nyoungs_modulus = 116.1e9\n\n[demods.3]\nharmonic = 7\n",
        "inhomogeneity.toml",
    )
    .unwrap();
    let mut expected = default_settings();
    expected.sample.youngs_modulus = 116.1e9;
    for inclusion in &mut expected.inclusions {
        inclusion.youngs_modulus = inclusion.relative_modulus * 116.1e9;
    }
    expected.demods[3].harmonic = 7;
    assert_eq!(s, expected);
}

/// The outputs a change takes back from a stopped unit: those whose nodes it writes, each
/// output's node a node of the registry; a whole load (`None`) writes them all.
#[test]
fn the_outputs_a_change_writes_are_those_of_its_nodes() {
    use ftafm::config::PidTarget;
    let bit = |t: PidTarget| 1u64 << t as u64;
    let paths = [
        "/sample/youngs_modulus".to_owned(),
        "/drive/frequency".to_owned(),
    ];
    assert_eq!(
        PidTarget::written(Some(&paths)),
        bit(PidTarget::DriveFrequency)
    );
    assert_eq!(PidTarget::written(Some(&[])), 0);
    let all = PidTarget::ALL.iter().fold(0, |m, t| m | bit(*t));
    assert_eq!(PidTarget::written(None), all);
    for &t in PidTarget::ALL {
        assert_eq!(PidTarget::written(Some(&[t.node().to_owned()])), bit(t));
        assert!(
            registry().iter().any(|n| n.path == t.node()),
            "{}",
            t.node()
        );
    }
}

#[test]
fn inline_demod_tables_change_only_their_keys() {
    // Demodulator 4 (harmonic 5): not one the inversion needs (6 and 17).
    let s = load_str("[demods]\n4 = { order = 2, enable = false }\n", "t.toml").unwrap();
    let mut expected = default_settings();
    expected.demods[4].order = 2;
    expected.demods[4].enable = false;
    assert_eq!(s, expected);
}

#[test]
fn arrays_are_replaced_whole() {
    let s = load_str("[cantilever]\nq = [50, 60.5]\nextra_modes = 3\n", "t.toml").unwrap();
    assert_eq!(s.cantilever.q, [50.0, 60.5]);
    assert_eq!(s.cantilever.extra_modes, 3);
}

#[test]
fn cross_checks_run_after_the_whole_file() {
    // The drive alone is above Nyquist at 10 MHz; with the faster sampling it is fine,
    // whichever table comes first.
    let both = "[drive]\nfrequency = 6e6\n\n[synth]\nsample_rate = 100e6\n";
    let s = load_str(both, "fast.toml").unwrap();
    assert_eq!(s.drive.frequency, 6e6);
    assert_eq!(s.synth.sample_rate, 100e6);
    let message = error_of("[drive]\nfrequency = 6e6\n");
    assert_mentions(
        &message,
        &[
            "test.toml",
            "/drive/frequency = 6 MHz",
            "/synth/sample_rate",
        ],
    );
}

#[test]
fn integral_floats_are_integers() {
    let s = load_str("[demods.0]\norder = 4.0\n", "t.toml").unwrap();
    assert_eq!(s.demods[0].order, 4);
    assert_mentions(
        &error_of("[demods.0]\norder = 4.5\n"),
        &["/demods/0/order = 4.5", "not an integer", "1 ≤ value ≤ 8"],
    );
}

// ---------------------------------------------------------------------------------------------
// Every error class names the key

#[test]
fn unknown_key_lists_the_keys_of_its_table() {
    let message = error_of("[sample]\nyoungs_moduls = 1e9\n");
    assert_eq!(
        message,
        "unknown key /sample/youngs_moduls in test.toml; keys of [sample]: youngs_modulus, poisson"
    );
}

#[test]
fn unknown_table_lists_the_top_level() {
    let message = error_of("[smaple]\npoisson = 0.3\n");
    assert_mentions(&message, &["/smaple", "test.toml", "cantilever", "demods"]);
    let message = error_of("[demods.32]\nenable = false\n");
    assert_mentions(&message, &["/demods/32", "[demods]", "0 … 31"]);
    let message = error_of("[demods.3]\nphase = 1.0\n");
    assert_mentions(&message, &["/demods/3/phase", "[demods.3]", "harmonic"]);
}

#[test]
fn a_value_where_a_table_belongs() {
    let message = error_of("sample = 3\n");
    assert_mentions(&message, &["/sample", "table", "youngs_modulus"]);
}

#[test]
fn a_table_where_a_value_belongs() {
    let message = error_of("[sample.poisson]\nx = 1\n");
    assert_mentions(&message, &["/sample/poisson", "wrong type"]);
}

#[test]
fn wrong_type_names_key_value_and_expectation() {
    let message = error_of("[sample]\nyoungs_modulus = \"hard\"\n");
    assert_eq!(
        message,
        "test.toml: /sample/youngs_modulus = \"hard\" has the wrong type: expected a number, \
         0 < value ≤ 1e13 Pa"
    );
    assert_mentions(
        &error_of("[noise]\nenable = 1\n"),
        &["/noise/enable = 1", "true or false"],
    );
    assert_mentions(
        &error_of("[demods.1]\nharmonic = \"2\"\n"),
        &["/demods/1/harmonic", "\"2\"", "an integer"],
    );
    assert_mentions(
        &error_of("[synth]\nengine = \"fast\"\n"),
        &["/synth/engine = \"fast\"", "\"paper\", \"coupled\""],
    );
}

#[test]
fn moduli_must_be_positive() {
    for value in ["-129e9", "0.0", "0"] {
        let message = error_of(&format!("[sample]\nyoungs_modulus = {value}\n"));
        assert_mentions(
            &message,
            &[
                "/sample/youngs_modulus = ",
                "out of range",
                "0 < value ≤ 1e13 Pa",
            ],
        );
    }
    assert_mentions(
        &error_of("[tip]\nyoungs_modulus = -1.0\n"),
        &["/tip/youngs_modulus = -1 is out of range"],
    );
}

#[test]
fn poisson_ratio_is_inside_the_open_interval() {
    for value in ["0.5", "-1.0", "0.7"] {
        let message = error_of(&format!("[sample]\npoisson = {value}\n"));
        let shown = value.trim_end_matches(".0");
        assert_eq!(
            message,
            format!(
                "test.toml: /sample/poisson = {shown} is out of range: allowed -1 < value < 0.5"
            )
        );
    }
    let s = load_str(
        "[sample]\npoisson = 0.49\n[tip]\npoisson = -0.99\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!((s.sample.poisson, s.tip.poisson), (0.49, -0.99));
}

#[test]
fn quality_factors() {
    assert_mentions(
        &error_of("[cantilever]\nq = []\n"),
        &["/cantilever/q = []", "empty"],
    );
    assert_mentions(
        &error_of("[cantilever]\nq = [100, 0.4]\n"),
        &[
            "/cantilever/q",
            "entry 1 (0.4)",
            "out of range",
            "0.5 < value ≤ 1e7",
        ],
    );
    assert_mentions(
        &error_of("[cantilever]\nq = [100, \"x\"]\n"),
        &["/cantilever/q", "entry 1", "not a number"],
    );
    assert_mentions(
        &error_of("[cantilever]\nq = 100\n"),
        &["/cantilever/q = 100", "wrong type", "a list"],
    );
    let seventeen = vec!["100"; 17].join(", ");
    assert_mentions(
        &error_of(&format!("[cantilever]\nq = [{seventeen}]\n")),
        &["/cantilever/q", "17 entries"],
    );
    assert_mentions(
        &error_of("[cantilever]\nextra_modes = 12\n"),
        &[
            "/cantilever/extra_modes = 12",
            "/cantilever/q",
            "17 modes",
            "16",
        ],
    );
    assert_mentions(
        &error_of("[cantilever]\nq = [100]\nextra_modes = 2\n"),
        &["/cantilever/extra_modes = 2", "/cantilever/q", "at least 2"],
    );
}

#[test]
fn nan_and_infinity_are_refused() {
    assert_eq!(
        error_of("[sample]\npoisson = nan\n"),
        "test.toml: /sample/poisson = nan is not a finite number: allowed -1 < value < 0.5"
    );
    for value in ["inf", "-inf", "+inf"] {
        let message = error_of(&format!("[drive]\nfrequency = {value}\n"));
        assert_mentions(
            &message,
            &["/drive/frequency = ", "not a finite number", "Hz"],
        );
    }
    assert_mentions(
        &error_of("[cantilever]\nq = [100, nan]\n"),
        &["/cantilever/q = [100, nan]", "not a finite number"],
    );
}

#[test]
fn demod_order_above_eight() {
    assert_eq!(
        error_of("[demods.2]\norder = 9\n"),
        "test.toml: /demods/2/order = 9 is out of range: allowed 1 ≤ value ≤ 8"
    );
    assert_mentions(
        &error_of("[demods.2]\norder = 0\n"),
        &["/demods/2/order = 0"],
    );
}

#[test]
fn harmonic_above_nyquist_is_out_of_band_not_refused() {
    let s = load_str("[demods.3]\nharmonic = 60\n", "t.toml").unwrap();
    assert_eq!(s.demods[3].harmonic, 60);
    assert!(!s.demod_active(3));
    assert_eq!(s.demods_out_of_band(), [3]);
    let info = &s.list("/demods/3/harmonic").unwrap()[0];
    assert_mentions(
        info.warning.as_deref().unwrap(),
        &["out of band", "6 MHz", "Nyquist", "no frames"],
    );
    assert!(s.list("/demods/4/harmonic").unwrap()[0].warning.is_none());
    // A disabled one is just kept, without a warning.
    let s = load_str("[demods.3]\nharmonic = 60\nenable = false\n", "t.toml").unwrap();
    assert!(s.node_warning("/demods/3/harmonic").is_none());
}

/// The second excitation: refused where it cannot drive (the paper engine, above Nyquist),
/// each message naming the nodes, and beside a scan only with loops that leave the drive
/// alone; off, it is only a reference, and a
/// demodulator on it is in or out of band by its own frequency.
#[test]
fn second_excitation_is_refused_where_it_cannot_drive() {
    let on = "[drive2]\nenable = true\n";
    assert_mentions(
        &error_of(&format!("{on}[synth]\nengine = \"paper\"\n")),
        &["/drive2/enable", "/synth/engine", "coupled"],
    );
    // A scan takes it (bimodal maps) and mode 2's loops, not a loop on the drive its
    // feedback reads.
    let scan = format!("{on}[scan]\nenable = true\n");
    load_str(&scan, "t.toml").expect("a scan with the second excitation");
    let pll = "oscillator = \"drive2\"\ninput = \"phase\"\noutput_min = 600e3\n\
               output_max = 650e3\np = 0.0\ni = 1.0\nsetpoint = 0.0\n";
    load_str(
        &format!("{scan}[pids.0]\nenable = true\noutput = \"drive2_frequency\"\n{pll}"),
        "t.toml",
    )
    .expect("mode 2's PLL beside a scan");
    assert_mentions(
        &error_of(&format!(
            "{scan}[pids.0]\nenable = true\noutput = \"drive_frequency\"\ninput = \"phase\"\n\
             output_min = 90e3\noutput_max = 110e3\nsetpoint = 0.0\n"
        )),
        &[
            "/pids/0/output",
            "drive_frequency",
            "/scan/enable",
            "/feedback/enable",
        ],
    );
    // A unit on the PLL's frequency shift needs the PLL.
    assert_mentions(
        &error_of("[pids.2]\nenable = true\ninput = \"frequency_shift\"\n"),
        &[
            "/pids/2/input",
            "frequency_shift",
            "\"phase\"",
            "drive_frequency",
        ],
    );
    // With the scan's own feedback off, loops on the drive and the surface run beside it
    // (a unit on the surface is then the scan's feedback).
    load_str(
        &format!(
            "{scan}[feedback]\nenable = false\n[pids.0]\nenable = true\n\
             output = \"drive_frequency\"\ninput = \"phase\"\noutput_min = 90e3\n\
             output_max = 110e3\nsetpoint = 0.0\n[pids.1]\nenable = true\n"
        ),
        "t.toml",
    )
    .expect("a PLL and a unit on the surface beside a scan without its feedback");
    assert_mentions(
        &error_of(&format!("{on}frequency = 6e6\n")),
        &["/drive2/frequency", "6 MHz", "Nyquist", "5 MHz"],
    );
    // Off, any frequency stands; a demodulator on it above Nyquist is out of band.
    let s = load_str(
        "[drive2]\nfrequency = 6e6\n[demods.20]\noscillator = \"drive2\"\nharmonic = 1\n",
        "t.toml",
    )
    .unwrap();
    assert!(!s.demod_active(20));
    assert_mentions(
        s.node_warning("/demods/20/oscillator").as_deref().unwrap(),
        &["out of band", "/drive2/frequency", "6 MHz"],
    );
    // On drive2, demodulator 5's harmonic 6 is no harmonic of the drive: the inversion's
    // harmonic_a = 6 loses its only measure.
    assert_mentions(
        &error_of("[demods.5]\noscillator = \"drive2\"\n"),
        &["/inversion/harmonic_a = 6 is not measured by any enabled demodulator"],
    );
    assert_mentions(
        &error_of("[demods.3]\noscillator = \"drive3\"\n"),
        &["/demods/3/oscillator", "drive3", "drive2"],
    );
    // `list` gives the Nyquist limit while it drives, the static range while it is off.
    let range = |s: &Settings| {
        let info = &s.list("/drive2/frequency").unwrap()[0];
        (info.max.clone(), info.max_inclusive)
    };
    assert_eq!(range(&default_settings()), (json!(1e8), Some(true)));
    let on = load_str("[drive2]\nenable = true\n", "t.toml").unwrap();
    assert_eq!(range(&on), (json!(5e6), Some(false)));
}

/// A 300 kHz, 40 N/m lever, set up in one place: the drive follows f1, the demodulators it
/// pushes above Nyquist are out of band, and the inversion takes in-band harmonics.
#[test]
fn a_300_khz_lever_loads_from_its_cantilever_alone() {
    let s = load_str("[cantilever]\nf1 = 300e3\nk = 40\n", "lever.toml").unwrap();
    assert!(s.drive.follow_f1);
    assert_eq!(s.drive.frequency, 300e3);
    assert_eq!(s.demods_out_of_band(), (16..32).collect::<Vec<_>>());
    assert_eq!(s.inversion_harmonics(), Some((6, 16)));
    let warnings = s.warnings();
    assert_eq!(warnings.len(), 3, "{warnings:?}");
    assert_mentions(&warnings[0], &["16 (H17)", "31 (H32)", "300 kHz", "5 MHz"]);
    assert_mentions(&warnings[1], &["/inversion/harmonic_b", "uses harmonic 16"]);
    assert_mentions(
        &warnings[2],
        &[
            "force estimate biased",
            "harmonics 14-32",
            "raise /synth/sample_rate to 25e6",
        ],
    );
    // At runtime too: one set of f1 moves the drive.
    let mut s = default_settings();
    assert_eq!(
        s.set("/cantilever/f1", &json!(300e3)).unwrap(),
        json!(300e3)
    );
    assert_eq!(s.drive.frequency, 300e3);
    assert_eq!(s.demods_out_of_band().len(), 16);
}

/// Switching the sample to a polymer keeps the 10 % softer disc, not a silicon-stiff one.
#[test]
fn inclusions_given_relative_to_the_sample_follow_it() {
    let mut s = default_settings();
    assert_eq!(s.inclusions[0].relative_modulus, 0.9);
    s.set("/sample/youngs_modulus", &json!(3e9)).unwrap();
    assert_eq!(s.inclusions[0].youngs_modulus, 0.9 * 3e9);
    assert_eq!(s.inclusions[1].youngs_modulus, 3e9);
    // An absolute modulus, in a file or by set, detaches that inclusion only.
    let file = load_str(
        "[sample]\nyoungs_modulus = 3e9\n[inclusions.0]\nyoungs_modulus = 1e9\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!(
        (
            file.inclusions[0].youngs_modulus,
            file.inclusions[0].relative_modulus
        ),
        (1e9, 0.0)
    );
    assert_eq!(file.inclusions[1].youngs_modulus, 3e9);
    s.set("/inclusions/0/youngs_modulus", &json!(2e9)).unwrap();
    s.set("/sample/youngs_modulus", &json!(5e9)).unwrap();
    assert_eq!(s.inclusions[0].youngs_modulus, 2e9);
    // Relative again: follows at once.
    s.set("/inclusions/0/relative_modulus", &json!(0.5))
        .unwrap();
    assert_eq!(s.inclusions[0].youngs_modulus, 2.5e9);
    // Both, disagreeing: refused, naming both.
    assert_mentions(
        &error_of("[inclusions.0]\nyoungs_modulus = 1e9\nrelative_modulus = 0.9\n"),
        &[
            "/inclusions/0/youngs_modulus = 1 GPa",
            "/inclusions/0/relative_modulus = 0.9",
            "116.1 GPa",
        ],
    );
    // A base material so stiff that a relative inclusion would leave its range is refused.
    let mut s = default_settings();
    s.set("/inclusions/2/relative_modulus", &json!(2.0))
        .unwrap();
    let error = s.set("/sample/youngs_modulus", &json!(1e13)).unwrap_err();
    assert_mentions(
        &error.to_string(),
        &[
            "/sample/youngs_modulus",
            "/inclusions/2/youngs_modulus = 2e13",
        ],
    );
}

#[test]
fn an_explicit_drive_stops_following_f1_in_any_key_order() {
    for text in [
        "[cantilever]\nf1 = 300e3\n[drive]\nfrequency = 295e3\n",
        "[drive]\nfrequency = 295e3\n[cantilever]\nf1 = 300e3\n",
    ] {
        let s = load_str(text, "t.toml").unwrap();
        assert!(!s.drive.follow_f1, "{text}");
        assert_eq!(s.drive.frequency, 295e3, "{text}");
    }
    // Both following and another frequency: a conflict that names both.
    assert_mentions(
        &error_of("[drive]\nfollow_f1 = true\nfrequency = 295e3\n"),
        &[
            "/drive/frequency = 295 kHz",
            "/drive/follow_f1 = true",
            "/cantilever/f1 = 100 kHz",
        ],
    );
    // At runtime: the drive set off f1 stops following; f1 then moves alone; following
    // again brings the drive back.
    let mut s = default_settings();
    s.set("/drive/frequency", &json!(99e3)).unwrap();
    assert!(!s.drive.follow_f1);
    s.set("/cantilever/f1", &json!(101e3)).unwrap();
    assert_eq!(s.drive.frequency, 99e3);
    s.set("/drive/follow_f1", &json!(true)).unwrap();
    assert_eq!(s.drive.frequency, 101e3);
    // The drive set to f1 itself changes nothing.
    let before = s.clone();
    s.set("/drive/frequency", &json!(101e3)).unwrap();
    assert_eq!(s, before);
}

#[test]
fn other_relations_name_both_keys() {
    assert_mentions(
        &error_of("[drive]\nfrequency = 6e6\n"),
        &["/drive/frequency = 6 MHz", "/synth/sample_rate / 2 = 5 MHz"],
    );
    assert_mentions(
        &error_of("[demods.4]\ntimeconstant = 5e-8\n"),
        &[
            "/demods/4/timeconstant = 50 ns",
            "1 / /synth/sample_rate = 100 ns",
        ],
    );
    assert_mentions(
        &error_of("[demods.4]\nrate = 2e7\n"),
        &["/demods/4/rate = 20 MHz", "/synth/sample_rate = 10 MHz"],
    );
    assert_mentions(
        &error_of("[synth]\nsample_rate = 100.0\n"),
        &["/synth/sample_rate = 100", "1000 ≤ value ≤ 1e9 Hz"],
    );
    assert_mentions(
        &error_of("[synth]\nseed = -1\n"),
        &["/synth/seed = -1", "out of range"],
    );
}

#[test]
fn noise_ranges_name_the_key() {
    assert_eq!(
        error_of("[noise]\ntemperature = -1\n"),
        "test.toml: /noise/temperature = -1 is out of range: allowed 0 ≤ value ≤ 10000 K"
    );
    assert_eq!(
        error_of("[noise]\ndetector_density = nan\n"),
        "test.toml: /noise/detector_density = nan is not a finite number: allowed \
         0 ≤ value ≤ 1e-9 m/√Hz"
    );
    assert_mentions(
        &error_of("[noise]\ndetector_density = 2e-9\n"),
        &["/noise/detector_density = 2e-9", "out of range"],
    );
    assert_eq!(
        error_of("[noise]\nadc_bits = 33\n"),
        "test.toml: /noise/adc_bits = 33 is out of range: allowed 0 ≤ value ≤ 32"
    );
    assert_eq!(
        error_of("[noise]\nadc_range = 0\n"),
        "test.toml: /noise/adc_range = 0 is out of range: allowed 1e-12 ≤ value ≤ 1e-5 m"
    );
    // Zero switches each source off, and is allowed.
    let s = load_str(
        "[noise]\ntemperature = 0\ndetector_density = 0\nadc_bits = 0\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!(
        (
            s.noise.temperature,
            s.noise.detector_density,
            s.noise.adc_bits
        ),
        (0.0, 0.0, 0)
    );
}

#[test]
fn spectrum_size_is_a_power_of_two_in_range() {
    assert_eq!(
        error_of("[spectrum]\nsize = 1000\n"),
        "test.toml: /spectrum/size = 1000 is not a power of two: allowed a power of two from \
         256 to 1048576"
    );
    for size in ["128", "2097152"] {
        assert_eq!(
            error_of(&format!("[spectrum]\nsize = {size}\n")),
            format!(
                "test.toml: /spectrum/size = {size} is out of range: allowed a power of two \
                 from 256 to 1048576"
            )
        );
    }
    assert_mentions(
        &error_of("[spectrum]\nsize = 4096.5\n"),
        &["/spectrum/size = 4096.5", "not an integer"],
    );
    for size in [256, 4096, 1 << 20] {
        let s = load_str(&format!("[spectrum]\nsize = {size}\n"), "t.toml").unwrap();
        assert_eq!(s.spectrum.size, size);
    }
}

#[test]
fn contact_substeps_are_even_and_in_range() {
    assert_eq!(
        error_of("[synth]\ncontact_substeps = 7\n"),
        "test.toml: /synth/contact_substeps = 7 is odd: allowed an even number from 2 to 64"
    );
    for n in ["0", "66"] {
        assert_eq!(
            error_of(&format!("[synth]\ncontact_substeps = {n}\n")),
            format!(
                "test.toml: /synth/contact_substeps = {n} is out of range: allowed an even \
                 number from 2 to 64"
            )
        );
    }
    assert_mentions(
        &error_of("[synth]\ncontact_substeps = 6.5\n"),
        &["/synth/contact_substeps = 6.5", "not an integer"],
    );
    // Absent (older files): the default.
    assert_eq!(load_str("", "t.toml").unwrap().synth.contact_substeps, 12);
    for n in [2, 6, 12, 64] {
        let s = load_str(&format!("[synth]\ncontact_substeps = {n}\n"), "t.toml").unwrap();
        assert_eq!(s.synth.contact_substeps, n);
    }
}

#[test]
fn spectrum_window_and_rate() {
    assert_eq!(
        error_of("[spectrum]\nwindow = \"kaiser\"\n"),
        "test.toml: /spectrum/window = \"kaiser\" is not allowed: choose one of \
         \"rectangular\", \"hann\", \"blackman_harris\", \"flat_top\""
    );
    for window in SpectrumWindow::ALL {
        let text = format!("[spectrum]\nwindow = \"{}\"\n", window.name());
        assert_eq!(load_str(&text, "t.toml").unwrap().spectrum.window, window);
        assert_eq!(SpectrumWindow::from_name(window.name()), Some(window));
    }
    assert_eq!(
        error_of("[spectrum]\nrate = 0\n"),
        "test.toml: /spectrum/rate = 0 is out of range: allowed 0.001 ≤ value ≤ 1000 Hz"
    );
    // Frames may overlap: 1000 spectra per second of 2^20 samples (0.1 s each at 10 MHz).
    let s = load_str("[spectrum]\nrate = 1000\nsize = 1048576\n", "t.toml").unwrap();
    assert!(s.spectrum.rate > s.synth.sample_rate / f64::from(s.spectrum.size));
}

#[test]
fn scope_ranges_name_the_key() {
    assert_eq!(
        error_of("[scope]\nlength = 8\n"),
        "test.toml: /scope/length = 8 is out of range: allowed 16 ≤ value ≤ 65536"
    );
    assert_eq!(
        error_of("[scope]\nlength = 65537\n"),
        "test.toml: /scope/length = 65537 is out of range: allowed 16 ≤ value ≤ 65536"
    );
    assert_eq!(
        error_of("[scope]\ndecimation = 0\n"),
        "test.toml: /scope/decimation = 0 is out of range: allowed 1 ≤ value ≤ 10000"
    );
    assert_mentions(
        &error_of("[scope]\ndecimation = 10001\n"),
        &["/scope/decimation = 10001", "out of range"],
    );
    assert_mentions(
        &error_of("[scope]\nlength = 100.5\n"),
        &["/scope/length = 100.5", "not an integer"],
    );
    assert_eq!(
        error_of("[scope]\nrate = 0\n"),
        "test.toml: /scope/rate = 0 is out of range: allowed 0.001 ≤ value ≤ 100 Hz"
    );
    assert_eq!(
        error_of("[scope]\nrate = 101\n"),
        "test.toml: /scope/rate = 101 is out of range: allowed 0.001 ≤ value ≤ 100 Hz"
    );
    assert_mentions(
        &error_of("[scope]\nenable = \"yes\"\n"),
        &["/scope/enable = \"yes\"", "true or false"],
    );
    for (overlay, path) in [
        ("[scope]\nlength = 8\n", "/scope/length"),
        ("[scope]\ndecimation = 0\n", "/scope/decimation"),
        ("[scope]\nrate = 101\n", "/scope/rate"),
    ] {
        assert_eq!(load_str(overlay, "t.toml").unwrap_err().path(), Some(path));
    }
    // The ends themselves are allowed.
    let s = load_str("[scope]\nlength = 16\nrate = 100\n", "t.toml").unwrap();
    assert_eq!((s.scope.length, s.scope.rate), (16, 100.0));
    let s = load_str("[scope]\ndecimation = 10000\nrate = 0.1\n", "t.toml").unwrap();
    assert_eq!((s.scope.decimation, s.scope.rate), (10000, 0.1));
}

const OVERLAPPING_TRACES: &str = "/scope/length × /scope/decimation / /synth/sample_rate = \
                                  65536 × 2 / 10 MHz = 13.1072 ms, the duration of one trace, \
                                  must not exceed 1 / /scope/rate = 1 / 100 Hz = 10 ms: traces \
                                  must not overlap (lower /scope/rate, /scope/length or \
                                  /scope/decimation)";

#[test]
fn scope_traces_must_not_overlap() {
    // 65536 samples at 10 MS/s last 6.5536 ms, within the 10 ms between traces at 100 Hz.
    let s = load_str("[scope]\nlength = 65536\nrate = 100\n", "t.toml").unwrap();
    assert_eq!((s.scope.length, s.scope.decimation), (65536, 1));
    // Every other sample doubles that to 13.1 ms: the traces would overlap.
    let overlay = "[scope]\nlength = 65536\ndecimation = 2\nrate = 100\n";
    assert_eq!(
        error_of(overlay),
        format!("test.toml: {OVERLAPPING_TRACES}")
    );
    assert_eq!(
        load_str(overlay, "t.toml").unwrap_err().path(),
        Some("/scope/rate")
    );
    // The same relation ties the scope to the sample rate: 2000 samples at 20 kHz last 0.1 s,
    // longer than the 50 ms between the default's 20 traces a second (the drive is lowered
    // too, to stay below Nyquist).
    assert_mentions(
        &error_of("[synth]\nsample_rate = 20e3\n[drive]\nfrequency = 1e3\n"),
        &[
            "/scope/length × /scope/decimation / /synth/sample_rate = 2000 × 1 / 20 kHz = 100 ms",
            "1 / /scope/rate = 1 / 20 Hz = 50 ms",
            "must not overlap",
        ],
    );
    // Exactly one trace per period is allowed: 65536 × 10 samples at 6.5536 MS/s is 0.1 s.
    let s = load_str(
        "[synth]\nsample_rate = 6553600\n[scope]\nlength = 65536\ndecimation = 10\nrate = 10\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!(s.scope.rate, 10.0);
    // A disabled scope is checked as well, so enabling it never fails.
    assert_mentions(
        &error_of("[scope]\nenable = false\nlength = 65536\ndecimation = 2\nrate = 100\n"),
        &["traces must not overlap"],
    );
    // By `set`, the node set is named first, then the relation with all four nodes.
    let mut s = default_settings();
    s.set("/scope/length", &json!(65536)).unwrap();
    s.set("/scope/rate", &json!(100)).unwrap();
    let before = s.clone();
    let error = s.set("/scope/decimation", &json!(2)).unwrap_err();
    assert_eq!(error.path(), "/scope/decimation");
    assert_eq!(error.code(), "invalid_value");
    assert_eq!(
        error.to_string(),
        format!("cannot set /scope/decimation = 2: {OVERLAPPING_TRACES}")
    );
    assert_eq!(s, before);
    // And `list` reports the highest values that still fit.
    let max_of = |s: &Settings, path: &str| s.nodes_under(path).into_iter().next().unwrap().max;
    assert_eq!(max_of(&s, "/scope/decimation"), json!(1));
    assert_eq!(max_of(&s, "/scope/length"), json!(65536));
    assert_eq!(max_of(&s, "/scope/rate"), json!(100.0));
    s.set("/scope/rate", &json!(20)).unwrap();
    // 10 MS/s / 20 Hz = 500000 samples per trace period.
    assert_eq!(max_of(&s, "/scope/decimation"), json!(7));
    s.set("/scope/decimation", &json!(7)).unwrap();
    assert!(s.set("/scope/decimation", &json!(8)).is_err());
    assert_eq!(max_of(&s, "/scope/length"), json!(65536));
    let d = default_settings();
    assert_eq!(max_of(&d, "/scope/decimation"), json!(250));
    assert_eq!(max_of(&d, "/scope/rate"), json!(100.0));
}

const WILDCARD_REFUSED: &str = "/server/allowed_origins = [\"*\"]: entry 0 (\"*\") is not \
                                allowed (a wildcard would let any web page drive the \
                                instrument; list each origin as scheme://host[:port]): allowed \
                                a list of 0 to 64 strings of at most 256 bytes, each an origin \
                                scheme://host[:port] with scheme http or https";

#[test]
fn allowed_origins_are_plain_http_origins() {
    let error = load_str("[server]\nallowed_origins = [\"*\"]\n", "test.toml").unwrap_err();
    assert_eq!(error.path(), Some("/server/allowed_origins"));
    assert_eq!(error.to_string(), format!("test.toml: {WILDCARD_REFUSED}"));
    let refused = [
        (
            r#"["ftp://x"]"#,
            "entry 0 (\"ftp://x\") is not an origin (it must start with \"http://\" or \"https://\")",
        ),
        (
            r#"["http://x/path"]"#,
            "entry 0 (\"http://x/path\") is not an origin (it has a path",
        ),
        (r#"["http://localhost:3000/"]"#, "trailing \"/\""),
        (
            r#"["http://localhost:3000", 3]"#,
            "entry 1 (3) is not a string",
        ),
        (
            r#"["http://localhost:3000", ["http://x"]]"#,
            "entry 1 ([\"http://x\"]) is not a string",
        ),
        (r#"[""]"#, "entry 0 (\"\") is empty"),
        (r#"["http://"]"#, "the host is missing"),
        (r#"["https://:443"]"#, "the host is missing"),
        (r#"["http://*.example.com"]"#, "wildcards are not supported"),
        (r#"["http://x?a=1"]"#, "query or fragment"),
        (r#"["http://user@x"]"#, "user name"),
        (r#"["http://x y"]"#, "white space"),
        (
            r#"["http://x:port"]"#,
            "the port after the host must be a number",
        ),
        (
            r#"["http://x:65536"]"#,
            "the port after the host must be a number",
        ),
        (r#"["http://[::1"]"#, "closing"),
        (r#"["localhost:3000"]"#, "must start with"),
        (
            r#""http://localhost:3000""#,
            "has the wrong type: expected a list of 0 to 64 strings",
        ),
        ("[\"http://x\", \"*\"]", "entry 1 (\"*\") is not allowed"),
    ];
    for (value, part) in refused {
        let message = error_of(&format!("[server]\nallowed_origins = {value}\n"));
        assert_mentions(&message, &["test.toml: /server/allowed_origins = ", part]);
    }
    let long = format!("http://{}.example", "a".repeat(250));
    assert_mentions(
        &error_of(&format!("[server]\nallowed_origins = [\"{long}\"]\n")),
        &[
            "/server/allowed_origins",
            "entry 0",
            "is 265 bytes long",
            "at most 256 bytes",
        ],
    );
    let many: Vec<String> = (0..65).map(|i| format!("\"http://host{i}\"")).collect();
    let message = error_of(&format!(
        "[server]\nallowed_origins = [{}]\n",
        many.join(", ")
    ));
    assert_mentions(
        &message,
        &[
            "/server/allowed_origins = ",
            "has 65 entries",
            "0 to 64 strings",
        ],
    );
    // Long lists are cut short in the message.
    assert!(message.len() < 400, "{message}");
    // 64 entries at the longest are fine, and so are ports and IPv6 hosts.
    let most: Vec<String> = (0..64)
        .map(|i| format!("\"https://{:0>248}\"", i))
        .collect();
    let s = load_str(
        &format!("[server]\nallowed_origins = [{}]\n", most.join(", ")),
        "t.toml",
    )
    .unwrap();
    assert_eq!(s.server.allowed_origins.len(), 64);
    assert!(s.server.allowed_origins.iter().all(|o| o.len() == 256));
    let ok = [
        "http://localhost:3000",
        "https://lab.example.org",
        "http://127.0.0.1:8080",
        "http://[::1]:8080",
        "https://[2001:db8::1]",
    ];
    let s = load_str(
        &format!("[server]\nallowed_origins = {}\n", json!(ok)),
        "t.toml",
    )
    .unwrap();
    assert_eq!(s.server.allowed_origins, ok);
    let s = load_str("[server]\nallowed_origins = []\n", "t.toml").unwrap();
    assert!(s.server.allowed_origins.is_empty());
}

#[test]
fn allowed_origins_by_set() {
    let mut s = default_settings();
    assert_eq!(s.get("/server/allowed_origins").unwrap(), json!([]));
    let origins = json!(["http://localhost:3000", "https://lab.example"]);
    assert_eq!(s.set("/server/allowed_origins", &origins).unwrap(), origins);
    assert_eq!(s.get("/server/allowed_origins").unwrap(), origins);
    assert_eq!(
        s.server.allowed_origins,
        ["http://localhost:3000", "https://lab.example"]
    );
    let before = s.clone();
    let error = s.set("/server/allowed_origins", &json!(["*"])).unwrap_err();
    assert_eq!(error.to_string(), WILDCARD_REFUSED);
    assert_eq!(error.code(), "invalid_value");
    assert_eq!(s, before);
    assert_eq!(
        s.set("/server/allowed_origins", &json!([])).unwrap(),
        json!([])
    );
    assert!(s.server.allowed_origins.is_empty());
}

#[test]
fn dsp_threads_are_checked_and_fixed_while_running() {
    assert_eq!(default_settings().dsp.threads, 0, "auto by default");
    assert_eq!(
        error_of("[dsp]\nthreads = 9\n"),
        "test.toml: /dsp/threads = 9 is out of range: allowed 0 ≤ value ≤ 8"
    );
    assert_mentions(
        &error_of("[dsp]\nthreads = -1\n"),
        &["/dsp/threads", "0 ≤ value ≤ 8"],
    );
    assert_mentions(
        &error_of("[dsp]\nthreads = \"auto\"\n"),
        &["/dsp/threads", "0 ≤ value ≤ 8"],
    );
    assert_eq!(
        load_str("[dsp]\nthreads = 3\n", "t").unwrap().dsp.threads,
        3
    );
    let mut s = default_settings();
    assert!(matches!(
        s.set("/dsp/threads", &json!(2)),
        Err(NodeError::ReadOnly { .. })
    ));
}

#[test]
fn server_ranges_name_the_key() {
    assert_eq!(
        error_of("[server]\nmax_clients = 0\n"),
        "test.toml: /server/max_clients = 0 is out of range: allowed 1 ≤ value ≤ 4096"
    );
    assert_mentions(
        &error_of("[server]\nmax_clients = 4097\n"),
        &["/server/max_clients = 4097", "out of range"],
    );
    assert_eq!(
        error_of("[server]\nclient_queue = 8\n"),
        "test.toml: /server/client_queue = 8 is out of range: allowed 16 ≤ value ≤ 65536"
    );
    assert_mentions(
        &error_of("[server]\nclient_queue = 65537\n"),
        &["/server/client_queue = 65537", "out of range"],
    );
    assert_eq!(
        error_of("[server]\nstall_timeout = 0.5\n"),
        "test.toml: /server/stall_timeout = 0.5 is out of range: allowed 1 ≤ value ≤ 600 s"
    );
    assert_mentions(
        &error_of("[server]\nstall_timeout = 601\n"),
        &["/server/stall_timeout = 601", "out of range"],
    );
    assert_mentions(
        &error_of("[server]\nstall_timeout = inf\n"),
        &["/server/stall_timeout = inf", "not a finite number"],
    );
    for (overlay, path) in [
        ("[server]\nmax_clients = 0\n", "/server/max_clients"),
        ("[server]\nclient_queue = 8\n", "/server/client_queue"),
        ("[server]\nstall_timeout = 0.5\n", "/server/stall_timeout"),
        (
            "[server]\nallowed_origins = [\"*\"]\n",
            "/server/allowed_origins",
        ),
        ("[server]\nmax_client = 3\n", "/server/max_client"),
    ] {
        assert_eq!(load_str(overlay, "t.toml").unwrap_err().path(), Some(path));
    }
    let s = load_str(
        "[server]\nmax_clients = 4096\nclient_queue = 16\nstall_timeout = 600\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!(
        (
            s.server.max_clients,
            s.server.client_queue,
            s.server.stall_timeout
        ),
        (4096, 16, 600.0)
    );
    // All of them may change at runtime.
    let mut s = default_settings();
    assert_eq!(s.set("/server/max_clients", &json!(1)).unwrap(), json!(1));
    assert_eq!(
        s.set("/server/client_queue", &json!(65536.0)).unwrap(),
        json!(65536)
    );
    assert_eq!(
        s.set("/server/stall_timeout", &json!(1)).unwrap(),
        json!(1.0)
    );
    assert_eq!(s.set("/scope/enable", &json!(false)).unwrap(), json!(false));
    assert_eq!(
        (
            s.server.max_clients,
            s.server.client_queue,
            s.server.stall_timeout,
            s.scope.enable
        ),
        (1, 65536, 1.0, false)
    );
}

const HARMONIC_NOT_MEASURED: &str = "/inversion/harmonic_b = 40 is not measured by any enabled \
                                     demodulator: while /inversion/enable = true, \
                                     /inversion/harmonic_a and /inversion/harmonic_b must each \
                                     be the harmonic of an enabled demodulator \
                                     (/demods/N/harmonic with /demods/N/enable = true), and \
                                     enabled demodulators cover harmonics 1–32";

const SAME_HARMONICS: &str = "/inversion/harmonic_a = 17 and /inversion/harmonic_b = 17 must \
                              differ: the inversion needs two distinct harmonics";

#[test]
fn inversion_ranges_name_the_key() {
    assert_eq!(
        error_of("[inversion]\nmethod = \"magic\"\n"),
        "test.toml: /inversion/method = \"magic\" is not allowed: choose one of \"full\", \
         \"two_harmonic\""
    );
    assert_eq!(
        error_of("[inversion]\nharmonic_a = 1\n"),
        "test.toml: /inversion/harmonic_a = 1 is out of range: allowed 2 ≤ value ≤ 10000"
    );
    assert_mentions(
        &error_of("[inversion]\nharmonic_b = 10001\n"),
        &["/inversion/harmonic_b = 10001", "out of range"],
    );
    assert_mentions(
        &error_of("[inversion]\nharmonic_b = 0\n"),
        &["/inversion/harmonic_b = 0", "2 ≤ value ≤ 10000"],
    );
    assert_eq!(
        error_of("[inversion]\naveraging = 0\n"),
        "test.toml: /inversion/averaging = 0 is out of range: allowed 1 ≤ value ≤ 10000"
    );
    assert_mentions(
        &error_of("[inversion]\naveraging = 10001\n"),
        &["/inversion/averaging = 10001", "out of range"],
    );
    assert_eq!(
        error_of("[inversion]\npoints = 8\n"),
        "test.toml: /inversion/points = 8 is out of range: allowed 16 ≤ value ≤ 4096"
    );
    assert_mentions(
        &error_of("[inversion]\npoints = 4097\n"),
        &["/inversion/points = 4097", "out of range"],
    );
    assert_mentions(
        &error_of("[inversion]\npoints = 100.5\n"),
        &["/inversion/points = 100.5", "not an integer"],
    );
    assert_mentions(
        &error_of("[inversion]\nenable = \"yes\"\n"),
        &["/inversion/enable = \"yes\"", "true or false"],
    );
    assert_mentions(
        &error_of("[inversion]\nmethd = \"full\"\n"),
        &["/inversion/methd", "[inversion]", "harmonic_a", "points"],
    );
    for (overlay, path) in [
        ("[inversion]\nmethod = \"magic\"\n", "/inversion/method"),
        ("[inversion]\nharmonic_a = 1\n", "/inversion/harmonic_a"),
        ("[inversion]\nharmonic_b = 40\n", "/inversion/harmonic_b"),
        ("[inversion]\nharmonic_a = 17\n", "/inversion/harmonic_b"),
        ("[inversion]\naveraging = 0\n", "/inversion/averaging"),
        ("[inversion]\npoints = 8\n", "/inversion/points"),
    ] {
        assert_eq!(load_str(overlay, "t.toml").unwrap_err().path(), Some(path));
    }
    // The ends themselves are allowed (a harmonic at the end needs a demodulator there).
    let s = load_str(
        "[inversion]\nmethod = \"two_harmonic\"\nharmonic_a = 2\naveraging = 10000\n\
         points = 16\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!(
        (
            s.inversion.method,
            s.inversion.harmonic_a,
            s.inversion.averaging,
            s.inversion.points
        ),
        (InversionMethod::TwoHarmonic, 2, 10000, 16)
    );
    let s = load_str(
        "[inversion]\nharmonic_b = 10000\npoints = 4096\naveraging = 1\n\
         [synth]\nsample_rate = 1e9\n[drive]\nfrequency = 1e4\n[demods.31]\nharmonic = 10000\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!((s.inversion.harmonic_b, s.inversion.points), (10000, 4096));
}

#[test]
fn inversion_method_names() {
    assert_eq!(InversionMethod::NAMES, ["full", "two_harmonic"]);
    for (method, name) in InversionMethod::ALL.into_iter().zip(InversionMethod::NAMES) {
        assert_eq!(method.name(), *name);
        assert_eq!(InversionMethod::from_name(name), Some(method));
        let text = format!("[inversion]\nmethod = \"{name}\"\n");
        assert_eq!(load_str(&text, "t.toml").unwrap().inversion.method, method);
    }
    assert_eq!(InversionMethod::from_name("magic"), None);
    assert_eq!(InversionMethod::from_name("two-harmonic"), None);
    let mut s = default_settings();
    assert_eq!(
        s.set("/inversion/method", &json!("two_harmonic")).unwrap(),
        json!("two_harmonic")
    );
    assert_eq!(s.inversion.method, InversionMethod::TwoHarmonic);
    assert_eq!(
        serde_json::to_value(InversionMethod::TwoHarmonic).unwrap(),
        json!("two_harmonic")
    );
}

#[test]
fn inversion_harmonics_differ_and_are_measured() {
    // Harmonic 40 lies beyond the default bank (harmonics 1–32).
    assert_eq!(
        error_of("[inversion]\nharmonic_b = 40\n"),
        format!("test.toml: {HARMONIC_NOT_MEASURED}")
    );
    // With the inversion off, nothing needs to measure it.
    let s = load_str("[inversion]\nharmonic_b = 40\nenable = false\n", "t.toml").unwrap();
    assert_eq!((s.inversion.harmonic_b, s.inversion.enable), (40, false));
    // Or a demodulator moved there, in the same file, in either order.
    let s = load_str(
        "[inversion]\nharmonic_b = 40\n[demods.31]\nharmonic = 40\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!(s.inversion.harmonic_b, 40);
    // A disabled demodulator does not count.
    assert_mentions(
        &error_of("[demods.5]\nenable = false\n"),
        &[
            "test.toml: /inversion/harmonic_a = 6 is not measured",
            "/inversion/enable = true",
            "/demods/N/harmonic",
            "/demods/N/enable",
            "enabled demodulators cover harmonics 1–5, 7–32",
        ],
    );
    // Equal harmonics are refused, enabled or not.
    assert_eq!(
        error_of("[inversion]\nharmonic_a = 17\n"),
        format!("test.toml: {SAME_HARMONICS}")
    );
    assert_eq!(
        error_of("[inversion]\nharmonic_a = 17\nenable = false\n"),
        format!("test.toml: {SAME_HARMONICS}")
    );

    // By `set`: the node set is named first, then the relation.
    let mut s = default_settings();
    let before = s.clone();
    let error = s.set("/inversion/harmonic_b", &json!(40)).unwrap_err();
    assert_eq!(error.code(), "invalid_value");
    assert_eq!(error.path(), "/inversion/harmonic_b");
    assert_eq!(error.to_string(), HARMONIC_NOT_MEASURED);
    let error = s.set("/inversion/harmonic_a", &json!(17)).unwrap_err();
    assert_eq!(error.path(), "/inversion/harmonic_a");
    assert_eq!(
        error.to_string(),
        format!("cannot set /inversion/harmonic_a = 17: {SAME_HARMONICS}")
    );
    let error = s.set("/demods/16/enable", &json!(false)).unwrap_err();
    assert_eq!(error.path(), "/demods/16/enable");
    assert_mentions(
        &error.to_string(),
        &[
            "cannot set /demods/16/enable = false: /inversion/harmonic_b = 17 is not measured",
            "enabled demodulators cover harmonics 1–16, 18–32",
        ],
    );
    let error = s.set("/demods/16/harmonic", &json!(40)).unwrap_err();
    assert_mentions(
        &error.to_string(),
        &[
            "cannot set /demods/16/harmonic = 40: /inversion/harmonic_b = 17",
            "harmonics 1–16, 18–32, 40",
        ],
    );
    assert_eq!(s, before);
    // Disable the inversion, and the same sets succeed; enabling it again then fails.
    s.set("/inversion/enable", &json!(false)).unwrap();
    assert_eq!(
        s.set("/inversion/harmonic_b", &json!(40)).unwrap(),
        json!(40)
    );
    s.set("/demods/16/enable", &json!(false)).unwrap();
    let disabled = s.clone();
    let error = s.set("/inversion/enable", &json!(true)).unwrap_err();
    assert_eq!(error.path(), "/inversion/enable");
    assert_mentions(
        &error.to_string(),
        &[
            "cannot set /inversion/enable = true: /inversion/harmonic_b = 40 is not measured",
            "harmonics 1–16, 18–32",
        ],
    );
    assert_eq!(s, disabled);
    // Measure harmonic 40 and the inversion may run on it.
    s.set("/demods/16/harmonic", &json!(40)).unwrap();
    s.set("/demods/16/enable", &json!(true)).unwrap();
    assert_eq!(
        s.set("/inversion/enable", &json!(true)).unwrap(),
        json!(true)
    );
    // Moving the inversion to another measured harmonic frees the old one's demodulator.
    let mut s = default_settings();
    assert_eq!(
        s.set("/inversion/harmonic_b", &json!(30.0)).unwrap(),
        json!(30)
    );
    s.set("/demods/16/enable", &json!(false)).unwrap();
    // And `list` narrows the harmonics to what the enabled demodulators measure.
    let info = |s: &Settings, path: &str| s.nodes_under(path).into_iter().next().unwrap();
    let a = info(&s, "/inversion/harmonic_a");
    assert_eq!((&a.min, &a.max), (&json!(2), &json!(32)));
    // Without harmonics 31 and 32, the highest left is 30, which harmonic_b uses.
    s.set("/demods/30/enable", &json!(false)).unwrap();
    s.set("/demods/31/enable", &json!(false)).unwrap();
    let a = info(&s, "/inversion/harmonic_a");
    assert_eq!((&a.min, &a.max), (&json!(2), &json!(29)));
    let b = info(&s, "/inversion/harmonic_b");
    assert_eq!((&b.min, &b.max), (&json!(2), &json!(30)));
    s.set("/inversion/enable", &json!(false)).unwrap();
    let a = info(&s, "/inversion/harmonic_a");
    assert_eq!((&a.min, &a.max), (&json!(2), &json!(10000)));
}

#[test]
fn inversion_nodes_change_at_runtime() {
    let mut s = default_settings();
    for (path, value, applied) in [
        ("/inversion/enable", json!(false), json!(false)),
        (
            "/inversion/method",
            json!("two_harmonic"),
            json!("two_harmonic"),
        ),
        ("/inversion/harmonic_a", json!(2), json!(2)),
        ("/inversion/harmonic_b", json!(32.0), json!(32)),
        ("/inversion/averaging", json!(10), json!(10)),
        ("/inversion/points", json!(4096), json!(4096)),
        ("/inversion/enable", json!(true), json!(true)),
    ] {
        assert_eq!(s.set(path, &value).unwrap(), applied, "{path}");
        assert_eq!(s.get(path).unwrap(), applied, "{path}");
    }
    assert_eq!(
        s.inversion,
        InversionSettings {
            enable: true,
            method: InversionMethod::TwoHarmonic,
            harmonic_a: 2,
            harmonic_b: 32,
            averaging: 10,
            points: 4096,
        }
    );
    s.validate().unwrap();
}

// ---------------------------------------------------------------------------------------------
// Scan, feedback and the sample map

const LINE_RATE_TOO_HIGH: &str = "/scan/line_rate = 100 Hz: with 64 pixels per line \
                                  (/scan/pixels) each pixel must last at least 10 drive \
                                  periods (10 / /drive/frequency = 100 µs), so at most \
                                  /drive/frequency / (20 × /scan/pixels) = 78.125 Hz";

const DRIVE_TOO_LOW_FOR_SCAN: &str = "cannot set /drive/frequency = 2000: /scan/line_rate = \
                                      2 Hz: with 64 pixels per line (/scan/pixels) each \
                                      pixel must last at least 10 drive periods (10 / \
                                      /drive/frequency = 5 ms), so at most /drive/frequency \
                                      / (20 × /scan/pixels) = 1.5625 Hz";

const UNKNOWN_INCLUSION: &str =
    "unknown key /inclusions/8 in site.toml; keys of [inclusions]: 0 … 7";

#[test]
fn scan_and_feedback_overlays_change_only_what_they_name() {
    let s = load_str(
        "[scan]\nenable = true\nsize = 5e-6\npixels = 256\nline_rate = 1.5\nx = 1e-6\n\
         y = -2e-6\n[feedback]\nenable = false\nsetpoint = 15e-9\nproportional = 0.5\n\
         integral = 500\n",
        "scan.toml",
    )
    .unwrap();
    let mut expected = default_settings();
    expected.scan = ScanSettings {
        enable: true,
        size: 5e-6,
        pixels: 256,
        line_rate: 1.5,
        x: 1e-6,
        y: -2e-6,
    };
    expected.feedback = FeedbackSettings {
        enable: false,
        setpoint: 15e-9,
        proportional: 0.5,
        integral: 500.0,
    };
    assert_eq!(s, expected);
    // Integral floats are integers here too.
    assert_eq!(
        load_str("[scan]\npixels = 64.0\n", "t.toml")
            .unwrap()
            .scan
            .pixels,
        64
    );
    // The ends themselves are allowed.
    let s = load_str(
        "[scan]\nsize = 100e-6\npixels = 8\nline_rate = 100\nx = -1e-3\ny = 1e-3\n\
         [feedback]\nsetpoint = 1e-6\nproportional = 10\nintegral = 1e6\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!((s.scan.pixels, s.scan.line_rate), (8, 100.0));
    let s = load_str(
        "[scan]\npixels = 1024\nline_rate = 1\n[feedback]\nsetpoint = 0\nintegral = 0\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!((s.scan.pixels, s.feedback.integral), (1024, 0.0));
}

#[test]
fn scan_and_feedback_ranges_name_the_key() {
    for (overlay, message) in [
        (
            "[scan]\nsize = 0\n",
            "/scan/size = 0 is out of range: allowed 0 < value ≤ 1e-4 m",
        ),
        (
            "[scan]\nsize = 2e-4\n",
            "/scan/size = 2e-4 is out of range: allowed 0 < value ≤ 1e-4 m",
        ),
        (
            "[scan]\npixels = 7\n",
            "/scan/pixels = 7 is out of range: allowed 8 ≤ value ≤ 1024",
        ),
        (
            "[scan]\npixels = 1025\n",
            "/scan/pixels = 1025 is out of range: allowed 8 ≤ value ≤ 1024",
        ),
        (
            "[scan]\nline_rate = 0\n",
            "/scan/line_rate = 0 is out of range: allowed 0.001 ≤ value ≤ 100 Hz",
        ),
        (
            "[scan]\nline_rate = 101\n",
            "/scan/line_rate = 101 is out of range: allowed 0.001 ≤ value ≤ 100 Hz",
        ),
        (
            "[scan]\nx = 2e-3\n",
            "/scan/x = 0.002 is out of range: allowed -0.001 ≤ value ≤ 0.001 m",
        ),
        (
            "[scan]\ny = -0.0011\n",
            "/scan/y = -0.0011 is out of range: allowed -0.001 ≤ value ≤ 0.001 m",
        ),
        (
            "[feedback]\nsetpoint = -1e-9\n",
            "/feedback/setpoint = -1e-9 is out of range: allowed 0 ≤ value ≤ 1e-6 m",
        ),
        (
            "[feedback]\nsetpoint = 2e-6\n",
            "/feedback/setpoint = 2e-6 is out of range: allowed 0 ≤ value ≤ 1e-6 m",
        ),
        (
            "[feedback]\nproportional = 11\n",
            "/feedback/proportional = 11 is out of range: allowed 0 ≤ value ≤ 10",
        ),
        (
            "[feedback]\nproportional = -0.1\n",
            "/feedback/proportional = -0.1 is out of range: allowed 0 ≤ value ≤ 10",
        ),
        (
            "[feedback]\nintegral = 2e6\n",
            "/feedback/integral = 2e6 is out of range: allowed 0 ≤ value ≤ 1e6 1/s",
        ),
    ] {
        assert_eq!(error_of(overlay), format!("test.toml: {message}"));
        let path = message.split(' ').next().unwrap();
        assert_eq!(load_str(overlay, "t.toml").unwrap_err().path(), Some(path));
    }
    assert_mentions(
        &error_of("[scan]\npixels = 100.5\n"),
        &["/scan/pixels = 100.5", "not an integer", "8 ≤ value ≤ 1024"],
    );
    assert_mentions(
        &error_of("[scan]\nenable = \"yes\"\n"),
        &["/scan/enable = \"yes\"", "true or false"],
    );
    assert_mentions(
        &error_of("[feedback]\nintegral = nan\n"),
        &["/feedback/integral = nan", "not a finite number", "1/s"],
    );
    assert_mentions(
        &error_of("[scan]\nline_rat = 1\n"),
        &["/scan/line_rat", "[scan]", "line_rate", "pixels"],
    );
}

#[test]
fn scan_line_rate_leaves_ten_drive_periods_per_pixel() {
    // 100 kHz / (20 × 64 pixels) = 78.125 Hz: allowed, and just above it refused.
    let s = load_str("[scan]\nline_rate = 78.125\n", "t.toml").unwrap();
    assert_eq!(s.scan.line_rate, 78.125);
    assert_eq!(
        error_of("[scan]\nline_rate = 100\n"),
        format!("test.toml: {LINE_RATE_TOO_HIGH}")
    );
    assert_eq!(
        load_str("[scan]\nline_rate = 100\n", "t.toml")
            .unwrap_err()
            .path(),
        Some("/scan/line_rate")
    );
    assert_mentions(
        &error_of("[scan]\nline_rate = 78.13\n"),
        &["/scan/line_rate = 78.13 Hz", "at most", "= 78.125 Hz"],
    );
    // Checked while the scan is off, so starting it never fails.
    assert_mentions(
        &error_of("[scan]\nline_rate = 100\nenable = false\n"),
        &["/scan/line_rate = 100 Hz"],
    );
    // Fewer pixels, or a faster drive in the same file (150 kHz / (20 × 64) = 117 Hz), make
    // room: the order of the keys does not matter.
    let s = load_str("[scan]\nline_rate = 100\npixels = 32\n", "t.toml").unwrap();
    assert_eq!((s.scan.line_rate, s.scan.pixels), (100.0, 32));
    let s = load_str(
        "[scan]\nline_rate = 100\n[drive]\nfrequency = 150e3\n[cantilever]\nf1 = 150e3\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!(s.scan.line_rate, 100.0);
    // More pixels at the default 2 Hz: 100 kHz / (20 × 2 Hz) = 2500 ≥ 1024, always fine;
    // at 10 Hz at most 500.
    assert!(load_str("[scan]\npixels = 1024\n", "t.toml").is_ok());
    assert_mentions(
        &error_of("[scan]\npixels = 512\nline_rate = 10\n"),
        &[
            "/scan/line_rate = 10 Hz: with 512 pixels per line (/scan/pixels)",
            "10 drive periods",
            "/drive/frequency",
            "= 9.765625 Hz",
        ],
    );
}

#[test]
fn the_image_stream_carries_at_most_20000_pixels_per_second() {
    // A 1 MHz drive leaves 50000 / pixels by the dwell time; the stream's 20000 pixels per
    // second bind first: 128 pixels allow 78.125 lines per second.
    let fast = "[synth]\nsample_rate = 100e6\n[drive]\nfrequency = 1e6\n[cantilever]\nf1 = 1e6\n";
    let s = load_str(
        &format!("{fast}[scan]\npixels = 128\nline_rate = 78.125\n"),
        "t.toml",
    )
    .unwrap();
    assert_eq!(s.scan.line_rate, 78.125);
    let message = error_of(&format!("{fast}[scan]\npixels = 128\nline_rate = 100\n"));
    assert_eq!(
        message,
        "test.toml: /scan/line_rate = 100 Hz: with 128 pixels per line (/scan/pixels) the \
         image stream would carry 2 × /scan/pixels × /scan/line_rate = 25600 pixels per \
         second, more than its 20000, so at most 20000 / (2 × /scan/pixels) = 78.125 Hz"
    );
}

#[test]
fn scan_relation_by_set_names_the_node_set() {
    let mut s = default_settings();
    let before = s.clone();
    let error = s.set("/scan/line_rate", &json!(100)).unwrap_err();
    assert_eq!(error.code(), "invalid_value");
    assert_eq!(error.path(), "/scan/line_rate");
    assert_eq!(error.to_string(), LINE_RATE_TOO_HIGH);
    // The drive is tied to the scan: too slow a drive is refused, naming the line rate.
    let error = s.set("/drive/frequency", &json!(2e3)).unwrap_err();
    assert_eq!(error.path(), "/drive/frequency");
    assert_eq!(error.to_string(), DRIVE_TOO_LOW_FOR_SCAN);
    // Pixels: at 20 Hz, 100 kHz / (20 × 20 Hz) = 250 pixels at most.
    s.set("/scan/line_rate", &json!(20)).unwrap();
    let after_rate = s.clone();
    let error = s.set("/scan/pixels", &json!(256)).unwrap_err();
    assert_eq!(error.path(), "/scan/pixels");
    assert_mentions(
        &error.to_string(),
        &[
            "cannot set /scan/pixels = 256: /scan/line_rate = 20 Hz: with 256 pixels per line",
            "at most /drive/frequency / (20 × /scan/pixels) = 19.53125 Hz",
        ],
    );
    assert_eq!(s, after_rate);
    // `list` reports the limits as they stand.
    let info = |s: &Settings, path: &str| s.nodes_under(path).into_iter().next().unwrap();
    assert_eq!(info(&s, "/scan/pixels").max, json!(250));
    assert_eq!(info(&s, "/scan/line_rate").max, json!(78.125));
    assert_eq!(s.set("/scan/pixels", &json!(250)).unwrap(), json!(250));
    assert_eq!(info(&s, "/scan/line_rate").max, json!(20.0));
    assert!(s.set("/scan/pixels", &json!(251)).is_err());
    s.set("/scan/pixels", &json!(64)).unwrap();
    s.set("/scan/line_rate", &json!(2.0)).unwrap();
    assert_eq!(s, before);
}

#[test]
fn scan_feedback_and_inclusion_nodes_change_at_runtime() {
    let mut s = default_settings();
    for (path, value, applied) in [
        ("/scan/enable", json!(true), json!(true)),
        ("/scan/size", json!(2e-6), json!(2e-6)),
        ("/scan/pixels", json!(64.0), json!(64)),
        ("/scan/line_rate", json!(4), json!(4.0)),
        ("/scan/x", json!(-5e-7), json!(-5e-7)),
        ("/scan/y", json!(5e-7), json!(5e-7)),
        ("/feedback/enable", json!(false), json!(false)),
        ("/feedback/setpoint", json!(12e-9), json!(12e-9)),
        ("/feedback/proportional", json!(0.2), json!(0.2)),
        ("/feedback/integral", json!(1500), json!(1500.0)),
        ("/inclusions/4/enable", json!(true), json!(true)),
        (
            "/inclusions/4/shape",
            json!("rectangle"),
            json!("rectangle"),
        ),
        ("/inclusions/4/x", json!(1e-7), json!(1e-7)),
        ("/inclusions/4/y", json!(-1e-7), json!(-1e-7)),
        ("/inclusions/4/width", json!(3e-7), json!(3e-7)),
        ("/inclusions/4/length", json!(2e-7), json!(2e-7)),
        ("/inclusions/4/height", json!(-5e-9), json!(-5e-9)),
        ("/inclusions/4/youngs_modulus", json!(70e9), json!(70e9)),
        ("/inclusions/4/poisson", json!(0.17), json!(0.17)),
    ] {
        let info = s.nodes_under(path).into_iter().next().unwrap();
        assert!(info.writable, "{path}");
        assert_eq!(s.set(path, &value).unwrap(), applied, "{path}");
        assert_eq!(s.get(path).unwrap(), applied, "{path}");
    }
    assert_eq!(
        s.scan,
        ScanSettings {
            enable: true,
            size: 2e-6,
            pixels: 64,
            line_rate: 4.0,
            x: -5e-7,
            y: 5e-7,
        }
    );
    assert_eq!(
        s.feedback,
        FeedbackSettings {
            enable: false,
            setpoint: 12e-9,
            proportional: 0.2,
            integral: 1500.0,
        }
    );
    assert_eq!(
        s.inclusions[4],
        InclusionSettings {
            enable: true,
            shape: InclusionShape::Rectangle,
            x: 1e-7,
            y: -1e-7,
            width: 3e-7,
            length: 2e-7,
            height: -5e-9,
            youngs_modulus: 70e9,
            relative_modulus: 0.0,
            poisson: 0.17,
        }
    );
    // Only inclusion 4 changed.
    let defaults = default_settings();
    for (n, inclusion) in s.inclusions.iter().enumerate().filter(|(n, _)| *n != 4) {
        assert_eq!(*inclusion, defaults.inclusions[n], "inclusion {n}");
    }
    s.validate().unwrap();
}

#[test]
fn a_partial_inclusion_overlay_changes_only_that_slot() {
    let s = load_str(
        "[inclusions.2]\nenable = true\nwidth = 50e-9\n",
        "inclusion.toml",
    )
    .unwrap();
    let mut expected = default_settings();
    expected.inclusions[2].enable = true;
    expected.inclusions[2].width = 50e-9;
    assert_eq!(s, expected);
    // The inline form does the same.
    let s = load_str(
        "[inclusions]\n2 = { enable = true, width = 50e-9 }\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!(s, expected);
    // Two slots, and the base material, in one file.
    let s = load_str(
        "[inclusions.7]\nshape = \"rectangle\"\nheight = 2e-9\n[inclusions.0]\nenable = false\n\
         [sample]\nyoungs_modulus = 100e9\n",
        "t.toml",
    )
    .unwrap();
    let mut expected = default_settings();
    expected.inclusions[7].shape = InclusionShape::Rectangle;
    expected.inclusions[7].height = 2e-9;
    expected.inclusions[0].enable = false;
    expected.sample.youngs_modulus = 100e9;
    // The inclusions are given relative to the base material: they follow it.
    for inclusion in &mut expected.inclusions {
        inclusion.youngs_modulus = inclusion.relative_modulus * 100e9;
    }
    assert_eq!(s, expected);
}

#[test]
fn inclusion_ranges_name_the_key() {
    for (overlay, message) in [
        (
            "[inclusions.3]\nx = 1.5e-3\n",
            "/inclusions/3/x = 0.0015 is out of range: allowed -0.001 ≤ value ≤ 0.001 m",
        ),
        (
            "[inclusions.3]\ny = -2e-3\n",
            "/inclusions/3/y = -0.002 is out of range: allowed -0.001 ≤ value ≤ 0.001 m",
        ),
        (
            "[inclusions.0]\nwidth = 0\n",
            "/inclusions/0/width = 0 is out of range: allowed 0 < value ≤ 0.001 m",
        ),
        (
            "[inclusions.0]\nlength = 2e-3\n",
            "/inclusions/0/length = 0.002 is out of range: allowed 0 < value ≤ 0.001 m",
        ),
        (
            "[inclusions.5]\nheight = 2e-6\n",
            "/inclusions/5/height = 2e-6 is out of range: allowed -1e-6 ≤ value ≤ 1e-6 m",
        ),
        (
            "[inclusions.5]\nyoungs_modulus = 0\n",
            "/inclusions/5/youngs_modulus = 0 is out of range: allowed 0 < value ≤ 1e13 Pa",
        ),
        (
            "[inclusions.6]\npoisson = 0.5\n",
            "/inclusions/6/poisson = 0.5 is out of range: allowed -1 < value < 0.5",
        ),
        (
            "[inclusions.1]\nshape = \"circle\"\n",
            "/inclusions/1/shape = \"circle\" is not allowed: choose one of \"disc\", \
             \"rectangle\"",
        ),
    ] {
        assert_eq!(error_of(overlay), format!("test.toml: {message}"));
        let path = message.split(' ').next().unwrap();
        assert_eq!(load_str(overlay, "t.toml").unwrap_err().path(), Some(path));
    }
    // A pit and the ends are allowed.
    let s = load_str(
        "[inclusions.5]\nheight = -1e-6\nwidth = 1e-3\nx = -1e-3\n",
        "t.toml",
    )
    .unwrap();
    assert_eq!(s.inclusions[5].height, -1e-6);
    assert_mentions(
        &error_of("[inclusions.1]\nenable = 1\n"),
        &["/inclusions/1/enable = 1", "true or false"],
    );
    assert_mentions(
        &error_of("[inclusions.1]\nradius = 1e-7\n"),
        &["/inclusions/1/radius", "[inclusions.1]", "width", "length"],
    );
    assert_eq!(InclusionShape::NAMES, ["disc", "rectangle"]);
    for (shape, name) in InclusionShape::ALL.into_iter().zip(InclusionShape::NAMES) {
        assert_eq!(shape.name(), *name);
        assert_eq!(InclusionShape::from_name(name), Some(shape));
    }
}

#[test]
fn unknown_inclusion_indices_are_refused() {
    assert_eq!(
        load_str("[inclusions.8]\nenable = true\n", "site.toml")
            .unwrap_err()
            .to_string(),
        UNKNOWN_INCLUSION
    );
    let error = load_str("[inclusions.8]\nenable = true\n", "site.toml").unwrap_err();
    assert_eq!(error.path(), Some("/inclusions/8"));
    assert_mentions(
        &error_of("[inclusions]\n03 = { enable = true }\n"),
        &["/inclusions/03", "[inclusions]", "0 … 7"],
    );
    assert_mentions(
        &error_of("inclusions = 3\n"),
        &["/inclusions", "table", "0 … 7"],
    );
    let mut s = default_settings();
    let error = s.set("/inclusions/8/enable", &json!(true)).unwrap_err();
    assert_eq!(error.code(), "unknown_path");
    assert_mentions(&error.to_string(), &["/inclusions/8/enable", "0 … 7"]);
    assert_eq!(s, default_settings());
}

#[test]
fn docs_inclusion_example_loads() {
    let docs = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/docs/configuration.md"
    ))
    .unwrap();
    let example = docs
        .split("```toml\n")
        .find(|block| block.starts_with("# bump.toml"))
        .and_then(|block| block.split("```").next())
        .expect("docs/configuration.md has the bump.toml example");
    let s = load_str(example, "bump.toml").unwrap();
    let mut expected = default_settings();
    expected.inclusions[2] = InclusionSettings {
        enable: true,
        shape: InclusionShape::Rectangle,
        x: 200e-9,
        y: 0.0,
        width: 200e-9,
        length: 100e-9,
        height: 50e-9,
        youngs_modulus: 3e9,
        relative_modulus: 0.0,
        poisson: 0.35,
    };
    assert_eq!(s, expected);
}

#[test]
fn the_coupled_engine_is_accepted_with_or_without_a_scan() {
    for runtime in [true, false] {
        let mut s = default_settings();
        let result = if runtime {
            s.set("/synth/engine", &json!("coupled"))
        } else {
            s.apply("/synth/engine", &json!("coupled"))
        };
        result.unwrap();
        assert_eq!(s.synth.engine, Engine::Coupled);
        s.set("/scan/enable", &json!(true)).unwrap();
        assert!(s.scan.enable);
    }
    let s = load_str("[synth]\nengine = \"coupled\"\n", "test.toml").unwrap();
    assert_eq!(s.synth.engine, Engine::Coupled);
    let s = load_str(
        "[synth]\nengine = \"coupled\"\n[scan]\nenable = true\n",
        "test.toml",
    )
    .unwrap();
    assert!(s.scan.enable && s.synth.engine == Engine::Coupled);
    // An unknown engine is refused with the names allowed.
    let error = load_str("[synth]\nengine = \"quantum\"\n", "test.toml").unwrap_err();
    assert_eq!(error.path(), Some("/synth/engine"));
    assert!(error.to_string().contains("\"coupled\""), "{error}");
}

#[test]
fn syntax_errors_carry_file_line_and_column() {
    let message = error_of("[sample]\npoisson = = 0.3\n");
    assert_mentions(&message, &["test.toml", "line 2", "column"]);
    let message = error_of("[sample\n");
    assert_mentions(&message, &["test.toml", "line 1"]);
}

#[test]
fn unreadable_file_names_the_file_and_the_os_error() {
    let path = std::path::Path::new("/nonexistent/ftafm/site.toml");
    let error = load(Some(path)).unwrap_err();
    assert!(matches!(error, ConfigError::Read { .. }));
    let expected_os = std::io::Error::from(std::io::ErrorKind::NotFound).to_string();
    let message = error.to_string();
    assert_mentions(&message, &["/nonexistent/ftafm/site.toml"]);
    assert!(
        message.contains(&expected_os) || message.contains("No such file"),
        "{message}"
    );
}

#[test]
fn files_load_from_disk() {
    let dir = std::env::temp_dir().join(format!("ftafm-config-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("soft.toml");
    std::fs::write(&path, "[sample]\nyoungs_modulus = 1e9\n").unwrap();
    assert_eq!(load(Some(&path)).unwrap().sample.youngs_modulus, 1e9);
    std::fs::write(&path, "[sample]\npoisson = 0.7\n").unwrap();
    let message = load(Some(&path)).unwrap_err().to_string();
    assert_mentions(&message, &["soft.toml", "/sample/poisson = 0.7"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn config_errors_expose_the_key() {
    let key = |overlay: &str| {
        load_str(overlay, "t.toml")
            .unwrap_err()
            .path()
            .map(str::to_owned)
    };
    assert_eq!(key("[sample]\nfoo = 1\n").as_deref(), Some("/sample/foo"));
    assert_eq!(
        key("[sample]\npoisson = 0.7\n").as_deref(),
        Some("/sample/poisson")
    );
    assert_eq!(key("[x\n"), None);
}

// ---------------------------------------------------------------------------------------------
// get / set

#[test]
fn read_only_nodes_refuse_set_but_config_may_apply() {
    let mut s = default_settings();
    let error = s.set("/synth/sample_rate", &json!(20e6)).unwrap_err();
    assert_eq!(
        error,
        NodeError::ReadOnly {
            path: "/synth/sample_rate".into()
        }
    );
    assert_eq!(error.code(), "read_only");
    assert_eq!(s, default_settings());
    assert_eq!(
        s.apply("/synth/sample_rate", &json!(20e6)).unwrap(),
        json!(20e6)
    );
    assert_eq!(s.synth.sample_rate, 20e6);
}

#[test]
fn unknown_paths() {
    let mut s = default_settings();
    for path in [
        "/sample/youngs_moduls",
        "/demods/32/rate",
        "/sample",
        "",
        "/",
        "nope",
    ] {
        let error = s.get(path).unwrap_err();
        assert!(matches!(error, NodeError::UnknownPath { .. }), "{path}");
        assert_eq!(error.code(), "unknown_path");
        assert_mentions(&error.to_string(), &[path]);
        assert!(matches!(
            s.set(path, &json!(1)),
            Err(NodeError::UnknownPath { .. })
        ));
    }
    assert_mentions(
        &s.get("/sample/youngs_moduls").unwrap_err().to_string(),
        &["youngs_modulus, poisson"],
    );
}

#[test]
fn set_returns_the_value_as_applied() {
    let mut s = default_settings();
    assert_eq!(s.set("/demods/0/order", &json!(2.0)).unwrap(), json!(2));
    assert_eq!(
        s.set("/cantilever/f1", &json!(150000)).unwrap(),
        json!(150000.0)
    );
    assert_eq!(
        s.set("/synth/engine", &json!("paper")).unwrap(),
        json!("paper")
    );
    assert_eq!(s.synth.engine, Engine::Paper);
    assert_eq!(
        s.set("/spectrum/window", &json!("flat_top")).unwrap(),
        json!("flat_top")
    );
    assert_eq!(s.spectrum.window, SpectrumWindow::FlatTop);
    assert_eq!(
        s.set("/spectrum/size", &json!(1024.0)).unwrap(),
        json!(1024)
    );
    assert_eq!(s.set("/noise/adc_bits", &json!(0)).unwrap(), json!(0));
    assert_eq!(s.set("/noise/temperature", &json!(0)).unwrap(), json!(0.0));
    assert_eq!(
        s.set("/synth/seed", &json!(u64::MAX)).unwrap(),
        json!(u64::MAX)
    );
    assert_eq!(
        s.set("/cantilever/q", &json!([10, 20])).unwrap(),
        json!([10.0, 20.0])
    );
    assert_eq!(s.get("/demods/0/order").unwrap(), json!(2));
}

#[test]
fn failed_set_changes_nothing() {
    let mut s = default_settings();
    s.set("/sample/youngs_modulus", &json!(116.1e9)).unwrap();
    let before = s.clone();
    let attempts = [
        ("/sample/poisson", json!(0.7)),
        ("/sample/poisson", json!("0.3")),
        ("/sample/youngs_modulus", json!(-1.0)),
        ("/cantilever/q", json!([])),
        ("/cantilever/q", json!([100, 0.4])),
        ("/cantilever/extra_modes", json!(12)),
        ("/demods/3/order", json!(9)),
        ("/demods/3/harmonic", json!(-1)),
        ("/drive/frequency", json!(6e6)),
        ("/synth/engine", json!("fast")),
        ("/noise/enable", json!(null)),
        ("/noise/temperature", json!(-1.0)),
        ("/noise/detector_density", json!(2e-9)),
        ("/noise/adc_bits", json!(33)),
        ("/noise/adc_range", json!(0.0)),
        ("/spectrum/size", json!(1000)),
        ("/spectrum/window", json!("kaiser")),
        ("/spectrum/rate", json!(0.0)),
        ("/synth/engine", json!("quantum")),
        ("/synth/sample_rate", json!(20e6)),
        ("/scope/enable", json!(1)),
        ("/scope/length", json!(8)),
        ("/scope/length", json!(65537)),
        ("/scope/decimation", json!(0)),
        ("/scope/decimation", json!(400)),
        ("/scope/rate", json!(0.0)),
        ("/scope/rate", json!(101.0)),
        ("/server/allowed_origins", json!(["*"])),
        ("/server/allowed_origins", json!(["ftp://x"])),
        ("/server/allowed_origins", json!(["http://x/path"])),
        ("/server/allowed_origins", json!(["http://x", 1])),
        ("/server/allowed_origins", json!("http://x")),
        ("/server/allowed_origins", json!(vec!["http://x"; 65])),
        ("/server/max_clients", json!(0)),
        ("/server/client_queue", json!(8)),
        ("/server/stall_timeout", json!(0.5)),
        ("/inversion/enable", json!("yes")),
        ("/inversion/method", json!("magic")),
        ("/inversion/method", json!(1)),
        ("/inversion/harmonic_a", json!(1)),
        ("/inversion/harmonic_a", json!(17)),
        ("/inversion/harmonic_a", json!(10001)),
        ("/inversion/harmonic_a", json!(6.5)),
        ("/inversion/harmonic_b", json!(40)),
        ("/inversion/harmonic_b", json!(6)),
        ("/inversion/averaging", json!(0)),
        ("/inversion/averaging", json!(10001)),
        ("/inversion/points", json!(8)),
        ("/inversion/points", json!(4097)),
        // The demodulators that measure the inversion's harmonics 6 and 17.
        ("/demods/5/enable", json!(false)),
        ("/demods/16/harmonic", json!(40)),
    ];
    for (path, value) in attempts {
        let error = s.set(path, &value).unwrap_err();
        assert_eq!(error.path(), path);
        assert_eq!(s, before, "set {path} = {value} changed the settings");
    }
}

#[test]
fn a_drive_that_pushes_demodulators_out_of_band_is_taken_and_they_are_named() {
    // At 200 kHz, harmonics 25 and up (demodulators 24 … 31) sit at or above the 5 MHz
    // Nyquist frequency: they stop producing frames, and say so.
    let mut s = default_settings();
    s.set("/drive/frequency", &json!(200e3)).unwrap();
    assert!(!s.drive.follow_f1);
    assert_eq!(s.demods_out_of_band(), (24..32).collect::<Vec<_>>());
    assert_mentions(
        s.node_warning("/demods/24/enable").as_deref().unwrap(),
        &[
            "/demods/24/harmonic × /drive/frequency = 25 × 200 kHz = 5 MHz",
            "Nyquist",
        ],
    );
    // Back in band when the drive comes down.
    s.set("/drive/frequency", &json!(150e3)).unwrap();
    assert!(s.demods_out_of_band().is_empty());
    // In band, but H27-H32 (4.05-4.8 MHz) above the anti-alias filter's flat 4 MHz.
    let warnings = s.warnings();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert_mentions(&warnings[0], &["harmonics 27-32", "12.5e6"]);
}

#[test]
fn every_node_round_trips_through_set() {
    let mut s = default_settings();
    let before = s.clone();
    for info in s.nodes() {
        assert_eq!(s.get(&info.path).unwrap(), info.value);
        let result = s.set(&info.path, &info.value);
        if info.writable {
            assert_eq!(result.unwrap(), info.value, "{}", info.path);
        } else {
            assert!(matches!(result, Err(NodeError::ReadOnly { .. })));
            assert_eq!(s.apply(&info.path, &info.value).unwrap(), info.value);
        }
        assert_eq!(s, before, "{}", info.path);
    }
}

#[test]
fn list_entries_have_the_protocol_fields() {
    let nodes = default_settings().nodes();
    assert_eq!(nodes.len(), registry().len());
    // 72 scalar nodes, 8 inclusions of 10 nodes, 32 demodulators of 6, 4 PIDs of 14.
    assert_eq!(nodes.len(), 72 + 8 * 10 + 32 * 6 + 4 * 14);
    let entry = serde_json::to_value(&nodes[0]).unwrap();
    let keys: BTreeSet<&str> = entry
        .as_object()
        .unwrap()
        .keys()
        .map(String::as_str)
        .collect();
    assert_eq!(
        keys,
        BTreeSet::from([
            "path",
            "value",
            "unit",
            "writable",
            "min",
            "max",
            "min_inclusive",
            "max_inclusive",
            "description",
            "type"
        ])
    );
    let poisson = nodes.iter().find(|n| n.path == "/sample/poisson").unwrap();
    assert_eq!((&poisson.min, &poisson.max), (&json!(-1.0), &json!(0.5)));
    assert_eq!(
        (poisson.min_inclusive, poisson.max_inclusive),
        (Some(false), Some(false))
    );
    assert_eq!(poisson.unit, "1");
    let rate = nodes
        .iter()
        .find(|n| n.path == "/synth/sample_rate")
        .unwrap();
    assert!(!rate.writable);
    let engine = nodes.iter().find(|n| n.path == "/synth/engine").unwrap();
    assert_eq!((&engine.unit[..], &engine.min), ("", &Value::Null));
    let size = nodes.iter().find(|n| n.path == "/spectrum/size").unwrap();
    assert_eq!((&size.min, &size.max), (&json!(256), &json!(1048576)));
    assert_eq!(size.unit, "samples");
    let density = nodes
        .iter()
        .find(|n| n.path == "/noise/detector_density")
        .unwrap();
    assert_eq!(density.unit, "m/√Hz");
    assert!(density.writable);
    let spectrum_rate = nodes.iter().find(|n| n.path == "/spectrum/rate").unwrap();
    assert_eq!(spectrum_rate.max, json!(1000.0));
    let find = |path: &str| nodes.iter().find(|n| n.path == path).unwrap();
    let origins = find("/server/allowed_origins");
    assert_eq!(
        (
            &origins.value,
            &origins.unit[..],
            &origins.min,
            &origins.max
        ),
        (&json!([]), "", &Value::Null, &Value::Null)
    );
    assert!(origins.writable);
    for (path, unit, min, max) in [
        ("/scope/length", "samples", json!(16), json!(65536)),
        ("/scope/decimation", "samples", json!(1), json!(250)),
        ("/scope/rate", "Hz", json!(0.001), json!(100.0)),
        ("/server/max_clients", "clients", json!(1), json!(4096)),
        ("/server/client_queue", "messages", json!(16), json!(65536)),
        ("/server/stall_timeout", "s", json!(1.0), json!(600.0)),
        ("/inversion/enable", "", Value::Null, Value::Null),
        ("/inversion/method", "", Value::Null, Value::Null),
        // While enabled, the harmonics the enabled demodulators measure (2 … 32 by default).
        ("/inversion/harmonic_a", "", json!(2), json!(32)),
        ("/inversion/harmonic_b", "", json!(2), json!(32)),
        ("/inversion/averaging", "frames", json!(1), json!(10000)),
        ("/inversion/points", "samples", json!(16), json!(4096)),
        ("/scan/enable", "", Value::Null, Value::Null),
        ("/scan/size", "m", json!(0.0), json!(100e-6)),
        // 2 Hz allows up to 2500 pixels by the dwell time: the static 1024 stands.
        ("/scan/pixels", "pixels", json!(8), json!(1024)),
        // 100 kHz / (20 × 64 pixels).
        ("/scan/line_rate", "Hz", json!(0.001), json!(78.125)),
        ("/scan/x", "m", json!(-1e-3), json!(1e-3)),
        ("/scan/y", "m", json!(-1e-3), json!(1e-3)),
        ("/feedback/enable", "", Value::Null, Value::Null),
        ("/feedback/setpoint", "m", json!(0.0), json!(1e-6)),
        ("/feedback/proportional", "1", json!(0.0), json!(10.0)),
        ("/feedback/integral", "1/s", json!(0.0), json!(1e6)),
        ("/inclusions/3/enable", "", Value::Null, Value::Null),
        ("/inclusions/3/shape", "", Value::Null, Value::Null),
        ("/inclusions/3/x", "m", json!(-1e-3), json!(1e-3)),
        ("/inclusions/3/y", "m", json!(-1e-3), json!(1e-3)),
        ("/inclusions/3/width", "m", json!(0.0), json!(1e-3)),
        ("/inclusions/3/length", "m", json!(0.0), json!(1e-3)),
        ("/inclusions/3/height", "m", json!(-1e-6), json!(1e-6)),
        (
            "/inclusions/3/youngs_modulus",
            "Pa",
            json!(0.0),
            json!(1e13),
        ),
        ("/inclusions/3/poisson", "1", json!(-1.0), json!(0.5)),
    ] {
        let info = find(path);
        assert_eq!(
            (&info.unit[..], &info.min, &info.max),
            (unit, &min, &max),
            "{path}"
        );
        assert!(info.writable, "{path}");
    }
    // Limits that depend on other nodes are reported as they stand now.
    // The Nyquist frequency, for the drive and (while the drive follows it) f1; a
    // demodulator's harmonic may lie above it (out of band), so its static range stands.
    for path in ["/drive/frequency", "/cantilever/f1"] {
        let node = nodes.iter().find(|n| n.path == path).unwrap();
        assert_eq!(node.max, json!(5e6), "{path}");
    }
    let harmonic = nodes
        .iter()
        .find(|n| n.path == "/demods/0/harmonic")
        .unwrap();
    assert_eq!(harmonic.max, json!(10_000));
    for info in &nodes {
        assert!(info.description.ends_with('.'), "{}", info.path);
    }
}

#[test]
fn nodes_under_matches_whole_segments() {
    let s = default_settings();
    let paths: Vec<String> = s
        .nodes_under("/demods/1")
        .into_iter()
        .map(|n| n.path)
        .collect();
    assert_eq!(
        paths,
        [
            "/demods/1/enable",
            "/demods/1/harmonic",
            "/demods/1/order",
            "/demods/1/timeconstant",
            "/demods/1/rate",
            "/demods/1/oscillator"
        ]
    );
    // A trailing slash is malformed, as it is for `get` and `set`.
    assert_eq!(s.nodes_under("/sample/").len(), 0);
    assert_eq!(s.nodes_under("/sample").len(), 2);
    assert_eq!(s.nodes_under("/noise").len(), 5);
    assert_eq!(s.nodes_under("/spectrum").len(), 4);
    assert_eq!(s.nodes_under("/scope").len(), 4);
    assert_eq!(s.nodes_under("/server").len(), 6);
    let paths: Vec<String> = s
        .nodes_under("/inversion")
        .into_iter()
        .map(|n| n.path)
        .collect();
    assert_eq!(
        paths,
        [
            "/inversion/enable",
            "/inversion/method",
            "/inversion/harmonic_a",
            "/inversion/harmonic_b",
            "/inversion/averaging",
            "/inversion/points"
        ]
    );
    assert_eq!(s.nodes_under("/scan").len(), 6);
    assert_eq!(s.nodes_under("/feedback").len(), 4);
    assert_eq!(s.nodes_under("/inclusions").len(), 8 * 10);
    let paths: Vec<String> = s
        .nodes_under("/inclusions/2")
        .into_iter()
        .map(|n| n.path)
        .collect();
    assert_eq!(
        paths,
        [
            "/inclusions/2/enable",
            "/inclusions/2/shape",
            "/inclusions/2/x",
            "/inclusions/2/y",
            "/inclusions/2/width",
            "/inclusions/2/length",
            "/inclusions/2/height",
            "/inclusions/2/youngs_modulus",
            "/inclusions/2/relative_modulus",
            "/inclusions/2/poisson"
        ]
    );
    assert_eq!(s.nodes_under("/sample/poisson").len(), 1);
    assert_eq!(s.nodes_under("/").len(), s.nodes().len());
    assert!(s.nodes_under("/samp").is_empty());
}

// ---------------------------------------------------------------------------------------------
// Docs and defaults stay in step with the registry

/// `/demods/17/rate` → `/demods/N/rate`, `/inclusions/3/x` → `/inclusions/N/x`,
/// `/pids/2/p` → `/pids/N/p`: the docs describe each index-keyed table once.
fn generic_path(path: &str) -> String {
    let indexed = ["/demods/", "/inclusions/", "/pids/"]
        .iter()
        .any(|table| path.starts_with(table));
    let segments: Vec<&str> = path
        .split('/')
        .enumerate()
        .map(|(i, segment)| {
            let is_index = segment.bytes().all(|b| b.is_ascii_digit());
            if i == 2 && indexed && is_index {
                "N"
            } else {
                segment
            }
        })
        .collect();
    segments.join("/")
}

/// Equal JSON values, numbers compared as numbers (`100` is `100.0`).
fn same_value(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => x.as_f64() == y.as_f64(),
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(x, y)| same_value(x, y))
        }
        _ => a == b,
    }
}

#[test]
fn docs_describe_every_node() {
    let docs = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/docs/configuration.md"
    ))
    .unwrap();
    assert!(docs.contains("`/demods/N/…` for N = 0 … 31"));
    assert!(docs.contains("`/inclusions/N/…` for N = 0 … 7"));
    assert!(docs.contains("`/pids/N/…` for N = 0 … 3"));
    let documented: BTreeSet<String> = registry().iter().map(|s| generic_path(&s.path)).collect();
    let mut problems = Vec::new();
    let mut checked = BTreeSet::new();
    for spec in registry() {
        let path = generic_path(&spec.path);
        if !checked.insert(path.clone()) {
            continue;
        }
        let row = docs
            .lines()
            .find(|line| line.starts_with(&format!("| `{path}` |")))
            .unwrap_or_else(|| panic!("docs/configuration.md has no table row for {path}"));
        let unit = if spec.unit.is_empty() {
            "—"
        } else {
            spec.unit
        };
        assert!(
            row.contains(&format!("| {unit} |")),
            "unit of {path}: {row}"
        );
        let runtime = if spec.writable { "| yes |" } else { "| no |" };
        assert!(row.contains(runtime), "writability of {path}: {row}");
        // The allowed values as the node table states them (the docs add the limits
        // between nodes after them).
        let cells: Vec<&str> = row.split(" | ").collect();
        if let Kind::Float(range) = spec.kind
            && !cells[3].contains(&range.to_string())
        {
            problems.push(format!(
                "range of {path}: the node table says {range}, the docs {}",
                cells[3]
            ));
        }
        // The default as the embedded default file has it (tables vary by entry).
        if !path.contains("/N/") {
            let default = default_settings().get(&spec.path).unwrap();
            let shown = cells[2].split('`').nth(1).unwrap_or(cells[2]);
            let documented = toml::from_str::<toml::Table>(&format!("v = {shown}"))
                .map(|t| serde_json::to_value(&t["v"]).unwrap());
            if !documented.is_ok_and(|d| same_value(&d, &default)) {
                problems.push(format!(
                    "default of {path}: the docs say {shown}, config/default.toml {default}"
                ));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    // And no row for a node that does not exist.
    for line in docs.lines().filter(|l| l.starts_with("| `/")) {
        let path = line.split('`').nth(1).unwrap();
        assert!(
            documented.contains(path),
            "docs list {path}, which is no node"
        );
    }
}

#[test]
fn docs_example_overlay_loads_and_its_warning_is_as_documented() {
    let docs = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/docs/configuration.md"
    ))
    .unwrap();
    let example = docs
        .split("```toml\n")
        .find(|block| block.starts_with("# soft.toml"))
        .and_then(|block| block.split("```").next())
        .expect("docs/configuration.md has the soft.toml example");
    let s = load_str(example, "soft.toml").unwrap();
    let mut expected = default_settings();
    expected.sample.youngs_modulus = 3e9;
    for inclusion in &mut expected.inclusions {
        inclusion.youngs_modulus = inclusion.relative_modulus * 3e9;
    }
    expected.sample.poisson = 0.35;
    expected.synth.sample_rate = 50e6;
    expected.demods[3].harmonic = 60;
    expected.demods[3].timeconstant = 1e-3;
    assert_eq!(s, expected);
    let without_synth = example
        .replace("[synth]", "")
        .replace("sample_rate = 50e6", "");
    // Without the faster sampling, demodulator 3 is out of band, and the docs quote why.
    let slow = load_str(&without_synth, "soft.toml").unwrap();
    assert_eq!(slow.demods_out_of_band(), [3]);
    let message = slow.node_warning("/demods/3/harmonic").unwrap();
    assert!(
        docs.contains(&format!("`{message}`")),
        "docs lack {message:?}"
    );
}

#[test]
fn docs_quote_the_scope_and_origin_errors() {
    let docs = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/docs/configuration.md"
    ))
    .unwrap();
    for message in [
        OVERLAPPING_TRACES,
        WILDCARD_REFUSED,
        HARMONIC_NOT_MEASURED,
        SAME_HARMONICS,
        LINE_RATE_TOO_HIGH,
        DRIVE_TOO_LOW_FOR_SCAN,
        UNKNOWN_INCLUSION,
    ] {
        assert!(
            docs.contains(&format!("`{message}`")),
            "docs lack {message:?}"
        );
    }
    assert_mentions(&docs, &["`\"*\"` is refused", "drive the instrument"]);
}

#[test]
fn every_default_is_inside_its_range() {
    let s = default_settings();
    s.validate().unwrap();
    let number = |v: &Value| v.as_f64().unwrap();
    for info in s.nodes() {
        let values: Vec<f64> = match &info.value {
            Value::Number(_) => vec![number(&info.value)],
            // Lists of numbers; lists of text (`/server/allowed_origins`) have no bounds.
            Value::Array(items) if info.min.is_number() => items.iter().map(number).collect(),
            _ => continue,
        };
        for x in values {
            assert!(x >= number(&info.min), "{} = {x} < {}", info.path, info.min);
            assert!(x <= number(&info.max), "{} = {x} > {}", info.path, info.max);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Arbitrary input never breaks the settings

fn any_json() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::from),
        any::<i64>().prop_map(Value::from),
        any::<u64>().prop_map(Value::from),
        any::<f64>().prop_map(Value::from),
        (-1e3..1e3f64).prop_map(Value::from),
        // Values near the limits and plausible settings, so that many sets succeed.
        prop::sample::select(vec![
            -1.0, 0.0, 0.28, 0.5, 0.6, 1.0, 2.0, 4.0, 8.0, 9.0, 49.0, 50.0, 100.0, 1e-9, 1e-7,
            20e-9, 1e-6, 1e-5, 1e-3, 1e3, 1e5, 2e5, 5e6, 1e7, 1e8, 1e9, 1e13, 129e9, 1e-13, 300.0,
            1e4, 16.0, 32.0, 33.0, 128.0, 256.0, 1000.0, 1024.0, 32768.0, 1048576.0, 2097152.0,
        ])
        .prop_map(Value::from),
        prop::sample::select(vec![
            "paper",
            "coupled",
            "",
            "fast",
            "rectangular",
            "hann",
            "blackman_harris",
            "flat_top",
            "kaiser",
            "*",
            "http://localhost:3000",
            "https://lab.example",
            "ftp://x",
            "http://x/path",
            "full",
            "two_harmonic",
            "two-harmonic",
            "magic",
            "disc",
            "rectangle",
            "circle",
        ])
        .prop_map(Value::from),
        // Inversion harmonics, averaging and points near their limits, and harmonics the
        // default bank does and does not measure.
        prop::sample::select(vec![
            0u64, 1, 2, 3, 5, 6, 7, 8, 15, 16, 17, 18, 31, 32, 33, 40, 4095, 4096, 4097, 9999,
            10000, 10001,
        ])
        .prop_map(Value::from),
        // Scan, feedback and inclusion values near their limits.
        prop::sample::select(vec![
            -2e-3, -1e-3, -1e-6, 1e-4, 2e-4, 8.0, 7.0, 39.0, 39.0625, 40.0, 78.0, 1023.0, 1025.0,
            2e-3, 1e6, 2e6, 10.0, 11.0,
        ])
        .prop_map(Value::from),
        // Scope and server values near their limits.
        prop::sample::select(vec![
            0.5, 15.0, 16.0, 20.0, 64.0, 127.0, 600.0, 601.0, 2000.0, 4096.0, 4097.0, 10000.0,
            10001.0, 65536.0, 65537.0, 101.0,
        ])
        .prop_map(Value::from),
        "\\PC{0,8}".prop_map(Value::from),
    ];
    leaf.prop_recursive(2, 24, 8, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..6).prop_map(Value::Array),
            prop::collection::vec((-10.0..1e4f64).prop_map(Value::from), 0..20)
                .prop_map(Value::Array),
            // Lists of origins, valid and not, up to and past the 64-entry limit.
            prop::collection::vec(any_origin(), 0..70).prop_map(Value::Array),
            // Short lists of valid origins, so that many of these sets succeed.
            prop::collection::vec(
                "https?://[a-z0-9]{1,12}(:[0-9]{1,4})?".prop_map(Value::from),
                0..8
            )
            .prop_map(Value::Array),
            prop::collection::btree_map("[a-z]{1,4}", inner, 0..3)
                .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

/// Origin-like strings: valid ones, and ones that break one rule each.
fn any_origin() -> impl Strategy<Value = Value> {
    prop_oneof![
        4 => ("https?://[a-z0-9.-]{1,12}(:[0-9]{1,5})?").prop_map(Value::from),
        1 => prop::sample::select(vec![
            "*",
            "",
            "http://",
            "http://x/",
            "http://x/path",
            "ftp://x",
            "http://*.x",
            "http://[::1]:80",
        ])
        .prop_map(Value::from),
        1 => "\\PC{0,300}".prop_map(Value::from),
        1 => any::<u8>().prop_map(Value::from),
    ]
}

fn any_path() -> impl Strategy<Value = String> {
    let known: Vec<String> = registry().iter().map(|s| s.path.clone()).collect();
    // The inversion's nodes, and the demodulator nodes its relation ties them to, more often
    // than one path in ~200 would give.
    let inversion: Vec<String> = registry()
        .iter()
        .map(|s| s.path.clone())
        .filter(|p| p.starts_with("/inversion/"))
        .chain(
            [
                "/demods/5/enable",
                "/demods/5/harmonic",
                "/demods/16/enable",
                "/demods/16/harmonic",
                "/demods/31/harmonic",
            ]
            .map(String::from),
        )
        .collect();
    // The scan's nodes and the drive they are tied to.
    let scan: Vec<String> = registry()
        .iter()
        .map(|s| s.path.clone())
        .filter(|p| p.starts_with("/scan/") || p.starts_with("/feedback/"))
        .chain(["/drive/frequency".to_owned()])
        .collect();
    prop_oneof![
        9 => prop::sample::select(known),
        3 => prop::sample::select(inversion),
        2 => prop::sample::select(scan),
        1 => prop::sample::select(vec![
            "",
            "/",
            "/sample",
            "/demods/32/rate",
            "/demods/-1/rate",
            "/inclusions/8/x",
            "/inclusions",
        ])
        .prop_map(String::from),
    ]
}

proptest! {
    #[test]
    fn arbitrary_sets_never_panic_or_invalidate(
        ops in prop::collection::vec((any_path(), any_json(), any::<bool>()), 1..48)
    ) {
        let mut s: Settings = default_settings();
        for (path, value, at_runtime) in &ops {
            let before = s.clone();
            let result = if *at_runtime { s.set(path, value) } else { s.apply(path, value) };
            match result {
                Ok(applied) => prop_assert_eq!(s.get(path).unwrap(), applied),
                Err(error) => {
                    prop_assert_eq!(&s, &before);
                    prop_assert!(!error.to_string().is_empty());
                }
            }
            prop_assert!(s.validate().is_ok(), "{:?}", s.validate());
            // The inversion's invariants, checked independently of `validate`.
            let inv = &s.inversion;
            prop_assert!(inv.harmonic_a != inv.harmonic_b);
            for k in [inv.harmonic_a, inv.harmonic_b] {
                prop_assert!((2..=10_000).contains(&k));
                if inv.enable {
                    prop_assert!(
                        s.demods.iter().any(|d| d.enable && d.harmonic == k),
                        "harmonic {} unmeasured", k
                    );
                }
            }
            // The scan's relation, checked independently of `validate`.
            let scan = &s.scan;
            let pixels = f64::from(scan.pixels);
            prop_assert!((8..=1024).contains(&scan.pixels));
            prop_assert!(2.0 * pixels * scan.line_rate <= 20_000.0);
            prop_assert!(1.0 / (2.0 * pixels * scan.line_rate) >= 10.0 / s.drive.frequency * (1.0 - 1e-12));
            prop_assert_eq!(s.inclusions.len(), 8);
            prop_assert!((1..=10_000).contains(&inv.averaging));
            prop_assert!((16..=4096).contains(&inv.points));
            prop_assert_eq!(
                InversionMethod::from_name(inv.method.name()),
                Some(inv.method)
            );
        }
    }
}

fn next_up(x: f64) -> f64 {
    if x == 0.0 {
        return f64::from_bits(1);
    }
    let bits = x.to_bits();
    f64::from_bits(if x > 0.0 { bits + 1 } else { bits - 1 })
}

/// Whether `error` is the physics check's (the 1-DOF orbit or the cantilever), which no
/// range can express.
fn is_physics(error: &NodeError) -> bool {
    let message = error.to_string();
    message.contains("1-DOF tapping problem") || message.contains("gives no cantilever")
}

/// `list`'s `min` and `max` are what `set` accepts given the other settings: values just
/// inside them are applied (unless the 1-DOF orbit itself fails there), values just outside
/// refused. Checked on the default and on a lighter instrument (2 MS/s, harmonics ≤ 9).
#[test]
fn list_ranges_are_what_set_accepts() {
    let mut light = default_settings();
    light.synth.sample_rate = 2e6;
    for d in &mut light.demods {
        d.harmonic = d.harmonic.min(9);
        d.rate = 200.0;
    }
    light.inversion.enable = false;
    for base in [default_settings(), light] {
        for info in base.nodes() {
            if !info.writable || info.min.is_null() {
                continue;
            }
            let set = |value: Value| base.clone().set(&info.path, &value);
            let (inside, outside): (Vec<Value>, Vec<Value>) =
                if let (Some(lo), Some(hi)) = (info.min.as_u64(), info.max.as_u64()) {
                    let mut outside = vec![json!(hi as f64 + 1.0)];
                    if lo > 0 {
                        outside.push(json!(lo - 1));
                    }
                    (vec![json!(lo), json!(hi)], outside)
                } else {
                    let (lo, hi) = (info.min.as_f64().unwrap(), info.max.as_f64().unwrap());
                    let step = (hi - lo) * 1e-9;
                    (
                        vec![json!(lo + step), json!(hi - step)],
                        vec![json!(-next_up(-lo)), json!(next_up(hi))],
                    )
                };
            let wrap = |v: Value| {
                if info.value.is_array() { json!([v]) } else { v }
            };
            for v in inside {
                if let Err(e) = set(wrap(v.clone())) {
                    assert!(
                        is_physics(&e),
                        "{} = {v} inside list's range: {e}",
                        info.path
                    );
                }
            }
            for v in outside {
                assert!(
                    set(wrap(v.clone())).is_err(),
                    "{} = {v} outside list's range [{}, {}] was accepted",
                    info.path,
                    info.min,
                    info.max
                );
            }
        }
    }
    // The drive's limit is the Nyquist frequency (demodulators above it are out of band,
    // not a limit), and 5 Q values leave room for 11 extra modes of the 16.
    let s = default_settings();
    let find = |path: &str| s.nodes().into_iter().find(|n| n.path == path).unwrap();
    assert_eq!(find("/drive/frequency").max, json!(5e6));
    // 20 × 64 pixels × 2 Hz: each pixel lasts ten drive periods at 2.56 kHz.
    assert_eq!(find("/drive/frequency").min, json!(2560.0));
    // Which ends are themselves allowed, as the checks enforce them: the Nyquist frequency
    // is excluded, the dwell-time limit allowed; the 0 of `0 < value` excluded.
    let ends = |path: &str| (find(path).min_inclusive, find(path).max_inclusive);
    assert_eq!(ends("/drive/frequency"), (Some(true), Some(false)));
    assert!(s.clone().set("/drive/frequency", &json!(2560.0)).is_ok());
    assert!(s.clone().set("/drive/frequency", &json!(5e6)).is_err());
    assert_eq!(ends("/sample/youngs_modulus"), (Some(false), Some(true)));
    assert!(
        s.clone()
            .set("/sample/youngs_modulus", &json!(0.0))
            .is_err()
    );
    assert!(
        s.clone()
            .set("/sample/youngs_modulus", &json!(1e13))
            .is_ok()
    );
    assert_eq!(ends("/scan/pixels"), (Some(true), Some(true)));
    assert_eq!(ends("/noise/enable"), (None, None));
    assert_eq!(find("/cantilever/extra_modes").max, json!(11));
    assert!(s.clone().set("/cantilever/extra_modes", &json!(11)).is_ok());
    assert!(
        s.clone()
            .set("/cantilever/extra_modes", &json!(12))
            .is_err()
    );
}

/// In-range values whose 1-DOF orbit cannot be found pass the schema (`Settings::set`,
/// a config file) and are refused by the model's check with the same message, so `serve`
/// and `paper` never start on them; the schema itself runs no physics.
#[test]
fn physics_failures_are_refused_by_the_model_for_files_and_commands_alike() {
    for (path, table, key, value) in [
        ("/cantilever/f1", "cantilever", "f1", 1e8),
        ("/cantilever/k", "cantilever", "k", 5e-324),
    ] {
        // The drive stays at 100 kHz: a drive following f1 = 1e8 would be above Nyquist.
        let mut base = default_settings();
        base.set("/drive/follow_f1", &json!(false)).unwrap();
        base.set(path, &json!(value)).expect(path);
        let model_error = ftafm::model::check(&base).expect_err(path).to_string();
        assert!(
            model_error.contains("1-DOF tapping problem"),
            "{model_error}"
        );
        let text = format!("[drive]\nfollow_f1 = false\n[{table}]\n{key} = {value:e}\n");
        let loaded = load_str(&text, "t.toml").expect(path);
        assert_eq!(
            ftafm::model::check(&loaded).unwrap_err().to_string(),
            model_error
        );

        let dir = std::env::temp_dir().join(format!("ftafm-physics-{}-{key}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("c.toml");
        std::fs::write(&file, &text).unwrap();
        for args in [
            vec!["paper", "--config", file.to_str().unwrap(), "--json"],
            vec![
                "serve",
                "--config",
                file.to_str().unwrap(),
                "--bind",
                "127.0.0.1:0",
            ],
        ] {
            let out = std::process::Command::new(env!("CARGO_BIN_EXE_ftafm"))
                .args(&args)
                .output()
                .unwrap();
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
            assert!(stderr.contains(&model_error), "{args:?}: {stderr}");
            assert!(out.stdout.is_empty(), "{args:?} printed {:?}", out.stdout);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// The values that spun the 1-DOF solver for more than ten minutes before the port was
/// bound (Q = 1e7 with a 1 µm free amplitude, Q = 3e6 with 0.3 µm): the solver's transient
/// is bounded, so `serve --config` decides in its bounded time, binds, prints its URL and
/// stops on SIGTERM.
#[test]
fn serve_decides_a_high_q_configuration_and_binds() {
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    for (q, amplitude) in [(1e7, 1e-6), (3e6, 3e-7)] {
        let dir = std::env::temp_dir().join(format!("ftafm-wedge-{}-{q}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("c.toml");
        std::fs::write(
            &file,
            format!("[cantilever]\nq = [{q:e}]\n[drive]\nfree_amplitude = {amplitude:e}\n"),
        )
        .unwrap();
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_ftafm"))
            .args([
                "serve",
                "--config",
                file.to_str().unwrap(),
                "--bind",
                "127.0.0.1:0",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        assert!(line.contains("http://127.0.0.1:"), "Q = {q:e}: {line:?}");
        let kill = std::process::Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status()
            .unwrap();
        assert!(kill.success());
        assert_eq!(child.wait().unwrap().code(), Some(0), "Q = {q:e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// Keys and values are quoted cut short: a 20 MB key gives a message of a few hundred
/// bytes that still says how long it was.
#[test]
fn quoted_keys_and_values_are_cut() {
    let huge = "x".repeat(20_000_000);
    let cases = [
        format!("[sample]\n{huge} = 1\n"),
        format!("{huge} = 1\n"),
        format!("[synth]\nengine = \"{huge}\"\n"),
        format!("[server]\nallowed_origins = [\"http://{huge}\"]\n"),
        format!("[cantilever]\nq = [{}1]\n", "2, ".repeat(1_000_000)),
        format!("[sample]\nyoungs_modulus = {huge}\n"),
    ];
    for text in &cases {
        let message = load_str(text, "t.toml").unwrap_err().to_string();
        assert!(
            message.len() < 1000,
            "{} bytes: {}",
            message.len(),
            &message[..300]
        );
    }
    let message = load_str(&cases[0], "t.toml").unwrap_err().to_string();
    assert!(message.contains("(20000008 bytes)"), "{message}");
    let mut s = default_settings();
    for error in [
        s.get(&format!("/{huge}")).unwrap_err(),
        s.set(&format!("/sample/{huge}"), &json!(1)).unwrap_err(),
        s.set("/synth/engine", &json!(huge)).unwrap_err(),
        s.list(&format!("/{huge}")).unwrap_err(),
    ] {
        let message = error.to_string();
        assert!(message.len() < 1000, "{} bytes", message.len());
        assert!(message.contains(" bytes)"), "{message}");
    }
}

/// `list`, `get` and `set` share one rule for paths: a malformed one (`//`, a trailing or
/// doubled slash) is an unknown path that says it is malformed; `/` alone lists the tree.
#[test]
fn paths_follow_one_rule_for_every_op() {
    let mut s = default_settings();
    for path in ["//", "/sample/", "/sample//poisson", "/sample/poisson/"] {
        for error in [
            s.get(path).unwrap_err(),
            s.set(path, &json!(0.3)).unwrap_err(),
            s.list(path).unwrap_err(),
        ] {
            assert_eq!(error.code(), "unknown_path", "{path}");
            assert!(
                error.to_string().starts_with("malformed path"),
                "{path}: {error}"
            );
        }
    }
    assert_eq!(s.list("/").unwrap(), s.nodes());
    assert_eq!(s.list("/sample").unwrap().len(), 2);
    assert_eq!(s.list("/sample/poisson").unwrap().len(), 1);
    let error = s.list("/sample/nothing").unwrap_err();
    assert_eq!(error.code(), "unknown_path");
    assert!(
        error.to_string().contains("youngs_modulus, poisson"),
        "{error}"
    );
}

// ---------------------------------------------------------------------------------------------
// Settings as a file, and batch sets

/// `settings_toml` writes a file `--config` reads back to the very same settings: the
/// default, and settings moved away from it in every kind of node (a preset's lever,
/// demodulators, inclusions given relative and absolute, the drive off f1).
#[test]
fn settings_written_as_toml_read_back_the_same() {
    let mut moved =
        ftafm::config::load_with_presets(&["tap300".into(), "polystyrene".into()], None).unwrap();
    moved
        .set_many(&[
            ("/demods/3/harmonic".into(), json!(7)),
            ("/demods/31/enable".into(), json!(true)),
            ("/inclusions/1/youngs_modulus".into(), json!(3.3e9)),
            ("/drive/frequency".into(), json!(299e3)),
            ("/cantilever/q".into(), json!([450.0, 600.0])),
            ("/spectrum/window".into(), json!("blackman_harris")),
        ])
        .unwrap();
    assert!(
        !moved.drive.follow_f1,
        "a drive frequency off f1 stops following it"
    );
    for settings in [default_settings(), moved] {
        let text = ftafm::config::settings_toml(&settings).unwrap();
        let back = load_str(&text, "saved.toml").unwrap_or_else(|e| panic!("{e}\n{text}"));
        assert_eq!(back, settings, "{text}");
    }
}

/// A batch set checks its nodes against each other once, after all are written (f1 and the
/// drive moved together keep following), returns the values as applied in order, and on
/// any error names its node and changes nothing.
#[test]
fn a_batch_set_is_checked_as_a_whole_and_all_or_nothing() {
    let base = default_settings();
    let mut s = base.clone();
    let applied = s
        .set_many(&[
            ("/drive/frequency".into(), json!(50e3)),
            ("/surface/distance".into(), json!(1.5e-8)),
            ("/demods/2/harmonic".into(), json!(4.0)),
        ])
        .unwrap();
    assert_eq!(applied, vec![json!(50e3), json!(1.5e-8), json!(4)]);
    assert_eq!(s.drive.frequency, 50e3);
    assert!(!s.drive.follow_f1);

    // f1 and the drive together: following f1 with the drive given at the new f1 is fine.
    let mut t = base.clone();
    t.set_many(&[
        ("/cantilever/f1".into(), json!(120e3)),
        ("/drive/frequency".into(), json!(120e3)),
    ])
    .unwrap();
    assert!(t.drive.follow_f1);
    assert_eq!(t.drive.frequency, 120e3);

    for (values, names) in [
        (
            vec![
                ("/surface/distance".into(), json!(1e-8)),
                ("/drive/frequncy".into(), json!(1.0)),
            ],
            "/drive/frequncy",
        ),
        (
            vec![
                ("/surface/distance".into(), json!(1e-8)),
                ("/synth/sample_rate".into(), json!(20e6)),
            ],
            "/synth/sample_rate",
        ),
        (
            vec![
                ("/surface/distance".into(), json!(1e-8)),
                ("/sample/youngs_modulus".into(), json!(-1.0)),
            ],
            "/sample/youngs_modulus",
        ),
    ] {
        let mut u = base.clone();
        let err = u.set_many(&values).unwrap_err().to_string();
        assert!(err.contains(names), "{err}");
        assert_eq!(u, base, "a refused batch changed something: {err}");
    }
}

/// The second excitation's frequency (Hz) of `names` laid over the default, and mode 2's
/// natural frequency (Hz) of the lever they configure, as the physics builds it.
fn drive2_and_mode_2(names: &[String]) -> (f64, f64) {
    let s =
        ftafm::config::load_with_presets(names, None).unwrap_or_else(|e| panic!("{names:?}: {e}"));
    let lever = ftafm::model::cantilever(&s).unwrap_or_else(|e| panic!("{names:?}: {e}"));
    (s.drive2.frequency, lever.modes[1].frequency)
}

/// Every preset, alone and every lever with every sample in either order, leaves
/// `/drive2/frequency` on mode 2 of the lever it configures (within 1e-6 of f2: the
/// files give it to 7 digits), so bimodal AFM drives mode 2 on resonance: a lever preset
/// sets its own, a sample preset leaves the lever's. Switched on, the second excitation
/// lies below the Nyquist frequency at the preset's sample rate and at the default's
/// (the `preset` op keeps the running one), so it validates.
#[test]
fn every_preset_drives_mode_2_of_its_own_lever() {
    let name = |p: &ftafm::config::Preset| p.name.to_owned();
    let mut combinations: Vec<Vec<String>> = ftafm::config::PRESETS
        .iter()
        .map(|p| vec![name(p)])
        .collect();
    for lever in ftafm::config::PRESETS
        .iter()
        .filter(|p| p.kind == ftafm::config::PresetKind::Cantilever)
    {
        for sample in ftafm::config::PRESETS
            .iter()
            .filter(|p| p.kind == ftafm::config::PresetKind::Sample)
        {
            combinations.push(vec![name(lever), name(sample)]);
            combinations.push(vec![name(sample), name(lever)]);
        }
    }
    let default_rate = default_settings().synth.sample_rate;
    for names in combinations {
        let (f, f2) = drive2_and_mode_2(&names);
        assert!(
            ((f - f2) / f2).abs() < 1e-6,
            "{names:?}: /drive2/frequency = {f} Hz, mode 2 at {f2} Hz"
        );
        let mut s = ftafm::config::load_with_presets(&names, None).unwrap();
        s.drive2.enable = true;
        for rate in [s.synth.sample_rate, default_rate] {
            assert!(f < rate / 2.0, "{names:?}: {f} Hz at {rate} S/s");
            let mut at = s.clone();
            at.synth.sample_rate = rate;
            at.validate()
                .unwrap_or_else(|e| panic!("{names:?}, drive2 on at {rate} S/s: {e}"));
        }
    }
}
