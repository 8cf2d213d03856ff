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
//! - Every replica sharing the models folder (which retraining needs) sees every job: the
//!   replica that runs a job writes its record into the folder and acts on cancels asked
//!   through the others ([`super::job_records`]).
//! - On SIGTERM the drain waits for the accepted jobs, queued and running ([`Jobs::idle`]),
//!   within `--drain-timeout`, and uploads that arrive meanwhile are refused (503 /
//!   UNAVAILABLE); only jobs cut off by the cap are lost, and logged by id.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore};

use super::errors::{ApiError, ErrorKind};
use super::job_records::{Claim, JobRecords, LOST_AFTER};
use facepose_core::model::validate::ValidationReport;

/// How long a finished job stays visible.
pub const JOB_TTL: Duration = Duration::from_secs(3600);
/// The most jobs kept.
pub const MAX_JOBS: usize = 256;

/// Where a job is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
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

/// A job as the API shows it, and as its record in the models folder holds it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
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
    pub kind: String,
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
    /// The replica that accepted the upload and runs the job (its host name).
    #[serde(default)]
    pub replica: String,
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
    /// When its record was last written into the models folder.
    written: Option<Instant>,
}

/// The job table and the trainer's queue.
#[derive(Debug)]
pub struct Jobs {
    table: Mutex<BTreeMap<String, Entry>>,
    trainer: Arc<Semaphore>,
    /// Uploads being received or checked and jobs not finished: `max_queued + 1` permits.
    slots: Arc<Semaphore>,
    max_queued: usize,
    /// The models folder's job records, if there is a folder.
    records: Option<JobRecords>,
    /// This replica's name, in its jobs.
    replica: String,
    /// Held while a record is written, so that the last write is of the latest state.
    io: Mutex<()>,
}

/// What a cancel did.
#[derive(Debug, Clone, PartialEq)]
pub enum Cancel {
    /// The job ran here and is cancelled.
    Done(Job),
    /// The job runs on another replica, which was asked to cancel it at its next stage; the
    /// job as last recorded.
    Requested(Job),
}

