//! One page per task in `report.html` (a section shown by CSS `:target`): its scene views,
//! keyframes, scores and episodes, with downscaled thumbnails as `data:` URIs; and the index of
//! tasks.

use std::fmt::Write as _;

use super::*;

pub(super) fn judges_of(report: &Report) -> Vec<&str> {
    report
        .results
        .quality
        .as_ref()
        .map(|q| q.judges.iter().map(|j| j.judge.as_str()).collect())
        .unwrap_or_default()
}

pub(super) fn task_quality<'a>(report: &'a Report, task: &str) -> Vec<&'a TaskQuality> {
    report
        .results
        .quality
        .as_ref()
        .map(|q| q.tasks.iter().filter(|t| t.task_id == task).collect())
        .unwrap_or_default()
}

pub(super) fn task_index(report: &Report) -> String {
    let judges = judges_of(report);
    let mut out = String::from(
        "<section id=\"tasks\">\n<h2>Tasks</h2>\n<p class=\"caption\">Open a task for its scene \
         views, keyframes and scores. Judge columns: mean scene alignment (1–5) / mean \
         completion (0–10).</p>\n<table>\n<tr><th>task</th><th>group</th><th>success</th>",
    );
    for j in &judges {
        let _ = write!(out, "<th>{}</th>", esc(j));
    }
    out.push_str("</tr>\n");
    for t in &report.results.tasks {
        let _ = write!(
            out,
            "<tr><td><a href=\"#{}\">{}</a></td><td>{}</td><td class=\"n\">{}</td>",
            task_anchor(&t.id),
            esc(&t.id),
            esc(&t.group),
            prop(&t.success)
        );
        let tq = task_quality(report, &t.id);
        for j in &judges {
            let cell = tq.iter().find(|q| q.judge == *j).map_or("–".into(), |q| {
                format!(
                    "{} / {}",
                    num(q.scene_alignment.mean, 1),
                    num(q.completion.mean, 1)
                )
            });
            let _ = write!(out, "<td class=\"n\">{cell}</td>");
        }
        out.push_str("</tr>\n");
    }
    out.push_str("</table>\n</section>\n");
    out
}

