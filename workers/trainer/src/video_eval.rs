//! Video prediction measured as the world-model paper's Table II (PSNR, SSIM of open-loop
//! predictions), and the action test over open-loop windows: the same starts with the true
//! actions, another episode's and zero actions. Works on any [`WorldModelService`].
//!
//! # Windows
//! Each clip is cut into windows of `horizon` predicted frames starting at frames 0, `horizon`,
//! 2·`horizon`, … (a clip shorter than one window gives one window of what it has). A window is
//! imagined from its real first frame and state with `horizon` actions, never seeing another
//! real frame, and compared with the real frames that followed.
//!
//! # Metrics
//! Per predicted frame, in [0, 1] units: the mean squared error per pixel-channel; PSNR
//! `10·log10(1 / mse)` (capped at 100 dB for identical frames); SSIM (Wang et al. 2004) with an
//! 11×11 Gaussian window of σ 1.5, `C1 = 0.01²`, `C2 = 0.03²`, over the valid window positions
//! of each channel, averaged — scikit-image's `structural_similarity(gaussian_weights=True)`
//! without its border padding. Figures are means over every predicted frame. LPIPS and FVD need
//! pretrained networks (AlexNet/VGG, I3D) that cannot be had from the package registries this
//! project may use, so they are not computed.

use assay_model::clip::Clip;
use assay_model::world::{WorldError, WorldModelService, WorldStart};
use tch::{Kind, Tensor};

use crate::imagination::replay;

/// Imagined frames per window of the action test and the video figures (the paper's 16).
pub const HORIZON: usize = 16;

/// The open-loop figures of one model on one set of clips.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct OpenLoop {
    pub clips: usize,
    pub windows: usize,
    /// Predicted frames (each window's, summed).
    pub frames: usize,
    pub horizon: usize,
    /// With the window's own actions.
    pub mse_true: f64,
    pub psnr: f64,
    pub ssim: f64,
    /// With the actions of the next clip's window (the action test).
    pub mse_shuffled: f64,
    /// With all-zero actions.
    pub mse_zero: f64,
    /// `mse_shuffled / mse_true`: near 1 for a model that ignores its actions.
    pub ratio_shuffled: f64,
}

/// Mean squared error per pixel-channel, in [0, 1] units.
pub fn mse(a: &[u8], b: &[u8]) -> f64 {
    crate::imagination::mse(a, b)
}

/// PSNR in dB of two frames of bytes (100 for identical frames).
pub fn psnr(a: &[u8], b: &[u8]) -> f64 {
    let m = mse(a, b);
    if m <= 1e-10 {
        100.0
    } else {
        (10.0 * (1.0 / m).log10()).min(100.0)
    }
}

/// SSIM of two `width`×`height` RGB frames (module docs). Computed with libtorch in double
/// precision (a separable Gaussian as two depthwise convolutions), so it costs little in any
/// build.
pub fn ssim(a: &[u8], b: &[u8], width: usize, height: usize) -> f64 {
    const R: i64 = 5;
    if width as i64 <= 2 * R || height as i64 <= 2 * R {
        return f64::NAN;
    }
    let k: Vec<f64> = (0..=2 * R)
        .map(|i| (-(((i - R) as f64).powi(2)) / (2.0 * 1.5 * 1.5)).exp())
        .collect();
    let sum: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|v| v / sum).collect();
    let kernel = Tensor::from_slice(&k);
    let (kx, ky) = (
        kernel.view([1, 1, 1, 2 * R + 1]).repeat([3, 1, 1, 1]),
        kernel.view([1, 1, 2 * R + 1, 1]).repeat([3, 1, 1, 1]),
    );
    let image = |f: &[u8]| {
        Tensor::from_slice(f)
            .view([1, height as i64, width as i64, 3])
            .permute([0, 3, 1, 2])
            .to_kind(Kind::Double)
            / 255.0
    };
    let blur = |x: &Tensor| {
        x.conv2d(&kx, None::<Tensor>, [1, 1], [0, 0], [1, 1], 3)
            .conv2d(&ky, None::<Tensor>, [1, 1], [0, 0], [1, 1], 3)
    };
    tch::no_grad(|| {
        let (x, y) = (image(a), image(b));
        let (mu_x, mu_y) = (blur(&x), blur(&y));
        let var_x = blur(&(&x * &x)) - &mu_x * &mu_x;
        let var_y = blur(&(&y * &y)) - &mu_y * &mu_y;
        let cov = blur(&(&x * &y)) - &mu_x * &mu_y;
        let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
        let map = ((&mu_x * &mu_y * 2.0 + c1) * (cov * 2.0 + c2))
            / ((&mu_x * &mu_x + &mu_y * &mu_y + c1) * (var_x + var_y + c2));
        map.mean(Kind::Double).double_value(&[])
    })
}

