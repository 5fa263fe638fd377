//! Sentence embeddings from sentence-transformers model folders (BERT and MPNet families), computed
//! exactly as the Python library computes them: the model's tokenizer with truncation at the
//! model's `max_seq_length` (from `sentence_bert_config.json`, not the tokenizer file's own
//! setting), texts stripped of surrounding whitespace, padding to the longest text of a batch,
//! the transformer forward, mean pooling over the attention mask, then L2 normalisation when the
//! model's pipeline ends with `Normalize`.
//!
//! The forward is written with tch over the folder's `model.safetensors`; texts are sorted by
//! length before batching (padding costs nothing then) and returned in the caller's order.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use tch::{Device, Kind, Tensor};
use tokenizers::{Tokenizer, TruncationDirection, TruncationParams, TruncationStrategy};

/// Why a model folder cannot be used, or a batch cannot be embedded.
#[derive(Debug, thiserror::Error)]
pub enum EmbedError {
    #[error("embedding model {dir}: {file}: {reason}")]
    Model {
        dir: PathBuf,
        file: &'static str,
        reason: String,
    },
    #[error("embedding model {dir}: tokenizer: {reason}")]
    Tokenizer { dir: PathBuf, reason: String },
    #[error("embedding model {dir}: torch: {0}", dir = .1.display())]
    Torch(tch::TchError, PathBuf),
}

/// The transformer families this forward implements.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Family {
    Bert,
    MPNet,
}

#[derive(Debug, Deserialize)]
struct HfConfig {
    model_type: String,
    hidden_size: i64,
    num_hidden_layers: usize,
    num_attention_heads: i64,
    #[serde(default = "default_eps")]
    layer_norm_eps: f64,
    #[serde(default)]
    hidden_act: Option<String>,
    #[serde(default)]
    pad_token_id: Option<i64>,
    #[serde(default)]
    relative_attention_num_buckets: Option<i64>,
}

fn default_eps() -> f64 {
    1e-12
}

#[derive(Debug, Deserialize)]
struct SbertConfig {
    max_seq_length: usize,
}

#[derive(Debug, Deserialize)]
struct PoolingConfig {
    #[serde(default)]
    pooling_mode_mean_tokens: bool,
    #[serde(default)]
    pooling_mode_cls_token: bool,
    #[serde(default)]
    pooling_mode_max_tokens: bool,
}

#[derive(Debug, Deserialize)]
struct ModuleEntry {
    #[serde(rename = "type")]
    kind: String,
    #[serde(default)]
    path: String,
}

/// A loaded sentence-transformers model.
pub struct SentenceModel {
    dir: PathBuf,
    family: Family,
    tokenizer: Tokenizer,
    weights: HashMap<String, Tensor>,
    hidden: i64,
    heads: i64,
    layers: usize,
    eps: f64,
    pad_id: i64,
    buckets: i64,
    max_seq_length: usize,
    normalize: bool,
    device: Device,
}

impl std::fmt::Debug for SentenceModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SentenceModel")
            .field("dir", &self.dir)
            .field("family", &self.family)
            .field("hidden", &self.hidden)
            .field("layers", &self.layers)
            .field("max_seq_length", &self.max_seq_length)
            .finish()
    }
}

fn read_json<T: serde::de::DeserializeOwned>(
    dir: &Path,
    file: &'static str,
) -> Result<T, EmbedError> {
    let path = dir.join(file);
    let text = std::fs::read_to_string(&path).map_err(|e| EmbedError::Model {
        dir: dir.to_owned(),
        file,
        reason: e.to_string(),
    })?;
    serde_json::from_str(&text).map_err(|e| EmbedError::Model {
        dir: dir.to_owned(),
        file,
        reason: e.to_string(),
    })
}

