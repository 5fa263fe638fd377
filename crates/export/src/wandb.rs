//! `assay export wandb RUN OUT`: a run's figures ([`crate::scalars`]) as a Weights & Biases
//! offline run, `OUT/offline-run-YYYYMMDD_HHMMSS-<id>/run-<id>.wandb`, the folder `wandb.init(mode=
//! "offline")` leaves behind; `wandb sync OUT/offline-run-*` uploads it like any offline run.
//!
//! What the run holds: its config (the run's resolved settings, `config.toml`'s `[eval]` table, key
//! by key, and the batch id, Assay version and settings hash), one history row per distinct step
//! of the scalars (step 0 holds every figure; the dynamics-diversity curve adds a row per
//! budget, so W&B draws it against the budget), a summary of each scalar's last value, and a
//! clean exit. Its id (8 characters, as W&B's) is a hash of the batch id and its submission time,
//! so exporting a run twice gives the same run (and the same bytes).
//!
//! The file is written here, without the `wandb` package: W&B's transaction log is LevelDB's log
//! format (32 KiB blocks; each chunk a 7-byte header — checksum, length, type FULL / FIRST /
//! MIDDLE / LAST — and its data; a block's tail too short for a header is zero-filled) after a
//! 7-byte file header (`:W&B`, magic 0xBEE1, version 0), with zlib's CRC-32 of the type byte and
//! the data, unmasked (LevelDB masks a CRC-32C). Each record is a `wandb_internal.Record`
//! (wandb/proto/wandb_internal.proto) numbered from 1: header, run, history…, summary, exit — the
//! order an offline run of `wandb` 0.30 writes them in.
//!
//! Owns: the run's layout and the file's encoding.

use std::path::{Path, PathBuf};

use anyhow::Context;
use prost::Message;

use crate::crc::crc32;
use crate::read_report;
use crate::scalars::{Scalar, scalars};

const BLOCK: usize = 32 * 1024;
const CHUNK_HEADER: usize = 7;
const FULL: u8 = 1;
const FIRST: u8 = 2;
const MIDDLE: u8 = 3;
const LAST: u8 = 4;

/// `wandb_internal.Record`: its number and one of the record types (a `oneof` on the wire is
/// the one field that is present).
#[derive(Clone, PartialEq, prost::Message)]
struct Record {
    #[prost(int64, tag = "1")]
    num: i64,
    #[prost(message, optional, tag = "2")]
    history: Option<HistoryRecord>,
    #[prost(message, optional, tag = "3")]
    summary: Option<SummaryRecord>,
    #[prost(message, optional, tag = "17")]
    run: Option<RunRecord>,
    #[prost(message, optional, tag = "18")]
    exit: Option<RunExitRecord>,
    #[prost(message, optional, tag = "21")]
    header: Option<HeaderRecord>,
}

#[derive(Clone, PartialEq, prost::Message)]
struct HeaderRecord {
    #[prost(message, optional, tag = "1")]
    version_info: Option<VersionInfo>,
}

#[derive(Clone, PartialEq, prost::Message)]
struct VersionInfo {
    #[prost(string, tag = "1")]
    producer: String,
}

#[derive(Clone, PartialEq, prost::Message)]
struct RunRecord {
    #[prost(string, tag = "1")]
    run_id: String,
    #[prost(string, tag = "3")]
    project: String,
    #[prost(message, optional, tag = "4")]
    config: Option<ConfigRecord>,
    #[prost(string, tag = "8")]
    display_name: String,
    #[prost(string, tag = "9")]
    notes: String,
    #[prost(string, repeated, tag = "10")]
    tags: Vec<String>,
    #[prost(message, optional, tag = "17")]
    start_time: Option<Timestamp>,
}

/// `google.protobuf.Timestamp`.
#[derive(Clone, PartialEq, prost::Message)]
struct Timestamp {
    #[prost(int64, tag = "1")]
    seconds: i64,
    #[prost(int32, tag = "2")]
    nanos: i32,
}

