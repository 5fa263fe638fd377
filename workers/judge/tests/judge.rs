//! The judge against a local OpenAI-compatible server (real HTTP, real request and response
//! JSON) that records what it receives and answers from a script: images per request, prompt
//! versions, retries on timeouts, 429 and 500, unusable answers, the cache and the budget.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use assay_judge::{Judge, JudgeConfig};
use assay_model::episode::{EpisodeImagery, EpisodeOutcome, Keyframe, LabelSource, NamedArtifact};
use assay_model::quality::{Item, JudgeOutcome};
use assay_openai::EndpointConfig;
use assay_testkit::fixture::{Fixture, Received, Reply, Script, scoring_script};

const DESCRIPTION: &str = "put the red cube into the white box";

/// An episode whose 4 views and 8 keyframes are distinct small files in `root`.
fn episode(root: &Path) -> EpisodeOutcome {
    let put = |name: &str| {
        let key = format!("imagery/{name}.png");
        std::fs::create_dir_all(root.join("imagery")).unwrap();
        // Not a real PNG: the judge sends bytes, the fixture only counts them.
        std::fs::write(root.join(&key), format!("png {name}")).unwrap();
        key
    };
    EpisodeOutcome {
        task_id: "t".into(),
        seed: 0,
        policy: "oracle".into(),
        success: true,
        label_source: LabelSource::Sim,
        predicates: vec![],
        steps: 1,
        sim_time_s: 0.0,
        artifact: String::new(),
        spec_hash: String::new(),
        versions: Default::default(),
        imagery: Some(EpisodeImagery {
            adapter: "test".into(),
            views: (0..4)
                .map(|i| NamedArtifact {
                    name: format!("view{i}"),
                    artifact: put(&format!("view{i}")),
                })
                .collect(),
            keyframes: (0..8)
                .map(|i| Keyframe {
                    step: i,
                    camera: "front".into(),
                    artifact: put(&format!("key{i}")),
                    goals_met: 0,
                })
                .collect(),
            contact_sheet: String::new(),
            video: None,
            caption: None,
            clip: None,
        }),
        cutoff: None,
        generator_reward: None,
        scenes: None,
    }
}

fn endpoint(f: &Fixture) -> EndpointConfig {
    EndpointConfig {
        timeout_s: 0.5,
        retries: 3,
        backoff_initial_s: 0.01,
        backoff_max_s: 0.05,
        concurrency: 4,
        ..EndpointConfig::new(f.base_url(), "test-vlm")
    }
}

fn judge(cfg: EndpointConfig) -> Judge {
    Judge::new("vlm", &JudgeConfig::OpenAi(cfg)).unwrap()
}

fn run(j: &Judge, root: &Path, repeats: u32, budget: Option<f64>) -> JudgeOutcome {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let ep = episode(root);
    rt.block_on(j.judge(
        &ep,
        DESCRIPTION,
        repeats,
        budget,
        &assay_judge::Artifacts::new(root, Default::default()),
    ))
    .unwrap()
    .outcome
}

fn is_completion(r: &Received) -> bool {
    r.prompt_version.as_deref() == Some("completion/v1")
}

#[test]
fn asks_each_item_k_times_with_its_images_and_prompt_version() {
    let f = Fixture::start(scoring_script()).unwrap();
    let root = tempfile::tempdir().unwrap();
    let out = run(&judge(endpoint(&f)), root.path(), 3, None);
    let got = f.received();
    assert_eq!(got.len(), 6, "2 items x 3 repeats");
    for r in &got {
        assert_eq!(r.path, "/v1/chat/completions");
        assert_eq!(r.model, "test-vlm");
        assert!(r.text.contains(DESCRIPTION), "{}", r.text);
        let (images, prompt) = if is_completion(r) {
            (8, "completion/v1")
        } else {
            (4, "scene-alignment/v1")
        };
        assert_eq!(r.images, images);
        assert_eq!(r.prompt_version.as_deref(), Some(prompt));
        assert!(r.text.contains(&format!("{images} images")));
        // The images are the episode's files, in order.
        let first = r.image_urls()[0].clone();
        let b64 = first.strip_prefix("data:image/png;base64,").unwrap();
        let bytes = base64_decode(b64);
        let expected = if images == 8 { "png key0" } else { "png view0" };
        assert_eq!(String::from_utf8(bytes).unwrap(), expected);
    }
    assert_eq!(out.item(Item::SceneAlignment).unwrap().scores, [4.0; 3]);
    assert_eq!(out.item(Item::Completion).unwrap().scores, [7.0; 3]);
    assert_eq!(out.item(Item::Completion).unwrap().prompt, "completion/v1");
    assert_eq!(out.usage.calls, 6);
    assert_eq!(out.usage.cached, 0);
    assert!(out.usage.tokens_in > 6 * 85 * 4);
    assert_eq!(out.repeats, 3);
    assert_eq!(
        (out.backend.as_str(), out.model.as_str()),
        ("openai", "test-vlm")
    );
}

