//! One page per task in `report.html` (a section shown by CSS `:target`): its scene views,
//! keyframes, scores and episodes, with downscaled thumbnails as `data:` URIs; and the index of
//! tasks.

use base64::Engine as _;

use super::*;
use crate::quality::TaskQuality;
use crate::report::TaskResult;
use crate::tables;
use crate::view::{proportion, score};
use assay_model::episode::EpisodeImagery;

fn task_quality<'a>(report: &'a Report, task: &str) -> Vec<&'a TaskQuality> {
    report
        .results
        .quality
        .as_ref()
        .map(|q| q.tasks.iter().filter(|t| t.task_id == task).collect())
        .unwrap_or_default()
}

pub(super) fn task_index(report: &Report) -> Markup {
    html! {
        section id="tasks" {
            h2 { "Tasks" }
            p.caption {
                "Open a task for its scene views, keyframes and scores; its judges' scores are \
                 also in the table below it."
            }
            (table(&tables::success_per_task(&report.results)))
            @if let Some(q) = &report.results.quality {
                h3 { "Quality per task" }
                (table(&tables::quality_per_task(q)))
            }
        }
    }
}

pub(super) fn task_page(inputs: &HtmlInputs<'_>, t: &TaskResult) -> Markup {
    let pictured = t
        .episodes
        .iter()
        .find_map(|e| e.imagery.as_ref().map(|i| (e, i)));
    let judged = task_quality(inputs.report, &t.id);
    let failed: Vec<_> = t.episodes.iter().filter(|e| !e.success).collect();
    let labels = inputs.report.results.policy_labels();
    let policy = |name: &str| cell(&Cell::policy(name, labels));
    html! {
        section class="task" id=(task_anchor(&t.id)) {
            h2 { "Task " (t.name) }
            p { a href="#tasks" { "← all tasks" } }
            table {
                @for (k, v) in [
                    ("id", &t.id),
                    ("name", &t.name),
                    ("group", &t.group),
                    ("pipeline", &t.pipeline),
                    ("origin", &t.origin),
                    ("spec hash", &t.spec_hash),
                ] {
                    tr { th { (k) } td { (v) } }
                }
                tr { th { "success" } td { (cell(&proportion(&t.success))) } }
            }
            @if t.by_policy.len() > 1 {
                h3 { "Success by policy" }
                table {
                    @for p in inputs.report.results.shown(&t.by_policy, |p| &p.policy) {
                        tr { td { (policy(&p.policy)) } td.n { (cell(&proportion(&p.success))) } }
                    }
                }
            }
            @if !t.predicates.is_empty() {
                h3 { "Goal predicates" }
                table {
                    tr { th { "predicate" } th { "held" } }
                    @for p in &t.predicates {
                        tr { td { code { (p.label) } } td.n { (p.holds) " / " (p.of) } }
                    }
                }
            }
            @match pictured {
                Some((e, imagery)) => {
                    h3 { "Pictures of episode seed " (e.seed) ", policy " (policy(&e.policy)) }
                    (pictures(inputs, imagery))
                },
                None => p.absent { "No pictures: the batch did not render this task." },
            }
            @let videos: Vec<_> = t.episodes.iter()
                .filter_map(|e| e.imagery.as_ref()?.video.as_ref().map(|v| (e, v)))
                .collect();
            @if !videos.is_empty() {
                h3 { "Episode videos" }
                p {
                    @for (i, (e, v)) in videos.iter().enumerate() {
                        @if i > 0 { " · " }
                        a href={ "artifacts/" (v) } { "seed " (e.seed) ", " (policy(&e.policy)) }
                    }
                }
            }
            @if !judged.is_empty() {
                h3 { "Judges" }
                table {
                    tr {
                        th { "judge" } th { "scene alignment (1–5)" } th { "completion (0–10)" }
                        th { "completion variance over repeats" }
                        th { "completion variance over episodes" }
                        th { "unjudged" } th { "errors" }
                    }
                    @for q in &judged {
                        tr {
                            td { (q.judge) }
                            td.n { (cell(&score(q.scene_alignment.mean, q.scene_alignment.variance, q.scene_alignment.n))) }
                            td.n { (cell(&score(q.completion.mean, q.completion.variance, q.completion.n))) }
                            @for v in [q.completion_split.over_repeats, q.completion_split.over_episodes] {
                                td.n { @match v { Some(v) => (format!("{v:.3}")), None => "n/a" } }
                            }
                            td.n { (q.unjudged) }
                            td { (q.errors.join("; ")) }
                        }
                    }
                }
            }
            @if let Some(reward) = crate::tables::generator_reward(&t.episodes) {
                h3 { "The generator's own reward" }
                p {
                    "Mean " (reward) ", beside success: its goals checked in order, each met once counted for good, partial reward for the share of a goal's objects in place."
                }
                table {
                    tr { th { "seed" } th { "policy" } th { "success" } th { "reward" } th { "steps met" } }
                    @for e in t.episodes.iter().filter(|e| e.generator_reward.is_some()) {
                        @let g = e.generator_reward.as_ref().expect("filtered");
                        tr {
                            td.n { (e.seed) }
                            td { (policy(&e.policy)) }
                            td { @if e.success { "yes" } @else { "no" } }
                            td.n { (format!("{:.3} of {:.3}", g.value, g.max)) }
                            td.n { (g.steps_met) " of " (g.steps) }
                        }
                    }
                }
            }
            @if !failed.is_empty() {
                h3 { "Unsuccessful episodes" }
                table {
                    tr { th { "seed" } th { "policy" } th { "unmet predicates" } }
                    @for e in failed {
                        tr {
                            td.n { (e.seed) }
                            td { (policy(&e.policy)) }
                            td {
                                @for (i, p) in e.unmet.iter().enumerate() {
                                    @if i > 0 { br; }
                                    code { (p.label) } ": " (p.detail)
                                }
                                @if let Some(why) = &e.cutoff {
                                    @if !e.unmet.is_empty() { br; }
                                    (why)
                                }
                            }
                        }
                    }
                }
            }
            @if !t.failures.is_empty() {
                h3 { "Episodes that did not finish" }
                table {
                    tr { th { "seed" } th { "policy" } th { "attempts" } th { "error" } }
                    @for f in &t.failures {
                        tr {
                            td.n { (f.seed) }
                            td { (policy(&f.policy)) }
                            td.n { (f.attempts) }
                            td { @if f.cancelled { "(cancelled) " } (f.error) }
                        }
                    }
                }
            }
        }
    }
}