/// How often a running job's progress alone is written into its record.
const PROGRESS_WRITES: Duration = Duration::from_secs(1);

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
    /// A table whose queue holds at most `max_queued` jobs besides the one training, seen by
    /// this replica alone.
    pub fn new(max_queued: usize) -> Self {
        Self::shared(max_queued, None, super::job_records::replica_name())
    }

    /// [`Jobs::new`] whose jobs are recorded in `records` (a models folder's) for the other
    /// replicas, as `replica`.
    pub fn shared(max_queued: usize, records: Option<JobRecords>, replica: String) -> Self {
        Jobs {
            table: Mutex::new(BTreeMap::new()),
            trainer: Arc::new(Semaphore::new(1)),
            slots: Arc::new(Semaphore::new(max_queued.saturating_add(1))),
            max_queued,
            records,
            replica,
            io: Mutex::new(()),
        }
    }

    /// Writes job `id`'s latest state into its record (if there is a folder); a change of
    /// progress alone (`force` false) at most every [`PROGRESS_WRITES`]. A failure is logged:
    /// the job goes on, seen by this replica only.
    fn persist(&self, id: &str, force: bool) {
        let Some(records) = &self.records else {
            return;
        };
        off_the_workers(|| {
            let _io = self.io.lock().unwrap_or_else(|e| e.into_inner());
            let job = {
                let mut table = self.table();
                let Some(e) = table.get_mut(id) else {
                    return;
                };
                if !force && e.written.is_some_and(|t| t.elapsed() < PROGRESS_WRITES) {
                    return;
                }
                e.written = Some(Instant::now());
                e.job.clone()
            };
            if let Err(err) = records.write(&job) {
                tracing::warn!(job = id, %err, "could not write the job's record into the models \
                    folder: other replicas will not see its latest state");
            }
            if job.state.is_finished() {
                records.clear_claim(id);
            }
        });
    }

    fn table(&self) -> std::sync::MutexGuard<'_, BTreeMap<String, Entry>> {
        self.table.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A place in the queue for an upload about to be read, or 429 when every place is taken
    /// (by jobs not finished and uploads being received). Take it before reading the upload;
    /// give it to the job ([`crate::retrain::job::submit_reserved`]).
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
        kind: &str,
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
            kind: kind.into(),
            uploaded,
            activate,
            created: stamp.clone(),
            updated: stamp,
            validation,
            version: None,
            error: None,
            replica: self.replica.clone(),
        };
        table.insert(
            id.clone(),
            Entry {
                job: job.clone(),
                finished: None,
                cancel: Arc::new(Notify::new()),
                task: true,
                written: None,
            },
        );
        super::metrics::retrain_jobs_waiting(queued(&table));
        drop(table);
        if let Some(records) = &self.records {
            off_the_workers(|| records.sweep());
        }
        self.persist(&id, true);
        Ok(job)
    }

    /// The job `id`: this replica's, else the models folder's record of another replica's.
    pub fn get(&self, id: &str) -> Result<Job, ApiError> {
        if let Some(e) = self.table().get(id) {
            return Ok(e.job.clone());
        }
        self.recorded(id)?.ok_or_else(|| unknown(id))
    }

    /// The models folder's record of job `id`, if any; a queued or running job whose record
    /// its replica stopped touching as failed ([`lost`]).
    fn recorded(&self, id: &str) -> Result<Option<Job>, ApiError> {
        let Some(records) = &self.records else {
            return Ok(None);
        };
        let read = records.read_aged(id).map_err(|e| {
            ApiError::new(
                ErrorKind::Internal,
                format!("could not read the record of job {id} in the models folder: {e}"),
            )
        })?;
        Ok(read.map(|(job, age)| {
            if !job.state.is_finished() && age >= LOST_AFTER {
                lost(job, age)
            } else {
                job
            }
        }))
    }

    /// Touches the records of this replica's queued and running jobs, so that the other
    /// replicas know they are alive ([`super::job_records::HEARTBEAT`]); a record that has gone
    /// (swept, or never written) is written again.
    pub fn heartbeat(&self) {
        let Some(records) = &self.records else {
            return;
        };
        let live: Vec<String> = self
            .table()
            .iter()
            .filter(|(_, e)| !e.job.state.is_finished())
            .map(|(id, _)| id.clone())
            .collect();
        for id in live {
            let touched = off_the_workers(|| records.touch(&id));
            match touched {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => self.persist(&id, true),
                Err(err) => tracing::warn!(job = id, %err, "could not touch the job's record: \
                    other replicas will take the job as lost within a minute"),
            }
        }
    }

    /// Changes a job (and its `updated` time); a finished job starts its time to live. A job
    /// already finished (a cancelled one, say) is left as it is.
    pub fn update(&self, id: &str, f: impl FnOnce(&mut Job)) {
        self.change(id, f, false);
    }

    /// [`Jobs::update`], the record written at once if `force`, else as progress.
    fn change(&self, id: &str, f: impl FnOnce(&mut Job), force: bool) {
        {
            let mut table = self.table();
            if let Some(e) = table.get_mut(id) {
                change(e, f);
            }
            super::metrics::retrain_jobs_waiting(queued(&table));
        }
        self.persist(id, force);
    }

    /// The job is running `stage`, `progress` done; false (and nothing changes) when it has
    /// been cancelled, here or through another replica, so the job stops there. Writing is
    /// claimed in the models folder first, so that no cancel through another replica is
    /// accepted once the version is being written.
    #[must_use]
    pub fn stage(&self, id: &str, stage: JobStage, progress: f64) -> bool {
        if let Some(records) = &self.records {
            let claim = off_the_workers(|| match stage {
                JobStage::Writing => match records.claim(id, Claim::Write) {
                    Ok(c) => Some(c),
                    Err(err) => {
                        // Without the claim a cancel elsewhere could be accepted: no write.
                        tracing::warn!(job = id, %err, "could not claim the job for its write");
                        Some(Claim::Cancel)
                    }
                },
                JobStage::Activating => None,
                _ => records.claimed(id),
            });
            if claim == Some(Claim::Cancel) {
                tracing::info!(job = id, "cancel asked through another replica");
                // Cancelled here as well, unless it ended meanwhile.
                let _ = self.cancel(id);
                return false;
            }
        }
        let mut running = false;
        self.change(
            id,
            |j| {
                j.state = JobState::Running;
                j.stage = Some(stage);
                j.progress = progress;
                running = true;
            },
            true,
        );
        running
    }

    /// Cancels a job that has not started writing its version: a queued one never trains, a
    /// running one stops at its next stage (what it computed is dropped). A job another replica
    /// runs is asked to ([`Cancel::Requested`]). 404 for an unknown job; 409 for a finished one,
    /// or one writing or activating its version (too late: roll back or delete the version once
    /// the job ends).
    pub fn cancel(&self, id: &str) -> Result<Cancel, ApiError> {
        let mut table = self.table();
        let Some(e) = table.get_mut(id) else {
            drop(table);
            let job = self.recorded(id)?.ok_or_else(|| unknown(id))?;
            cancellable(&job)?;
            if let Some(records) = &self.records {
                let claim = records.claim(id, Claim::Cancel).map_err(|e| {
                    ApiError::new(
                        ErrorKind::Internal,
                        format!(
                            "could not ask for the cancel of job {id} in the models folder: {e}"
                        ),
                    )
                })?;
                if claim == Claim::Write {
                    return Err(ApiError::new(
                        ErrorKind::Conflict,
                        format!(
                            "job {id} is writing its version: too late to cancel; once it ends, \
                             activate another version or delete this one (/v1/models/{}/versions)",
                            job.model
                        ),
                    ));
                }
            }
            return Ok(Cancel::Requested(job));
        };
        cancellable(&e.job)?;
        change(e, |j| {
            j.state = JobState::Cancelled;
            j.stage = None;
        });
        e.cancel.notify_one();
        let job = e.job.clone();
        super::metrics::retrain_jobs_waiting(queued(&table));
        drop(table);
        self.persist(id, true);
        Ok(Cancel::Done(job))
    }

    /// Marks jobs whose task the drain cut off as failed, with what to do, so that their
    /// records do not stay `running`.
    pub fn abandon(&self, ids: &[String], cap: Duration) {
        for id in ids {
            let version_note = |j: &Job| {
                format!(
                    "this replica ({}) stopped before the job ended (its drain reached \
                     --drain-timeout, {cap:?}); send the upload again (a version it was writing \
                     may still appear in /v1/models/{}/versions)",
                    j.replica, j.model
                )
            };
            self.change(
                id,
                |j| {
                    j.error = Some(version_note(j));
                    j.state = JobState::Failed;
                    j.stage = None;
                },
                true,
            );
        }
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
        self.change(
            id,
            |j| {
                j.state = JobState::Succeeded;
                j.stage = None;
                j.progress = 1.0;
            },
            true,
        );
    }

    /// The job has ended with `error`.
    pub fn fail(&self, id: &str, error: String) {
        self.change(
            id,
            |j| {
                j.state = JobState::Failed;
                j.stage = None;
                j.error = Some(error);
            },
            true,
        );
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

/// Runs `f`, which touches the models folder, without holding up the async tasks of the worker
/// it is called on (`block_in_place` on a multi-threaded runtime). The write stays synchronous,
/// so a job's record is written before the job is said to have ended and the drain can end.
fn off_the_workers<T>(f: impl FnOnce() -> T) -> T {
    use tokio::runtime::{Handle, RuntimeFlavor};
    match Handle::try_current() {
        Ok(h) if h.runtime_flavor() == RuntimeFlavor::MultiThread => tokio::task::block_in_place(f),
        _ => f(),
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

/// A recorded job whose replica has not touched its record for `age`: failed, as far as the
/// other replicas can tell, and saying why.
fn lost(mut job: Job, age: Duration) -> Job {
    job.error = Some(format!(
        "replica {} stopped without ending this job (killed, out of memory, or cut off from the \
         models folder): its record was last updated {} s ago, while it was {}; send the upload \
         again",
        if job.replica.is_empty() {
            "(unnamed)"
        } else {
            &job.replica
        },
        age.as_secs(),
        job.stage.map_or(job.state.name(), JobStage::name),
    ));
    job.state = JobState::Failed;
    job.stage = None;
    job
}

/// Ok if `job` can still be cancelled, else the 409 that says why not.
fn cancellable(job: &Job) -> Result<(), ApiError> {
    let id = &job.id;
    match (job.state, job.stage) {
        (s, _) if s.is_finished() => Err(ApiError::new(
            ErrorKind::Conflict,
            format!(
                "job {id} has already {}; there is nothing to cancel",
                finished_verb(s)
            ),
        )),
        (_, Some(stage @ (JobStage::Writing | JobStage::Activating))) => Err(ApiError::new(
            ErrorKind::Conflict,
            format!(
                "job {id} is {} its version: too late to cancel; once it ends, activate another \
                 version or delete this one (/v1/models/{}/versions)",
                stage.name(),
                job.model
            ),
        )),
        _ => Ok(()),
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
            "unknown job {id:?}: no replica sharing this models folder has it (jobs are kept \
             for an hour after they end); GET /v1/models/{{name}}/versions lists the versions \
             every replica sees"
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
        let Cancel::Done(j) = jobs.cancel(&waiting.id).unwrap() else {
            panic!("a job of this replica is cancelled here");
        };
        assert_eq!((j.state, j.stage), (JobState::Cancelled, None));
        tokio::time::timeout(Duration::from_secs(1), waiter)
            .await
            .expect("the waiting task is woken")
            .unwrap();
        tokio::time::timeout(Duration::from_secs(1), jobs.cancelled(&waiting.id))
            .await
            .expect("a later wait ends at once");

        // A running job: cancelled; its next stage does not start and nothing overwrites it.
        assert!(matches!(
            jobs.cancel(&running.id).unwrap(),
            Cancel::Done(Job {
                state: JobState::Cancelled,
                ..
            })
        ));
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

    /// Sets the modification time of `path` to `by` ago: a record or claim left that long.
    fn set_age(path: &std::path::Path, by: Duration) {
        let f = std::fs::File::options().write(true).open(path).unwrap();
        f.set_modified(std::time::SystemTime::now() - by).unwrap();
    }

    /// A fresh folder for the job records of a test.
    fn records_dir(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("facepose-jobs-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn replicas_sharing_a_folder_see_and_cancel_each_others_jobs() {
        let dir = records_dir("shared");
        let replica =
            |name: &str| Jobs::shared(4, Some(JobRecords::new(&dir, name.into())), name.into());
        let (a, b) = (replica("a"), replica("b"));
        let job = a.create("m", "shapes", 10, true, None).unwrap();
        assert_eq!(job.replica, "a");
        // B reads what A wrote, at every change.
        assert_eq!(b.get(&job.id).unwrap(), job);
        assert!(a.stage(&job.id, JobStage::Training, 0.3));
        let seen = b.get(&job.id).unwrap();
        assert_eq!(
            (seen.state, seen.stage),
            (JobState::Running, Some(JobStage::Training))
        );
        // Progress alone is written at most once a second; a stage change at once.
        a.update(&job.id, |j| j.progress = 0.5);
        assert_eq!(b.get(&job.id).unwrap().progress, 0.3);

        // A cancel through B is a request, acted on at A's next stage.
        let Cancel::Requested(asked) = b.cancel(&job.id).unwrap() else {
            panic!("B does not run the job");
        };
        assert_eq!(asked.state, JobState::Running);
        assert!(!a.stage(&job.id, JobStage::Writing, 0.85));
        let ended = b.get(&job.id).unwrap();
        assert_eq!(ended.state, JobState::Cancelled);
        assert_eq!(a.get(&job.id).unwrap(), ended);
        // Finished: the request is gone, and a second cancel says why not.
        assert!(!dir.join(".jobs").join(format!("{}.claim", job.id)).exists());
        let e = b.cancel(&job.id).unwrap_err();
        assert_eq!(e.kind, ErrorKind::Conflict);
        assert!(e.message.contains("has already been cancelled"), "{e}");

        // A job writing its version cannot be cancelled from anywhere.
        let late = a.create("m", "shapes", 10, true, None).unwrap();
        assert!(a.stage(&late.id, JobStage::Writing, 0.85));
        let e = b.cancel(&late.id).unwrap_err();
        assert!(e.message.contains("is writing its version"), "{e}");
        // The race: B reads a record from before the write and asks for a cancel just after A
        // claimed the job for its write. The claim stands and B is refused.
        let raced = a.create("m", "shapes", 10, true, None).unwrap();
        assert!(a.stage(&raced.id, JobStage::Training, 0.3));
        let stale_record = b.get(&raced.id).unwrap();
        assert_eq!(stale_record.stage, Some(JobStage::Training));
        let records = JobRecords::new(&dir, "a".into());
        assert_eq!(
            records.claim(&raced.id, Claim::Write).unwrap(),
            Claim::Write
        );
        let e = b.cancel(&raced.id).unwrap_err();
        assert_eq!(e.kind, ErrorKind::Conflict);
        assert!(e.message.contains("is writing its version"), "{e}");
        // The other way round: B's cancel claimed first, so A does not write.
        let first = a.create("m", "shapes", 10, true, None).unwrap();
        assert!(a.stage(&first.id, JobStage::Training, 0.3));
        assert!(matches!(b.cancel(&first.id).unwrap(), Cancel::Requested(_)));
        assert!(!a.stage(&first.id, JobStage::Writing, 0.85));
        assert_eq!(b.get(&first.id).unwrap().state, JobState::Cancelled);
        // A drain cut short marks what it abandons as failed, for the others to see.
        a.abandon(std::slice::from_ref(&late.id), Duration::from_secs(10));
        let gone = b.get(&late.id).unwrap();
        assert_eq!(gone.state, JobState::Failed);
        assert!(gone.error.unwrap().contains("replica (a) stopped"));

        // Unknown ids, including ones that are not ids at all, are 404s, not file look-ups.
        for id in ["0123456789abcdef0123456789abcdef", "../../etc/passwd", ""] {
            assert_eq!(b.get(id).unwrap_err().kind, ErrorKind::NotFound, "{id}");
            assert_eq!(b.cancel(id).unwrap_err().kind, ErrorKind::NotFound, "{id}");
        }
        // Without a folder a replica knows its own jobs only.
        assert_eq!(
            Jobs::new(1).get(&job.id).unwrap_err().kind,
            ErrorKind::NotFound
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_job_whose_replica_stopped_touching_it_is_lost_to_the_others() {
        let dir = records_dir("lost");
        let replica =
            |name: &str| Jobs::shared(4, Some(JobRecords::new(&dir, name.into())), name.into());
        let (a, b) = (replica("a"), replica("b"));
        let job = a.create("m", "shapes", 10, true, None).unwrap();
        assert!(a.stage(&job.id, JobStage::Training, 0.3));
        let record = dir.join(".jobs").join(format!("{}.json", job.id));
        let age = |by: Duration| set_age(&record, by);
        // Under a minute without a touch: alive.
        age(LOST_AFTER - Duration::from_secs(5));
        assert_eq!(b.get(&job.id).unwrap().state, JobState::Running);
        // Past it: failed to the others, saying why, and not cancellable.
        age(LOST_AFTER + Duration::from_secs(5));
        let seen = b.get(&job.id).unwrap();
        assert_eq!((seen.state, seen.stage), (JobState::Failed, None));
        let why = seen.error.unwrap();
        assert!(
            why.contains("replica a stopped without ending this job") && why.contains("training"),
            "{why}"
        );
        let e = b.cancel(&job.id).unwrap_err();
        assert_eq!(e.kind, ErrorKind::Conflict, "{e}");
        assert!(!dir.join(".jobs").join(format!("{}.claim", job.id)).exists());
        // Its own replica still runs it; its heartbeat makes it alive again to the others.
        assert_eq!(a.get(&job.id).unwrap().state, JobState::Running);
        a.heartbeat();
        assert_eq!(b.get(&job.id).unwrap().state, JobState::Running);
        // A record that has gone is written again by the heartbeat; ended jobs are left alone.
        std::fs::remove_file(&record).unwrap();
        a.heartbeat();
        assert_eq!(b.get(&job.id).unwrap().stage, Some(JobStage::Training));
        a.succeed(&job.id);
        age(LOST_AFTER + Duration::from_secs(5));
        a.heartbeat();
        assert_eq!(b.get(&job.id).unwrap().state, JobState::Succeeded);
        let (_, untouched) = JobRecords::new(&dir, "b".into())
            .read_aged(&job.id)
            .unwrap()
            .unwrap();
        assert!(untouched >= LOST_AFTER, "{untouched:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn old_records_are_swept_when_a_job_is_created() {
        let dir = records_dir("sweep");
        let jobs = Jobs::shared(4, Some(JobRecords::new(&dir, "a".into())), "a".into());
        let done = jobs.create("m", "shapes", 10, true, None).unwrap();
        jobs.succeed(&done.id);
        let running = jobs.create("m", "shapes", 10, true, None).unwrap();
        assert!(jobs.stage(&running.id, JobStage::Training, 0.3));
        let file = |name: String| dir.join(".jobs").join(name);
        let record = |id: &str| file(format!("{id}.json"));
        let aged = |path: std::path::PathBuf, by: Duration| set_age(&path, by);
        let age = |id: &str, by: Duration| aged(record(id), by);
        // A cancel asked an hour ago for the running job, not yet acted on.
        let claims = JobRecords::new(&dir, "b".into());
        assert_eq!(
            claims.claim(&running.id, Claim::Cancel).unwrap(),
            Claim::Cancel
        );
        aged(
            file(format!("{}.claim", running.id)),
            JOB_TTL + Duration::from_secs(60),
        );
        // A job whose replica died an hour ago, with a cancel asked then too.
        let lost = jobs.create("m", "shapes", 10, true, None).unwrap();
        assert!(jobs.stage(&lost.id, JobStage::Training, 0.3));
        claims.claim(&lost.id, Claim::Cancel).unwrap();
        aged(
            file(format!("{}.claim", lost.id)),
            JOB_TTL + Duration::from_secs(60),
        );
        // Over the time to live: the finished job's record goes, and the lost one's with its
        // claim; the running job's record (touched by its heartbeat) and its pending claim
        // stay, until the claim is a day old.
        age(&done.id, JOB_TTL + Duration::from_secs(60));
        age(&lost.id, JOB_TTL + Duration::from_secs(60));
        let _ = jobs.create("m", "shapes", 10, true, None).unwrap();
        assert!(!record(&done.id).exists());
        assert!(!record(&lost.id).exists());
        assert_eq!(claims.claimed(&lost.id), None);
        assert!(record(&running.id).exists());
        assert_eq!(claims.claimed(&running.id), Some(Claim::Cancel));
        aged(
            file(format!("{}.claim", running.id)),
            Duration::from_secs(25 * 3600),
        );
        let _ = jobs.create("m", "shapes", 10, true, None).unwrap();
        assert!(record(&running.id).exists());
        assert_eq!(claims.claimed(&running.id), None);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
