//! Judges as the configuration file names them.
//!
//! ```toml
//! [judges.gpt-4o]
//! backend = "openai"
//! base_url = "https://api.openai.com/v1"
//! model = "gpt-4o"
//! api_key_env = "OPENAI_API_KEY"
//!
//! [judges.llava-gpt4]
//! backend = "caption+llm"
//! captioner = { base_url = "http://127.0.0.1:11434/v1", model = "llava:13b" }
//! scorer = { base_url = "https://api.openai.com/v1", model = "gpt-4", api_key_env = "OPENAI_API_KEY" }
//! ```
//!
//! `offline` is always there; a configuration may not redefine it.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use assay_openai::EndpointConfig;

/// The built-in judge's name.
pub const OFFLINE: &str = "offline";

/// The judge part of Assay's configuration file (other sections are ignored here).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Config {
    #[serde(default)]
    pub judges: BTreeMap<String, JudgeConfig>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "backend", deny_unknown_fields)]
pub enum JudgeConfig {
    /// The built-in offline judge.
    #[serde(rename = "offline")]
    Offline {},
    /// A vision-language model behind an OpenAI-compatible endpoint sees the images.
    #[serde(rename = "openai")]
    OpenAi(EndpointConfig),
    /// A caption model describes each image, an LLM scores the captions.
    #[serde(rename = "caption+llm")]
    CaptionLlm {
        captioner: Captioner,
        scorer: EndpointConfig,
    },
}

/// The first stage of a caption + LLM judge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Captioner {
    /// `"offline"`: the render role's structured caption of the scene views (it describes the
    /// initial scene only, so such a judge scores scene alignment only).
    Builtin(String),
    /// A VLM behind an OpenAI-compatible endpoint captions each image.
    Endpoint(EndpointConfig),
}

impl Config {
    /// Parses a TOML configuration, checking every judge.
    pub fn parse(text: &str) -> Result<Self, String> {
        let cfg: Config = toml::from_str(text).map_err(|e| e.to_string())?;
        for (name, j) in &cfg.judges {
            let bad = |why: String| Err(format!("judges.{name}: {why}"));
            if name == OFFLINE && *j != (JudgeConfig::Offline {}) {
                return bad("'offline' is the built-in judge and cannot be redefined".into());
            }
            match j {
                JudgeConfig::Offline {} => {}
                JudgeConfig::OpenAi(e) => {
                    if let Err(e) = e.validate() {
                        return bad(e.to_string());
                    }
                }
                JudgeConfig::CaptionLlm { captioner, scorer } => {
                    if let Err(e) = scorer.validate() {
                        return bad(format!("scorer: {e}"));
                    }
                    match captioner {
                        Captioner::Builtin(s) if s == OFFLINE => {}
                        Captioner::Builtin(s) => {
                            return bad(format!(
                                "captioner: {s:?} is not a captioner (\"offline\" or an endpoint table)"
                            ));
                        }
                        Captioner::Endpoint(e) => {
                            if let Err(e) = e.validate() {
                                return bad(format!("captioner: {e}"));
                            }
                        }
                    }
                }
            }
        }
        Ok(cfg)
    }

    /// Reads a configuration file; errors name the file.
    pub fn load(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("configuration {}: {e}", path.display()))?;
        Self::parse(&text).map_err(|e| format!("configuration {}: {e}", path.display()))
    }

    /// The judge called `name` (the offline judge when not configured otherwise).
    pub fn judge(&self, name: &str) -> Option<JudgeConfig> {
        match self.judges.get(name) {
            Some(j) => Some(j.clone()),
            None if name == OFFLINE => Some(JudgeConfig::Offline {}),
            None => None,
        }
    }

    /// Names of every judge, the offline one included.
    pub fn names(&self) -> Vec<String> {
        let mut names: Vec<String> = self.judges.keys().cloned().collect();
        if !names.iter().any(|n| n == OFFLINE) {
            names.push(OFFLINE.into());
        }
        names.sort();
        names
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_example_configuration_reads() {
        let cfg = Config::parse(include_str!("../../../examples/assay.toml")).unwrap();
        assert_eq!(cfg.names(), ["gpt-4o", "llava-gpt4", "offline", "qwen-vl"]);
    }

    #[test]
    fn reads_every_backend_and_names_errors() {
        let cfg = Config::parse(
            r#"
            [judges.gpt-4o]
            backend = "openai"
            base_url = "https://api.openai.com/v1"
            model = "gpt-4o"
            api_key_env = "OPENAI_API_KEY"
            requests_per_minute = 60

            [judges.blip-gpt4]
            backend = "caption+llm"
            captioner = { base_url = "http://127.0.0.1:8000/v1", model = "blip2" }
            scorer = { base_url = "https://api.openai.com/v1", model = "gpt-4" }

            [judges.offline-two-stage]
            backend = "caption+llm"
            captioner = "offline"
            scorer = { base_url = "http://127.0.0.1:8000/v1", model = "qwen" }
            "#,
        )
        .unwrap();
        assert_eq!(
            cfg.names(),
            ["blip-gpt4", "gpt-4o", "offline", "offline-two-stage"]
        );
        match cfg.judge("gpt-4o").unwrap() {
            JudgeConfig::OpenAi(e) => {
                assert_eq!(e.model, "gpt-4o");
                assert_eq!(e.requests_per_minute, Some(60.0));
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(cfg.judge("offline"), Some(JudgeConfig::Offline {}));
        assert_eq!(cfg.judge("nope"), None);

        let err = Config::parse("[judges.x]\nbackend = \"openai\"\nmodel = \"m\"\n").unwrap_err();
        assert!(err.contains("base_url"), "{err}");
        let err = Config::parse(
            "[judges.x]\nbackend = \"openai\"\nbase_url = \"http://h/v1\"\nmodel = \"m\"\ntemprature = 1\n",
        )
        .unwrap_err();
        assert!(err.contains("temprature"), "{err}");
        let err = Config::parse("[judges.x]\nbackend = \"gemini\"\n").unwrap_err();
        assert!(err.contains("gemini"), "{err}");
        let err = Config::parse(
            "[judges.x]\nbackend = \"caption+llm\"\ncaptioner = \"blip\"\nscorer = { base_url = \"http://h/v1\", model = \"m\" }\n",
        )
        .unwrap_err();
        assert!(err.contains("judges.x: captioner"), "{err}");
        let err = Config::parse(
            "[judges.offline]\nbackend = \"openai\"\nbase_url = \"http://h/v1\"\nmodel = \"m\"\n",
        )
        .unwrap_err();
        assert!(err.contains("built-in"), "{err}");
    }
}
