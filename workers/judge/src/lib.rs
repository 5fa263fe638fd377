//! `assay-judge`: the judge role. Scores an episode's quality as appendix A.1 of the
//! generative-simulation evaluation paper does — scene alignment (1–5) from the 4 views of the
//! initial scene, task completion (0–10) from the 8 keyframes, each answer ending in `Score: X`,
//! every item asked k times — with three kinds of judge:
//!
//! - `openai`: a vision-language model behind any OpenAI-compatible chat-completions endpoint
//!   (hosted GPT-4o-class models; vLLM, Ollama, LM Studio, SGLang serving LLaVA, Qwen-VL, ...);
//! - `caption+llm`: a caption model describes each image, an LLM scores the captions (the
//!   paper's "GPT-4 + BLIP2 / LLaVA / Cambrian" pipelines);
//! - `offline`: the built-in rubric, which needs no model (see [`judge`]).
//!
//! Owns: prompts, configuration, the answer cache, retries and budgets. Never: rendering,
//! physics, the job store.

pub mod config;
pub mod judge;
pub mod prompts;

pub use config::{Config, JudgeConfig, OFFLINE};
pub use judge::{Artifacts, Judge, JudgeError, Judged};
