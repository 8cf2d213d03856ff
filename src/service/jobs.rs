//! Retraining jobs: an in-memory table of what each upload became (state, progress, the
//! validation report, the new version, the reason of a failure), and the trainer's queue.
//!
//! - One training runs at a time (a permit of a fair semaphore: jobs start in the order they
//!   were accepted); training runs on the blocking pool, off the request path.
//! - At most `--max-queued-jobs` jobs wait for the trainer: an upload takes a slot
//!   ([`Jobs::reserve`]) before its body is read, and the job keeps it until it ends; an
//!   upload beyond that is refused at once with 429 / UNAVAILABLE (retry later), so uploads in
//!   memory are bounded too.
//! - A job can be cancelled until it starts writing its version ([`Jobs::cancel`]): a queued
//!   one never trains, a running one stops at its next stage. A finished job never changes.
//! - Finished jobs are kept for [`JOB_TTL`], and at most [`MAX_JOBS`] jobs are kept in all
//!   (the oldest finished ones go first).
//! - Job ids are per replica: the table is in memory, so a job is visible only on the replica
//!   that accepted its upload (the versions it wrote are in the models folder, seen by all).
//! - On SIGTERM the drain waits for the accepted jobs, queued and running ([`Jobs::idle`]),
//!   within `--drain-timeout`, and uploads that arrive meanwhile are refused (503 /
//!   UNAVAILABLE); only jobs cut off by the cap are lost, and logged by id.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Serialize;
use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore};

use super::errors::{ApiError, ErrorKind};
use crate::model::validate::ValidationReport;

/// How long a finished job stays visible.
pub const JOB_TTL: Duration = Duration::from_secs(3600);
/// The most jobs kept.
pub const MAX_JOBS: usize = 256;

/// Where a job is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
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
    /// Done: cancelled (`POST /v1/models/jobs/{id}:cancel`) before its version was written.
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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
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

/// A job as the API shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Job {
    /// 32 hex digits, random.
    pub id: String,
    /// The model being retrained.
    pub model: String,
    pub state: JobState,
    /// While running: what it is doing.
    pub stage: Option<JobStage>,
    /// 0 to 1, by stage (validation to 0.3, training to 0.85, writing and activating to 1).
    pub progress: f64,
    /// `shapes` (3D) or `subjects` (multi-view).
    pub kind: &'static str,
    /// Shapes or subjects uploaded.
    pub uploaded: usize,
    /// Whether the new version is activated when written.
    pub activate: bool,
    /// RFC 3339 times.
    pub created: String,
    pub updated: String,
    /// Kept and dropped shapes (subjects), with the reason of each drop. For 3D shapes it is
    /// there from the start; for multi-view sets once structure from motion has run.
    #[schema(value_type = Option<Object>)]
    pub validation: Option<ValidationReport>,
    /// The version written (also on a job that failed to activate it).
    pub version: Option<String>,
    /// Why the job failed: what to fix.
    pub error: Option<String>,
}

#[derive(Debug)]
struct Entry {
    job: Job,
    finished: Option<Instant>,
    /// Wakes the job's task if it is waiting for the trainer when it is cancelled.
    cancel: Arc<Notify>,
    /// Whether the job's task still runs: a job cancelled while training is finished in the
    /// table at once, but its task ends (and frees the trainer) only after the current stage.
    task: bool,
}

/// The job table and the trainer's queue.
#[derive(Debug)]
pub struct Jobs {
    table: Mutex<BTreeMap<String, Entry>>,
    trainer: Arc<Semaphore>,
    /// Uploads being received or checked and jobs not finished: `max_queued + 1` permits.
    slots: Arc<Semaphore>,
    max_queued: usize,
}

