//! The policy [`Interface`] on the wire: `assay.v1.PolicyInterface` both ways, and the
//! observation's named images.

use assay_model::policy::{
    ActionSpace, CameraRequest, CameraSource, Interface, NamedImage, StatePart,
};
use assay_proto::v1 as pb;

/// The interface a server declares; `None` (the field unset) is the original one.
pub fn interface_from_pb(p: Option<pb::PolicyInterface>) -> Result<Interface, String> {
    let Some(p) = p else {
        return Ok(Interface::default());
    };
    let mut i = Interface::default();
    if !p.cameras.is_empty() {
        i.cameras = p
            .cameras
            .into_iter()
            .map(|c| CameraRequest {
                name: c.name,
                source: CameraSource::parse(&c.source),
                width: c.width,
                height: c.height,
                depth: c.depth,
            })
            .collect();
    }
    if !p.state.is_empty() {
        i.state = p
            .state
            .iter()
            .map(|s| StatePart::parse(s))
            .collect::<Result<_, _>>()
            .map_err(|e| format!("interface.state: {e}"))?;
    }
    i.action =
        ActionSpace::parse(&p.action_space).map_err(|e| format!("interface.action_space: {e}"))?;
    i.execute = (p.execute_horizon > 0).then_some(p.execute_horizon);
    i.validate()?;
    Ok(i)
}

pub fn interface_to_pb(i: &Interface) -> pb::PolicyInterface {
    pb::PolicyInterface {
        cameras: i
            .cameras
            .iter()
            .map(|c| pb::CameraRequest {
                name: c.name.clone(),
                source: c.source.name().to_owned(),
                width: c.width,
                height: c.height,
                depth: c.depth,
            })
            .collect(),
        state: i.state.iter().map(|s| s.name().to_owned()).collect(),
        action_space: i.action.name().to_owned(),
        execute_horizon: i.execute.unwrap_or(0),
    }
}

pub fn images_to_pb(images: &[NamedImage]) -> Vec<pb::Image> {
    images
        .iter()
        .map(|im| pb::Image {
            name: im.name.clone(),
            width: im.width,
            height: im.height,
            rgb: im.rgb.clone(),
            depth: im.depth.clone(),
        })
        .collect()
}

/// Checks a chunk of `dims`-float actions (None: the answer's own `action_dims`, at least 1).
pub fn chunk(
    r: pb::PolicyActResponse,
    dims: Option<usize>,
    max_chunk: usize,
) -> Result<Vec<Vec<f32>>, String> {
    let d = r.action_dims as usize;
    if d == 0 || dims.is_some_and(|want| want != d) {
        return Err(format!(
            "action_dims is {}, expected {}",
            r.action_dims,
            dims.map_or("at least 1".to_string(), |d| d.to_string())
        ));
    }
    let n = r.actions.len();
    if n == 0 || !n.is_multiple_of(d) || n / d > max_chunk {
        return Err(format!(
            "{n} floats is not a chunk of 1 to {max_chunk} actions of {d}"
        ));
    }
    if let Some(i) = r.actions.iter().position(|x| !x.is_finite()) {
        return Err(format!(
            "action {} has the non-finite value {}",
            i / d,
            r.actions[i]
        ));
    }
    Ok(r.actions.chunks_exact(d).map(<[f32]>::to_vec).collect())
}
