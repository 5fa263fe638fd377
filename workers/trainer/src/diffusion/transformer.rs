//! The transformer denoiser of a diffusion policy: Chi et al.'s `TransformerForDiffusion` with
//! the observations as conditioning (`obs_as_cond`, `causal_attn`, no condition encoder layers),
//! sized by [`TransformerSize`].
//!
//! - **Tokens**: each action of the noisy chunk through a linear layer, plus a learned position
//!   embedding (one per chunk step).
//! - **Memory** (what the tokens attend to): the diffusion step's sinusoidal embedding and, per
//!   observed step, that step's image features and proprioception through a linear layer, plus a
//!   learned position embedding; then Chi et al.'s condition MLP (Linear → Mish → Linear).
//! - **Decoder**: `layers` pre-norm layers of PyTorch's `TransformerDecoderLayer` (`norm_first`):
//!   causal self-attention among the chunk's tokens, cross-attention to the memory — chunk step
//!   `t` sees the diffusion step and the observed steps `s ≤ t + 1` (Chi et al.'s memory mask) —
//!   and a GELU MLP 4× wide, each added to its input; a final LayerNorm and a linear layer to the
//!   predicted noise.
//!
//! Dropout is left out (Chi et al.'s 0.1 on larger data; these fits are a few thousand steps). The
//! layer norms are the world model's (`world_model::Norm`, ε 10⁻³).

use assay_model::diffusion::TransformerSize;
use tch::{Kind, Tensor};

use crate::world_model::{Init, Linear, Norm};

/// Multi-head attention with query, key, value and output projections.
struct Attention {
    q: Linear,
    k: Linear,
    v: Linear,
    out: Linear,
    heads: i64,
}

impl Attention {
    fn new(init: &mut Init, name: &str, width: i64, heads: i64) -> Self {
        Self {
            q: Linear::new(init, &format!("{name}/q"), width, width, true),
            k: Linear::new(init, &format!("{name}/k"), width, width, true),
            v: Linear::new(init, &format!("{name}/v"), width, width, true),
            out: Linear::new(init, &format!("{name}/out"), width, width, true),
            heads,
        }
    }

    /// `x` `[B, T, E]` attends `memory` `[B, S, E]`; `allowed` `[T, S]` (bool) says which.
    fn forward(&self, x: &Tensor, memory: &Tensor, allowed: &Tensor) -> Tensor {
        let (b, t, e) = x.size3().expect("[B, T, E]");
        let s = memory.size()[1];
        let d = e / self.heads;
        let split = |y: Tensor, n: i64| y.view([b, n, self.heads, d]).transpose(1, 2);
        let q = split(self.q.forward(x), t);
        let k = split(self.k.forward(memory), s);
        let v = split(self.v.forward(memory), s);
        let scores = q.matmul(&k.transpose(-2, -1)) / (d as f64).sqrt();
        let weights = scores
            .masked_fill(&allowed.logical_not(), f64::NEG_INFINITY)
            .softmax(-1, Kind::Float);
        let mixed = weights.matmul(&v).transpose(1, 2).reshape([b, t, e]);
        self.out.forward(&mixed)
    }
}

/// One pre-norm decoder layer.
struct Layer {
    norm1: Norm,
    self_attention: Attention,
    norm2: Norm,
    cross_attention: Attention,
    norm3: Norm,
    mlp1: Linear,
    mlp2: Linear,
}

impl Layer {
    fn new(init: &mut Init, name: &str, width: i64, heads: i64) -> Self {
        Self {
            norm1: Norm::new(init, &format!("{name}/norm1"), width),
            self_attention: Attention::new(init, &format!("{name}/self"), width, heads),
            norm2: Norm::new(init, &format!("{name}/norm2"), width),
            cross_attention: Attention::new(init, &format!("{name}/cross"), width, heads),
            norm3: Norm::new(init, &format!("{name}/norm3"), width),
            mlp1: Linear::new(init, &format!("{name}/mlp1"), width, 4 * width, true),
            mlp2: Linear::new(init, &format!("{name}/mlp2"), 4 * width, width, true),
        }
    }