/// The windows of a clip of `len` frames: `(start, predicted frames)`.
fn windows_of(len: usize, horizon: usize) -> Vec<(usize, usize)> {
    if len < 2 {
        return Vec::new();
    }
    if len - 1 < horizon {
        return vec![(0, len - 1)];
    }
    (0..)
        .map(|k| k * horizon)
        .take_while(|s| s + horizon < len)
        .map(|s| (s, horizon))
        .collect()
}

/// The start of a window: the clip's frames and state at `t`.
fn start_at(clip: &Clip, t: usize, name: &StartName<'_>) -> WorldStart {
    crate::imagination::start_at(clip, t, name.task_id, name.seed, name.instruction)
}

/// What a world model is told of an episode besides its frames.
pub struct StartName<'a> {
    pub task_id: &'a str,
    pub seed: u64,
    pub instruction: &'a str,
}

fn actions(clip: &Clip, start: usize, n: usize) -> Vec<Vec<f32>> {
    let d = clip.action_dims as usize;
    (start..start + n)
        .map(|t| clip.actions[t * d..(t + 1) * d].to_vec())
        .collect()
}

/// The one-step image error of `world` on `clips`: every next frame imagined from the real one
/// before it with its action (the MSE per pixel-channel, averaged over the predicted frames).
pub fn one_step_mse(
    world: &dyn WorldModelService,
    clips: &[&Clip],
    names: &[StartName<'_>],
) -> Result<f64, WorldError> {
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, clip) in clips.iter().enumerate() {
        let frame = (clip.width * clip.height * 3) as usize;
        for t in 0..clip.len().saturating_sub(1) {
            let imagined = replay(world, &start_at(clip, t, &names[i]), &actions(clip, t, 1))?;
            sum += mse(&imagined[0], &clip.rgb[(t + 1) * frame..(t + 2) * frame]);
            n += 1;
        }
    }
    Ok(if n > 0 { sum / n as f64 } else { 0.0 })
}

