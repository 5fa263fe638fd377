//! What the video model's clips hold (their interface, cameras, state and action widths) and
//! the resizing of cameras to and from the model's frame size.

use assay_model::clip::{ACTION_DIMS, Clip, PROPRIO_DIMS};
use assay_model::interface::Interface;
use tch::Tensor;

/// What the training clips hold, which every clip (and every imagined start) must match: their
/// interface, each camera's size (the first is the clip's frames, the others its views), the
/// state and action widths, and the object floats the model predicts beside the state (0: none).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Layout {
    pub(super) interface: String,
    pub(super) cameras: Vec<(String, u32, u32)>,
    pub(super) state: usize,
    pub(super) action: usize,
    pub(super) objects: usize,
}

impl Layout {
    pub(super) fn of(clip: &Clip) -> Self {
        let first = Interface::parse_args(&clip.interface)
            .ok()
            .and_then(|i| i.cameras.first().map(|c| c.name.clone()))
            .unwrap_or_else(|| "image".into());
        let mut cameras = vec![(first, clip.width, clip.height)];
        cameras.extend(
            clip.views
                .iter()
                .map(|v| (v.name.clone(), v.width, v.height)),
        );
        Self {
            interface: clip.interface.clone(),
            cameras,
            state: clip.proprio_dims as usize,
            action: clip.action_dims as usize,
            objects: 0,
        }
    }

    /// The layout of `train` for a model whose config asks for objects (`objects`): the first
    /// clip's, predicting its objects when every clip carries the same number of them.
    pub(super) fn of_training(train: &[Clip], objects: bool) -> Self {
        let mut layout = Self::of(&train[0]);
        let o = train[0].object_dims as usize;
        if objects && o > 0 && train.iter().all(|c| c.object_dims as usize == o) {
            layout.objects = o;
        }
        layout
    }

    /// Floats of the model's state: the clip's state, then the objects'.
    pub(super) fn width(&self) -> usize {
        self.state + self.objects
    }

    /// The model's state at frame `t` of `clip` (checked against the layout): its state, then
    /// its objects' positions when the model predicts them.
    pub(super) fn state_at<'a>(&self, clip: &'a Clip, t: usize) -> impl Iterator<Item = &'a f32> {
        let p = self.state;
        let objects = if self.objects > 0 {
            clip.objects_at(t)
        } else {
            &[]
        };
        clip.proprio[t * p..(t + 1) * p].iter().chain(objects)
    }

    /// The original interface's: one camera of `size`, 4 state and 4 action floats.
    pub(super) fn original(size: u32) -> Self {
        Self {
            interface: String::new(),
            cameras: vec![("image".into(), size, size)],
            state: PROPRIO_DIMS,
            action: ACTION_DIMS,
            objects: 0,
        }
    }

    /// The interface, each camera at its size.
    pub(super) fn interface(&self) -> Interface {
        let sizes: Vec<(u32, u32)> = self.cameras.iter().map(|(_, w, h)| (*w, *h)).collect();
        crate::imagination::sized_interface(&self.interface, &sizes)
    }

    /// Whether the state's last float is "holding" (rounded to 0 or 1 in imagined states).
    pub(super) fn holding_last(&self) -> bool {
        Interface::parse_args(&self.interface)
            .map(|i| i.state.last() == Some(&assay_model::interface::StatePart::Holding))
            .unwrap_or(true)
    }

    pub(super) fn describe(&self) -> String {
        let cams: Vec<String> = self
            .cameras
            .iter()
            .map(|(n, w, h)| format!("'{n}' {w}x{h}"))
            .collect();
        format!(
            "camera(s) {}, {} state{} and {} action floats{}",
            cams.join(", "),
            self.state,
            if self.objects > 0 {
                format!(", {} object", self.objects)
            } else {
                String::new()
            },
            self.action,
            if self.interface.is_empty() {
                String::new()
            } else {
                format!(" (interface {})", self.interface)
            }
        )
    }

    /// Why `clip` cannot be trained with clips of this layout.
    pub(super) fn check(&self, clip: &Clip) -> Result<(), String> {
        clip.validate().map_err(|e| e.to_string())?;
        let mut other = Layout::of(clip);
        if self.objects > 0 {
            other.objects = clip.object_dims as usize;
        }
        if other != *self {
            return Err(format!(
                "a clip of {}: the other clips have {}",
                other.describe(),
                self.describe()
            ));
        }
        if !clip.interface.is_empty() {
            Interface::parse_args(&clip.interface)
                .map_err(|e| format!("interface '{}': {e}", clip.interface))?;
        }
        crate::world_model::finite_values(clip)
    }

    /// Channels of all cameras stacked.
    pub(super) fn channels(&self) -> i64 {
        3 * self.cameras.len() as i64
    }
}

/// `x` (`[N, C, h, w]`) at `s`×`s`: area-averaged down, bilinear up, as it is when it fits.
pub(crate) fn resized(x: &Tensor, s: i64) -> Tensor {
    let (h, w) = (x.size()[2], x.size()[3]);
    if (h, w) == (s, s) {
        x.shallow_clone()
    } else if h >= s && w >= s {
        x.adaptive_avg_pool2d([s, s])
    } else {
        x.upsample_bilinear2d([s, s], false, None, None)
    }
}

/// `x` (`[N, C, s, s]`) at `h`×`w`, bilinear; as it is when it fits.
pub(super) fn resized_to(x: &Tensor, h: i64, w: i64) -> Tensor {
    if (x.size()[2], x.size()[3]) == (h, w) {
        x.shallow_clone()
    } else {
        x.upsample_bilinear2d([h, w], false, None, None)
    }
}