    fn forward(&self, x: &Tensor, memory: &Tensor, causal: &Tensor, cross: &Tensor) -> Tensor {
        let h = self.norm1.forward(x);
        let x = x + self.self_attention.forward(&h, &h, causal);
        let x = &x
            + self
                .cross_attention
                .forward(&self.norm2.forward(&x), memory, cross);
        let h = self.mlp1.forward(&self.norm3.forward(&x)).gelu("none");
        &x + self.mlp2.forward(&h)
    }
}

/// The transformer denoiser; its parameters are created in `init` under `transformer/…`.
pub(super) struct TransformerDenoiser {
    input: Linear,
    position: Tensor,
    condition_input: Linear,
    condition_position: Tensor,
    condition_mlp: (Linear, Linear),
    layers: Vec<Layer>,
    norm: Norm,
    head: Linear,
    width: i64,
}

impl TransformerDenoiser {
    /// For chunks of `horizon` actions of `action_dims`, and `observed` steps of `per_step`
    /// conditioning values each.
    pub(super) fn new(
        init: &mut Init,
        size: &TransformerSize,
        horizon: i64,
        action_dims: i64,
        observed: i64,
        per_step: i64,
    ) -> Self {
        let e = size.width;
        Self {
            input: Linear::new(init, "transformer/input", action_dims, e, true),
            // Small random positions (Chi et al. draw them from N(0, 0.02)).
            position: init.uniform("transformer/position".into(), &[horizon, e], 4096, 4096),
            condition_input: Linear::new(init, "transformer/condition", per_step, e, true),
            condition_position: init.uniform(
                "transformer/condition_position".into(),
                &[observed + 1, e],
                4096,
                4096,
            ),
            condition_mlp: (
                Linear::new(init, "transformer/condition_mlp1", e, 4 * e, true),
                Linear::new(init, "transformer/condition_mlp2", 4 * e, e, true),
            ),
            layers: (0..size.layers)
                .map(|k| Layer::new(init, &format!("transformer/layer{k}"), e, size.heads))
                .collect(),
            norm: Norm::new(init, "transformer/norm", e),
            head: Linear::new(init, "transformer/head", e, action_dims, true),
            width: e,
        }
    }

    /// The predicted noise `[B, T, A]` of `noisy` `[B, T, A]` at diffusion steps `t` `[B]`
    /// (float), given the observation conditioning `[B, observed, per_step]`.
    pub(super) fn forward(&self, noisy: &Tensor, t: &Tensor, observed: &Tensor) -> Tensor {
        let device = noisy.device();
        let horizon = noisy.size()[1];
        let steps = observed.size()[1];
        let x = self.input.forward(noisy) + &self.position;
        let time = super::sinusoid(t, self.width).unsqueeze(1);
        let memory = Tensor::cat(&[time, self.condition_input.forward(observed)], 1)
            + &self.condition_position;
        let memory = self
            .condition_mlp
            .1
            .forward(&self.condition_mlp.0.forward(&memory).mish());
        let rows = Tensor::arange(horizon, (Kind::Int64, device)).unsqueeze(1);
        let causal = rows.ge_tensor(&Tensor::arange(horizon, (Kind::Int64, device)).unsqueeze(0));
        // Memory slot 0 is the diffusion step, slot s ≥ 1 the observed step s − 1: chunk step t
        // sees slots s ≤ t + 1.
        let cross =
            (rows + 1).ge_tensor(&Tensor::arange(steps + 1, (Kind::Int64, device)).unsqueeze(0));
        let mut x = x;
        for layer in &self.layers {
            x = layer.forward(&x, &memory, &causal, &cross);
        }
        self.head.forward(&self.norm.forward(&x))
    }
}