impl SentenceModel {
    /// Loads a sentence-transformers model folder (`config.json`, `model.safetensors`,
    /// `tokenizer.json`, `sentence_bert_config.json`, `modules.json`, `1_Pooling/config.json`).
    pub fn load(dir: &Path, device: Device) -> Result<Self, EmbedError> {
        let model_err = |file: &'static str, reason: String| EmbedError::Model {
            dir: dir.to_owned(),
            file,
            reason,
        };
        let cfg: HfConfig = read_json(dir, "config.json")?;
        let family = match cfg.model_type.as_str() {
            "bert" => Family::Bert,
            "mpnet" => Family::MPNet,
            other => {
                return Err(model_err(
                    "config.json",
                    format!("model_type {other:?} is not supported (bert and mpnet are)"),
                ));
            }
        };
        if let Some(act) = cfg.hidden_act.as_deref()
            && act != "gelu"
        {
            return Err(model_err(
                "config.json",
                format!("hidden_act {act:?} is not supported (gelu is)"),
            ));
        }
        let sbert: SbertConfig = read_json(dir, "sentence_bert_config.json")?;
        let modules: Vec<ModuleEntry> = read_json(dir, "modules.json")?;
        let normalize = modules.iter().any(|m| m.kind.ends_with("models.Normalize"));
        let pooling_dir = modules
            .iter()
            .find(|m| m.kind.ends_with("models.Pooling"))
            .map(|m| m.path.clone())
            .ok_or_else(|| model_err("modules.json", "no Pooling module".into()))?;
        let pooling: PoolingConfig = {
            let path = dir.join(&pooling_dir).join("config.json");
            let text = std::fs::read_to_string(&path)
                .map_err(|e| model_err("1_Pooling/config.json", e.to_string()))?;
            serde_json::from_str(&text)
                .map_err(|e| model_err("1_Pooling/config.json", e.to_string()))?
        };
        if !pooling.pooling_mode_mean_tokens
            || pooling.pooling_mode_cls_token
            || pooling.pooling_mode_max_tokens
        {
            return Err(model_err(
                "1_Pooling/config.json",
                "only mean pooling is supported".into(),
            ));
        }
        let mut tokenizer = Tokenizer::from_file(dir.join("tokenizer.json")).map_err(|e| {
            EmbedError::Tokenizer {
                dir: dir.to_owned(),
                reason: e.to_string(),
            }
        })?;
        // sentence-transformers truncates at the model's max_seq_length and pads per batch,
        // whatever tokenizer.json says.
        tokenizer
            .with_truncation(Some(TruncationParams {
                direction: TruncationDirection::Right,
                max_length: sbert.max_seq_length,
                strategy: TruncationStrategy::LongestFirst,
                stride: 0,
            }))
            .map_err(|e| EmbedError::Tokenizer {
                dir: dir.to_owned(),
                reason: e.to_string(),
            })?;
        tokenizer.with_padding(None);
        let safetensors = dir.join("model.safetensors");
        if !safetensors.exists() {
            return Err(model_err(
                "model.safetensors",
                "missing (only safetensors weights are read; convert pytorch_model.bin first)"
                    .into(),
            ));
        }
        let weights = Tensor::read_safetensors(&safetensors)
            .map_err(|e| EmbedError::Torch(e, dir.to_owned()))?
            .into_iter()
            .map(|(name, t)| {
                let name = name
                    .strip_prefix("bert.")
                    .or_else(|| name.strip_prefix("mpnet."))
                    .map(str::to_owned)
                    .unwrap_or(name);
                (name, t.to_kind(Kind::Float).to_device(device))
            })
            .collect();
        let model = Self {
            dir: dir.to_owned(),
            family,
            tokenizer,
            weights,
            hidden: cfg.hidden_size,
            heads: cfg.num_attention_heads,
            layers: cfg.num_hidden_layers,
            eps: cfg.layer_norm_eps,
            pad_id: cfg.pad_token_id.unwrap_or(match family {
                Family::Bert => 0,
                Family::MPNet => 1,
            }),
            buckets: cfg.relative_attention_num_buckets.unwrap_or(32),
            max_seq_length: sbert.max_seq_length,
            normalize,
            device,
        };
        model.check_weights()?;
        Ok(model)
    }

    /// Every weight the forward reads, so a wrong folder fails at load, naming what is missing.
    fn check_weights(&self) -> Result<(), EmbedError> {
        let mut needed = vec![
            "embeddings.word_embeddings.weight".to_owned(),
            "embeddings.position_embeddings.weight".to_owned(),
            "embeddings.LayerNorm.weight".to_owned(),
        ];
        if self.family == Family::Bert {
            needed.push("embeddings.token_type_embeddings.weight".into());
        } else {
            needed.push("encoder.relative_attention_bias.weight".into());
        }
        for l in 0..self.layers {
            let (q, k, v, o, ln) = self.attention_names(l);
            needed.extend([q, k, v, o, ln].map(|n| format!("{n}.weight")));
            needed.push(format!("encoder.layer.{l}.intermediate.dense.weight"));
            needed.push(format!("encoder.layer.{l}.output.dense.weight"));
            needed.push(format!("encoder.layer.{l}.output.LayerNorm.weight"));
        }
        let missing: Vec<_> = needed
            .into_iter()
            .filter(|n| !self.weights.contains_key(n))
            .collect();
        if missing.is_empty() {
            Ok(())
        } else {
            Err(EmbedError::Model {
                dir: self.dir.clone(),
                file: "model.safetensors",
                reason: format!("missing weights: {}", missing.join(", ")),
            })
        }
    }

    fn attention_names(&self, l: usize) -> (String, String, String, String, String) {
        let a = format!("encoder.layer.{l}.attention");
        match self.family {
            Family::Bert => (
                format!("{a}.self.query"),
                format!("{a}.self.key"),
                format!("{a}.self.value"),
                format!("{a}.output.dense"),
                format!("{a}.output.LayerNorm"),
            ),
            Family::MPNet => (
                format!("{a}.attn.q"),
                format!("{a}.attn.k"),
                format!("{a}.attn.v"),
                format!("{a}.attn.o"),
                format!("{a}.LayerNorm"),
            ),
        }
    }

    pub fn family(&self) -> Family {
        self.family
    }

    pub fn dimensions(&self) -> i64 {
        self.hidden
    }

    pub fn max_seq_length(&self) -> usize {
        self.max_seq_length
    }

    /// Token count of each text as the model sees it (special tokens included, after truncation).
    pub fn token_counts(&self, texts: &[String]) -> Result<Vec<usize>, EmbedError> {
        Ok(self.tokenize(texts)?.iter().map(Vec::len).collect())
    }

    /// Token ids of each text as the model sees them.
    pub fn token_ids(&self, texts: &[String]) -> Result<Vec<Vec<i64>>, EmbedError> {
        self.tokenize(texts)
    }

    fn tokenize(&self, texts: &[String]) -> Result<Vec<Vec<i64>>, EmbedError> {
        let stripped: Vec<&str> = texts.iter().map(|t| t.trim()).collect();
        let encodings =
            self.tokenizer
                .encode_batch(stripped, true)
                .map_err(|e| EmbedError::Tokenizer {
                    dir: self.dir.clone(),
                    reason: e.to_string(),
                })?;
        Ok(encodings
            .iter()
            .map(|e| e.get_ids().iter().map(|&i| i as i64).collect())
            .collect())
    }

    /// Embeddings of `texts`, in their order, `batch_size` texts per forward.
    pub fn encode(&self, texts: &[String], batch_size: usize) -> Result<Vec<Vec<f32>>, EmbedError> {
        let ids = self.tokenize(texts)?;
        let mut order: Vec<usize> = (0..ids.len()).collect();
        order.sort_by_key(|&i| std::cmp::Reverse(ids[i].len()));
        let mut out = vec![Vec::new(); ids.len()];
        let _guard = tch::no_grad_guard();
        for chunk in order.chunks(batch_size.max(1)) {
            let batch: Vec<&[i64]> = chunk.iter().map(|&i| ids[i].as_slice()).collect();
            let vectors = self
                .forward(&batch)
                .map_err(|e| EmbedError::Torch(e, self.dir.clone()))?;
            for (row, &i) in chunk.iter().enumerate() {
                out[i] = vectors[row].clone();
            }
        }
        Ok(out)
    }

    fn w(&self, name: &str) -> &Tensor {
        &self.weights[name]
    }

    fn b(&self, name: &str) -> Option<&Tensor> {
        self.weights.get(name)
    }

    fn dense(&self, x: &Tensor, name: &str) -> Tensor {
        x.linear(
            self.w(&format!("{name}.weight")),
            self.b(&format!("{name}.bias")),
        )
    }

    fn norm(&self, x: &Tensor, name: &str) -> Tensor {
        x.layer_norm(
            [self.hidden],
            Some(self.w(&format!("{name}.weight"))),
            self.b(&format!("{name}.bias")),
            self.eps,
            false,
        )
    }

    fn forward(&self, batch: &[&[i64]]) -> Result<Vec<Vec<f32>>, tch::TchError> {
        let b = batch.len() as i64;
        let len = batch.iter().map(|s| s.len()).max().unwrap_or(0) as i64;
        let mut ids = Vec::with_capacity((b * len) as usize);
        let mut mask = Vec::with_capacity((b * len) as usize);
        for s in batch {
            ids.extend_from_slice(s);
            mask.extend(std::iter::repeat_n(1i64, s.len()));
            for _ in s.len() as i64..len {
                ids.push(self.pad_id);
                mask.push(0);
            }
        }
        let ids = Tensor::from_slice(&ids)
            .view([b, len])
            .to_device(self.device);
        let mask = Tensor::from_slice(&mask)
            .view([b, len])
            .to_device(self.device);
        let lookup = |table: &str, indices: &Tensor| {
            Tensor::embedding(self.w(table), indices, -1, false, false)
        };
        let positions = match self.family {
            Family::Bert => Tensor::arange(len, (Kind::Int64, self.device)).unsqueeze(0),
            // Positions count real tokens from padding_idx + 1, as fairseq/RoBERTa do.
            Family::MPNet => mask.cumsum(1, Kind::Int64) * &mask + self.pad_id,
        };
        let mut x = lookup("embeddings.word_embeddings.weight", &ids)
            + lookup("embeddings.position_embeddings.weight", &positions);
        if self.family == Family::Bert {
            // One segment: every token type is 0.
            x += lookup("embeddings.token_type_embeddings.weight", &ids.zeros_like());
        }
        let mut x = self.norm(&x, "embeddings.LayerNorm");
        // Additive attention mask: the dtype's minimum where a key is padding (as transformers).
        let neg = (mask.ones_like() - &mask).to_kind(Kind::Float) * f64::from(f32::MIN);
        // Not `+=`: the position bias broadcasts the mask up to [b, heads, len, len].
        let bias = match self.family {
            Family::Bert => neg.view([b, 1, 1, len]),
            Family::MPNet => neg.view([b, 1, 1, len]) + self.position_bias(len),
        };
        let dh = self.hidden / self.heads;
        let scale = 1.0 / (dh as f64).sqrt();
        for l in 0..self.layers {
            let (q, k, v, o, ln) = self.attention_names(l);
            let split = |t: Tensor| t.view([b, len, self.heads, dh]).transpose(1, 2);
            let qh = split(self.dense(&x, &q));
            let kh = split(self.dense(&x, &k));
            let vh = split(self.dense(&x, &v));
            let scores = qh.matmul(&kh.transpose(-1, -2)) * scale + &bias;
            let probs = scores.softmax(-1, Kind::Float);
            let ctx = probs
                .matmul(&vh)
                .transpose(1, 2)
                .contiguous()
                .view([b, len, self.hidden]);
            x = self.norm(&(self.dense(&ctx, &o) + &x), &ln);
            let inter = self
                .dense(&x, &format!("encoder.layer.{l}.intermediate.dense"))
                .gelu("none");
            let out = self.dense(&inter, &format!("encoder.layer.{l}.output.dense"));
            x = self.norm(&(out + &x), &format!("encoder.layer.{l}.output.LayerNorm"));
        }
        let m = mask.to_kind(Kind::Float).unsqueeze(-1);
        let summed = (&x * &m).sum_dim_intlist(1, false, Kind::Float);
        let counts = m.sum_dim_intlist(1, false, Kind::Float).clamp_min(1e-9);
        let mut pooled = summed / counts;
        if self.normalize {
            let norms = pooled.norm_scalaropt_dim(2, [1], true).clamp_min(1e-12);
            pooled /= norms;
        }
        let pooled = pooled.to_device(Device::Cpu).contiguous();
        let flat: Vec<f32> = Vec::<f32>::try_from(pooled.view([-1]))?;
        Ok(flat
            .chunks(self.hidden as usize)
            .map(<[f32]>::to_vec)
            .collect())
    }

    /// MPNet's relative position bias, `[1, heads, len, len]`, with transformers' bucketing
    /// computed with the same float32 operations.
    fn position_bias(&self, len: i64) -> Tensor {
        let opts = (Kind::Int64, self.device);
        let context = Tensor::arange(len, opts).unsqueeze(1);
        let memory = Tensor::arange(len, opts).unsqueeze(0);
        let relative = memory - context;
        let num_buckets = self.buckets / 2;
        let max_distance = 128.0f64;
        let n = -relative;
        let mut ret = n.lt(0).to_kind(Kind::Int64) * num_buckets;
        let n = n.abs();
        let max_exact = num_buckets / 2;
        let is_small = n.lt(max_exact);
        let large = (n.to_kind(Kind::Float) / max_exact as f64).log()
            / (max_distance / max_exact as f64).ln()
            * (num_buckets - max_exact) as f64;
        let large = (large.to_kind(Kind::Int64) + max_exact).clamp_max(num_buckets - 1);
        ret += n.where_self(&is_small, &large);
        let values = Tensor::embedding(
            self.w("encoder.relative_attention_bias.weight"),
            &ret,
            -1,
            false,
            false,
        );
        values.permute([2, 0, 1]).unsqueeze(0)
    }
}
