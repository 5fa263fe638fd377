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

use crate::imagination::check_frames;

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

/// [`mse`] of each pair `(a[i], b[i])` of frames of one size (the callers check them), with
/// libtorch in double precision: the action test compares tens of thousands of frames, and this
/// crate builds unoptimised in the test profile.
fn mse_many(a: &[&[u8]], b: &[&[u8]]) -> Vec<f64> {
    let n = a.len().min(b.len());
    let len = a.first().map_or(0, |f| f.len());
    let frames = |f: &[&[u8]]| {
        Tensor::from_slice(&f[..n].concat())
            .view([n as i64, len as i64])
            .to_kind(Kind::Double)
    };
    let errors = tch::no_grad(|| {
        ((frames(a) - frames(b)) / 255.0)
            .square()
            .mean_dim([1i64].as_slice(), false, Kind::Double)
    });
    Vec::<f64>::try_from(&errors).expect("a double vector")
}

/// PSNR in dB of a mean squared error in [0, 1] units ([`mse`]; 100 for none).
pub fn psnr(mse: f64) -> f64 {
    if mse <= 1e-10 {
        100.0
    } else {
        (10.0 * (1.0 / mse).log10()).min(100.0)
    }
}

/// Frames compared at once by [`ssim`] (its double-precision maps of 160×120 frames take
/// about 15 MB each at this count).
const SSIM_BATCH: usize = 32;

/// SSIM (module docs) of each pair `(a[i], b[i])` of `width`×`height` RGB frames, computed with
/// libtorch in double precision over batches of frames: the separable Gaussian as two matrix
/// products with banded matrices (a depthwise convolution in double precision has no fast path
/// on a CPU: 26 ms a 160×120 frame against 6.5 ms), so it costs little in any build.
pub fn ssim(a: &[&[u8]], b: &[&[u8]], width: usize, height: usize) -> Vec<f64> {
    const R: usize = 5;
    if width <= 2 * R || height <= 2 * R {
        return vec![f64::NAN; a.len().min(b.len())];
    }
    let k: Vec<f64> = (0..=2 * R)
        .map(|i| (-((i as f64 - R as f64).powi(2)) / (2.0 * 1.5 * 1.5)).exp())
        .collect();
    let sum: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|v| v / sum).collect();
    // `band(n)[j][j + i] = k[i]`: the valid positions of a 1-D filter over `n` values.
    let band = |n: usize| {
        let valid = n - 2 * R;
        let mut m = vec![0f64; valid * n];
        for j in 0..valid {
            m[j * n + j..j * n + j + 2 * R + 1].copy_from_slice(&k);
        }
        Tensor::from_slice(&m).view([valid as i64, n as i64])
    };
    let (rows, cols) = (band(height), band(width).tr());
    let images = |frames: &[&[u8]]| {
        let bytes: Vec<u8> = frames.concat();
        Tensor::from_slice(&bytes)
            .view([frames.len() as i64, height as i64, width as i64, 3])
            .permute([0, 3, 1, 2])
            .to_kind(Kind::Double)
            / 255.0
    };
    // Along each row, then along each column: `[N, 3, H, W]` → `[N, 3, H − 2R, W − 2R]`.
    let blur = |x: &Tensor| rows.matmul(&x.matmul(&cols));
    let mut out = Vec::with_capacity(a.len());
    for (a, b) in a.chunks(SSIM_BATCH).zip(b.chunks(SSIM_BATCH)) {
        let n = a.len().min(b.len());
        let map = tch::no_grad(|| {
            let (x, y) = (images(&a[..n]), images(&b[..n]));
            let (mu_x, mu_y) = (blur(&x), blur(&y));
            let var_x = blur(&(&x * &x)) - &mu_x * &mu_x;
            let var_y = blur(&(&y * &y)) - &mu_y * &mu_y;
            let cov = blur(&(&x * &y)) - &mu_x * &mu_y;
            let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
            (((&mu_x * &mu_y * 2.0 + c1) * (cov * 2.0 + c2))
                / ((&mu_x * &mu_x + &mu_y * &mu_y + c1) * (var_x + var_y + c2)))
                .mean_dim([1i64, 2, 3].as_slice(), false, Kind::Double)
        });
        out.extend(Vec::<f64>::try_from(&map).expect("a double vector"));
    }
    out
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
/// Each clip's frames are imagined together ([`WorldModelService::replay_many`]).
pub fn one_step_mse(
    world: &dyn WorldModelService,
    clips: &[&Clip],
    names: &[StartName<'_>],
) -> Result<f64, WorldError> {
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, clip) in clips.iter().enumerate() {
        let frame = (clip.width * clip.height * 3) as usize;
        let steps = clip.len().saturating_sub(1);
        let starts: Vec<WorldStart> = (0..steps).map(|t| start_at(clip, t, &names[i])).collect();
        let moves: Vec<Vec<Vec<f32>>> = (0..steps).map(|t| actions(clip, t, 1)).collect();
        let runs: Vec<(&WorldStart, &[Vec<f32>])> = starts
            .iter()
            .zip(&moves)
            .map(|(s, a)| (s, a.as_slice()))
            .collect();
        let imagined = world.replay_many(&runs)?;
        for (t, frames) in imagined.iter().enumerate() {
            check_frames(frames, 1, &starts[t])?;
        }
        let next: Vec<&[u8]> = imagined.iter().map(|f| f[0].rgb.as_slice()).collect();
        let real: Vec<&[u8]> = (1..=steps)
            .map(|t| &clip.rgb[t * frame..(t + 1) * frame])
            .collect();
        sum += mse_many(&next, &real).iter().sum::<f64>();
        n += steps;
    }
    Ok(if n > 0 { sum / n as f64 } else { 0.0 })
}