/// A place in the trainer's queue, taken before an upload is read; held by the job until it
/// ends.
#[derive(Debug)]
pub struct Slot(#[allow(dead_code)] OwnedSemaphorePermit);

/// The current time, RFC 3339, UTC.
pub fn now_rfc3339() -> String {
    time::OffsetDateTime::now_utc()
        .format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default()
}

impl Jobs {
    /// A table whose queue holds at most `max_queued` jobs besides the one training.
    pub fn new(max_queued: usize) -> Self {
        Jobs {
            table: Mutex::new(BTreeMap::new()),
            trainer: Arc::new(Semaphore::new(1)),
            slots: Arc::new(Semaphore::new(max_queued.saturating_add(1))),
            max_queued,
        }
    }

    fn table(&self) -> std::sync::MutexGuard<'_, BTreeMap<String, Entry>> {
        self.table.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A place in the queue for an upload about to be read, or 429 when every place is taken
    /// (by jobs not finished and uploads being received). Take it before reading the upload;
    /// give it to the job ([`crate::service::retrain::job::submit_reserved`]).
    pub fn reserve(&self) -> Result<Slot, ApiError> {
        self.slots
            .clone()
            .try_acquire_owned()
            .map(Slot)
            .map_err(|_| {
                ApiError::new(
                    ErrorKind::Overloaded,
                    format!(
                        "{} retraining jobs are queued or running (--max-queued-jobs {}); retry \
                     later",
                        self.max_queued.saturating_add(1),
                        self.max_queued
                    ),
                )
            })
    }

    /// Registers a new job (state `queued`); its upload holds a [`Slot`].
    pub fn create(
        &self,
        model: &str,
        kind: &'static str,
        uploaded: usize,
        activate: bool,
        validation: Option<ValidationReport>,
    ) -> Result<Job, ApiError> {
        let mut table = self.table();
        let now = Instant::now();
        table.retain(|_, e| e.finished.is_none_or(|t| now.duration_since(t) < JOB_TTL));
        while table.len() >= MAX_JOBS {
            let oldest = table
                .iter()
                .filter_map(|(id, e)| e.finished.map(|t| (t, id.clone())))
                .min();
            match oldest {
                Some((_, id)) => {
                    table.remove(&id);
                }
                None => break,
            }
        }
        let id = format!(
            "{:016x}{:016x}",
            rand::random::<u64>(),
            rand::random::<u64>()
        );
        let stamp = now_rfc3339();
        let job = Job {
            id: id.clone(),
            model: model.into(),
            state: JobState::Queued,
            stage: None,
            progress: 0.0,
            kind,
            uploaded,
            activate,
            created: stamp.clone(),
            updated: stamp,
            validation,
            version: None,
            error: None,
        };
        table.insert(
            id,
            Entry {
                job: job.clone(),
                finished: None,
                cancel: Arc::new(Notify::new()),
                task: true,
            },
        );
        super::metrics::retrain_jobs_waiting(queued(&table));
        Ok(job)
    }

    /// The job `id`.
    pub fn get(&self, id: &str) -> Result<Job, ApiError> {
        self.table()
            .get(id)
            .map(|e| e.job.clone())
            .ok_or_else(|| unknown(id))
    }

    /// Changes a job (and its `updated` time); a finished job starts its time to live. A job
    /// already finished (a cancelled one, say) is left as it is.
    pub fn update(&self, id: &str, f: impl FnOnce(&mut Job)) {
        let mut table = self.table();
        if let Some(e) = table.get_mut(id) {
            change(e, f);
        }
        super::metrics::retrain_jobs_waiting(queued(&table));
    }

    /// The job is running `stage`, `progress` done; false (and nothing changes) when it has
    /// been cancelled, so the job stops there.
    #[must_use]
    pub fn stage(&self, id: &str, stage: JobStage, progress: f64) -> bool {
        let mut running = false;
        self.update(id, |j| {
            j.state = JobState::Running;
            j.stage = Some(stage);
            j.progress = progress;
            running = true;
        });
        running
    }

    /// Cancels a job that has not started writing its version: a queued one never trains, a
    /// running one stops at its next stage (what it computed is dropped). 404 for an unknown
    /// job; 409 for a finished one, or one writing or activating its version (too late: roll
    /// back or delete the version once the job ends).
    pub fn cancel(&self, id: &str) -> Result<Job, ApiError> {
        let mut table = self.table();
        let e = table.get_mut(id).ok_or_else(|| unknown(id))?;
        let too_late = |what: String| {
            ApiError::new(
                ErrorKind::Conflict,
                format!("job {id} {what}; there is nothing to cancel"),
            )
        };
        match (e.job.state, e.job.stage) {
            (s, _) if s.is_finished() => {
                return Err(too_late(format!("has already {}", finished_verb(s))));
            }
            (_, Some(stage @ (JobStage::Writing | JobStage::Activating))) => {
                return Err(ApiError::new(
                    ErrorKind::Conflict,
                    format!(
                        "job {id} is {} its version: too late to cancel; once it ends, activate \
                         another version or delete this one (/v1/models/{}/versions)",
                        stage.name(),
                        e.job.model
                    ),
                ));
            }
            _ => {}
        }
        change(e, |j| {
            j.state = JobState::Cancelled;
            j.stage = None;
        });
        e.cancel.notify_one();
        let job = e.job.clone();
        super::metrics::retrain_jobs_waiting(queued(&table));
        Ok(job)
    }

    /// Resolves when job `id` is cancelled (at once if it already was; never for an unknown
    /// job).
    pub async fn cancelled(&self, id: &str) {
        let signal = {
            let table = self.table();
            table
                .get(id)
                .map(|e| (e.job.state == JobState::Cancelled, e.cancel.clone()))
        };
        let signal = match signal {
            Some((true, _)) => return,
            Some((false, s)) => s,
            None => return std::future::pending().await,
        };
        // A cancel between the look-up and this wait left a permit: it ends at once.
        signal.notified().await
    }

    /// The job has ended well.
    pub fn succeed(&self, id: &str) {
        self.update(id, |j| {
            j.state = JobState::Succeeded;
            j.stage = None;
            j.progress = 1.0;
        });
    }

    /// The job has ended with `error`.
    pub fn fail(&self, id: &str, error: String) {
        self.update(id, |j| {
            j.state = JobState::Failed;
            j.stage = None;
            j.error = Some(error);
        });
    }

    /// Resolves once no job is queued or running and no upload is being received (the drain
    /// waits for it: the uploads the server accepted are not dropped on shutdown).
    pub async fn idle(&self) {
        let all = u32::try_from(self.max_queued.saturating_add(1)).unwrap_or(u32::MAX);
        let _all = self.slots.acquire_many(all).await;
    }

    /// The job's task has ended (whatever the job's state): see [`Jobs::unfinished`].
    pub fn task_ended(&self, id: &str) {
        if let Some(e) = self.table().get_mut(id) {
            e.task = false;
        }
    }

    /// The ids and states of the jobs whose task still runs, oldest first: queued, running,
    /// and cancelled ones still finishing their stage (`cancelled, stopping`).
    pub fn unfinished(&self) -> Vec<(String, &'static str)> {
        let table = self.table();
        let mut left: Vec<_> = table
            .values()
            .filter(|e| e.task)
            .map(|e| {
                let state = match e.job.state {
                    JobState::Cancelled => "cancelled, stopping",
                    s => s.name(),
                };
                (e.job.created.clone(), e.job.id.clone(), state)
            })
            .collect();
        left.sort();
        left.into_iter().map(|(_, id, state)| (id, state)).collect()
    }

    /// Waits for the trainer (jobs are served in order).
    pub async fn trainer(&self) -> Option<OwnedSemaphorePermit> {
        self.trainer.clone().acquire_owned().await.ok()
    }
}

/// Applies `f` to a job not finished, with the bookkeeping of [`Jobs::update`].
fn change(e: &mut Entry, f: impl FnOnce(&mut Job)) {
    if e.job.state.is_finished() {
        return;
    }
    f(&mut e.job);
    e.job.updated = now_rfc3339();
    if e.job.state.is_finished() {
        e.finished = Some(Instant::now());
        super::metrics::retrain_job_finished(e.job.state.name());
    }
}

/// "succeeded", "failed", "been cancelled": after "has already".
fn finished_verb(s: JobState) -> &'static str {
    match s {
        JobState::Cancelled => "been cancelled",
        other => other.name(),
    }
}

