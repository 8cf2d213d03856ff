//! Where a retraining job is and what it is doing: the states the job table, its records, the
//! API and the errors name. Apart from the job table (`jobs`), which depends on the errors, so
//! that the errors need not depend on it.

use serde::{Deserialize, Serialize};

/// Where a job is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// Accepted, waiting for the trainer (one job trains at a time).
    Queued,
    /// Working: see `stage` and `progress`.
    Running,
    /// Done: the new version is written (`version`) and, if `activate` was set, active.
    Succeeded,
    /// Done: see `error` (and `validation` for the shapes that were dropped).
    Failed,
    /// Done: cancelled before its version was written.
    Cancelled,
}

impl JobState {
    /// The name on the wire.
    pub fn name(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Succeeded => "succeeded",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }

    /// Succeeded, failed or cancelled: a finished job no longer changes.
    pub fn is_finished(self) -> bool {
        matches!(
            self,
            JobState::Succeeded | JobState::Failed | JobState::Cancelled
        )
    }
}

/// What a running job is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum JobStage {
    /// Multi-view sets: structure from motion and validation of the rebuilt shapes.
    Validating,
    /// Mean shape, visibility, regressions.
    Training,
    /// Writing the version into the models folder.
    Writing,
    /// Loading the version back and making it the active one.
    Activating,
}

impl JobStage {
    /// The name on the wire.
    pub fn name(self) -> &'static str {
        match self {
            JobStage::Validating => "validating",
            JobStage::Training => "training",
            JobStage::Writing => "writing",
            JobStage::Activating => "activating",
        }
    }
}
