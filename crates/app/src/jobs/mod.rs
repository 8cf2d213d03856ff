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
//!   through the others ([`records`]).
//! - On SIGTERM the drain waits for the accepted jobs, queued and running ([`Jobs::idle`]),
//!   within `--drain-timeout`, and uploads that arrive meanwhile are refused (503 /
//!   UNAVAILABLE); only jobs cut off by the cap are lost, and logged by id.

pub mod records;

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore};

use crate::blocking::off_the_workers;
use crate::error::{NotCancellable, ServiceError};
use crate::metrics::Metrics;
use facepose_core::model::validate::ValidationReport;
use records::{Claim, JobRecords, LOST_AFTER};

/// How long a finished job stays visible.
pub const JOB_TTL: Duration = Duration::from_secs(3600);
/// The most jobs kept.
pub const MAX_JOBS: usize = 256;

pub use crate::job_state::{JobStage, JobState};

/// A job as the API shows it, and as its record in the models folder holds it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Job {
    /// 32 hex digits, random.
    pub id: String,
    /// The model being retrained.
    pub model: String,
    /// Its state.
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
    /// When it last changed, RFC 3339.
    pub updated: String,
    /// Kept and dropped shapes (subjects), with the reason of each drop. For 3D shapes it is
    /// there from the start; for multi-view sets once structure from motion has run.
    #[cfg_attr(feature = "openapi", schema(value_type = Option<Object>))]
    pub validation: Option<ValidationReport>,
    /// The version written (also on a job that failed to activate it).
    pub version: Option<String>,
    /// Why the job failed: what to fix.
    pub error: Option<String>,
    /// The replica that accepted the upload and runs the job (its host name).
    #[serde(default)]
    pub replica: String,
    /// The process id of that replica's server: with `replica`, it tells a replica that
    /// restarts which jobs died with its previous run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pid: Option<u32>,
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
    metrics: Metrics,
}

