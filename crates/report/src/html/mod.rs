//! `report.html`: one self-contained page with the paper's views of a batch — per-group success,
//! scene alignment against completion (figure 4), judge agreement (figure 3), text and dynamics
//! diversity (Tables 1 and 2), generalization (Table 3), policy ranking, invalid tasks, and one
//! page per task with its scene views, keyframes and scores.
//!
//! Owns: the page, written with `maud` templates (every text escaped unless marked otherwise;
//! only the SVG figures are inserted as they are). Its tables are [`crate::tables`], the same
//! that report.md shows. Never fetches anything and never makes the browser fetch anything:
//! figures are inline SVG ([`crate::figures`]), pictures are `data:` URIs of downscaled
//! thumbnails, there is no script and no external font or style; the per-task "pages" are
//! sections shown by CSS `:target`. Never does IO itself: artifacts come through
//! [`HtmlInputs::artifact`]. Deterministic: the same inputs give the same bytes.

use maud::{DOCTYPE, Markup, PreEscaped, html};

use crate::report::Report;
use crate::view::{Cell, Span, Table};
use assay_stats::agreement::AgreementTable;

mod overview;
mod sections;
mod tasks;

use overview::{header, imports, invalid, overview};
use sections::{figure_3, figure_4, ranking, table_1, table_2, table_3};
pub use tasks::thumbnail;
use tasks::{task_index, task_page};

/// What the page is made from.
pub struct HtmlInputs<'a> {
    pub report: &'a Report,
    /// Bytes of an artifact by its key (`imagery/<sha>.png`), None when missing (the page then
    /// says so, no broken `<img>`).
    pub artifact: &'a dyn Fn(&str) -> Option<Vec<u8>>,
    /// Human ratings agreement (figure 3), when the user gave ratings.
    pub human: Option<&'a AgreementTable>,
}

/// Width of the thumbnails, pixels.
pub const THUMB_WIDTH: u32 = 192;

/// Keyframes shown per task (of the 8 a render role draws), evenly spaced, the last included.
pub const KEYFRAMES_SHOWN: usize = 8;

const STYLE: &str = "\
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:0 auto;max-width:1200px;\
padding:0 16px 48px;color:#1a1a1a;background:#fff;line-height:1.4}\
header{border-bottom:1px solid #ccc;padding:8px 0}\
nav{position:sticky;top:0;background:#f6f6f6;border-bottom:1px solid #ccc;padding:6px 8px;\
z-index:1}nav a{margin-right:14px}\
table{border-collapse:collapse;margin:8px 0 16px;display:block;max-width:100%;overflow-x:auto}\
th,td{border:1px solid #ddd;padding:3px 8px;text-align:left;vertical-align:top}\
td.n,th.n{text-align:right;font-variant-numeric:tabular-nums}th{background:#f2f2f2}\
.fig{margin:8px 0}.fig svg{max-width:100%}.row{display:flex;flex-wrap:wrap;gap:16px;\
align-items:flex-start}\
.absent,.missing{color:#8a5a00;font-style:italic}.undefined{color:#8a5a00}\
figure.thumb{display:inline-block;margin:4px;text-align:center;font-size:12px}\
figure.thumb img{display:block;border:1px solid #ccc}\
section.task{display:none;border-top:2px solid #888;margin-top:24px}\
section.task:target{display:block}\
.imagined figure.thumb img{width:128px;height:auto;image-rendering:pixelated}\
.ok{color:#1a7f37}.fail{color:#b3261e}caption,.caption{font-size:13px;color:#444;\
text-align:left;max-width:680px}";

/// The sections and their titles in the navigation bar.
const NAV: [(&str, &str); 10] = [
    ("overview", "Overview"),
    ("figure-4", "Scene vs completion"),
    ("figure-3", "Judge agreement"),
    ("table-1", "Text diversity"),
    ("table-2", "Dynamics diversity"),
    ("table-3", "Generalization"),
    ("ranking", "Ranking"),
    ("invalid", "Invalid tasks"),
    ("imports", "Import"),
    ("tasks", "Tasks"),
];

