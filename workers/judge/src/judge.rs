//! Judging one episode: both items, each asked `repeats` times, through the cache, within the
//! batch's budget, with retries.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use assay_model::caption::{SceneCaption, offline_alignment};
use assay_model::episode::EpisodeOutcome;
use assay_model::quality::{Item, ItemError, ItemOutcome, JudgeOutcome, Usage, parse_score};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::config::{Captioner, JudgeConfig};
use crate::prompts::{self, Prompt};
use assay_openai::{CallError, ChatRequest, Endpoint, backoff_delay};

/// A judge ready to score episodes.
pub struct Judge {
    name: String,
    kind: Kind,
}

enum Kind {
    Offline,
    Vlm(Arc<Endpoint>),
    CaptionLlm {
        /// None: the render role's structured caption.
        captioner: Option<Arc<Endpoint>>,
        scorer: Arc<Endpoint>,
    },
}

/// Why an episode could not be judged at all (a shard failure, not an item error).
#[derive(Debug, thiserror::Error)]
pub enum JudgeError {
    /// Retrying cannot help (no imagery, a judge that cannot start).
    #[error("{0}")]
    Permanent(String),
    /// Another attempt may succeed (an image not yet visible on a shared filesystem).
    #[error("{0}")]
    Retryable(String),
}

/// What a judge shard produces: the outcome and its transcript (JSON), which the caller stores.
pub struct Judged {
    pub outcome: JudgeOutcome,
    pub transcript: Vec<u8>,
}

/// One exchange with a model (or the offline rubric), for the transcript.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Exchange {
    item: String,
    repeat: u32,
    stage: String,
    prompt: String,
    images: Vec<String>,
    attempts: Vec<Attempt>,
    cached: bool,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Attempt {
    #[serde(skip_serializing_if = "Option::is_none")]
    answer: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
}

/// A cached answer.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct CachedAnswer {
    text: String,
    tokens_in: u64,
    tokens_out: u64,
}

/// What the shard's calls share: the budget, what has been spent and the transcript.
struct Ledger {
    budget_left_usd: Option<f64>,
    usage: Mutex<Usage>,
    transcript: Mutex<Vec<Exchange>>,
    root: PathBuf,
}

impl Ledger {
    fn spent_out(&self) -> bool {
        match self.budget_left_usd {
            Some(b) => self.usage.lock().expect("ledger").cost_usd >= b,
            None => false,
        }
    }
}

/// The end of asking one question: an answer, or why there is none.
enum Asked {
    Answer(String),
    Failed {
        error: String,
        raw: Option<String>,
    },
    /// The budget was spent before the question could be asked.
    Unjudged,
}

