//! Adam with gradient clipping by global norm, written out so that its state (the moments and the
//! step count) can be checkpointed and restored bit for bit: tch's built-in optimizers keep their
//! state inside libtorch where it cannot be saved.

use tch::Tensor;

/// Adam (Kingma & Ba) with bias correction, no weight decay.
pub(crate) struct Adam {
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    /// Gradients are scaled down so that their global L2 norm is at most this (DreamerV3 clips
    /// the world model's gradients at 1000).
    pub clip: f64,
    /// Updates taken so far (the `t` of the bias correction).
    pub t: u64,
    /// First and second moments, one per parameter, in parameter order.
    pub m: Vec<Tensor>,
    pub v: Vec<Tensor>,
}

impl Adam {
    pub fn new(params: &[Tensor], lr: f64, clip: f64) -> Self {
        let zeros = || params.iter().map(Tensor::zeros_like).collect::<Vec<_>>();
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            clip,
            t: 0,
            m: zeros(),
            v: zeros(),
        }
    }

    /// One update from the gradients accumulated in `params` (which are zeroed afterwards).
    /// Returns the global gradient norm before clipping.
    pub fn step(&mut self, params: &mut [Tensor]) -> f64 {
        tch::no_grad(|| {
            let grads: Vec<Tensor> = params
                .iter()
                .map(|p| {
                    let g = p.grad();
                    if g.defined() { g } else { p.zeros_like() }
                })
                .collect();
            let norm = grads
                .iter()
                .map(|g| g.square().sum(tch::Kind::Double))
                .fold(
                    Tensor::from(0.0f64).to_device(params[0].device()),
                    |a, b| a + b,
                )
                .sqrt()
                .double_value(&[]);
            let scale = if norm.is_finite() && norm > self.clip {
                self.clip / (norm + 1e-6)
            } else {
                1.0
            };
            self.t += 1;
            let bc1 = 1.0 - self.beta1.powi(self.t as i32);
            let bc2 = 1.0 - self.beta2.powi(self.t as i32);
            for (i, p) in params.iter_mut().enumerate() {
                let g = &grads[i] * scale;
                let _ = self.m[i].g_mul_scalar_(self.beta1);
                let _ = self.m[i].g_add_(&(&g * (1.0 - self.beta1)));
                let _ = self.v[i].g_mul_scalar_(self.beta2);
                let _ = self.v[i].g_add_(&(g.square() * (1.0 - self.beta2)));
                let denom = (&self.v[i] / bc2).sqrt() + self.eps;
                let update = (&self.m[i] / bc1) / denom * self.lr;
                let _ = p.g_sub_(&update);
                p.zero_grad();
            }
            norm
        })
    }
}