/// Completion requests get 429 (Retry-After 1 s), then 500, then an answer slower than the
/// timeout, then a score; scene alignment is answered at once.
#[test]
fn retries_after_429_500_and_timeouts_honouring_retry_after() {
    let seen = Arc::new(Mutex::new(0usize));
    let script: Script = {
        let seen = seen.clone();
        Arc::new(move |r: &Received| {
            if !is_completion(r) {
                return Reply::text("The scene fits.\nScore: 3");
            }
            let mut n = seen.lock().unwrap();
            *n += 1;
            match *n {
                1 => Reply::Status {
                    code: 429,
                    retry_after: Some("1".into()),
                    body: r#"{"error":{"message":"slow down"}}"#.into(),
                },
                2 => Reply::Status {
                    code: 500,
                    retry_after: None,
                    body: "internal error".into(),
                },
                3 => Reply::text("Score: 9").after(3.0),
                _ => Reply::text("Mostly done.\nScore: 6"),
            }
        })
    };
    let f = Fixture::start(script).unwrap();
    let root = tempfile::tempdir().unwrap();
    let start = Instant::now();
    let out = run(&judge(endpoint(&f)), root.path(), 1, None);
    let completion = out.item(Item::Completion).unwrap();
    assert_eq!(completion.scores, [6.0], "{completion:?}");
    assert!(completion.errors.is_empty());
    assert_eq!(out.item(Item::SceneAlignment).unwrap().scores, [3.0]);
    assert_eq!(f.received().iter().filter(|r| is_completion(r)).count(), 4);
    // The 429's Retry-After (1 s) was waited out, though the backoff is capped at 50 ms.
    assert!(
        start.elapsed().as_secs_f64() >= 1.0,
        "{:?}",
        start.elapsed()
    );
}

#[test]
fn an_unusable_answer_is_retried_then_recorded_as_the_items_error() {
    let script: Script = Arc::new(|r: &Received| {
        if is_completion(r) {
            Reply::text("The robot seems to have tried hard. I would rate it highly.")
        } else {
            Reply::text("Score: 4")
        }
    });
    let f = Fixture::start(script).unwrap();
    let root = tempfile::tempdir().unwrap();
    let out = run(&judge(endpoint(&f)), root.path(), 2, None);
    let completion = out.item(Item::Completion).unwrap();
    assert!(completion.scores.is_empty());
    assert_eq!(completion.errors.len(), 2, "one per repeat");
    for e in &completion.errors {
        assert!(e.error.contains("after 4 attempt(s)"), "{}", e.error);
        assert!(
            e.error.contains("no line of the form 'Score: X'"),
            "{}",
            e.error
        );
        assert!(e.raw.as_deref().unwrap().contains("tried hard"));
    }
    // 1 + 3 retries per repeat; the other item is unaffected.
    assert_eq!(f.received().iter().filter(|r| is_completion(r)).count(), 8);
    assert_eq!(out.item(Item::SceneAlignment).unwrap().scores, [4.0, 4.0]);
}

#[test]
fn a_second_run_is_served_entirely_from_the_cache() {
    // The first 3 completion answers are unusable (so some repeats are asked twice), the rest
    // score: the cache keeps every answer, so a rerun replays each repeat's answers in order.
    let asked = Arc::new(Mutex::new(0usize));
    let script: Script = {
        let asked = asked.clone();
        Arc::new(move |r: &Received| {
            if !is_completion(r) {
                return scoring_script()(r);
            }
            let mut n = asked.lock().unwrap();
            *n += 1;
            if *n <= 3 {
                Reply::text("Score: eleven")
            } else {
                Reply::text("Score: 5")
            }
        })
    };
    let f = Fixture::start(script).unwrap();
    let root = tempfile::tempdir().unwrap();
    let first = run(&judge(endpoint(&f)), root.path(), 3, None);
    let calls = f.count();
    assert_eq!(calls, 3 + 2 * 3);
    assert_eq!(first.usage.calls, calls as u64);
    assert_eq!(first.item(Item::Completion).unwrap().scores, [5.0; 3]);
    // A new judge (another worker, another day) over the same artifact store.
    let second = run(&judge(endpoint(&f)), root.path(), 3, None);
    assert_eq!(f.count(), calls, "no new request");
    assert_eq!(second.usage.calls, 0);
    assert_eq!(second.usage.cached, calls as u64);
    assert_eq!(second.items, first.items);
    // Another temperature is another question.
    let hotter = EndpointConfig {
        temperature: 1.0,
        ..endpoint(&f)
    };
    run(&judge(hotter), root.path(), 1, None);
    assert!(f.count() > calls);
}

