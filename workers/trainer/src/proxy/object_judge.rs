//! The object judge (`ProxyConfig::object_judge`): whether a task is done, read off the state
//! and the scene objects' positions a world model predicts (`VideoModelConfig::object_weight`)
//! rather than off an imagined frame. A frame judge can be fooled by a blur that looks like the
//! oracle's ending; a predicted position says where the model thinks the block is.
//!
//! Features of a state `s` and objects `o₁…o_k` (x, y, z each): every value of `s`, each
//! object's height, and for each pair `i < j` the squared differences of x, y and z and the
//! signed difference of z — "in", "on" and "near" are thresholds on those. Standardised on the
//! training examples; logistic regression with an L2 penalty, positives weighted by
//! negatives/positives (as the frame judge), full-batch Adam from zero weights: deterministic,
//! nothing drawn at random. The examples are the frame judge's: each training episode's last
//! frame (its outcome) and its frames at `judge_not_done` (not done), real and replayed in the
//! world model with the real actions.

use assay_model::world::WorldFrame;

/// Full-batch Adam steps of the fit.
const STEPS: usize = 1500;
const LR: f64 = 0.05;
/// L2 penalty on the weights (not the bias), per example.
const L2: f64 = 1e-3;

/// The features of a state and the objects' positions (see the module docs).
pub(crate) fn features(state: &[f32], objects: &[f32]) -> Vec<f64> {
    let k = objects.len() / 3;
    let at = |i: usize, d: usize| f64::from(objects[3 * i + d]);
    let mut f: Vec<f64> = state.iter().map(|v| f64::from(*v)).collect();
    f.extend((0..k).map(|i| at(i, 2)));
    for i in 0..k {
        for j in i + 1..k {
            for d in 0..3 {
                f.push((at(i, d) - at(j, d)).powi(2));
            }
            f.push(at(j, 2) - at(i, 2));
        }
    }
    f
}

/// The features of a world model's imagined frame, when it predicted state and objects.
pub(crate) fn imagined_features(frame: &WorldFrame) -> Option<Vec<f64>> {
    Some(features(frame.state.as_deref()?, frame.objects.as_deref()?))
}

/// A trained object judge.
#[derive(Debug, Clone)]
pub(crate) struct ObjectJudge {
    mean: Vec<f64>,
    dev: Vec<f64>,
    weights: Vec<f64>,
    bias: f64,
    /// The answer of a judge trained on one class only.
    constant: Option<f64>,
}

impl ObjectJudge {
    /// Fits the judge on `examples` (features, done); returns it with its training accuracy.
    /// Every example must have as many features as the first.
    pub(crate) fn fit(examples: &[(Vec<f64>, bool)]) -> (Self, f64) {
        let n = examples.len();
        let d = examples.first().map_or(0, |e| e.0.len());
        let positives = examples.iter().filter(|e| e.1).count();
        let mut mean = vec![0.0; d];
        let mut dev = vec![1.0; d];
        for k in 0..d {
            let m = examples.iter().map(|e| e.0[k]).sum::<f64>() / n.max(1) as f64;
            let var = examples.iter().map(|e| (e.0[k] - m).powi(2)).sum::<f64>() / n.max(1) as f64;
            mean[k] = m;
            dev[k] = if var.sqrt() > 1e-9 { var.sqrt() } else { 1.0 };
        }
        let mut judge = Self {
            mean,
            dev,
            weights: vec![0.0; d],
            bias: 0.0,
            constant: None,
        };
        if positives == 0 || positives == n {
            judge.constant = Some(if positives > 0 { 1.0 } else { 0.0 });
            return (judge, 1.0);
        }
        let x: Vec<Vec<f64>> = examples.iter().map(|e| judge.standardised(&e.0)).collect();
        let pos_weight = (n - positives) as f64 / positives as f64;
        // Adam on [weights…, bias].
        let (mut m, mut v) = (vec![0.0; d + 1], vec![0.0; d + 1]);
        let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8);
        for step in 1..=STEPS {
            // The weighted mean gradient of the loss: the weights' (with the penalty), then
            // the bias'.
            let mut grad = vec![0.0; d + 1];
            let mut total = 0.0;
            for (xi, e) in x.iter().zip(examples) {
                let p = sigmoid(judge.logit(xi));
                let (y, w) = if e.1 { (1.0, pos_weight) } else { (0.0, 1.0) };
                let g = w * (p - y);
                for (gk, xk) in grad.iter_mut().zip(xi.iter().chain([&1.0])) {
                    *gk += g * xk;
                }
                total += w;
            }
            for (gk, wk) in grad.iter_mut().zip(judge.weights.iter().chain([&0.0])) {
                *gk = *gk / total + L2 * wk;
            }
            let t = step as i32;
            let mut updates = Vec::with_capacity(d + 1);
            for ((mk, vk), gk) in m.iter_mut().zip(v.iter_mut()).zip(&grad) {
                *mk = b1 * *mk + (1.0 - b1) * gk;
                *vk = b2 * *vk + (1.0 - b2) * gk * gk;
                let (mh, vh) = (*mk / (1.0 - b1.powi(t)), *vk / (1.0 - b2.powi(t)));
                updates.push(LR * mh / (vh.sqrt() + eps));
            }
            for (wk, u) in judge.weights.iter_mut().zip(&updates) {
                *wk -= u;
            }
            judge.bias -= updates[d];
        }
        let correct = x
            .iter()
            .zip(examples)
            .filter(|(xi, e)| (sigmoid(judge.logit(xi)) >= 0.5) == e.1)
            .count();
        (judge, correct as f64 / n as f64)
    }

    fn standardised(&self, f: &[f64]) -> Vec<f64> {
        f.iter()
            .zip(self.mean.iter().zip(&self.dev))
            .map(|(v, (m, s))| (v - m) / s)
            .collect()
    }

    fn logit(&self, x: &[f64]) -> f64 {
        self.bias + x.iter().zip(&self.weights).map(|(a, b)| a * b).sum::<f64>()
    }

    /// The probability that `state` and `objects` show the task done; 0 for features of
    /// another width than the training examples' (another number of objects).
    pub(crate) fn probability(&self, state: &[f32], objects: &[f32]) -> f64 {
        if let Some(c) = self.constant {
            return c;
        }
        let f = features(state, objects);
        if f.len() != self.weights.len() {
            return 0.0;
        }
        sigmoid(self.logit(&self.standardised(&f)))
    }
}

