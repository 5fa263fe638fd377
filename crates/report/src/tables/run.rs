//! The Run and Provenance sections' tables: what depends on the machine and the moment, and
//! what produced the figures.

use crate::report::{Provenance, RunInfo};
use crate::view::{Cell, Span, Table};

/// What depends on the machine and the moment.
pub fn run(run: &RunInfo) -> Table {
    let mut table = Table::new(["measure", "value"]);
    let mut row = |k: &str, v: Cell| table.row(vec![k.into(), v]);
    row(
        "batch",
        Cell::code(&run.batch_id).and(Span::Text(format!(" ({})", run.state))),
    );
    row("submitted", Cell::text(utc(run.submitted_at_unix_ms)));
    row(
        "finished",
        run.finished_at_unix_ms
            .map_or_else(Cell::missing, |ms| Cell::text(utc(ms))),
    );
    row(
        "wall time",
        run.wall_time_s
            .map_or_else(Cell::missing, |s| Cell::text(format!("{s:.1} s"))),
    );
    row(
        "throughput",
        match run.episodes_per_s {
            Some(e) => Cell::text(format!(
                "{e:.2} episodes/s, {:.0} steps/s",
                run.sim_steps_per_s.unwrap_or(0.0)
            )),
            None => Cell::missing(),
        },
    );
    row(
        "attempts beyond the first",
        Cell::text(run.extra_attempts.to_string()),
    );
    row(
        "workers",
        Cell::text(format!(
            "{} ({})",
            run.workers.len(),
            run.workers.join(", ")
        )),
    );
    if !run.events.is_empty() {
        row("events", super::lines(run.events.iter().cloned()));
    }
    table
}

/// What produced the figures.
pub fn provenance(p: &Provenance) -> Table {
    let mut table = Table::new(["what", "value"]);
    for (what, values) in p.rows() {
        let value = match values.as_slice() {
            [] => Cell::missing(),
            [hash] if what.contains("SHA-256") => Cell::code(hash),
            v => super::lines(v.iter().cloned()),
        };
        table.row(vec![what.into(), value]);
    }
    table
}

/// Formats unix milliseconds as UTC `YYYY-MM-DD hh:mm:ss UTC`.
pub fn utc(ms: i64) -> String {
    let secs = ms.div_euclid(1000);
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Howard Hinnant's civil_from_days.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02} UTC",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_dates() {
        assert_eq!(utc(0), "1970-01-01 00:00:00 UTC");
        assert_eq!(utc(1_700_000_000_000), "2023-11-14 22:13:20 UTC");
    }
}