impl Judge {
    pub fn new(name: &str, cfg: &JudgeConfig) -> Result<Self, JudgeError> {
        let endpoint = |e: &assay_openai::EndpointConfig| {
            Endpoint::new(e.clone())
                .map(Arc::new)
                .map_err(|err| JudgeError::Permanent(format!("judge '{name}': {err}")))
        };
        let kind = match cfg {
            JudgeConfig::Offline {} => Kind::Offline,
            JudgeConfig::OpenAi(e) => Kind::Vlm(endpoint(e)?),
            JudgeConfig::CaptionLlm { captioner, scorer } => Kind::CaptionLlm {
                captioner: match captioner {
                    Captioner::Builtin(_) => None,
                    Captioner::Endpoint(e) => Some(endpoint(e)?),
                },
                scorer: endpoint(scorer)?,
            },
        };
        Ok(Self {
            name: name.to_owned(),
            kind,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    pub fn backend(&self) -> &'static str {
        match self.kind {
            Kind::Offline => "offline",
            Kind::Vlm(_) => "openai",
            Kind::CaptionLlm { .. } => "caption+llm",
        }
    }

    /// The model(s) behind the judge, as reports show them.
    pub fn model(&self) -> String {
        match &self.kind {
            Kind::Offline => format!("assay-offline {}", env!("CARGO_PKG_VERSION")),
            Kind::Vlm(e) => e.config().model.clone(),
            Kind::CaptionLlm { captioner, scorer } => format!(
                "{} → {}",
                captioner
                    .as_ref()
                    .map_or("assay structured caption", |c| c.config().model.as_str()),
                scorer.config().model
            ),
        }
    }

    /// Judges one rendered episode of a task described by `description`: scene alignment from
    /// its 4 views and completion from its 8 keyframes, each asked `repeats` times. An imagined
    /// rollout (a world model's, for policy ranking) has keyframes and no views: only its
    /// completion is asked. Answers come from the cache under `root` when the same question was
    /// asked before; no new request is made once `budget_left_usd` is spent (those repeats are
    /// counted as unjudged).
    pub async fn judge(
        &self,
        episode: &EpisodeOutcome,
        description: &str,
        repeats: u32,
        budget_left_usd: Option<f64>,
        artifacts: &Artifacts,
    ) -> Result<Judged, JudgeError> {
        let root = artifacts.root.as_path();
        let imagery = episode.imagery.as_ref().ok_or_else(|| {
            JudgeError::Permanent(format!(
                "task {} seed {}: the episode has no imagery to judge (its batch did not ask for pictures)",
                episode.task_id, episode.seed
            ))
        })?;
        let ledger = Arc::new(Ledger {
            budget_left_usd,
            usage: Mutex::new(Usage::default()),
            transcript: Mutex::new(Vec::new()),
            root: root.to_owned(),
        });
        let repeats = repeats.max(1);
        let views: Vec<String> = imagery.views.iter().map(|v| v.artifact.clone()).collect();
        let keyframes: Vec<String> = imagery
            .keyframes
            .iter()
            .map(|k| k.artifact.clone())
            .collect();
        // Items with images to show: an imagined rollout has no scene views.
        let asked: Vec<(Item, &Vec<String>)> = [
            (Item::SceneAlignment, &views),
            (Item::Completion, &keyframes),
        ]
        .into_iter()
        .filter(|(item, keys)| *item == Item::Completion || !keys.is_empty())
        .collect();
        let items = match &self.kind {
            Kind::Offline if views.is_empty() => {
                return Err(JudgeError::Permanent(format!(
                    "task {} seed {}: the offline judge cannot judge a rollout without scene views (an imagined one): its completion is the simulator's",
                    episode.task_id, episode.seed
                )));
            }
            Kind::Offline => offline(episode, description, repeats, artifacts, &ledger)?,
            Kind::Vlm(endpoint) => {
                let mut items = Vec::new();
                for &(item, keys) in &asked {
                    let images = read_images(artifacts, keys, item)?;
                    let prompt = Prompt::for_images(item);
                    let text = prompt.render(description, &[]);
                    items.push(
                        ask_repeats(
                            endpoint, item, prompt.id, &text, &images, keys, repeats, &ledger,
                        )
                        .await,
                    );
                }
                items
            }
            Kind::CaptionLlm { captioner, scorer } => {
                let mut items = Vec::new();
                for &(item, keys) in &asked {
                    let captions = match captioner {
                        Some(c) => {
                            let images = read_images(artifacts, keys, item)?;
                            caption_images(c, item, &images, keys, &ledger).await
                        }
                        // The structured caption describes the initial scene only.
                        None if item == Item::SceneAlignment => {
                            let caption = read_caption(artifacts, imagery.caption.as_deref())?;
                            Ok(vec![caption.to_text()])
                        }
                        None => continue,
                    };
                    let prompt = Prompt::for_captions(item);
                    items.push(match captions {
                        Ok(captions) => {
                            let text = prompt.render(description, &captions);
                            ask_repeats(scorer, item, prompt.id, &text, &[], keys, repeats, &ledger)
                                .await
                        }
                        Err(outcome) => ItemOutcome {
                            prompt: prompt.id.into(),
                            ..outcome
                        },
                    });
                }
                items
            }
        };
        let usage = ledger.usage.lock().expect("ledger").clone();
        let transcript = serde_json::to_vec_pretty(&*ledger.transcript.lock().expect("ledger"))
            .map_err(|e| JudgeError::Permanent(format!("transcript: {e}")))?;
        Ok(Judged {
            outcome: JudgeOutcome {
                judge: self.name.clone(),
                backend: self.backend().into(),
                model: self.model(),
                task_id: episode.task_id.clone(),
                seed: episode.seed,
                policy: episode.policy.clone(),
                repeats,
                items,
                usage,
                transcript: None,
            },
            transcript,
        })
    }
}

/// The built-in judge: scene alignment from the render role's structured caption (what the
/// views show, measured from their segments and depth) against the description; completion from
/// the goal predicates that held at the last keyframe (the simulator's ground truth). It is a
/// deterministic rubric, not a model: every repeat gives the same answer.
fn offline(
    episode: &EpisodeOutcome,
    description: &str,
    repeats: u32,
    artifacts: &Artifacts,
    ledger: &Ledger,
) -> Result<Vec<ItemOutcome>, JudgeError> {
    let imagery = episode.imagery.as_ref().expect("checked by the caller");
    let alignment = match imagery.caption.as_deref() {
        Some(key) => {
            let caption = read_caption(artifacts, Some(key))?;
            let s = offline_alignment(description, &caption);
            Ok(format!("{}\nScore: {:.2}", s.rationale, s.score))
        }
        None => Err(
            "the episode's imagery has no scene caption (rendered by an older worker)".to_owned(),
        ),
    };
    let goals = episode.predicates.len();
    let completion = match imagery.keyframes.last() {
        _ if goals == 0 => Err("the task has no goal predicates".to_owned()),
        None => Err("the episode has no keyframes".to_owned()),
        Some(last) => {
            let trace: Vec<String> = imagery
                .keyframes
                .iter()
                .map(|k| format!("{}/{goals}", k.goals_met))
                .collect();
            Ok(format!(
                "Goal predicates holding at the {} keyframes: {}. At the end {} of {goals} hold.\nScore: {:.2}",
                imagery.keyframes.len(),
                trace.join(", "),
                last.goals_met,
                10.0 * f64::from(last.goals_met) / goals as f64
            ))
        }
    };
    let mut items = Vec::new();
    for (item, prompt, answer, images) in [
        (
            Item::SceneAlignment,
            prompts::OFFLINE_SCENE_ALIGNMENT,
            alignment,
            imagery.caption.iter().cloned().collect::<Vec<_>>(),
        ),
        (
            Item::Completion,
            prompts::OFFLINE_COMPLETION,
            completion,
            imagery
                .keyframes
                .iter()
                .map(|k| k.artifact.clone())
                .collect(),
        ),
    ] {
        let mut out = ItemOutcome {
            item,
            prompt: prompt.into(),
            scores: Vec::new(),
            errors: Vec::new(),
            unjudged: 0,
        };
        for repeat in 0..repeats {
            let parsed = answer.clone().and_then(|text| {
                parse_score(&text, item).map_err(|e| format!("{e}; answer: {text}"))
            });
            match parsed {
                Ok(score) => out.scores.push(score),
                Err(error) => out.errors.push(ItemError {
                    repeat,
                    error,
                    raw: None,
                }),
            }
        }
        ledger.transcript.lock().expect("ledger").push(Exchange {
            item: item.name().into(),
            repeat: 0,
            stage: "offline rubric (the same for every repeat)".into(),
            prompt: prompt.into(),
            images,
            attempts: vec![match &answer {
                Ok(a) => Attempt {
                    answer: Some(a.clone()),
                    error: None,
                },
                Err(e) => Attempt {
                    answer: None,
                    error: Some(e.clone()),
                },
            }],
            cached: false,
        });
        items.push(out);
    }
    Ok(items)
}

/// Where a judge reads an episode's pictures and caption: bytes the worker already holds (read
/// from the node's shared memory, where the render role that drew them keeps them), else the
/// artifact store's files. Counts which was which.
pub struct Artifacts {
    pub root: PathBuf,
    held: std::collections::HashMap<String, Vec<u8>>,
    from_memory: std::sync::atomic::AtomicU32,
    from_store: std::sync::atomic::AtomicU32,
}

impl Artifacts {
    /// Reads from `root`, and first from `held` (key → bytes).
    pub fn new(root: &Path, held: std::collections::HashMap<String, Vec<u8>>) -> Self {
        Self {
            root: root.to_owned(),
            held,
            from_memory: Default::default(),
            from_store: Default::default(),
        }
    }

    fn read(&self, key: &str) -> std::io::Result<Vec<u8>> {
        use std::sync::atomic::Ordering::Relaxed;
        if let Some(bytes) = self.held.get(key) {
            self.from_memory.fetch_add(1, Relaxed);
            return Ok(bytes.clone());
        }
        // A key from a shard is opened below the store's folder, never beside it.
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(
            &mut assay_spec::assets::open_beneath(&self.root, Path::new(key))?,
            &mut bytes,
        )?;
        self.from_store.fetch_add(1, Relaxed);
        Ok(bytes)
    }

    /// Artifacts read so far from what the worker held, and from the artifact store.
    pub fn reads(&self) -> (u32, u32) {
        use std::sync::atomic::Ordering::Relaxed;
        (
            self.from_memory.load(Relaxed),
            self.from_store.load(Relaxed),
        )
    }
}

fn read_caption(artifacts: &Artifacts, key: Option<&str>) -> Result<SceneCaption, JudgeError> {
    let key = key.ok_or_else(|| {
        JudgeError::Permanent("the episode's imagery has no scene caption".into())
    })?;
    let bytes = artifacts
        .read(key)
        .map_err(|e| JudgeError::Retryable(format!("scene caption {key}: {e}")))?;
    serde_json::from_slice(&bytes)
        .map_err(|e| JudgeError::Permanent(format!("scene caption {key}: {e}")))
}

fn read_images(
    artifacts: &Artifacts,
    keys: &[String],
    item: Item,
) -> Result<Vec<Vec<u8>>, JudgeError> {
    if keys.len() != item.images() {
        return Err(JudgeError::Permanent(format!(
            "{}: the episode has {} images, the protocol asks for {}",
            item.name(),
            keys.len(),
            item.images()
        )));
    }
    keys.iter()
        .map(|k| {
            artifacts
                .read(k)
                .map_err(|e| JudgeError::Retryable(format!("image {k}: {e}")))
        })
        .collect()
}

/// The cache key of one answer: the model and its sampling temperature, the prompt's id and
/// full text, the images' content addresses, the repeat index, and which answer to this question
/// it was (0 for the first; a retry after an unusable answer is answer 1, ...). Every answer is
/// kept, usable or not, so a rerun replays the same answers and makes no new calls.
fn cache_key(
    endpoint: &Endpoint,
    prompt_id: &str,
    text: &str,
    images: &[String],
    repeat: u32,
    answer: u32,
) -> String {
    let cfg = endpoint.config();
    let mut h = Sha256::new();
    for part in [
        "assay-judge-cache/v1",
        &cfg.model,
        &format!("{:?}", cfg.temperature),
        prompt_id,
        text,
        &images.join(","),
        &repeat.to_string(),
        &answer.to_string(),
    ] {
        h.update((part.len() as u64).to_le_bytes());
        h.update(part.as_bytes());
    }
    hex::encode(h.finalize())
}

fn cache_path(root: &Path, key: &str) -> PathBuf {
    root.join("judge-cache")
        .join(&key[..2])
        .join(format!("{key}.json"))
}

fn cache_get(root: &Path, key: &str) -> Option<CachedAnswer> {
    let bytes = std::fs::read(cache_path(root, key)).ok()?;
    serde_json::from_slice(&bytes).ok()
}

fn cache_put(root: &Path, key: &str, answer: &CachedAnswer) {
    let path = cache_path(root, key);
    let write = || -> std::io::Result<()> {
        let dir = path.parent().expect("cache paths have a folder");
        std::fs::create_dir_all(dir)?;
        let tmp = dir.join(format!(
            ".tmp-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        std::fs::write(&tmp, serde_json::to_vec(answer).unwrap_or_default())?;
        std::fs::rename(&tmp, &path)
    };
    if let Err(e) = write() {
        tracing::warn!(error = %e, path = %path.display(), "judge cache: could not store an answer");
    }
}

/// Asks one question until it gets an answer that `accept` takes (retrying transport errors,
/// 408/409/429/5xx with backoff that honours `Retry-After`, and unacceptable answers), within
/// the budget. Answers already in the cache are replayed in order before any new call is made;
/// errors without an answer (timeouts, HTTP errors) are not cached.
#[allow(clippy::too_many_arguments)]
async fn ask(
    endpoint: &Endpoint,
    item: Item,
    stage: &str,
    prompt_id: &str,
    text: &str,
    images: &[Vec<u8>],
    image_keys: &[String],
    repeat: u32,
    ledger: &Ledger,
    accept: &(dyn Fn(&str) -> Result<(), String> + Sync),
) -> Asked {
    let mut exchange = Exchange {
        item: item.name().into(),
        repeat,
        stage: stage.into(),
        prompt: prompt_id.into(),
        images: image_keys.to_vec(),
        attempts: Vec::new(),
        cached: false,
    };
    let record = |exchange: Exchange| ledger.transcript.lock().expect("ledger").push(exchange);
    let key = |answer: u32| cache_key(endpoint, prompt_id, text, image_keys, repeat, answer);
    let mut answers = 0u32;
    let request = ChatRequest {
        prompt_version: prompt_id.into(),
        system: None,
        text: text.into(),
        images: images.to_vec(),
    };
    let retries = endpoint.config().retries;
    let mut jitter = assay_spec::rng::Rng::new(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64),
        &key(0),
    );
    let mut last: Option<(String, Option<String>)> = None;
    for attempt in 0..=retries {
        if let Some(hit) = cache_get(&ledger.root, &key(answers)) {
            answers += 1;
            ledger.usage.lock().expect("ledger").cached += 1;
            exchange.cached = true;
            let verdict = accept(&hit.text);
            exchange.attempts.push(Attempt {
                answer: Some(hit.text.clone()),
                error: verdict.as_ref().err().cloned(),
            });
            match verdict {
                Ok(()) => {
                    record(exchange);
                    return Asked::Answer(hit.text);
                }
                Err(why) => {
                    last = Some((format!("unusable answer: {why}"), Some(hit.text)));
                    continue;
                }
            }
        }
        if ledger.spent_out() {
            record(exchange);
            return match last {
                Some((error, raw)) if attempt > 0 => Asked::Failed {
                    error: format!("{error}; then the judge budget was spent"),
                    raw,
                },
                _ => Asked::Unjudged,
            };
        }
        let result = endpoint.chat(&request).await;
        let retry_after: Option<std::time::Duration>;
        match result {
            Ok(answer) => {
                {
                    let mut u = ledger.usage.lock().expect("ledger");
                    u.calls += 1;
                    u.tokens_in += answer.tokens_in;
                    u.tokens_out += answer.tokens_out;
                    u.cost_usd += endpoint.cost_usd(answer.tokens_in, answer.tokens_out);
                }
                exchange.attempts.push(Attempt {
                    answer: Some(answer.text.clone()),
                    error: None,
                });
                cache_put(
                    &ledger.root,
                    &key(answers),
                    &CachedAnswer {
                        text: answer.text.clone(),
                        tokens_in: answer.tokens_in,
                        tokens_out: answer.tokens_out,
                    },
                );
                answers += 1;
                match accept(&answer.text) {
                    Ok(()) => {
                        record(exchange);
                        return Asked::Answer(answer.text);
                    }
                    Err(why) => {
                        exchange.attempts.last_mut().expect("pushed").error = Some(why.clone());
                        last = Some((format!("unusable answer: {why}"), Some(answer.text)));
                        // A malformed answer is asked again at once: waiting does not fix it.
                        continue;
                    }
                }
            }
            Err(e) => {
                // A server that answered counts as a call; timeouts and transport errors made
                // none we know of.
                if matches!(e, CallError::Status { .. } | CallError::BadResponse(_)) {
                    ledger.usage.lock().expect("ledger").calls += 1;
                }
                exchange.attempts.push(Attempt {
                    answer: None,
                    error: Some(e.to_string()),
                });
                let retryable = e.retryable();
                retry_after = e.retry_after();
                last = Some((e.to_string(), last.and_then(|l| l.1)));
                if !retryable {
                    break;
                }
            }
        }
        if attempt < retries {
            let wait = backoff_delay(endpoint.config(), attempt, retry_after, jitter.unit());
            tokio::time::sleep(wait).await;
        }
    }
    let attempts = exchange.attempts.len();
    record(exchange);
    let (error, raw) = last.unwrap_or_else(|| ("no attempt was made".into(), None));
    Asked::Failed {
        error: format!("after {attempts} attempt(s): {error}"),
        raw,
    }
}

/// Asks one scored item `repeats` times, concurrently (the endpoint bounds what is in flight).
#[allow(clippy::too_many_arguments)]
async fn ask_repeats(
    endpoint: &Arc<Endpoint>,
    item: Item,
    prompt_id: &str,
    text: &str,
    images: &[Vec<u8>],
    image_keys: &[String],
    repeats: u32,
    ledger: &Arc<Ledger>,
) -> ItemOutcome {
    let accept = move |answer: &str| parse_score(answer, item).map(|_| ());
    let asks = (0..repeats).map(|repeat| {
        ask(
            endpoint, item, "score", prompt_id, text, images, image_keys, repeat, ledger, &accept,
        )
    });
    let answers = join_all(asks).await;
    let mut out = ItemOutcome {
        item,
        prompt: prompt_id.into(),
        scores: Vec::new(),
        errors: Vec::new(),
        unjudged: 0,
    };
    for (repeat, asked) in answers.into_iter().enumerate() {
        match asked {
            Asked::Answer(text) => match parse_score(&text, item) {
                Ok(s) => out.scores.push(s),
                Err(error) => out.errors.push(ItemError {
                    repeat: repeat as u32,
                    error,
                    raw: Some(text),
                }),
            },
            Asked::Failed { error, raw } => out.errors.push(ItemError {
                repeat: repeat as u32,
                error,
                raw,
            }),
            Asked::Unjudged => out.unjudged += 1,
        }
    }
    out
}

/// First stage of a caption + LLM judge: one caption per image (asked once, repeat 0). An item
/// whose captions cannot all be had is returned as its outcome (errors or unjudged).
async fn caption_images(
    captioner: &Endpoint,
    item: Item,
    images: &[Vec<u8>],
    keys: &[String],
    ledger: &Ledger,
) -> Result<Vec<String>, ItemOutcome> {
    let accept = |answer: &str| {
        if answer.trim().is_empty() {
            Err("empty caption".to_owned())
        } else {
            Ok(())
        }
    };
    let text = prompts::CAPTION.render("", &[]);
    let asks = images.iter().zip(keys).map(|(image, key)| {
        ask(
            captioner,
            item,
            "caption",
            prompts::CAPTION.id,
            &text,
            std::slice::from_ref(image),
            std::slice::from_ref(key),
            0,
            ledger,
            &accept,
        )
    });
    let mut captions = Vec::new();
    let mut failed = ItemOutcome {
        item,
        prompt: String::new(),
        scores: Vec::new(),
        errors: Vec::new(),
        unjudged: 0,
    };
    for (i, asked) in join_all(asks).await.into_iter().enumerate() {
        match asked {
            Asked::Answer(c) => captions.push(c),
            Asked::Failed { error, raw } => failed.errors.push(ItemError {
                repeat: 0,
                error: format!("caption of image {}: {error}", i + 1),
                raw,
            }),
            Asked::Unjudged => failed.unjudged = 1,
        }
    }
    if failed.errors.is_empty() && failed.unjudged == 0 {
        Ok(captions)
    } else {
        Err(failed)
    }
}

/// Runs futures concurrently on the current task and collects their outputs in order.
async fn join_all<F: std::future::Future>(futures: impl IntoIterator<Item = F>) -> Vec<F::Output> {
    let mut pending: Vec<std::pin::Pin<Box<F>>> = futures.into_iter().map(Box::pin).collect();
    let mut out: Vec<Option<F::Output>> = pending.iter().map(|_| None).collect();
    std::future::poll_fn(|cx| {
        let mut done = true;
        for (i, f) in pending.iter_mut().enumerate() {
            if out[i].is_none() {
                match f.as_mut().poll(cx) {
                    std::task::Poll::Ready(v) => out[i] = Some(v),
                    std::task::Poll::Pending => done = false,
                }
            }
        }
        if done {
            std::task::Poll::Ready(())
        } else {
            std::task::Poll::Pending
        }
    })
    .await;
    out.into_iter()
        .map(|o| o.expect("every future finished"))
        .collect()
}