/// A job whose task has not ended, as the drain sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Unfinished {
    /// Waiting for the trainer.
    Queued,
    /// Working.
    Running,
    /// Cancelled, its task finishing its current stage: it loses nothing if cut off.
    Stopping,
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
        Self::shared(max_queued, None, records::replica_name(), Metrics::new())
    }

    /// [`Jobs::new`] whose jobs are recorded in `records` (a models folder's) for the other
    /// replicas, as `replica`, reporting into `metrics`.
    pub fn shared(
        max_queued: usize,
        records: Option<JobRecords>,
        replica: String,
        metrics: Metrics,
    ) -> Self {
        Jobs {
            table: Mutex::new(BTreeMap::new()),
            trainer: Arc::new(Semaphore::new(1)),
            slots: Arc::new(Semaphore::new(max_queued.saturating_add(1))),
            max_queued,
            records,
            replica,
            io: Mutex::new(()),
            metrics,
        }
    }

    /// Writes job `id`'s latest state into its record (if there is a folder). A failure is
    /// logged: the job goes on, seen by this replica only.
    fn persist(&self, id: &str) {
        self.write_record(id, |_| true);
    }

    /// [`Jobs::persist`] for a change of progress alone: at most every [`PROGRESS_WRITES`].
    fn persist_progress(&self, id: &str) {
        self.write_record(id, |e| {
            e.written.is_none_or(|t| t.elapsed() >= PROGRESS_WRITES)
        });
    }

    fn write_record(&self, id: &str, due: impl FnOnce(&Entry) -> bool) {
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
                if !due(e) {
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
    /// give it to the job ([`crate::retrain::job::submit`]).
    pub fn reserve(&self) -> Result<Slot, ServiceError> {
        self.slots
            .clone()
            .try_acquire_owned()
            .map(Slot)
            .map_err(|_| ServiceError::QueueFull {
                max_queued: self.max_queued,
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
    ) -> Result<Job, ServiceError> {
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
            pid: Some(std::process::id()),
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
        self.metrics.retrain_jobs_waiting(queued(&table));
        drop(table);
        if let Some(records) = &self.records {
            off_the_workers(|| records.sweep());
        }
        self.persist(&id);
        Ok(job)
    }

    /// At start: the records of this replica's jobs that were queued or running when its
    /// previous run stopped (a record with this replica's name and a process id that is this
    /// process's, as after a container's restart, or of no live process) are ended as failed,
    /// saying so, at once rather than after [`LOST_AFTER`]; their claims go with them, and old
    /// records are swept. A live process of the same name (two servers on one host) keeps its
    /// jobs. Returns the ids ended.
    pub fn recover(&self) -> Vec<String> {
        let Some(records) = &self.records else {
            return vec![];
        };
        records.sweep();
        let me = std::process::id();
        let mut ended = Vec::new();
        for id in records.ids() {
            let Ok(Some(mut job)) = records.read(&id) else {
                continue;
            };
            let died = job.replica == self.replica
                && !job.state.is_finished()
                && job
                    .pid
                    .is_some_and(|pid| pid == me || !records::process_alive(pid));
            if !died || self.table().contains_key(&id) {
                continue;
            }
            job.error = Some(format!(
                "replica {} restarted while this job was {} (its process {} ended): send the \
                 upload again",
                job.replica,
                job.stage.map_or(job.state.name(), JobStage::name),
                job.pid.unwrap_or_default(),
            ));
            job.state = JobState::Failed;
            job.stage = None;
            job.updated = now_rfc3339();
            match records.write(&job) {
                Ok(()) => {
                    records.clear_claim(&id);
                    tracing::warn!(job = %id, model = %job.model, "a retraining job died with \
                        this replica's previous run: recorded as failed");
                    ended.push(id);
                }
                Err(err) => tracing::warn!(job = %id, %err, "could not record the job that died \
                    with this replica's previous run as failed"),
            }
        }
        ended
    }

    /// The job `id`: this replica's, else the models folder's record of another replica's.
    pub fn get(&self, id: &str) -> Result<Job, ServiceError> {
        if let Some(e) = self.table().get(id) {
            return Ok(e.job.clone());
        }
        self.recorded(id)?
            .ok_or_else(|| ServiceError::UnknownJob { id: id.into() })
    }

    /// The models folder's record of job `id`, if any; a queued or running job whose record
    /// its replica stopped touching as failed ([`lost`]).
    fn recorded(&self, id: &str) -> Result<Option<Job>, ServiceError> {
        let Some(records) = &self.records else {
            return Ok(None);
        };
        let read = records.read_aged(id).map_err(|e| {
            ServiceError::internal(format!(
                "could not read the record of job {id} in the models folder: {e}"
            ))
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
    /// replicas know they are alive ([`records::HEARTBEAT`]); a record that has gone
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
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => self.persist(&id),
                Err(err) => tracing::warn!(job = id, %err, "could not touch the job's record: \
                    other replicas will take the job as lost within a minute"),
            }
        }
    }

    /// Changes a job's progress (and its `updated` time); its record is rewritten at most
    /// every [`PROGRESS_WRITES`]. A job already finished (a cancelled one, say) is left as it is.
    pub fn update(&self, id: &str, f: impl FnOnce(&mut Job)) {
        self.apply(id, f);
        self.persist_progress(id);
    }

    /// Changes a job's state or stage; its record is rewritten at once.
    fn transition(&self, id: &str, f: impl FnOnce(&mut Job)) {
        self.apply(id, f);
        self.persist(id);
    }

    fn apply(&self, id: &str, f: impl FnOnce(&mut Job)) {
        let mut table = self.table();
        if let Some(e) = table.get_mut(id) {
            change(e, f, &self.metrics);
        }
        self.metrics.retrain_jobs_waiting(queued(&table));
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
        self.transition(id, |j| {
            j.state = JobState::Running;
            j.stage = Some(stage);
            j.progress = progress;
            running = true;
        });
        running
    }

    /// Cancels a job that has not started writing its version: a queued one never trains, a
    /// running one stops at its next stage (what it computed is dropped). A job another replica
    /// runs is asked to ([`Cancel::Requested`]). 404 for an unknown job; 409 for a finished one,
    /// or one writing or activating its version (too late: roll back or delete the version once
    /// the job ends).
    pub fn cancel(&self, id: &str) -> Result<Cancel, ServiceError> {
        let mut table = self.table();
        let Some(e) = table.get_mut(id) else {
            drop(table);
            let job = self
                .recorded(id)?
                .ok_or_else(|| ServiceError::UnknownJob { id: id.into() })?;
            cancellable(&job)?;
            if let Some(records) = &self.records {
                let claim = records.claim(id, Claim::Cancel).map_err(|e| {
                    ServiceError::internal(format!(
                        "could not ask for the cancel of job {id} in the models folder: {e}"
                    ))
                })?;
                if claim == Claim::Write {
                    return Err(ServiceError::NotCancellable {
                        id: id.into(),
                        model: job.model,
                        why: NotCancellable::Late(JobStage::Writing),
                    });
                }
            }
            return Ok(Cancel::Requested(job));
        };
        cancellable(&e.job)?;
        change(
            e,
            |j| {
                j.state = JobState::Cancelled;
                j.stage = None;
            },
            &self.metrics,
        );
        e.cancel.notify_one();
        let job = e.job.clone();
        self.metrics.retrain_jobs_waiting(queued(&table));
        drop(table);
        self.persist(id);
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
                     may still appear among the versions of model {:?})",
                    j.replica, j.model
                )
            };
            self.transition(id, |j| {
                j.error = Some(version_note(j));
                j.state = JobState::Failed;
                j.stage = None;
            });
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
        self.transition(id, |j| {
            j.state = JobState::Succeeded;
            j.stage = None;
            j.progress = 1.0;
        });
    }

    /// The job has ended with `error`.
    pub fn fail(&self, id: &str, error: String) {
        self.transition(id, |j| {
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

    /// The ids of the jobs whose task still runs, oldest first, with where they are: queued,
    /// running, or cancelled and finishing their stage.
    pub fn unfinished(&self) -> Vec<(String, Unfinished)> {
        let table = self.table();
        let mut left: Vec<_> = table
            .values()
            .filter(|e| e.task)
            .map(|e| {
                let state = match e.job.state {
                    JobState::Queued => Unfinished::Queued,
                    JobState::Running => Unfinished::Running,
                    _ => Unfinished::Stopping,
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
fn change(e: &mut Entry, f: impl FnOnce(&mut Job), metrics: &Metrics) {
    if e.job.state.is_finished() {
        return;
    }
    f(&mut e.job);
    e.job.updated = now_rfc3339();
    if e.job.state.is_finished() {
        e.finished = Some(Instant::now());
        metrics.retrain_job_finished(e.job.state.name());
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

/// Ok if `job` can still be cancelled, else why not.
fn cancellable(job: &Job) -> Result<(), ServiceError> {
    let why = match (job.state, job.stage) {
        (s, _) if s.is_finished() => NotCancellable::Ended(s),
        (_, Some(stage @ (JobStage::Writing | JobStage::Activating))) => {
            NotCancellable::Late(stage)
        }
        _ => return Ok(()),
    };
    Err(ServiceError::NotCancellable {
        id: job.id.clone(),
        model: job.model.clone(),
        why,
    })
}

/// Jobs waiting for the trainer (not the one running).
fn queued(table: &BTreeMap<String, Entry>) -> usize {
    table
        .values()
        .filter(|e| e.job.state == JobState::Queued)
        .count()
}

#[cfg(test)]
mod tests;
