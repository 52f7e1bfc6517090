//! `ftafm fm-invert` as a user runs it: a Δf(z) curve from the forward model (Giessibl's
//! integral over the oscillation) in a CSV file, the force back on stdout, as CSV or JSON;
//! errors name the flag, or the file and the line.

use std::path::PathBuf;
use std::process::{Command, Output};

use ftafm::physics::fm::{FmLever, frequency_shift_curve};

fn ftafm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ftafm"))
        .args(args)
        .output()
        .expect("the binary runs")
}

/// A file in the temporary directory, removed on drop. Its name is its own, also between
/// the tests of this file, which run at once in one process: one test's file must not be
/// removed under another's.
struct TempFile(PathBuf);

impl TempFile {
    fn new(name: &str, contents: &str) -> Self {
        static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let path = std::env::temp_dir().join(format!("ftafm-{}-{n}-{name}", std::process::id()));
        std::fs::write(&path, contents).unwrap();
        Self(path)
    }

    fn path(&self) -> &str {
        self.0.to_str().unwrap()
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// An exponential attraction, F = −1 nN·exp(−d/0.4 nm).
fn force(d: f64) -> f64 {
    -1e-9 * (-d / 0.4e-9).exp()
}

const LEVER: (f64, f64, f64) = (40.0, 300e3, 2e-9);

fn curve_file() -> TempFile {
    let lever = FmLever::new(LEVER.0, LEVER.1, LEVER.2).unwrap();
    let z: Vec<f64> = (0..800).map(|i| 0.1e-9 + 0.01e-9 * i as f64).collect();
    let df = frequency_shift_curve(&lever, force, &z);
    let mut text = String::from("# Δf(z) of an exponential attraction\nz,df\n");
    for (z, df) in z.iter().zip(&df) {
        text.push_str(&format!("{z:e},{df:e}\n"));
    }
    TempFile::new("curve.csv", &text)
}

fn lever_flags() -> Vec<String> {
    vec![
        "--k".into(),
        LEVER.0.to_string(),
        "--f0".into(),
        LEVER.1.to_string(),
        "--amplitude".into(),
        LEVER.2.to_string(),
    ]
}

fn run(file: &str, extra: &[&str]) -> Output {
    let flags = lever_flags();
    let mut args = vec!["fm-invert", file];
    args.extend(flags.iter().map(String::as_str));
    args.extend(extra);
    ftafm(&args)
}

/// The worst |F − force law| as a fraction of the law's range over the curve.
fn worst_error(z: &[f64], f: &[f64]) -> f64 {
    let exact: Vec<f64> = z.iter().map(|&d| force(d)).collect();
    let range = exact.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
        - exact.iter().cloned().fold(f64::INFINITY, f64::min);
    f.iter()
        .zip(&exact)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max)
        / range
}

#[test]
fn the_force_of_a_forward_modelled_curve_comes_back_as_csv_and_json() {
    let file = curve_file();
    let out = run(file.path(), &[]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("z,force"));
    let (z, f): (Vec<f64>, Vec<f64>) = lines
        .map(|l| {
            let (a, b) = l.split_once(',').unwrap();
            (a.parse::<f64>().unwrap(), b.parse::<f64>().unwrap())
        })
        .unzip();
    assert_eq!(z.len(), 799, "every sample but the last");
    let e = worst_error(&z, &f);
    assert!(e < 0.03, "worst error {e} of the range");

    let out = run(file.path(), &["--json"]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let z: Vec<f64> = serde_json::from_value(v["z"].clone()).unwrap();
    let f: Vec<f64> = serde_json::from_value(v["force"].clone()).unwrap();
    assert_eq!(z.len(), 799);
    assert!(worst_error(&z, &f) < 0.03);
}

#[test]
fn bad_flags_and_bad_files_exit_2_naming_what_is_wrong() {
    let file = TempFile::new("bad.csv", "z,df\n1e-9,-1\n3e-9,-2\n2e-9,-3\n");
    let out = run(file.path(), &[]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&format!("{}:4:", file.path())), "{err}");
    assert!(err.contains("increase"), "{err}");

    let file = TempFile::new("word.csv", "# header next\nz,df\n1e-9,abc\n");
    let out = run(file.path(), &[]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&format!("{}:3:", file.path())), "{err}");

    let good = curve_file();
    let out = ftafm(&[
        "fm-invert",
        good.path(),
        "--k",
        "-1",
        "--f0",
        "3e5",
        "--amplitude",
        "1e-9",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--k"));

    let out = ftafm(&[
        "fm-invert",
        "/nonexistent/curve.csv",
        "--k",
        "1",
        "--f0",
        "3e5",
        "--amplitude",
        "1e-9",
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/curve.csv"));
}