/// Indices of `shown` of `n` items, evenly spaced, first and last included.
pub(super) fn spaced(n: usize, shown: usize) -> Vec<usize> {
    if n <= shown {
        return (0..n).collect();
    }
    if shown <= 1 {
        return vec![n - 1];
    }
    (0..shown).map(|i| i * (n - 1) / (shown - 1)).collect()
}

fn pictures(inputs: &HtmlInputs<'_>, imagery: &EpisodeImagery) -> Markup {
    html! {
        h4 { "Initial scene" }
        div { @for v in &imagery.views { (thumb_figure(inputs, &v.artifact, &v.name)) } }
        h4 { "Keyframes" }
        div {
            @for i in spaced(imagery.keyframes.len(), KEYFRAMES_SHOWN) {
                @let k = &imagery.keyframes[i];
                (thumb_figure(
                    inputs,
                    &k.artifact,
                    &format!("step {} ({}), goals met {}", k.step, k.camera, k.goals_met),
                ))
            }
        }
        @if imagery.keyframes.len() > KEYFRAMES_SHOWN {
            p.caption { (KEYFRAMES_SHOWN) " of " (imagery.keyframes.len()) " keyframes shown." }
        }
    }
}

pub(super) fn thumb_figure(inputs: &HtmlInputs<'_>, key: &str, caption: &str) -> Markup {
    html! {
        figure.thumb {
            @match (inputs.artifact)(key).map(|bytes| thumbnail(&bytes, THUMB_WIDTH)) {
                None => span.missing { "(artifact missing: " (key) ")" },
                Some(Ok((png, w, h))) => img
                    src={ "data:image/png;base64," (base64::engine::general_purpose::STANDARD.encode(png)) }
                    width=(w) height=(h) alt=(caption);,
                Some(Err(why)) => span.missing { "(image format not shown: " (why) ")" },
            }
            figcaption { (caption) }
        }
    }
}

