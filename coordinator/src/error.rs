//! Coordinator errors, and the one place they become gRPC status codes.

#[derive(Debug, thiserror::Error)]
pub enum CoordError {
    #[error("job store: {0}")]
    Store(#[from] rusqlite::Error),
    #[error("stored data is not valid JSON: {0}")]
    Json(#[from] serde_json::Error),
    #[error("job store: {0}")]
    JobKind(#[from] assay_model::job::UnknownJobKind),
    #[error("job store: {0}")]
    ShardState(#[from] assay_model::job::UnknownShardState),
    #[error("not found: {0}")]
    NotFound(String),
    #[error("invalid request: {0}")]
    InvalidRequest(String),
    #[error("job store: the transaction this call was grouped in did not commit: {0}")]
    GroupCommit(String),
    #[error("the job store has stopped")]
    StoreStopped,
    /// The store's checkpointing thread could not start.
    #[error("job store: starting its checkpoint thread: {0}")]
    Checkpointer(std::io::Error),
    /// A batch the planner refuses (its documents, settings, templates or interfaces).
    #[error(transparent)]
    Plan(#[from] assay_plan::PlanError),
}

impl From<assay_plan::SettingsError> for CoordError {
    fn from(e: assay_plan::SettingsError) -> Self {
        CoordError::Plan(e.into())
    }
}

impl From<CoordError> for tonic::Status {
    fn from(e: CoordError) -> Self {
        match e {
            CoordError::NotFound(m) => tonic::Status::not_found(m),
            CoordError::InvalidRequest(m) => tonic::Status::invalid_argument(m),
            CoordError::Plan(e) if e.is_invalid_input() => {
                tonic::Status::invalid_argument(e.to_string())
            }
            CoordError::StoreStopped => {
                tonic::Status::unavailable("the coordinator is shutting down")
            }
            other => tonic::Status::internal(other.to_string()),
        }
    }
}