fn unknown(id: &str) -> ApiError {
    ApiError::new(
        ErrorKind::NotFound,
        format!(
            "unknown job {id:?}: job ids are per replica and kept for an hour after the job \
             ends; ask the replica that accepted the upload (GET /v1/models lists the versions \
             every replica sees)"
        ),
    )
}

/// Jobs waiting for the trainer (not the one running).
fn queued(table: &BTreeMap<String, Entry>) -> usize {
    table
        .values()
        .filter(|e| e.job.state == JobState::Queued)
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_queue_is_bounded_and_jobs_finish() {
        let jobs = Jobs::new(1);
        // One training and one waiting: two slots, taken before the uploads are read.
        let sa = jobs.reserve().unwrap();
        let sb = jobs.reserve().unwrap();
        let e = jobs.reserve().unwrap_err();
        assert_eq!(e.kind, ErrorKind::Overloaded);
        assert!(e.message.contains("--max-queued-jobs 1"), "{e}");
        assert!(e.message.contains("retry later"), "{e}");
        let a = jobs.create("m", "shapes", 10, true, None).unwrap();
        let b = jobs.create("m", "shapes", 10, true, None).unwrap();
        assert_eq!(queued(&jobs.table()), 2);
        assert!(jobs.stage(&a.id, JobStage::Training, 0.5));
        assert_eq!(jobs.get(&a.id).unwrap().state, JobState::Running);
        // The running job is not waiting.
        assert_eq!(queued(&jobs.table()), 1);
        jobs.fail(&a.id, "no".into());
        // The job ends: its slot is free again (an upload refused before it was read frees
        // its slot the same way).
        drop(sa);
        let sc = jobs.reserve().unwrap();
        let c = jobs.create("m", "shapes", 10, true, None).unwrap();
        assert_ne!(b.id, c.id);
        let failed = jobs.get(&a.id).unwrap();
        assert_eq!((failed.state, failed.stage), (JobState::Failed, None));
        assert_eq!(failed.error.as_deref(), Some("no"));
        jobs.succeed(&b.id);
        drop((sb, sc));
        assert_eq!(jobs.get(&b.id).unwrap().progress, 1.0);
        assert_eq!(jobs.get("nope").unwrap_err().kind, ErrorKind::NotFound);
        assert_eq!(a.id.len(), 32);
        assert_eq!(queued(&jobs.table()), 1);
    }

    #[tokio::test]
    async fn cancelling_stops_a_job_before_it_writes() {
        let jobs = Arc::new(Jobs::new(4));
        let waiting = jobs.create("m", "shapes", 10, true, None).unwrap();
        let running = jobs.create("m", "shapes", 10, true, None).unwrap();
        let writing = jobs.create("m", "shapes", 10, true, None).unwrap();
        assert!(jobs.stage(&running.id, JobStage::Training, 0.3));
        assert!(jobs.stage(&writing.id, JobStage::Writing, 0.85));

        // A queued job: cancelled at once, and its task, waiting for the trainer, is woken
        // (also when it starts waiting after the cancel).
        let waiter = tokio::spawn({
            let (jobs, id) = (jobs.clone(), waiting.id.clone());
            async move { jobs.cancelled(&id).await }
        });
        let j = jobs.cancel(&waiting.id).unwrap();
        assert_eq!((j.state, j.stage), (JobState::Cancelled, None));
        tokio::time::timeout(Duration::from_secs(1), waiter)
            .await
            .expect("the waiting task is woken")
            .unwrap();
        tokio::time::timeout(Duration::from_secs(1), jobs.cancelled(&waiting.id))
            .await
            .expect("a later wait ends at once");

        // A running job: cancelled; its next stage does not start and nothing overwrites it.
        assert_eq!(jobs.cancel(&running.id).unwrap().state, JobState::Cancelled);
        assert!(!jobs.stage(&running.id, JobStage::Writing, 0.85));
        jobs.fail(&running.id, "late".into());
        let j = jobs.get(&running.id).unwrap();
        assert_eq!((j.state, j.error), (JobState::Cancelled, None));

        // Too late, or nothing to cancel: 409; unknown: 404.
        let e = jobs.cancel(&writing.id).unwrap_err();
        assert_eq!(e.kind, ErrorKind::Conflict);
        assert!(e.message.contains("is writing its version"), "{e}");
        assert!(e.message.contains("/v1/models/m/versions"), "{e}");
        let e = jobs.cancel(&waiting.id).unwrap_err();
        assert_eq!(e.kind, ErrorKind::Conflict);
        assert!(e.message.contains("has already been cancelled"), "{e}");
        jobs.succeed(&writing.id);
        let e = jobs.cancel(&writing.id).unwrap_err();
        assert!(e.message.contains("has already succeeded"), "{e}");
        assert_eq!(jobs.cancel("nope").unwrap_err().kind, ErrorKind::NotFound);
        // The cancelled running job's task is still finishing its stage.
        jobs.task_ended(&waiting.id);
        jobs.task_ended(&writing.id);
        assert_eq!(
            jobs.unfinished(),
            vec![(running.id.clone(), "cancelled, stopping")]
        );
        jobs.task_ended(&running.id);
        assert!(jobs.unfinished().is_empty());
        assert_eq!(queued(&jobs.table()), 0);
    }

    #[tokio::test]
    async fn idle_waits_for_every_slot() {
        let jobs = Arc::new(Jobs::new(2));
        let slot = jobs.reserve().unwrap();
        let a = jobs.create("m", "shapes", 10, true, None).unwrap();
        let b = jobs.create("m", "shapes", 10, true, None).unwrap();
        assert!(jobs.stage(&b.id, JobStage::Training, 0.1));
        let mut left = jobs.unfinished();
        left.sort();
        let mut want = vec![(a.id.clone(), "queued"), (b.id.clone(), "running")];
        want.sort();
        assert_eq!(left, want);
        let waiter = tokio::spawn({
            let jobs = jobs.clone();
            async move { jobs.idle().await }
        });
        tokio::time::sleep(Duration::from_millis(20)).await;
        assert!(!waiter.is_finished(), "idle with a slot taken");
        jobs.succeed(&a.id);
        jobs.fail(&b.id, "no".into());
        // Their tasks still run until they say they ended.
        assert_eq!(jobs.unfinished().len(), 2);
        jobs.task_ended(&a.id);
        jobs.task_ended(&b.id);
        assert!(jobs.unfinished().is_empty());
        // idle() waits for the slots, which the tasks hold until they end.
        assert!(!waiter.is_finished(), "idle with a slot taken");
        drop(slot);
        tokio::time::timeout(Duration::from_secs(1), waiter)
            .await
            .expect("idle once the slot is free")
            .unwrap();
    }
}
