//! Generated types at the edge: the domain's batch documents, settings and spec errors to and
//! from their `assay.v1` messages. Nothing but field-for-field conversions.

use crate::v1 as pb;

impl From<&pb::TaskDocument> for assay_plan::TaskDocument {
    fn from(d: &pb::TaskDocument) -> Self {
        Self {
            origin: d.origin.clone(),
            format: d.format.clone(),
            content: d.content.clone(),
        }
    }
}

impl From<assay_plan::TaskDocument> for pb::TaskDocument {
    fn from(d: assay_plan::TaskDocument) -> Self {
        Self {
            origin: d.origin,
            format: d.format,
            content: d.content,
        }
    }
}

impl From<&pb::SubmitBatchRequest> for assay_plan::BatchSettings {
    fn from(r: &pb::SubmitBatchRequest) -> Self {
        Self {
            policies: r.policies.iter().map(|p| p.name.clone()).collect(),
            dynamics_budgets: r.dynamics_budgets.clone(),
            dynamics_json: r.dynamics_json.clone(),
            ranking_json: r.ranking_json.clone(),
            generalization_json: r.generalization_json.clone(),
        }
    }
}

impl From<&assay_spec::SpecError> for pb::SpecError {
    fn from(e: &assay_spec::SpecError) -> Self {
        Self {
            task_id: e.task.clone().unwrap_or_default(),
            origin: e.origin.clone(),
            path: e.path.clone(),
            reason: e.reason.clone(),
        }
    }
}