/// The page.
pub fn report_html(inputs: &HtmlInputs<'_>) -> String {
    let r = &inputs.report.results;
    let page = html! {
        (DOCTYPE)
        html lang="en" {
            head {
                meta charset="utf-8";
                meta name="viewport" content="width=device-width, initial-scale=1";
                title { "Assay report: " (r.batch_name) }
                link rel="icon" href="data:,";
                style { (PreEscaped(STYLE)) }
            }
            body {
                (header(inputs.report))
                nav { @for (id, title) in NAV { a href={ "#" (id) } { (title) } } }
                main {
                    (overview(inputs.report))
                    (figure_4(r.quality.as_ref()))
                    (figure_3(r.quality.as_ref(), inputs.human))
                    (table_1(r.diversity.as_ref()))
                    (table_2(r.diversity.as_ref()))
                    (table_3(r.generalization.as_ref()))
                    (ranking(inputs, r.ranking.as_ref()))
                    (invalid(inputs.report))
                    (imports(inputs.report))
                    (task_index(inputs.report))
                    @for t in &r.tasks { (task_page(inputs, t)) }
                }
            }
        }
    };
    let mut out = page.into_string();
    out.push('\n');
    out
}

/// The id of a task's section: `task-` and the task id with every character other than ASCII
/// letters, digits, `-` and `.` written `_xx` (hex), so any id gives a distinct fragment that
/// needs no escaping.
fn task_anchor(id: &str) -> String {
    use std::fmt::Write as _;
    let mut out = String::from("task-");
    for c in id.chars() {
        if c.is_ascii_alphanumeric() || c == '-' || c == '.' {
            out.push(c);
        } else {
            let mut buf = [0u8; 4];
            for b in c.encode_utf8(&mut buf).bytes() {
                let _ = write!(out, "_{b:02x}");
            }
        }
    }
    out
}

/// A table of the report ([`crate::tables`]) as HTML: numeric columns right-aligned, a total
/// row in header cells.
fn table(t: &Table) -> Markup {
    let class = |numeric: bool| numeric.then_some("n");
    html! {
        table {
            tr { @for c in &t.columns { th { (c.title) } } }
            @for r in &t.rows {
                tr {
                    @for (c, col) in r.cells.iter().zip(&t.columns) {
                        @if r.total {
                            th class=[class(col.numeric)] { (cell(c)) }
                        } @else {
                            td class=[class(col.numeric)] { (cell(c)) }
                        }
                    }
                }
            }
        }
    }
}

/// A cell's spans as HTML.
fn cell(c: &Cell) -> Markup {
    html! {
        @for s in &c.0 {
            @match s {
                Span::Text(t) => (t),
                Span::Code(t) => code { (t) },
                Span::Strong(t) => strong { (t) },
                Span::Undefined(why) => span.undefined { "undefined — " (why) },
                Span::Missing => "–",
                Span::Break => br;,
                Span::TaskLink(id) => a href={ "#" (task_anchor(id)) } { (id) },
                Span::Abbrev { short, full } => span title=(full) { (short) },
            }
        }
    }
}

/// A table, or nothing when it has no rows.
fn table_if_any(t: &Table) -> Markup {
    html! { @if !t.rows.is_empty() { (table(t)) } }
}

/// Says a section is not in this batch, and how to get it.
fn absent(what: &str) -> Markup {
    html! { p.absent { "Not in this batch (" (what) ")." } }
}

