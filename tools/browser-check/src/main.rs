//! `assay-browser-check FILE [--screenshot OUT.png] [--width W --height H] [--full-page]
//! [--timeout SECONDS]`: opens FILE in headless Chromium and prints what it found. Exit status 0
//! when clean, 1 when not, 2 when the check could not run.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use assay_browser_check::{Options, check_file};

const USAGE: &str = "usage: assay-browser-check FILE [--screenshot OUT.png] [--width W --height H] [--full-page] [--fragment ID] [--timeout SECONDS]";

fn main() -> ExitCode {
    let (file, options) = match parse(std::env::args().skip(1)) {
        Ok(parsed) => parsed,
        Err(message) => {
            eprintln!("{message}\n{USAGE}");
            return ExitCode::from(2);
        }
    };
    let started = Instant::now();
    let check = match check_file(&file, &options) {
        Ok(check) => check,
        Err(e) => {
            eprintln!("assay-browser-check: {e}");
            return ExitCode::from(2);
        }
    };
    println!(
        "{}: \"{}\", {} images ({} broken), screenshot {} bytes, {:.1}s",
        file.display(),
        check.title,
        check.images,
        check.broken_images,
        check.screenshot_bytes,
        started.elapsed().as_secs_f64()
    );
    for w in &check.warnings {
        println!("  warning: {w}");
    }
    let problems = check.problems();
    for p in &problems {
        println!("  FAIL {p}");
    }
    if problems.is_empty() {
        println!("clean");
        ExitCode::SUCCESS
    } else {
        println!("{} problem(s)", problems.len());
        ExitCode::from(1)
    }
}

fn parse(mut args: impl Iterator<Item = String>) -> Result<(PathBuf, Options), String> {
    let mut options = Options::default();
    let mut file = None;
    while let Some(arg) = args.next() {
        let mut value = |name: &str| args.next().ok_or_else(|| format!("{name} needs a value"));
        match arg.as_str() {
            "--screenshot" => options.screenshot = Some(PathBuf::from(value("--screenshot")?)),
            "--width" => options.viewport.0 = number(&value("--width")?)?,
            "--height" => options.viewport.1 = number(&value("--height")?)?,
            "--timeout" => options.timeout = Duration::from_secs(number(&value("--timeout")?)?.into()),
            "--full-page" => options.full_page = true,
            "--fragment" => options.fragment = Some(value("--fragment")?),
            "-h" | "--help" => return Err("Opens an HTML file in headless Chromium; fails on console errors, exceptions, failed or non-local requests.".into()),
            a if a.starts_with('-') => return Err(format!("unknown option {a}")),
            a if file.is_none() => file = Some(PathBuf::from(a)),
            a => return Err(format!("unexpected argument {a}")),
        }
    }
    Ok((file.ok_or("no FILE given")?, options))
}

fn number(s: &str) -> Result<u32, String> {
    s.parse()
        .ok()
        .filter(|n| *n > 0)
        .ok_or_else(|| format!("not a positive number: {s}"))
}
