//! Policy references as batches name them: `oracle`, `oracle:noise=0.01`.

/// A policy the cluster knows how to run.
#[derive(Debug, Clone, PartialEq)]
pub enum PolicySpec {
    /// The task's scripted oracle plan, with uniform noise (± m) added to every target in x and y.
    Oracle { noise: f64 },
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
        for arg in args.split(',').filter(|a| !a.is_empty()) {
            match arg.split_once('=').map(|(k, v)| (k, v.parse::<f64>())) {
                Some(("noise", Ok(v))) if v.is_finite() && v >= 0.0 => noise = v,
                _ => {
                    return Err(format!(
                        "policy '{name}': bad argument '{arg}' (expected noise=<metres>)"
                    ));
                }
            }
        }
        Ok(PolicySpec::Oracle { noise })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_known_policies_and_rejects_the_rest() {
        assert_eq!(
            PolicySpec::parse("oracle"),
            Ok(PolicySpec::Oracle { noise: 0.0 })
        );
        assert_eq!(
            PolicySpec::parse("oracle:noise=0.02"),
            Ok(PolicySpec::Oracle { noise: 0.02 })
        );
        assert!(
            PolicySpec::parse("diffusion")
                .unwrap_err()
                .contains("unknown policy")
        );
        assert!(PolicySpec::parse("oracle:noise=-1").is_err());
        assert!(PolicySpec::parse("oracle:speed=2").is_err());
    }
}