/// An SVG string placed in the page (without an XML prolog, if the drawer wrote one).
fn inline_svg(svg: &str) -> Markup {
    let body = match svg.trim_start().strip_prefix("<?xml") {
        Some(rest) => rest.split_once("?>").map_or("", |(_, b)| b),
        None => svg,
    };
    html! { div.fig { (PreEscaped(body.trim())) } }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use base64::Engine as _;

    use super::*;
    use crate::diversity::DiversityResults;
    use crate::generalization::{EvalEpisode, GeneralizationResults, GroupGeneralization};
    use crate::quality::build_quality;
    use crate::report::RunInfo;
    use crate::report::build_results;
    use crate::testing::judged;
    use assay_model::dynamics::{DynamicsConfig, DynamicsFit};
    use assay_model::episode::EpisodeImagery;
    use assay_model::episode::{
        EpisodeOutcome, Keyframe, LabelSource, NamedArtifact, PredicateValue, ShardRecord, TaskInfo,
    };
    use assay_stats::agreement::Estimate;
    use assay_stats::agreement::{AgreementRow, agreement};
    use assay_stats::diversity::{EmbeddingModel, TextDiversityRow, TextDiversityTable};

    const EVIL: &str = "<script>alert(1)</script>";

    fn tiny_png(w: u32, h: u32, colour: png::ColorType, depth: png::BitDepth) -> Vec<u8> {
        let channels = match colour {
            png::ColorType::Grayscale => 1,
            png::ColorType::GrayscaleAlpha => 2,
            png::ColorType::Rgb => 3,
            _ => 4,
        };
        let bytes_per = if depth == png::BitDepth::Sixteen {
            2
        } else {
            1
        };
        let data: Vec<u8> = (0..w * h * channels * bytes_per)
            .map(|i| (i * 7) as u8)
            .collect();
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(colour);
        enc.set_depth(depth);
        let mut writer = enc.write_header().unwrap();
        writer.write_image_data(&data).unwrap();
        writer.finish().unwrap();
        out
    }

    fn artifact(key: &str) -> Option<Vec<u8>> {
        match key {
            "imagery/ok.png" => Some(tiny_png(4, 3, png::ColorType::Rgb, png::BitDepth::Eight)),
            "imagery/big.png" => Some(tiny_png(
                640,
                480,
                png::ColorType::Rgba,
                png::BitDepth::Eight,
            )),
            "imagery/grey.png" => Some(tiny_png(
                5,
                5,
                png::ColorType::Grayscale,
                png::BitDepth::Eight,
            )),
            "imagery/deep.png" => Some(tiny_png(2, 2, png::ColorType::Rgb, png::BitDepth::Sixteen)),
            "imagery/junk.png" => Some(b"not a png".to_vec()),
            _ => None,
        }
    }

    fn info(id: &str, name: &str, group: &str) -> TaskInfo {
        TaskInfo {
            id: id.into(),
            name: name.into(),
            group: group.into(),
            pipeline: "assay".into(),
            origin: format!("tasks/{id}.yaml"),
            spec_hash: "h".into(),
        }
    }

    fn imagery() -> EpisodeImagery {
        let views = ["ok", "missing", "grey", "deep"];
        let frames = ["big", "ok", "junk", "ok"];
        EpisodeImagery {
            adapter: "test".into(),
            views: views
                .iter()
                .map(|v| NamedArtifact {
                    name: format!("view {v}"),
                    artifact: format!("imagery/{v}.png"),
                })
                .collect(),
            keyframes: frames
                .iter()
                .enumerate()
                .map(|(i, f)| Keyframe {
                    step: i as u64 * 10,
                    camera: "front".into(),
                    artifact: format!("imagery/{f}.png"),
                    goals_met: 0,
                })
                .collect(),
            contact_sheet: "imagery/sheet.png".into(),
            video: None,
            caption: None,
            clip: None,
        }
    }

    fn outcome(task: &str, seed: u64, success: bool, pictures: bool) -> EpisodeOutcome {
        EpisodeOutcome {
            task_id: task.into(),
            seed,
            policy: "oracle".into(),
            success,
            label_source: LabelSource::Sim,
            predicates: vec![PredicateValue {
                label: "on(cube, plate)".into(),
                holds: success,
                detail: format!("distance {} m", if success { 0.01 } else { 0.3 }),
            }],
            steps: 100,
            sim_time_s: 1.0,
            artifact: format!("episodes/{task}-{seed}"),
            spec_hash: "h".into(),
            versions: BTreeMap::new(),
            imagery: pictures.then(imagery),
            cutoff: None,
            generator_reward: None,
            scenes: None,
        }
    }

    fn fit(group: &str, budget: u32, trained: u32, mse: f64) -> DynamicsFit {
        DynamicsFit {
            group: group.into(),
            budget,
            train_episodes: trained,
            eval_episodes: 6,
            eval_image_mse: mse,
            eval_proprio_mse: 0.0,
            per_episode: Vec::new(),
            episodes: Vec::new(),
            final_train_loss: 0.1,
            steps: 10,
            epochs: 1.0,
            resumed_from_step: None,
            steps_per_s: 1.0,
            libtorch: String::new(),
            device: "cpu".into(),
            config: DynamicsConfig::default(),
        }
    }

    fn generalization() -> GeneralizationResults {
        let fit = crate::testing::diffusion_fit();
        let ep = |group: &str, held_out: bool, ok: bool| EvalEpisode {
            group: group.into(),
            task_id: "a".into(),
            held_out,
            success: Some(Ok(ok)),
        };
        let eps = [
            ep("g1", false, true),
            ep("g1", false, true),
            ep("g1", true, false),
            ep("g2", false, false),
        ];
        GeneralizationResults {
            groups: vec![
                GroupGeneralization::build("g1", "policies/g1", fit.clone(), &eps),
                GroupGeneralization::build("g2", "policies/g2", fit, &eps),
            ],
            errors: vec![("g3".into(), "out of <memory>".into())],
        }
    }

    /// Two groups, three tasks (one named like a script), two judges, every section.
    fn report() -> Report {
        let tasks = vec![
            info("a", EVIL, "g1"),
            info("b c/é", "b", "g1"),
            info("c", "c", "g2"),
        ];
        let outcomes = vec![
            outcome("a", 0, true, true),
            outcome("a", 1, false, true),
            outcome("b c/é", 0, true, false),
            outcome("c", 0, false, false),
        ];
        let mut shards: Vec<ShardRecord> = outcomes
            .iter()
            .map(|o| ShardRecord {
                task_id: o.task_id.clone(),
                seed: o.seed,
                policy: o.policy.clone(),
                judge: String::new(),
                attempts: 1,
                outcome: Some(o.clone()),
                error: None,
                cancelled: false,
            })
            .collect();
        shards.push(ShardRecord {
            task_id: "c".into(),
            seed: 1,
            policy: "oracle".into(),
            judge: String::new(),
            attempts: 3,
            outcome: None,
            error: Some("worker <lost>".into()),
            cancelled: false,
        });
        let invalid = vec![assay_spec::SpecError {
            task: Some("bad".into()),
            origin: "tasks/bad.yaml".into(),
            path: "scene.objects[0]".into(),
            reason: "unknown shape <blob>".into(),
        }];
        let mut results = build_results(
            "demo & test",
            &["oracle".into()],
            &[0, 1],
            &tasks,
            &shards,
            &invalid,
        );
        let records = vec![
            judged("offline", "a", 0, &[4.0, 4.0], &[10.0, 9.0]),
            judged("offline", "a", 1, &[2.0, 3.0], &[1.0, 0.0]),
            judged("offline", "b c/é", 0, &[5.0, 5.0], &[8.0, 8.0]),
            judged("offline", "c", 0, &[1.0, 1.0], &[2.0, 2.0]),
            judged("vlm", "a", 0, &[3.0, 3.0], &[5.0, 5.0]),
            judged("vlm", "c", 0, &[3.0, 3.0], &[5.0, 5.0]),
        ];
        results.quality = build_quality(&tasks, &outcomes, &records);
        let model = |name: &str| EmbeddingModel {
            name: name.into(),
            model: format!("{name}-model"),
            dimensions: 384,
        };
        results.diversity = Some(DiversityResults {
            text: Some(TextDiversityTable {
                models: vec![model("minilm"), model("mpnet")],
                rows: vec![
                    TextDiversityRow {
                        group: "g1".into(),
                        n: 2,
                        div: vec![Some(0.4), None],
                        errors: vec![None, Some("endpoint down".into())],
                    },
                    TextDiversityRow {
                        group: "All".into(),
                        n: 3,
                        div: vec![Some(0.5), Some(0.45)],
                        errors: Vec::new(),
                    },
                ],
            }),
            dynamics: vec![
                fit("g1", 10, 10, 0.002),
                fit("g1", 20, 12, 0.0015),
                fit("g2", 10, 4, 0.003),
            ],
            errors: vec![("dynamics g2 @ 20".into(), "trainer crashed".into())],
        });
        results.generalization = Some(generalization());
        results.ranking = Some(crate::testing::ranking_fixture());
        Report {
            report_version: crate::report::REPORT_VERSION,
            provenance: Default::default(),
            imports: vec![crate::report::ImportSummary {
                pipeline: "gensim".into(),
                root: "lib".into(),
                mapping_file: "import-report.json".into(),
                tasks: vec![
                    crate::report::ImportedTaskSummary {
                        id: "t1".into(),
                        name: "t1".into(),
                        source: "lib/generated_tasks/t1.py".into(),
                        imported: true,
                        errors: vec![],
                        inferred: vec!["oracle: per goal".into()],
                        not_mapped: vec!["max_steps: actions".into()],
                    },
                    crate::report::ImportedTaskSummary {
                        id: "rope".into(),
                        name: "rope".into(),
                        source: "lib/generated_tasks/rope.py".into(),
                        imported: false,
                        errors: vec!["make_ropes: ropes are deformable".into()],
                        inferred: vec![],
                        not_mapped: vec![],
                    },
                ],
            }],
            results,
            run: RunInfo {
                batch_id: "b00001".into(),
                state: "completed".into(),
                submitted_at_unix_ms: 1_700_000_000_000,
                finished_at_unix_ms: Some(1_700_000_060_000),
                wall_time_s: Some(60.0),
                episodes_per_s: Some(0.1),
                sim_steps_per_s: Some(10.0),
                extra_attempts: 0,
                workers: vec!["local/worker-0".into()],
                events: vec!["the local worker 0 process exited; started again".into()],
            },
        }
    }

    fn human() -> AgreementTable {
        AgreementTable {
            reference: "human".into(),
            group_column: None,
            resamples: 50,
            rows: vec![
                AgreementRow {
                    group: None,
                    judge: "offline".into(),
                    agreement: agreement(&[1.0, 5.0, 7.0, 9.0], &[2.0, 4.0, 8.0, 9.0], 50, 0),
                },
                AgreementRow {
                    group: None,
                    judge: "vlm".into(),
                    agreement: agreement(&[3.0, 3.0, 3.0], &[2.0, 4.0, 8.0], 50, 0),
                },
            ],
        }
    }

    fn render(report: &Report, human: Option<&AgreementTable>) -> String {
        report_html(&HtmlInputs {
            report,
            artifact: &artifact,
            human,
        })
    }

    /// Every `data:image/png;base64,` payload of `html`.
    fn data_pngs(html: &str) -> Vec<Vec<u8>> {
        let prefix = "data:image/png;base64,";
        html.match_indices(prefix)
            .map(|(i, _)| {
                let rest = &html[i + prefix.len()..];
                let end = rest.find('"').unwrap();
                base64::engine::general_purpose::STANDARD
                    .decode(&rest[..end])
                    .unwrap()
            })
            .collect()
    }

    #[test]
    fn the_page_is_self_contained_and_valid_enough() {
        let report = report();
        let human = human();
        let html = render(&report, Some(&human));
        assert!(html.starts_with("<!DOCTYPE html><html lang=\"en\">"));
        assert!(html.contains("<meta charset=\"utf-8\">"));
        assert!(html.contains("<title>Assay report: demo &amp; test</title>"));
        assert!(html.contains("<link rel=\"icon\" href=\"data:,\">"));
        let lower = html.to_lowercase();
        for bad in [
            "src=\"http",
            "href=\"http",
            "url(http",
            "<script",
            "@import",
            "<?xml",
        ] {
            assert!(!lower.contains(bad), "found {bad}");
        }
        // Every reference points into the page or is inline data.
        for attr in ["src=\"", "href=\""] {
            for (i, _) in html.match_indices(attr) {
                let target = &html[i + attr.len()..];
                assert!(
                    target.starts_with('#') || target.starts_with("data:"),
                    "{}",
                    &target[..target.len().min(60)]
                );
            }
        }
        assert!(!html.contains("NaN"));
        assert_eq!(html.matches("<svg").count(), html.matches("</svg>").count());
        for id in [
            "overview", "figure-4", "figure-3", "table-1", "table-2", "table-3", "ranking",
            "invalid", "tasks",
        ] {
            assert!(html.contains(&format!("id=\"{id}\"")), "{id}");
            assert!(html.contains(&format!("href=\"#{id}\"")), "{id}");
        }
        assert!(
            !lower.contains("not in this batch"),
            "every section is present"
        );
    }

    #[test]
    fn every_task_has_a_page_linked_from_the_index() {
        let report = report();
        let html = render(&report, None);
        assert_eq!(report.results.tasks.len(), 3);
        for t in &report.results.tasks {
            let anchor = task_anchor(&t.id);
            assert!(anchor.starts_with("task-"));
            assert!(
                anchor
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-._".contains(c)),
                "{anchor}"
            );
            assert!(html.contains(&format!("<section class=\"task\" id=\"{anchor}\">")));
            assert!(html.contains(&format!("href=\"#{anchor}\"")));
        }
        assert_ne!(task_anchor("a b"), task_anchor("a_20b"));
        assert!(html.contains("section.task:target{display:block}"));
        // The failed shard and the unmet predicate are on their task's page.
        assert!(html.contains("worker &lt;lost&gt;"));
        assert!(html.contains("distance 0.3 m"));
    }

    #[test]
    fn pictures_are_inline_thumbnails_or_say_why_not() {
        let html = render(&report(), None);
        let pngs = data_pngs(&html);
        // Task a's first episode: views ok + grey, keyframes big + ok + ok.
        assert_eq!(pngs.len(), 5);
        assert_eq!(html.matches("<img ").count(), 5);
        for bytes in &pngs {
            let reader = png::Decoder::new(std::io::Cursor::new(bytes))
                .read_info()
                .unwrap();
            assert!(reader.info().width <= THUMB_WIDTH);
        }
        assert!(html.contains("width=\"192\" height=\"144\""));
        assert!(html.contains("(artifact missing: imagery/missing.png)"));
        assert_eq!(html.matches("(image format not shown").count(), 2);
        assert!(html.contains("No pictures"));
    }

    #[test]
    fn thumbnails_keep_the_colour_type_and_refuse_other_formats() {
        let big = tiny_png(640, 480, png::ColorType::Rgba, png::BitDepth::Eight);
        let (png_bytes, w, h) = thumbnail(&big, 192).unwrap();
        assert_eq!((w, h), (192, 144));
        let reader = png::Decoder::new(std::io::Cursor::new(png_bytes))
            .read_info()
            .unwrap();
        assert_eq!(reader.info().color_type, png::ColorType::Rgba);
        let grey = tiny_png(1, 1, png::ColorType::GrayscaleAlpha, png::BitDepth::Eight);
        assert_eq!(thumbnail(&grey, 192).unwrap().1, 1);
        let deep = tiny_png(2, 2, png::ColorType::Rgb, png::BitDepth::Sixteen);
        assert!(thumbnail(&deep, 192).is_err());
        assert!(thumbnail(b"junk", 192).is_err());
    }

    #[test]
    fn report_text_is_escaped() {
        let html = render(&report(), None);
        assert!(!html.contains(EVIL));
        assert!(html.contains("&lt;script&gt;alert(1)&lt;/script&gt;"));
        assert!(html.contains("unknown shape &lt;blob&gt;"));
        assert!(html.contains("out of &lt;memory&gt;"));
    }

    #[test]
    fn undefined_agreement_is_shown_with_its_reason() {
        let human = human();
        assert!(human.rows[1].agreement.pearson.value.is_none());
        let html = render(&report(), Some(&human));
        assert!(html.contains("undefined — the reference scores are constant"));
        assert!(html.contains("humans (human)"));
        let e = Estimate {
            value: None,
            ci95: None,
            undefined: Some("needs 2".into()),
            no_interval: None,
        };
        let shown = cell(&crate::view::estimate(&e)).into_string();
        assert_eq!(
            shown,
            "<span class=\"undefined\">undefined — needs 2</span>"
        );
    }

    #[test]
    fn absent_sections_say_how_to_get_them() {
        let mut report = report();
        report.results.quality = None;
        report.results.diversity = None;
        report.results.ranking = None;
        report.results.generalization = None;
        let html = render(&report, None);
        assert!(html.contains("Not in this batch (run with --generalization)"));
        assert!(
            html.contains("Not in this batch (run with --rank-train-policies P,… --rank-ladder: ")
        );
        assert!(html.contains("Not in this batch (no judge ran: run with --judge)"));
        // The overview's success chart is the only figure left.
        assert_eq!(html.matches("<svg").count(), 1);
        assert!(html.contains("Success per group and policy (95 % Wilson intervals)"));
        let with_quality = render(&self::report(), None);
        assert!(
            with_quality.contains("Not in this batch (human ratings: run with --human-ratings)")
        );
    }

    #[test]
    fn markdown_and_html_show_the_same_tables() {
        use crate::tables;
        let report = report();
        let html = render(&report, None);
        let md = report.to_markdown();
        let r = &report.results;
        let q = r.quality.as_ref().unwrap();
        let d = r.diversity.as_ref().unwrap();
        let k = r.ranking.as_ref().unwrap();
        let c = &k.ranking.as_ref().unwrap().comparisons[0];
        let mut shared = vec![
            tables::summary(r),
            tables::success_per_group(r),
            tables::success_per_task(r),
            tables::invalid_tasks(r),
            tables::imports(&report.imports[0]),
            tables::run(&report.run),
            tables::provenance(&report.provenance),
            tables::judges(q),
            tables::agreement(&tables::against_simulator(q)),
            tables::quality_per_task(q),
            tables::text_diversity(d.text.as_ref().unwrap()),
            tables::dynamics_diversity(d),
            tables::diversity_errors(d, ""),
            tables::generalization(r.generalization.as_ref().unwrap()),
            tables::ranking_statistics(c),
            tables::ranking_policies(c, &k.labels),
            tables::ranking_compared(k),
            tables::proxy_models(k),
            tables::ranking_per_policy(k),
            tables::action_test(k),
            tables::repeat_consistency(k),
            tables::ranking_rows(k),
        ];
        let comparisons = &k.ranking.as_ref().unwrap().comparisons;
        shared.extend(comparisons.iter().map(tables::ranking_statistics));
        shared.extend(
            comparisons
                .iter()
                .map(|c| tables::ranking_policies(c, &k.labels)),
        );
        shared.extend(q.judges.iter().map(tables::quality_per_group));
        for t in &shared {
            assert!(!t.rows.is_empty(), "{}", t.markdown());
            assert!(
                md.contains(&t.markdown()),
                "not in report.md:\n{}",
                t.markdown()
            );
            assert!(
                html.contains(&table(t).into_string()),
                "not in report.html:\n{}",
                t.markdown()
            );
        }
    }

    #[test]
    fn the_same_inputs_give_the_same_page() {
        let (a, b) = (report(), report());
        let human = human();
        assert_eq!(render(&a, Some(&human)), render(&b, Some(&human)));
    }

    /// The demo batch's page, for looking at by hand: writes /tmp/report.html.
    /// `ASSAY_DEMO_DIR` (default /work/main/out/demo) holds report.json and artifacts/.
    #[test]
    #[ignore = "needs a demo run's report and artifacts"]
    fn demo_report_html() {
        let dir = std::path::PathBuf::from(
            std::env::var("ASSAY_DEMO_DIR").unwrap_or_else(|_| "/work/main/out/demo".into()),
        );
        let report: Report =
            serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
        let artifacts = dir.join("artifacts");
        let html = report_html(&HtmlInputs {
            report: &report,
            artifact: &|key: &str| std::fs::read(artifacts.join(key)).ok(),
            human: None,
        });
        std::fs::write("/tmp/report.html", &html).unwrap();
        println!(
            "/tmp/report.html: {} bytes, {} images",
            html.len(),
            html.matches("<img ").count()
        );
    }

    /// The ranking section shows, per group and ranked policy with imagined keyframes, the
    /// episode of the lowest seed as imagined, beside its keyframes in the simulator where the
    /// report has them; policies without keyframes are not shown.
    #[test]
    fn the_ranking_section_shows_what_the_world_model_imagined() {
        use crate::testing::{LADDER_BEST, ranking_fixture, report_with_ranking};
        let mut r = ranking_fixture();
        for g in &mut r.groups {
            for p in g.predictions.iter_mut().filter(|p| p.policy == LADDER_BEST) {
                p.imagined_keyframes = (0..8)
                    .map(|k| Keyframe {
                        step: 5 * k,
                        camera: "imagined".into(),
                        artifact: format!("imagined/{}-{}-{k}.png", p.task_id, p.seed),
                        goals_met: 0,
                    })
                    .collect();
            }
        }
        let mut report = report_with_ranking(r);
        // The ladder's best policy's episode of seed 0 in the simulator, with its imagery.
        let episode = |success: bool, keyframes: Vec<Keyframe>, clip: Option<String>| {
            crate::report::EpisodeRow {
                seed: 0,
                policy: LADDER_BEST.into(),
                success,
                label_source: LabelSource::Sim,
                steps: 100,
                artifact: "episodes/x.arrow".into(),
                unmet: Vec::new(),
                imagery: Some(EpisodeImagery {
                    adapter: "llvmpipe".into(),
                    views: Vec::new(),
                    keyframes,
                    contact_sheet: String::new(),
                    video: None,
                    caption: None,
                    clip,
                }),
                cutoff: None,
                generator_reward: None,
            }
        };
        fn task<'a>(r: &'a mut Report, id: &str) -> &'a mut crate::report::TaskResult {
            r.results.tasks.iter_mut().find(|t| t.id == id).unwrap()
        }
        // Task a's episode has render keyframes only.
        let keyframes = (0..2)
            .map(|k| Keyframe {
                step: 50 * k,
                camera: "front".into(),
                artifact: format!("imagery/real-{k}.png"),
                goals_met: 0,
            })
            .collect();
        task(&mut report, "a")
            .episodes
            .push(episode(true, keyframes, None));
        // Task c's episode has a dynamics clip of 3 frames: its own frames are shown.
        task(&mut report, "c").episodes.push(episode(
            false,
            Vec::new(),
            Some("clips/c0.clip".into()),
        ));
        let clip = assay_model::clip::Clip {
            height: 8,
            width: 8,
            interval_s: 0.1,
            proprio_dims: 4,
            action_dims: 4,
            rgb: (0..3 * 8 * 8 * 3).map(|i| i as u8).collect(),
            proprio: vec![0.0; 12],
            actions: vec![0.0; 12],
            interface: String::new(),
            views: Vec::new(),
            object_dims: 0,
            objects: Vec::new(),
        }
        .encode();
        let frames = |key: &str| match key {
            "clips/c0.clip" => Some(clip.clone()),
            k if k.starts_with("imagined/") || k.starts_with("imagery/real-") => {
                Some(tiny_png(8, 8, png::ColorType::Rgb, png::BitDepth::Eight))
            }
            _ => None,
        };
        let html = report_html(&HtmlInputs {
            report: &report,
            artifact: &frames,
            human: None,
        });
        assert!(html.contains("What the world model imagined"), "{html}");
        // g1: task a, seed 0 (the lowest of a and b); g2: task c, seed 0.
        assert_eq!(html.matches("<figcaption>imagined, frame ").count(), 16);
        assert!(html.contains("task a, seed 0") && html.contains("task c, seed 0"));
        assert!(!html.contains("task b, seed"));
        // Task a's real episode by its keyframes (it has no clip); task c's by its clip's frames
        // at the imagined ones' indices (0, 5, …, 35), its last where it ended sooner.
        assert_eq!(html.matches("<figcaption>real, step ").count(), 2);
        assert_eq!(html.matches("<figcaption>real, frame 0<").count(), 1);
        assert_eq!(
            html.matches("<figcaption>real, frame 2 (its last)<")
                .count(),
            7
        );
        assert!(html.contains("a success") && html.contains("a failure"));
        assert!(!html.contains("not in this report"));
        // An episode the report does not have says so.
        for t in &mut report.results.tasks {
            t.episodes.clear();
        }
        let html = report_html(&HtmlInputs {
            report: &report,
            artifact: &frames,
            human: None,
        });
        assert_eq!(html.matches("not in this report").count(), 2);
        // Only the policy with keyframes.
        assert_eq!(html.matches("<div class=\"imagined\">").count(), 2);
        // Without keyframes anywhere, no such section.
        let plain = report_html(&HtmlInputs {
            report: &report_with_ranking(ranking_fixture()),
            artifact: &frames,
            human: None,
        });
        assert!(!plain.contains("What the world model imagined"));
    }
}