#[derive(Clone, PartialEq, prost::Message)]
struct ConfigRecord {
    #[prost(message, repeated, tag = "1")]
    update: Vec<Item>,
}

/// `ConfigItem`, `HistoryItem` and `SummaryItem` have the same fields.
#[derive(Clone, PartialEq, prost::Message)]
struct Item {
    #[prost(string, tag = "1")]
    key: String,
    #[prost(string, tag = "16")]
    value_json: String,
}

#[derive(Clone, PartialEq, prost::Message)]
struct HistoryRecord {
    #[prost(message, repeated, tag = "1")]
    item: Vec<Item>,
    #[prost(message, optional, tag = "2")]
    step: Option<HistoryStep>,
}

#[derive(Clone, PartialEq, prost::Message)]
struct HistoryStep {
    #[prost(int64, tag = "1")]
    num: i64,
}

#[derive(Clone, PartialEq, prost::Message)]
struct SummaryRecord {
    #[prost(message, repeated, tag = "1")]
    update: Vec<Item>,
}

#[derive(Clone, PartialEq, prost::Message)]
struct RunExitRecord {
    #[prost(int32, tag = "1")]
    exit_code: i32,
    #[prost(int32, tag = "2")]
    runtime: i32,
}

/// What [`export`] wrote.
#[derive(Debug, Clone)]
pub struct Exported {
    /// The run's folder (`OUT/offline-run-…`), what `wandb sync` takes.
    pub dir: PathBuf,
    pub run_id: String,
    pub scalars: usize,
    pub steps: usize,
}

/// Writes `run`'s figures as an offline run of W&B project `project` under `out` (created when
/// missing; a run exported before is written again).
pub fn export(run: &Path, out: &Path, project: &str) -> anyhow::Result<Exported> {
    anyhow::ensure!(!project.trim().is_empty(), "--project: empty");
    let report = read_report(run)?;
    let scalars = scalars(&report);
    let submitted_ms = report.run.submitted_at_unix_ms;
    let run_id = run_id(&report.run.batch_id, submitted_ms);
    let started = submitted_ms.div_euclid(1000);
    let runtime = report.run.wall_time_s.unwrap_or(0.0);
    let mut config = vec![
        item("batch_id", &report.run.batch_id)?,
        item("assay_version", &report.provenance.assay_version)?,
        item("config_hash", &report.provenance.config_hash)?,
    ];
    config.extend(eval_settings(run)?);
    let mut records = vec![
        Record {
            header: Some(HeaderRecord {
                version_info: Some(VersionInfo {
                    producer: format!("assay {}", env!("CARGO_PKG_VERSION")),
                }),
            }),
            ..Default::default()
        },
        Record {
            run: Some(RunRecord {
                run_id: run_id.clone(),
                project: project.to_owned(),
                config: Some(ConfigRecord { update: config }),
                display_name: report.run.batch_id.clone(),
                notes: "Exported by `assay export wandb` from an `assay eval` run.".into(),
                tags: vec!["assay".into()],
                start_time: Some(Timestamp {
                    seconds: started,
                    nanos: (submitted_ms.rem_euclid(1000) * 1_000_000) as i32,
                }),
            }),
            ..Default::default()
        },
    ];
    let rows = history(&scalars);
    let timestamp = submitted_ms as f64 / 1000.0 + runtime;
    for (step, row) in &rows {
        let mut items = vec![
            item("_step", step)?,
            item("_runtime", &runtime)?,
            item("_timestamp", &timestamp)?,
        ];
        for s in row {
            items.push(item(&s.tag, &s.value)?);
        }
        records.push(Record {
            history: Some(HistoryRecord {
                item: items,
                step: Some(HistoryStep { num: *step }),
            }),
            ..Default::default()
        });
    }
    let mut summary = Vec::new();
    for s in last_values(&scalars) {
        summary.push(item(&s.tag, &s.value)?);
    }
    records.push(Record {
        summary: Some(SummaryRecord { update: summary }),
        ..Default::default()
    });
    records.push(Record {
        exit: Some(RunExitRecord {
            exit_code: 0,
            runtime: runtime.round() as i32,
        }),
        ..Default::default()
    });
    let mut log = Log::new();
    for (i, mut r) in records.into_iter().enumerate() {
        r.num = i as i64 + 1;
        log.append(&r.encode_to_vec());
    }
    let dir = out.join(format!("offline-run-{}-{run_id}", utc_stamp(started)));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let file = dir.join(format!("run-{run_id}.wandb"));
    std::fs::write(&file, log.bytes).with_context(|| format!("writing {}", file.display()))?;
    Ok(Exported {
        dir,
        run_id,
        scalars: scalars.len(),
        steps: rows.len(),
    })
}

