//! `assay export tensorboard RUN OUT`: a run's figures as TensorBoard scalars, one event file
//! (`events.out.tfevents.*`) that `tensorboard --logdir OUT`, `tbparse` and W&B's TensorBoard
//! sync read.
//!
//! Tags (`/` nests them in TensorBoard's sidebar; steps are 0 unless said):
//! - `success/<policy>` and `success/<group>/<policy>`: ground-truth success rates;
//! - `quality/<judge>/scene_alignment`, `quality/<judge>/completion`: mean judge scores, and
//!   `quality/<judge>/vs_sim_pearson_r` where defined;
//! - `diversity/text/<model>/<group>`: text diversity (eq. 1);
//! - `diversity/dynamics/<group>/eval_image_mse` and `.../train_loss`, at step = the budget
//!   (episodes trained on): the paper's diversity-against-budget curve;
//! - `ranking/<policy>/real` and `ranking/<policy>/<source>`: real and predicted success;
//! - `generalization/<group>/train` and `generalization/<group>/held_out`.
//!
//! The file is written here, not through a TensorFlow binding: TFRecord framing (length, masked
//! CRC-32C of the length, the record, its masked CRC-32C) around `Event` protocol buffers with
//! `simple_value` summaries (tensorboard/compat/proto/event.proto, summary.proto).
//!
//! Owns: the tags and the file's encoding.

use std::path::Path;

use anyhow::Context;
use prost::Message;

use assay_report::report::Report;

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

/// One scalar: its tag, step and value.
#[derive(Debug, Clone, PartialEq)]
pub struct Scalar {
    pub tag: String,
    pub step: i64,
    pub value: f64,
}

/// The scalars of a report (see the module's docs for the tags).
pub fn scalars(report: &Report) -> Vec<Scalar> {
    let mut out = Vec::new();
    let mut push = |tag: String, step: i64, value: Option<f64>| {
        if let Some(value) = value.filter(|v| v.is_finite()) {
            out.push(Scalar { tag, step, value });
        }
    };
    let r = &report.results;
    for p in &r.by_policy {
        push(format!("success/{}", p.policy), 0, p.success.rate);
    }
    for g in &r.groups {
        for p in &g.by_policy {
            push(
                format!("success/{}/{}", g.group, p.policy),
                0,
                p.success.rate,
            );
        }
    }
    if let Some(q) = &r.quality {
        for j in &q.judges {
            push(
                format!("quality/{}/scene_alignment", j.judge),
                0,
                j.scene_alignment.mean,
            );
            push(
                format!("quality/{}/completion", j.judge),
                0,
                j.completion.mean,
            );
            push(
                format!("quality/{}/vs_sim_pearson_r", j.judge),
                0,
                j.vs_sim.as_ref().and_then(|a| a.pearson.value),
            );
        }
    }
    if let Some(d) = &r.diversity {
        if let Some(t) = &d.text {
            for row in &t.rows {
                for (m, div) in t.models.iter().zip(&row.div) {
                    push(format!("diversity/text/{}/{}", m.name, row.group), 0, *div);
                }
            }
        }
        for f in &d.dynamics {
            let step = i64::from(f.budget);
            push(
                format!("diversity/dynamics/{}/eval_image_mse", f.group),
                step,
                Some(f.eval_image_mse),
            );
            push(
                format!("diversity/dynamics/{}/train_loss", f.group),
                step,
                Some(f.final_train_loss),
            );
        }
    }
    if let Some(k) = &r.ranking {
        for p in &k.policies {
            push(format!("ranking/{}/real", p.policy), 0, p.real.rate);
            for s in &p.predicted {
                push(
                    format!("ranking/{}/{}", p.policy, s.source),
                    0,
                    s.success.rate,
                );
            }
        }
    }
    if let Some(g) = &r.generalization {
        for row in &g.groups {
            push(
                format!("generalization/{}/train", row.group),
                0,
                row.train.rate,
            );
            push(
                format!("generalization/{}/held_out", row.group),
                0,
                row.held_out.rate,
            );
        }
    }
    out
}

/// Writes `run`'s report as an event file in `out` (created when missing); the file's path and
/// the number of scalars.
pub fn export(run: &Path, out: &Path) -> anyhow::Result<(std::path::PathBuf, usize)> {
    let path = run.join("report.json");
    let report: Report = serde_json::from_slice(&std::fs::read(&path).with_context(|| {
        format!(
            "{} is not an `assay eval` output folder (no report.json)",
            run.display()
        )
    })?)
    .with_context(|| format!("reading {}", path.display()))?;
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

/// CRC-32C (Castagnoli, reflected polynomial 0x82F63B78), bit by bit: event files are small.
fn crc32c(data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in data {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0x82F6_3B78
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_and_its_mask_match_the_published_check_values() {
        // The CRC-32C check value (RFC 3720 B.4 lists the algorithm; "123456789" is the
        // catalogue's check string).
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
        assert_eq!(crc32c(&[0u8; 32]), 0x8A91_36AA);
        // Masking as TensorFlow's crc32c::Mask: rotate right by 15, add 0xa282ead8
        // (0xE3069283 -> 0xC78AB0E5, worked by hand).
        assert_eq!(masked_crc(b"123456789"), 0xC78A_B0E5);
    }
}