#[test]
fn a_spent_budget_leaves_items_unjudged_and_stops_calls() {
    let f = Fixture::start(scoring_script()).unwrap();
    let priced = EndpointConfig {
        // Every request costs well over 1 cent (at least 340 tokens in).
        price_input_per_mtok: 100.0,
        concurrency: 1,
        ..endpoint(&f)
    };
    let root = tempfile::tempdir().unwrap();
    let none = run(&judge(priced.clone()), root.path(), 3, Some(0.0));
    assert_eq!(f.count(), 0);
    for item in &none.items {
        assert_eq!(item.unjudged, 3);
        assert!(item.scores.is_empty() && item.errors.is_empty());
    }
    let root = tempfile::tempdir().unwrap();
    let some = run(&judge(priced), root.path(), 3, Some(0.01));
    let judged: usize = some.items.iter().map(|i| i.scores.len()).sum();
    let unjudged: u32 = some.items.iter().map(|i| i.unjudged).sum();
    assert!(judged >= 1 && unjudged >= 1, "{some:?}");
    assert_eq!(judged + unjudged as usize, 6);
    assert_eq!(f.count(), judged);
    assert!(some.usage.cost_usd >= 0.01);
}

fn base64_decode(s: &str) -> Vec<u8> {
    use base64::Engine as _;
    base64::engine::general_purpose::STANDARD.decode(s).unwrap()
}

#[test]
fn caption_and_llm_captions_each_image_once_then_scores_the_captions() {
    // The captioner describes each image by its file name; the scorer answers by prompt.
    let script: Script = Arc::new(|r: &Received| match r.prompt_version.as_deref() {
        Some("caption/v1") => {
            let url = &r.image_urls()[0];
            let name = base64_decode(url.strip_prefix("data:image/png;base64,").unwrap());
            Reply::text(format!("a picture ({})", String::from_utf8(name).unwrap()))
        }
        Some("scene-alignment-captions/v1") => Reply::text("Score: 2"),
        Some("completion-captions/v1") => Reply::text("Score: 9"),
        other => panic!("prompt {other:?}"),
    });
    let f = Fixture::start(script).unwrap();
    let cfg = JudgeConfig::CaptionLlm {
        captioner: assay_judge::config::Captioner::Endpoint(EndpointConfig::new(
            f.base_url(),
            "test-captioner",
        )),
        scorer: EndpointConfig::new(f.base_url(), "test-llm"),
    };
    let j = Judge::new("two-stage", &cfg).unwrap();
    assert_eq!(j.model(), "test-captioner → test-llm");
    let root = tempfile::tempdir().unwrap();
    let out = run(&j, root.path(), 3, None);
    let got = f.received();
    let captions: Vec<&Received> = got
        .iter()
        .filter(|r| r.prompt_version.as_deref() == Some("caption/v1"))
        .collect();
    assert_eq!(
        captions.len(),
        4 + 8,
        "one caption per image, not per repeat"
    );
    assert!(
        captions
            .iter()
            .all(|r| r.images == 1 && r.model == "test-captioner")
    );
    let scored: Vec<&Received> = got.iter().filter(|r| r.model == "test-llm").collect();
    assert_eq!(scored.len(), 2 * 3);
    for r in &scored {
        assert_eq!(r.images, 0, "the LLM reads captions, not images");
        if r.prompt_version.as_deref() == Some("completion-captions/v1") {
            assert!(r.text.contains("1. a picture (png key0)"), "{}", r.text);
            assert!(r.text.contains("8. a picture (png key7)"), "{}", r.text);
        } else {
            assert!(r.text.contains("4. a picture (png view3)"), "{}", r.text);
        }
        assert!(r.text.contains(DESCRIPTION));
    }
    assert_eq!(out.item(Item::SceneAlignment).unwrap().scores, [2.0; 3]);
    assert_eq!(out.item(Item::Completion).unwrap().scores, [9.0; 3]);
    assert_eq!(
        out.item(Item::Completion).unwrap().prompt,
        "completion-captions/v1"
    );
    assert_eq!(out.backend, "caption+llm");
}

#[test]
fn a_client_error_is_not_retried() {
    let script: Script = Arc::new(|r: &Received| {
        if is_completion(r) {
            Reply::Status {
                code: 400,
                retry_after: None,
                body: r#"{"error":{"message":"too many images"}}"#.into(),
            }
        } else {
            Reply::text("Score: 5")
        }
    });
    let f = Fixture::start(script).unwrap();
    let root = tempfile::tempdir().unwrap();
    let out = run(&judge(endpoint(&f)), root.path(), 2, None);
    let completion = out.item(Item::Completion).unwrap();
    assert_eq!(completion.errors.len(), 2);
    let e = &completion.errors[0];
    assert!(e.error.starts_with("after 1 attempt(s): "), "{}", e.error);
    assert!(
        e.error.contains("400") && e.error.contains("too many images"),
        "{}",
        e.error
    );
    assert_eq!(f.received().iter().filter(|r| is_completion(r)).count(), 2);
    assert_eq!(out.item(Item::SceneAlignment).unwrap().scores, [5.0, 5.0]);
}
