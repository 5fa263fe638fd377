//! Policy references as batches name them: `oracle`, `oracle:noise=0.01`.

/// A policy the cluster knows how to run.
#[derive(Debug, Clone, PartialEq)]
pub enum PolicySpec {
    /// The task's scripted oracle plan, with uniform noise (± m) added to every target in x and y,
    /// locating objects either from the simulator's state or from what a camera sees.
    Oracle { noise: f64, sense: Sense },
}

/// Where a policy learns where things are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sense {
    /// The simulator's true object poses (privileged state).
    State,
    /// Depth and segmentation from the top-down camera, rendered every
    /// [`OBSERVE_EVERY_STEPS`] physics steps while the policy acts: a closed-loop policy that
    /// needs the render role on its worker.
    Camera,
}

/// A seeing policy's observation rate: every 8 physics steps, 30 Hz at the default 240 Hz.
pub const OBSERVE_EVERY_STEPS: u64 = 8;
/// Size of a seeing policy's camera images.
pub const OBSERVATION_SIZE: (u32, u32) = (320, 240);

/// The camera a seeing policy looks through: the top-down scene view at [`OBSERVATION_SIZE`].
pub fn observation_camera() -> crate::spec::Camera {
    let (width, height) = OBSERVATION_SIZE;
    crate::spec::Camera {
        width,
        height,
        ..crate::scene::scene_views().remove(0)
    }
}

/// Kinds of policy this release runs.
pub const KNOWN_POLICIES: &[&str] = &["oracle"];

impl PolicySpec {
    pub fn parse(name: &str) -> Result<PolicySpec, String> {
        let (kind, args) = name.split_once(':').unwrap_or((name, ""));
        if !KNOWN_POLICIES.contains(&kind) {
            return Err(format!(
                "unknown policy '{kind}' (known: {})",
                KNOWN_POLICIES.join(", ")
            ));
        }
        let mut noise = 0.0;
        let mut sense = Sense::State;
        for arg in args.split(',').filter(|a| !a.is_empty()) {
            match arg.split_once('=') {
                Some(("noise", v)) => match v.parse::<f64>() {
                    Ok(v) if v.is_finite() && v >= 0.0 => noise = v,
                    _ => return Err(format!("policy '{name}': bad noise '{v}' (metres, ≥ 0)")),
                },
                Some(("sense", "state")) => sense = Sense::State,
                Some(("sense", "camera")) => sense = Sense::Camera,
                _ => {
                    return Err(format!(
                        "policy '{name}': bad argument '{arg}' (expected noise=<metres> or sense=state|camera)"
                    ));
                }
            }
        }
        Ok(PolicySpec::Oracle { noise, sense })
    }

    /// Whether episodes of this policy need camera frames while they run.
    pub fn sees(&self) -> bool {
        matches!(
            self,
            PolicySpec::Oracle {
                sense: Sense::Camera,
                ..
            }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_known_policies_and_rejects_the_rest() {
        assert_eq!(
            PolicySpec::parse("oracle"),
            Ok(PolicySpec::Oracle {
                noise: 0.0,
                sense: Sense::State
            })
        );
        assert_eq!(
            PolicySpec::parse("oracle:noise=0.02"),
            Ok(PolicySpec::Oracle {
                noise: 0.02,
                sense: Sense::State
            })
        );
        let seeing = PolicySpec::parse("oracle:sense=camera,noise=0.01").unwrap();
        assert!(seeing.sees());
        assert!(PolicySpec::parse("oracle:sense=lidar").is_err());
        assert!(
            PolicySpec::parse("diffusion")
                .unwrap_err()
                .contains("unknown policy")
        );
        assert!(PolicySpec::parse("oracle:noise=-1").is_err());
        assert!(PolicySpec::parse("oracle:speed=2").is_err());
    }
}
