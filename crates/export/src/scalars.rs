//! A run's figures as named scalars, the common ground of the TensorBoard and W&B exports.
//!
//! Tags (`/` nests them in TensorBoard's sidebar and W&B's panel sections; steps are 0 unless
//! said):
//! - `success/<policy>` and `success/<group>/<policy>`: ground-truth success rates;
//! - `quality/<judge>/scene_alignment`, `quality/<judge>/completion`: mean judge scores, and
//!   `quality/<judge>/vs_sim_pearson_r` where defined;
//! - `diversity/text/<model>/<group>`: text diversity (eq. 1);
//! - `diversity/dynamics/<group>/eval_image_mse` and `.../train_loss`, at step = the budget
//!   (episodes trained on): the paper's diversity-against-budget curve;
//! - `ranking/<policy>/real` and `ranking/<policy>/<source>`: real and predicted success;
//! - `generalization/<group>/train` and `generalization/<group>/held_out`.
//!
//! Owns: the names. Reads a report; writes nothing.

use assay_report::report::Report;

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
