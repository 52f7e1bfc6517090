//! `ftafm stalls`: the machine's own stalls.

use std::process::ExitCode;

use super::{EXIT_USAGE, print_report};

pub fn command(seconds: f64, json: bool) -> Result<ExitCode, ExitCode> {
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= 86_400.0) {
        eprintln!("ftafm: --seconds = {seconds} is out of range: allowed 0 < S ≤ 86400");
        return Err(ExitCode::from(EXIT_USAGE));
    }
    let report = crate::cli::soak::measure_stalls(seconds, |t, max_ns, over| {
        eprintln!(
            "[{t:>5.0} s] longest stall so far {:.3} ms, {over} of at least 5 ms",
            max_ns as f64 / 1e6
        );
    })
    .map_err(|e| {
        eprintln!("ftafm: {e}");
        ExitCode::FAILURE
    })?;
    print_report(json, &report, crate::cli::soak::render_stalls);
    Ok(ExitCode::SUCCESS)
}