/// The open-loop figures of `world` on `clips` (see the module docs); `names[i]` is what the
/// model is told of clip `i`. The action test needs 2 clips or more (else its figures are 0).
pub fn open_loop(
    world: &dyn WorldModelService,
    clips: &[&Clip],
    names: &[StartName<'_>],
    horizon: usize,
) -> Result<OpenLoop, WorldError> {
    let horizon = horizon.max(1);
    let mut out = OpenLoop {
        clips: clips.len(),
        horizon,
        ..OpenLoop::default()
    };
    let (mut true_sum, mut shuffled_sum, mut zero_sum, mut psnr_sum, mut ssim_sum) =
        (0.0, 0.0, 0.0, 0.0, 0.0);
    for (i, clip) in clips.iter().enumerate() {
        let frame = (clip.width * clip.height * 3) as usize;
        let donor = clips[(i + 1) % clips.len()];
        let donor_windows = windows_of(donor.len(), horizon);
        for (k, (start, n)) in windows_of(clip.len(), horizon).into_iter().enumerate() {
            let begin = start_at(clip, start, &names[i]);
            let real = |t: usize| &clip.rgb[(start + t) * frame..(start + t + 1) * frame];
            let own = actions(clip, start, n);
            for (t, f) in replay(world, &begin, &own)?.iter().enumerate() {
                true_sum += mse(f, real(t + 1));
                psnr_sum += psnr(f, real(t + 1));
                ssim_sum += ssim(f, real(t + 1), clip.width as usize, clip.height as usize);
            }
            if clips.len() > 1 && !donor_windows.is_empty() {
                let (ds, dn) = donor_windows[k.min(donor_windows.len() - 1)];
                let mut other = actions(donor, ds, dn);
                while other.len() < n {
                    other.push(other.last().cloned().unwrap_or_default());
                }
                other.truncate(n);
                for (t, f) in replay(world, &begin, &other)?.iter().enumerate() {
                    shuffled_sum += mse(f, real(t + 1));
                }
            }
            let zeros = vec![vec![0.0f32; clip.action_dims as usize]; n];
            for (t, f) in replay(world, &begin, &zeros)?.iter().enumerate() {
                zero_sum += mse(f, real(t + 1));
            }
            out.windows += 1;
            out.frames += n;
        }
    }
    if out.frames > 0 {
        let n = out.frames as f64;
        out.mse_true = true_sum / n;
        out.psnr = psnr_sum / n;
        out.ssim = ssim_sum / n;
        out.mse_shuffled = shuffled_sum / n;
        out.mse_zero = zero_sum / n;
        out.ratio_shuffled = if out.mse_true > 0.0 {
            out.mse_shuffled / out.mse_true
        } else {
            0.0
        };
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(w: usize, h: usize, f: impl Fn(usize, usize) -> [u8; 3]) -> Vec<u8> {
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .flat_map(|(x, y)| f(x, y))
            .collect()
    }

    #[test]
    fn ssim_is_one_for_identical_frames_and_falls_with_noise() {
        let a = frame(32, 32, |x, y| [(x * 8) as u8, (y * 8) as u8, 128]);
        assert!((ssim(&a, &a, 32, 32) - 1.0).abs() < 1e-9);
        assert_eq!(psnr(&a, &a), 100.0);
        let b = frame(32, 32, |x, y| {
            let n = ((x * 7 + y * 13) % 5) as u8 * 6;
            [(x * 8) as u8 ^ n, (y * 8) as u8, 128u8.wrapping_add(n)]
        });
        let s = ssim(&a, &b, 32, 32);
        assert!(s < 0.99 && s > 0.0, "{s}");
        // A constant offset of 10/255 leaves structure and costs only luminance.
        let c = frame(32, 32, |x, y| {
            [(x * 8) as u8 / 2 + 10, (y * 8) as u8 / 2 + 10, 138]
        });
        let d = frame(32, 32, |x, y| [(x * 8) as u8 / 2, (y * 8) as u8 / 2, 128]);
        assert!(ssim(&c, &d, 32, 32) > 0.95);
        // PSNR of a uniform error of 1/255 per channel: 48.13 dB.
        let e = frame(32, 32, |_, _| [100, 100, 100]);
        let f = frame(32, 32, |_, _| [101, 101, 101]);
        assert!((psnr(&e, &f) - 48.1308).abs() < 1e-3, "{}", psnr(&e, &f));
    }

    /// SSIM summed directly over the valid window positions, to check the convolutions.
    fn ssim_direct(a: &[u8], b: &[u8], width: usize, height: usize) -> f64 {
        let r = 5usize;
        let k: Vec<f64> = (0..=2 * r)
            .map(|i| (-((i as f64 - r as f64).powi(2)) / (2.0 * 1.5 * 1.5)).exp())
            .collect();
        let sum: f64 = k.iter().sum();
        let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
        let mut total = 0.0;
        let (ow, oh) = (width - 2 * r, height - 2 * r);
        for ch in 0..3 {
            let px = |f: &[u8], x: usize, y: usize| f64::from(f[(y * width + x) * 3 + ch]) / 255.0;
            for y in 0..oh {
                for x in 0..ow {
                    let mut m = [0.0f64; 5];
                    for j in 0..=2 * r {
                        for i in 0..=2 * r {
                            let w = k[i] * k[j] / (sum * sum);
                            let (u, v) = (px(a, x + i, y + j), px(b, x + i, y + j));
                            for (slot, value) in m.iter_mut().zip([u, v, u * u, v * v, u * v]) {
                                *slot += w * value;
                            }
                        }
                    }
                    let (var_a, var_b) = (m[2] - m[0] * m[0], m[3] - m[1] * m[1]);
                    let cov = m[4] - m[0] * m[1];
                    total += ((2.0 * m[0] * m[1] + c1) * (2.0 * cov + c2))
                        / ((m[0] * m[0] + m[1] * m[1] + c1) * (var_a + var_b + c2));
                }
            }
        }
        total / (3 * ow * oh) as f64
    }

    #[test]
    fn ssim_by_convolution_equals_the_direct_sum() {
        // Not square, so that rows and columns cannot be swapped unnoticed.
        let (w, h) = (24, 17);
        let a = frame(w, h, |x, y| {
            [(x * 10) as u8, (y * 14) as u8, ((x * y) % 256) as u8]
        });
        let b = frame(w, h, |x, y| {
            [
                (x * 9 + y) as u8,
                (y * 15) as u8,
                ((x * y + 7 * x) % 256) as u8,
            ]
        });
        let (fast, direct) = (ssim(&a, &b, w, h), ssim_direct(&a, &b, w, h));
        assert!((fast - direct).abs() < 1e-12, "{fast} against {direct}");
        assert!(fast < 0.99, "{fast}");
    }

    #[test]
    fn windows_cover_full_horizons_and_short_clips() {
        assert_eq!(windows_of(1, 16), vec![]);
        assert_eq!(windows_of(10, 16), vec![(0, 9)]);
        assert_eq!(windows_of(17, 16), vec![(0, 16)]);
        assert_eq!(windows_of(40, 16), vec![(0, 16), (16, 16)]);
    }
}
