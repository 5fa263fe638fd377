//! Policies that declare their interface in their spec (joint actions, joint state, cameras)
//! checked against every task of the batch before it is stored: the error names the policy, the
//! task and the field. Servers that declare their interface in `Health` are checked when their
//! episodes start, not here.

use assay_model::policy::PolicySpec;

use crate::PlanError;
use crate::documents::PlannedTask;

/// Refuses a batch whose policy declares an interface one of its tasks cannot fill.
pub fn check_interfaces(policies: &[String], tasks: &[PlannedTask]) -> Result<(), PlanError> {
    let declared: Vec<(&String, PolicySpec)> = policies
        .iter()
        .filter_map(|p| PolicySpec::parse(p).ok().map(|s| (p, s)))
        .filter(|(_, s)| s.declared_interface().is_some())
        .collect();
    if declared.is_empty() {
        return Ok(());
    }
    for t in tasks {
        let spec: assay_spec::spec::TaskSpec =
            serde_json::from_str(&t.spec_json).map_err(|e| PlanError::PlannedSpec {
                task: t.info.id.clone(),
                reason: e.to_string(),
            })?;
        for (name, p) in &declared {
            let interface = p.declared_interface().expect("filtered");
            interface
                .check_task(&spec)
                .map_err(|e| PlanError::Interface {
                    policy: name.to_string(),
                    task: t.info.id.clone(),
                    reason: e.to_string(),
                })?;
        }
    }
    Ok(())
}