/// The open-loop figures of `world` on `clips` (see the module docs); `names[i]` is what the
/// model is told of clip `i`. The action test needs 2 clips or more (else its figures are 0).
/// Each clip's windows, with each of their three action sequences, are imagined together
/// ([`WorldModelService::replay_many`]).
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
        let real = |t: usize| &clip.rgb[t * frame..(t + 1) * frame];
        let donor = clips[(i + 1) % clips.len()];
        let donor_windows = windows_of(donor.len(), horizon);
        let shuffled = clips.len() > 1 && !donor_windows.is_empty();
        let windows = windows_of(clip.len(), horizon);
        let starts: Vec<WorldStart> = windows
            .iter()
            .map(|(start, _)| start_at(clip, *start, &names[i]))
            .collect();
        // Per window: its own actions, another clip's (when there is one) and zeros.
        let mut moves: Vec<(usize, Vec<Vec<f32>>)> = Vec::new();
        for (k, &(start, n)) in windows.iter().enumerate() {
            moves.push((k, actions(clip, start, n)));
            if shuffled {
                let (ds, dn) = donor_windows[k.min(donor_windows.len() - 1)];
                let mut other = actions(donor, ds, dn);
                while other.len() < n {
                    other.push(other.last().cloned().unwrap_or_default());
                }
                other.truncate(n);
                moves.push((k, other));
            }
            moves.push((k, vec![vec![0.0f32; clip.action_dims as usize]; n]));
        }
        let runs: Vec<(&WorldStart, &[Vec<f32>])> = moves
            .iter()
            .map(|(k, a)| (&starts[*k], a.as_slice()))
            .collect();
        let imagined = world.replay_many(&runs)?;
        let per_window = if shuffled { 3 } else { 2 };
        for (k, &(start, n)) in windows.iter().enumerate() {
            let of = |v: usize| -> Result<Vec<&[u8]>, WorldError> {
                let frames = &imagined[k * per_window + v];
                check_frames(frames, n, &starts[k])?;
                Ok(frames.iter().map(|f| f.rgb.as_slice()).collect())
            };
            let targets: Vec<&[u8]> = (1..=n).map(|t| real(start + t)).collect();
            let own = of(0)?;
            let ssims = ssim(&own, &targets, clip.width as usize, clip.height as usize);
            for (m, s) in mse_many(&own, &targets).into_iter().zip(ssims) {
                true_sum += m;
                psnr_sum += psnr(m);
                ssim_sum += s;
            }
            if shuffled {
                shuffled_sum += mse_many(&of(1)?, &targets).iter().sum::<f64>();
            }
            zero_sum += mse_many(&of(per_window - 1)?, &targets).iter().sum::<f64>();
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

    fn ssim_one(a: &[u8], b: &[u8], width: usize, height: usize) -> f64 {
        ssim(&[a], &[b], width, height)[0]
    }

    fn frame(w: usize, h: usize, f: impl Fn(usize, usize) -> [u8; 3]) -> Vec<u8> {
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .flat_map(|(x, y)| f(x, y))
            .collect()
    }

    #[test]
    fn ssim_is_one_for_identical_frames_and_falls_with_noise() {
        let a = frame(32, 32, |x, y| [(x * 8) as u8, (y * 8) as u8, 128]);
        assert!((ssim_one(&a, &a, 32, 32) - 1.0).abs() < 1e-9);
        assert_eq!(psnr(mse(&a, &a)), 100.0);
        let b = frame(32, 32, |x, y| {
            let n = ((x * 7 + y * 13) % 5) as u8 * 6;
            [(x * 8) as u8 ^ n, (y * 8) as u8, 128u8.wrapping_add(n)]
        });
        let s = ssim_one(&a, &b, 32, 32);
        assert!(s < 0.99 && s > 0.0, "{s}");
        // A constant offset of 10/255 leaves structure and costs only luminance.
        let c = frame(32, 32, |x, y| {
            [(x * 8) as u8 / 2 + 10, (y * 8) as u8 / 2 + 10, 138]
        });
        let d = frame(32, 32, |x, y| [(x * 8) as u8 / 2, (y * 8) as u8 / 2, 128]);
        assert!(ssim_one(&c, &d, 32, 32) > 0.95);
        // PSNR of a uniform error of 1/255 per channel: 48.13 dB.
        let e = frame(32, 32, |_, _| [100, 100, 100]);
        let f = frame(32, 32, |_, _| [101, 101, 101]);
        let p = psnr(mse(&e, &f));
        assert!((p - 48.1308).abs() < 1e-3, "{p}");
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
    fn ssim_by_matrix_products_equals_the_direct_sum() {
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
        let (fast, direct) = (ssim_one(&a, &b, w, h), ssim_direct(&a, &b, w, h));
        assert!((fast - direct).abs() < 1e-12, "{fast} against {direct}");
        assert!(fast < 0.99, "{fast}");
    }

    #[test]
    fn frames_compared_together_score_as_each_alone() {
        let (w, h) = (24, 17);
        let frames: Vec<Vec<u8>> = (0..45)
            .map(|k| {
                frame(w, h, |x, y| {
                    [
                        (x * 10 + k) as u8,
                        (y * 14 + 3 * k) as u8,
                        ((x * y + 7 * k) % 256) as u8,
                    ]
                })
            })
            .collect();
        // More pairs than one batch of SSIM maps.
        let a: Vec<&[u8]> = frames[..40].iter().map(Vec::as_slice).collect();
        let b: Vec<&[u8]> = frames[5..].iter().map(Vec::as_slice).collect();
        let (m, s) = (mse_many(&a, &b), ssim(&a, &b, w, h));
        assert_eq!((m.len(), s.len()), (40, 40));
        for i in 0..40 {
            let (one, direct) = (mse(a[i], b[i]), ssim_direct(a[i], b[i], w, h));
            assert!((m[i] - one).abs() < 1e-12, "{i}: {} against {one}", m[i]);
            assert!(
                (s[i] - direct).abs() < 1e-12,
                "{i}: {} against {direct}",
                s[i]
            );
        }
        assert!(m.iter().all(|v| *v > 0.0) && s.iter().all(|v| *v < 0.99));
    }

    #[test]
    fn windows_cover_full_horizons_and_short_clips() {
        assert_eq!(windows_of(1, 16), vec![]);
        assert_eq!(windows_of(10, 16), vec![(0, 9)]);
        assert_eq!(windows_of(17, 16), vec![(0, 16)]);
        assert_eq!(windows_of(40, 16), vec![(0, 16), (16, 16)]);
    }
}
