//! `assay export tensorboard RUN OUT`: a run's figures ([`crate::scalars`]) as TensorBoard
//! scalars, one event file (`events.out.tfevents.*`) that `tensorboard --logdir OUT` and `tbparse`
//! read.
//!
//! The file is written here, not through a TensorFlow binding: TFRecord framing (length, masked
//! CRC-32C of the length, the record, its masked CRC-32C) around `Event` protocol buffers with
//! `simple_value` summaries (tensorboard/compat/proto/event.proto, summary.proto).
//!
//! Owns: the file's encoding.

use std::path::Path;

use anyhow::Context;
use prost::Message;

use crate::crc::crc32c;
use crate::read_report;
use crate::scalars::scalars;

/// `tensorflow.Event`, the fields a scalar file uses.
#[derive(Clone, PartialEq, prost::Message)]
struct Event {
    #[prost(double, tag = "1")]
    wall_time: f64,
    #[prost(int64, tag = "2")]
    step: i64,
    #[prost(string, optional, tag = "3")]
    file_version: Option<String>,
    #[prost(message, optional, tag = "5")]
    summary: Option<Summary>,
}

/// `tensorflow.Summary`.
#[derive(Clone, PartialEq, prost::Message)]
struct Summary {
    #[prost(message, repeated, tag = "1")]
    value: Vec<SummaryValue>,
}

/// `tensorflow.Summary.Value` with a `simple_value`.
#[derive(Clone, PartialEq, prost::Message)]
struct SummaryValue {
    #[prost(string, tag = "1")]
    tag: String,
    #[prost(float, tag = "2")]
    simple_value: f32,
}

/// Writes `run`'s report as an event file in `out` (created when missing); the file's path and
/// the number of scalars.
pub fn export(run: &Path, out: &Path) -> anyhow::Result<(std::path::PathBuf, usize)> {
    let report = read_report(run)?;
    let scalars = scalars(&report);
    // One wall time for the whole file: the run's, so that exporting twice gives the same file.
    let wall_time = report.run.submitted_at_unix_ms as f64 / 1000.0;
    let mut bytes = Vec::new();
    record(
        &mut bytes,
        &Event {
            wall_time,
            step: 0,
            file_version: Some("brain.Event:2".into()),
            summary: None,
        }
        .encode_to_vec(),
    );
    for s in &scalars {
        record(
            &mut bytes,
            &Event {
                wall_time,
                step: s.step,
                file_version: None,
                summary: Some(Summary {
                    value: vec![SummaryValue {
                        tag: s.tag.clone(),
                        simple_value: s.value as f32,
                    }],
                }),
            }
            .encode_to_vec(),
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let file = out.join(format!(
        "events.out.tfevents.{:010}.assay.{}",
        report.run.submitted_at_unix_ms / 1000,
        report.run.batch_id
    ));
    std::fs::write(&file, bytes).with_context(|| format!("writing {}", file.display()))?;
    Ok((file, scalars.len()))
}

/// Appends one TFRecord: length, its masked CRC-32C, the data, its masked CRC-32C.
fn record(out: &mut Vec<u8>, data: &[u8]) {
    let len = (data.len() as u64).to_le_bytes();
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc(&len).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked_crc(data).to_le_bytes());
}

/// TFRecord's masked CRC-32C.
fn masked_crc(data: &[u8]) -> u32 {
    let c = crc32c(data);
    c.rotate_right(15).wrapping_add(0xa282_ead8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_mask_matches_tensorflows() {
        // Masking as TensorFlow's crc32c::Mask: rotate right by 15, add 0xa282ead8
        // (0xE3069283 -> 0xC78AB0E5, worked by hand).
        assert_eq!(masked_crc(b"123456789"), 0xC78A_B0E5);
    }
}