/// A config, history or summary item: `key` and its value as JSON.
fn item(key: &str, value: &impl serde::Serialize) -> anyhow::Result<Item> {
    Ok(Item {
        key: key.to_owned(),
        value_json: serde_json::to_string(value).with_context(|| format!("{key}: not JSON"))?,
    })
}

/// The `[eval]` table of the run's resolved configuration (`config.toml`), key by key; none
/// when the run has no such file (a run of an older Assay).
fn eval_settings(run: &Path) -> anyhow::Result<Vec<Item>> {
    let path = run.join("config.toml");
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(Vec::new());
    };
    let table: toml::Table =
        toml::from_str(&text).with_context(|| format!("reading {}", path.display()))?;
    let Some(eval) = table.get("eval").and_then(|e| e.as_table()) else {
        return Ok(Vec::new());
    };
    eval.iter().map(|(k, v)| item(k, v)).collect()
}

/// The scalars grouped by step, steps ascending (W&B's history only moves forward).
fn history(scalars: &[Scalar]) -> Vec<(i64, Vec<&Scalar>)> {
    let mut steps: Vec<i64> = scalars.iter().map(|s| s.step).collect();
    steps.sort_unstable();
    steps.dedup();
    steps
        .into_iter()
        .map(|step| (step, scalars.iter().filter(|s| s.step == step).collect()))
        .collect()
}

/// Each tag's value at its last step.
fn last_values(scalars: &[Scalar]) -> Vec<&Scalar> {
    let mut last: Vec<&Scalar> = Vec::new();
    for s in scalars {
        match last.iter_mut().find(|l| l.tag == s.tag) {
            Some(l) if l.step <= s.step => *l = s,
            Some(_) => {}
            None => last.push(s),
        }
    }
    last
}

/// 8 characters of `[0-9a-z]`, as W&B's run ids, from the batch id and its submission time.
fn run_id(batch_id: &str, submitted_ms: i64) -> String {
    let hex = assay_spec::hash::sha256_hex(format!("{batch_id}\n{submitted_ms}").as_bytes());
    let mut n = u64::from_str_radix(&hex[..16], 16).expect("hex digits");
    (0..8)
        .map(|_| {
            let c = b"0123456789abcdefghijklmnopqrstuvwxyz"[(n % 36) as usize];
            n /= 36;
            c as char
        })
        .collect()
}

/// `YYYYMMDD_HHMMSS` of a Unix time, UTC (W&B's run folders name local time; UTC keeps an
/// export the same wherever it runs), from the report's own UTC formatting.
fn utc_stamp(unix_s: i64) -> String {
    let digits: String = assay_report::tables::utc(unix_s * 1000)
        .chars()
        .filter(char::is_ascii_digit)
        .collect();
    format!("{}_{}", &digits[..8], &digits[8..])
}

/// W&B's transaction log: the file header, then records in LevelDB's block format.
struct Log {
    bytes: Vec<u8>,
}

impl Log {
    fn new() -> Self {
        let mut bytes = b":W&B".to_vec();
        bytes.extend_from_slice(&0xBEE1u16.to_le_bytes());
        bytes.push(0);
        Self { bytes }
    }