fn sigmoid(z: f64) -> f64 {
    1.0 / (1.0 + (-z).exp())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A block (object 0) and a bowl (object 1, at the origin); the state is a tool position and
    /// holding. Done: the block within 4 cm of the bowl in x and y, low, not held.
    fn example(block: [f32; 3], holding: bool) -> (Vec<f64>, bool) {
        let state = [
            block[0],
            block[1],
            block[2] + 0.05,
            f32::from(u8::from(holding)),
        ];
        let objects = [block[0], block[1], block[2], 0.0, 0.0, 0.0];
        let done = block[0].hypot(block[1]) < 0.04 && block[2] < 0.05 && !holding;
        (features(&state, &objects), done)
    }

    #[test]
    fn the_judge_learns_in_from_distances_between_objects_not_from_places() {
        // Blocks on a grid of places around the bowl, some held up in the air.
        let mut train = Vec::new();
        for i in -6..=6 {
            for j in -6..=6 {
                let (x, y) = (i as f32 * 0.015, j as f32 * 0.015);
                train.push(example([x, y, 0.02], false));
                if (i + j) % 3 == 0 {
                    train.push(example([x, y, 0.15], true));
                }
            }
        }
        let (judge, accuracy) = ObjectJudge::fit(&train);
        assert!(accuracy > 0.95, "training accuracy {accuracy}");
        let p = |block: [f32; 3], holding: bool| {
            let state = [
                block[0],
                block[1],
                block[2] + 0.05,
                f32::from(u8::from(holding)),
            ];
            judge.probability(&state, &[block[0], block[1], block[2], 0.0, 0.0, 0.0])
        };
        // Places between the grid's: in the bowl, beside it, above it in the gripper.
        assert!(p([0.007, -0.008, 0.02], false) > 0.8);
        assert!(p([0.08, 0.0, 0.02], false) < 0.2);
        assert!(p([0.005, 0.0, 0.15], true) < 0.2);
        // Deterministic, and refusing another number of objects.
        assert_eq!(ObjectJudge::fit(&train).0.weights, judge.weights);
        assert_eq!(judge.probability(&[0.0; 4], &[0.0; 3]), 0.0);
    }

    #[test]
    fn one_class_gives_a_constant_judge() {
        let train = vec![example([0.2, 0.2, 0.02], false); 5];
        let (judge, accuracy) = ObjectJudge::fit(&train);
        assert_eq!(accuracy, 1.0);
        assert_eq!(judge.probability(&[0.0; 4], &[0.0; 6]), 0.0);
    }

    #[test]
    fn features_are_the_state_heights_and_pairwise_differences() {
        let f = features(&[1.0, 2.0], &[0.0, 0.0, 1.0, 3.0, 4.0, 0.5]);
        assert_eq!(f, vec![1.0, 2.0, 1.0, 0.5, 9.0, 16.0, 0.25, -0.5]);
    }
}