/// A figure of a raw RGB frame `w`×`h` (row-major bytes), as a PNG at most [`THUMB_WIDTH`] wide.
pub(super) fn rgb_figure(rgb: &[u8], w: u32, h: u32, caption: &str) -> Markup {
    let encoded = (|| -> Result<(Vec<u8>, u32, u32), String> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, w, h);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut writer = enc.write_header().map_err(|e| e.to_string())?;
            writer.write_image_data(rgb).map_err(|e| e.to_string())?;
            writer.finish().map_err(|e| e.to_string())?;
        }
        // Downscaled only when wider than a thumbnail (a clip's frames are 64 px).
        if w > THUMB_WIDTH {
            thumbnail(&out, THUMB_WIDTH)
        } else {
            Ok((out, w, h))
        }
    })();
    html! {
        figure.thumb {
            @match encoded {
                Ok((png, w, h)) => img
                    src={ "data:image/png;base64," (base64::engine::general_purpose::STANDARD.encode(png)) }
                    width=(w) height=(h) alt=(caption);,
                Err(why) => span.missing { "(frame not shown: " (why) ")" },
            }
            figcaption { (caption) }
        }
    }
}

/// A PNG downscaled (box filter) to at most `width` pixels wide, re-encoded as PNG, with its
/// size; 8-bit greyscale, greyscale with alpha, RGB and RGBA are kept as they are; any other
/// format is an error that says which.
pub fn thumbnail(bytes: &[u8], width: u32) -> Result<(Vec<u8>, u32, u32), String> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
    let size = reader
        .output_buffer_size()
        .ok_or("image too large".to_owned())?;
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    if info.bit_depth != png::BitDepth::Eight {
        return Err(format!("{:?}-bit {:?}", info.bit_depth, info.color_type));
    }
    let channels: usize = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        other => return Err(format!("{other:?}")),
    };
    let (w, h) = (info.width as usize, info.height as usize);
    if w == 0 || h == 0 {
        return Err("empty image".into());
    }
    let tw = (width as usize).min(w).max(1);
    let th = ((h * tw + w / 2) / w).max(1);
    let mut small = vec![0u8; tw * th * channels];
    for oy in 0..th {
        let (y0, y1) = (oy * h / th, ((oy + 1) * h / th).max(oy * h / th + 1));
        for ox in 0..tw {
            let (x0, x1) = (ox * w / tw, ((ox + 1) * w / tw).max(ox * w / tw + 1));
            let count = ((y1 - y0) * (x1 - x0)) as u32;
            for c in 0..channels {
                let mut sum = 0u32;
                for y in y0..y1 {
                    let row = &buf[y * info.line_size..];
                    for x in x0..x1 {
                        sum += u32::from(row[x * channels + c]);
                    }
                }
                small[(oy * tw + ox) * channels + c] = ((sum + count / 2) / count) as u8;
            }
        }
    }
    let mut png_out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut png_out, tw as u32, th as u32);
        enc.set_color(info.color_type);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::High);
        let mut writer = enc.write_header().map_err(|e| e.to_string())?;
        writer.write_image_data(&small).map_err(|e| e.to_string())?;
        writer.finish().map_err(|e| e.to_string())?;
    }
    Ok((png_out, tw as u32, th as u32))
}
