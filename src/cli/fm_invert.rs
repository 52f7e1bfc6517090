//! `ftafm fm-invert FILE`: a measured FM-AFM frequency-shift curve Δf(z) to the force F(z)
//! by the Sader–Jarvis inversion ([`crate::physics::fm::sader_jarvis`]).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use super::EXIT_USAGE;
use crate::physics::fm::{self, FmError, FmLever};

/// `ftafm fm-invert`'s flags.
#[derive(clap::Args)]
pub struct FmInvertArgs {
    /// CSV with the header `z,df`: distance of closest approach z (m, increasing) and
    /// frequency shift Δf (Hz); `#` starts a comment; `-` reads stdin.
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// The lever's spring constant k (N/m).
    #[arg(long = "k", value_name = "N_PER_M")]
    pub k: f64,
    /// The lever's free resonance frequency f0 (Hz).
    #[arg(long = "f0", value_name = "HZ")]
    pub f0: f64,
    /// The oscillation amplitude A (m, zero to peak).
    #[arg(long, value_name = "M")]
    pub amplitude: f64,
    /// Print one JSON object {"z": [...], "force": [...]} instead of the CSV `z,force`.
    #[arg(long)]
    pub json: bool,
}

/// A parsed curve and the line each sample came from (1-based), for messages.
struct Curve {
    z: Vec<f64>,
    df: Vec<f64>,
    lines: Vec<usize>,
}

/// Parses the CSV `text` of `origin`; errors name the origin and the line.
fn parse(origin: &str, text: &str) -> Result<Curve, String> {
    let mut curve = Curve {
        z: Vec::new(),
        df: Vec::new(),
        lines: Vec::new(),
    };
    let mut header = false;
    for (n, raw) in text.lines().enumerate() {
        let line_no = n + 1;
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if !header {
            if fields != ["z", "df"] {
                return Err(format!(
                    "{origin}:{line_no}: the header must be `z,df` (z in m, Δf in Hz), found `{line}`"
                ));
            }
            header = true;
            continue;
        }
        if fields.len() != 2 {
            return Err(format!(
                "{origin}:{line_no}: expected 2 fields `z,df`, found {}",
                fields.len()
            ));
        }
        let mut values = [0.0; 2];
        for (value, (field, name)) in values.iter_mut().zip(fields.iter().zip(["z", "df"])) {
            *value = field
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    format!("{origin}:{line_no}: {name} `{field}` is not a finite number")
                })?;
        }
        curve.z.push(values[0]);
        curve.df.push(values[1]);
        curve.lines.push(line_no);
    }
    if !header {
        return Err(format!("{origin}: no header `z,df` (the file is empty)"));
    }
    Ok(curve)
}

fn read(file: &Path) -> Result<(String, String), String> {
    use std::io::Read;
    if file == Path::new("-") {
        let mut text = String::new();
        std::io::stdin()
            .read_to_string(&mut text)
            .map_err(|e| format!("stdin: {e}"))?;
        Ok(("stdin".to_owned(), text))
    } else {
        let origin = file.display().to_string();
        let text = std::fs::read_to_string(file).map_err(|e| format!("{origin}: {e}"))?;
        Ok((origin, text))
    }
}

/// Runs `ftafm fm-invert`: exit 2 for bad flags or a malformed curve (the message names
/// the flag, or the file and line), 1 when the file cannot be read.
pub fn command(args: FmInvertArgs) -> Result<ExitCode, ExitCode> {
    let usage = |e: String| {
        eprintln!("ftafm fm-invert: {e}");
        ExitCode::from(EXIT_USAGE)
    };
    let lever = FmLever::new(args.k, args.f0, args.amplitude).map_err(|e| match e {
        FmError::Parameter { name, .. } => usage(format!("--{name}: {e}")),
        e => usage(e.to_string()),
    })?;
    let (origin, text) = read(&args.file).map_err(|e| {
        eprintln!("ftafm fm-invert: {e}");
        ExitCode::FAILURE
    })?;
    let curve = parse(&origin, &text).map_err(usage)?;
    let force = fm::invert(&curve.z, &curve.df, &lever).map_err(|e| match e {
        FmError::NotIncreasing { index, .. } => {
            usage(format!("{origin}:{}: {e}", curve.lines[index]))
        }
        e => usage(format!("{origin}: {e}")),
    })?;
    if args.json {
        println!("{}", serde_json::to_string(&force).expect("finite numbers"));
    } else {
        let mut out = String::from("z,force\n");
        for (z, f) in force.z.iter().zip(&force.force) {
            out.push_str(&format!("{z:e},{f:e}\n"));
        }
        print!("{out}");
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_csv_takes_comments_and_names_bad_lines() {
        let c = parse(
            "f.csv",
            "# a curve\nz,df # header\n1e-9, -3\n\n2e-9,-1 # x\n",
        )
        .unwrap();
        assert_eq!(
            (c.z, c.df, c.lines),
            (vec![1e-9, 2e-9], vec![-3.0, -1.0], vec![3, 5])
        );
        let e = parse("f.csv", "z,f\n").err().unwrap();
        assert!(e.starts_with("f.csv:1:") && e.contains("z,df"), "{e}");
        let e = parse("f.csv", "z,df\n1,2\n3,x\n").err().unwrap();
        assert!(e.starts_with("f.csv:3:") && e.contains("df `x`"), "{e}");
        let e = parse("f.csv", "z,df\n1,2,3\n").err().unwrap();
        assert!(e.starts_with("f.csv:2:"), "{e}");
        let e = parse("f.csv", "z,df\nnan,2\n").err().unwrap();
        assert!(e.contains("z `nan`"), "{e}");
        assert!(parse("f.csv", "# only\n").is_err());
    }
}