pub(super) fn task_page(inputs: &HtmlInputs<'_>, t: &TaskResult) -> String {
    let mut out = format!(
        "<section class=\"task\" id=\"{}\">\n<h2>Task {}</h2>\n<p><a href=\"#tasks\">← all \
         tasks</a></p>\n<table>\n",
        task_anchor(&t.id),
        esc(&t.name)
    );
    for (k, v) in [
        ("id", &t.id),
        ("name", &t.name),
        ("group", &t.group),
        ("pipeline", &t.pipeline),
        ("origin", &t.origin),
        ("spec hash", &t.spec_hash),
    ] {
        let _ = writeln!(out, "<tr><th>{k}</th><td>{}</td></tr>", esc(v));
    }
    let _ = writeln!(
        out,
        "<tr><th>success</th><td>{}</td></tr>\n</table>",
        prop(&t.success)
    );
    if t.by_policy.len() > 1 {
        out.push_str("<h3>Success by policy</h3>\n<table>\n");
        for p in &t.by_policy {
            let _ = writeln!(
                out,
                "<tr><td>{}</td><td class=\"n\">{}</td></tr>",
                esc(&p.policy),
                prop(&p.success)
            );
        }
        out.push_str("</table>\n");
    }
    if !t.predicates.is_empty() {
        out.push_str(
            "<h3>Goal predicates</h3>\n<table>\n<tr><th>predicate</th><th>held</th></tr>\n",
        );
        for p in &t.predicates {
            let _ = writeln!(
                out,
                "<tr><td><code>{}</code></td><td class=\"n\">{} / {}</td></tr>",
                esc(&p.label),
                p.holds,
                p.of
            );
        }
        out.push_str("</table>\n");
    }
    match t
        .episodes
        .iter()
        .find_map(|e| e.imagery.as_ref().map(|i| (e, i)))
    {
        Some((e, imagery)) => {
            let _ = writeln!(
                out,
                "<h3>Pictures of episode seed {}, policy {}</h3>",
                e.seed,
                esc(&e.policy)
            );
            out.push_str(&pictures(inputs, imagery));
        }
        None => out
            .push_str("<p class=\"absent\">No pictures: the batch did not render this task.</p>\n"),
    }
    let tq = task_quality(inputs.report, &t.id);
    if !tq.is_empty() {
        out.push_str(
            "<h3>Judges</h3>\n<table>\n<tr><th>judge</th><th>scene alignment (1–5)</th>\
                      <th>completion (0–10)</th><th>unjudged</th><th>errors</th></tr>\n",
        );
        for q in &tq {
            let _ = writeln!(
                out,
                "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
                 <td class=\"n\">{}</td><td>{}</td></tr>",
                esc(&q.judge),
                score(&q.scene_alignment),
                score(&q.completion),
                q.unjudged,
                esc(&q.errors.join("; "))
            );
        }
        out.push_str("</table>\n");
    }
    let failed: Vec<_> = t.episodes.iter().filter(|e| !e.success).collect();
    if !failed.is_empty() {
        out.push_str(
            "<h3>Unsuccessful episodes</h3>\n<table>\n<tr><th>seed</th><th>policy</th>\
                      <th>unmet predicates</th></tr>\n",
        );
        for e in failed {
            let unmet: Vec<String> = e
                .unmet
                .iter()
                .map(|p| format!("<code>{}</code>: {}", esc(&p.label), esc(&p.detail)))
                .collect();
            let _ = writeln!(
                out,
                "<tr><td class=\"n\">{}</td><td>{}</td><td>{}</td></tr>",
                e.seed,
                esc(&e.policy),
                unmet.join("<br>")
            );
        }
        out.push_str("</table>\n");
    }
    if !t.failures.is_empty() {
        out.push_str(
            "<h3>Episodes that did not finish</h3>\n<table>\n<tr><th>seed</th>\
                      <th>policy</th><th>attempts</th><th>error</th></tr>\n",
        );
        for f in &t.failures {
            let _ = writeln!(
                out,
                "<tr><td class=\"n\">{}</td><td>{}</td><td class=\"n\">{}</td><td>{}{}</td></tr>",
                f.seed,
                esc(&f.policy),
                f.attempts,
                if f.cancelled { "(cancelled) " } else { "" },
                esc(&f.error)
            );
        }
        out.push_str("</table>\n");
    }
    out.push_str("</section>\n");
    out
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

pub(super) fn pictures(inputs: &HtmlInputs<'_>, imagery: &EpisodeImagery) -> String {
    let mut out = String::from("<h4>Initial scene</h4>\n<div>\n");
    for v in &imagery.views {
        out.push_str(&thumb_figure(inputs, &v.artifact, &v.name));
    }
    out.push_str("</div>\n<h4>Keyframes</h4>\n<div>\n");
    for i in spaced(imagery.keyframes.len(), KEYFRAMES_SHOWN) {
        let k = &imagery.keyframes[i];
        let caption = format!("step {} ({}), goals met {}", k.step, k.camera, k.goals_met);
        out.push_str(&thumb_figure(inputs, &k.artifact, &caption));
    }
    out.push_str("</div>\n");
    if imagery.keyframes.len() > KEYFRAMES_SHOWN {
        let _ = writeln!(
            out,
            "<p class=\"caption\">{KEYFRAMES_SHOWN} of {} keyframes shown.</p>",
            imagery.keyframes.len()
        );
    }
    out
}

pub(super) fn thumb_figure(inputs: &HtmlInputs<'_>, key: &str, caption: &str) -> String {
    let body = match (inputs.artifact)(key) {
        None => format!(
            "<span class=\"missing\">(artifact missing: {})</span>",
            esc(key)
        ),
        Some(bytes) => match thumbnail(&bytes, THUMB_WIDTH) {
            Ok((png, w, h)) => format!(
                "<img src=\"data:image/png;base64,{}\" width=\"{w}\" height=\"{h}\" alt=\"{}\">",
                base64::engine::general_purpose::STANDARD.encode(png),
                esc(caption)
            ),
            Err(why) => format!(
                "<span class=\"missing\">(image format not shown: {})</span>",
                esc(&why)
            ),
        },
    };
    format!(
        "<figure class=\"thumb\">{body}<figcaption>{}</figcaption></figure>\n",
        esc(caption)
    )
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