    /// Appends one record, split into chunks at block boundaries.
    fn append(&mut self, mut data: &[u8]) {
        let mut first = true;
        loop {
            let left = BLOCK - self.bytes.len() % BLOCK;
            if left < CHUNK_HEADER {
                self.bytes.resize(self.bytes.len() + left, 0);
                continue;
            }
            let room = left - CHUNK_HEADER;
            let n = data.len().min(room);
            let last = n == data.len();
            let kind = match (first, last) {
                (true, true) => FULL,
                (true, false) => FIRST,
                (false, false) => MIDDLE,
                (false, true) => LAST,
            };
            let mut checked = vec![kind];
            checked.extend_from_slice(&data[..n]);
            self.bytes.extend_from_slice(&crc32(&checked).to_le_bytes());
            self.bytes.extend_from_slice(&(n as u16).to_le_bytes());
            self.bytes.extend_from_slice(&checked);
            data = &data[n..];
            first = false;
            if last {
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reads the log back as its format says: the records' bytes, checksums checked.
    fn read(bytes: &[u8]) -> Vec<Vec<u8>> {
        assert_eq!(&bytes[..7], b":W&B\xe1\xbe\x00");
        let (mut pos, mut out, mut record) = (7, Vec::new(), Vec::new());
        while pos < bytes.len() {
            let left = BLOCK - pos % BLOCK;
            if left < CHUNK_HEADER {
                assert!(bytes[pos..pos + left].iter().all(|&b| b == 0));
                pos += left;
                continue;
            }
            let crc = u32::from_le_bytes(bytes[pos..pos + 4].try_into().unwrap());
            let n = usize::from(u16::from_le_bytes([bytes[pos + 4], bytes[pos + 5]]));
            assert!(CHUNK_HEADER + n <= left, "a chunk crosses a block");
            assert_eq!(crc, crc32(&bytes[pos + 6..pos + 7 + n]));
            record.extend_from_slice(&bytes[pos + 7..pos + 7 + n]);
            if matches!(bytes[pos + 6], FULL | LAST) {
                out.push(std::mem::take(&mut record));
            }
            pos += CHUNK_HEADER + n;
        }
        assert!(record.is_empty(), "a record left unfinished");
        out
    }

    #[test]
    fn records_of_any_size_come_back_across_block_boundaries() {
        let sizes = [0, 10, BLOCK - 14 - 3, 5, BLOCK * 2 + 123, 1, 40_000, 3];
        let records: Vec<Vec<u8>> = sizes
            .iter()
            .enumerate()
            .map(|(i, &n)| (0..n).map(|j| (i * 31 + j * 7) as u8).collect())
            .collect();
        let mut log = Log::new();
        for r in &records {
            log.append(r);
        }
        assert_eq!(read(&log.bytes), records);
    }

    #[test]
    fn stamps_ids_and_rows() {
        assert_eq!(utc_stamp(0), "19700101_000000");
        // 2026-11-27 07:48:02 UTC, the folder of a real offline run of wandb 0.30.
        assert_eq!(utc_stamp(1_795_765_682), "20261127_074802");
        assert_eq!(utc_stamp(951_782_400), "20000229_000000");
        let id = run_id("b00001-f77e37", 1);
        assert_eq!(id.len(), 8);
        assert!(
            id.bytes()
                .all(|c| c.is_ascii_digit() || c.is_ascii_lowercase())
        );
        assert_eq!(id, run_id("b00001-f77e37", 1));
        assert_ne!(id, run_id("b00001-f77e37", 2));
        let s = |tag: &str, step, value| Scalar {
            tag: tag.into(),
            step,
            value,
        };
        let scalars = [s("a", 8, 1.0), s("b", 0, 2.0), s("a", 4, 3.0)];
        let rows = history(&scalars);
        let steps: Vec<i64> = rows.iter().map(|r| r.0).collect();
        assert_eq!(steps, [0, 4, 8]);
        let last: Vec<(&str, f64)> = last_values(&scalars)
            .iter()
            .map(|s| (s.tag.as_str(), s.value))
            .collect();
        assert_eq!(last, [("a", 1.0), ("b", 2.0)]);
    }
}
