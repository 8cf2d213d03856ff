//! Retraining jobs as every replica sharing a models folder sees them: each job's record in
//! `MODELS/.jobs/<id>.json`, written by the replica that runs the job, read by the others.
//!
//! - The replica that accepted an upload keeps the job in memory ([`super::jobs`]) and writes
//!   its record at every change of state or stage (progress at most once a second). A record
//!   is replaced whole (temporary file, then rename), so a reader never sees half of one.
//! - Another replica answers `GET /v1/models/jobs/{id}` from the record, and a cancel by
//!   claiming the job for a cancel: the running replica acts on it at the job's next stage (a
//!   queued job never trains). Before writing its version the running replica claims the job
//!   for the write. The claim (`<id>.claim`) is made by a hard link, which only one can make,
//!   so a cancel and a write never both win: the loser learns which claim won.
//! - A replica killed without a drain leaves its jobs' records at their last state until they
//!   age out (below); a cancel through another replica is then accepted but never acted on.
//! - Records of jobs that ended more than [`JOB_TTL`](super::jobs::JOB_TTL) ago, and any record
//!   untouched for a day (a replica that died mid-job), are removed when a job is created.
//! - The hidden folder is skipped by the model catalog, as the folder's other hidden entries.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use super::jobs::{JOB_TTL, Job};

/// The folder of job records within a models folder.
pub const JOBS_DIR: &str = ".jobs";

/// A record untouched for this long is removed whatever its state: its replica stopped
/// without ending it.
const STALE: Duration = Duration::from_secs(24 * 3600);

/// Who claimed a job: a cancel through another replica, or the running replica's write of the
/// job's version. The first claim stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Claim {
    Cancel,
    Write,
}

impl Claim {
    fn tag(self) -> &'static [u8] {
        match self {
            Claim::Cancel => b"cancel\n",
            Claim::Write => b"write\n",
        }
    }
}

/// The job records of one models folder, and the name this replica writes into them.
#[derive(Debug, Clone)]
pub struct JobRecords {
    dir: PathBuf,
    replica: String,
}

/// Whether `id` has the shape of a job id (32 lower-case hex digits), so that it can name a
/// file.
pub fn is_job_id(id: &str) -> bool {
    id.len() == 32 && id.bytes().all(|c| matches!(c, b'0'..=b'9' | b'a'..=b'f'))
}

/// This replica's name: the host name (a pod's name in Kubernetes), else "unknown".
pub fn replica_name() -> String {
    let mut buf = [0u8; 256];
    // SAFETY: gethostname writes at most `len` bytes into the buffer it is given.
    let rc = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) };
    let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    match std::str::from_utf8(&buf[..end]) {
        Ok(name) if rc == 0 && !name.is_empty() => name.to_string(),
        _ => "unknown".to_string(),
    }
}

impl JobRecords {
    /// The records under `models_root`, written as `replica`.
    pub fn new(models_root: &Path, replica: String) -> Self {
        JobRecords {
            dir: models_root.join(JOBS_DIR),
            replica,
        }
    }

    /// The name this replica writes into its jobs.
    pub fn replica(&self) -> &str {
        &self.replica
    }

    fn record(&self, id: &str) -> PathBuf {
        self.dir.join(format!("{id}.json"))
    }

    fn claim_path(&self, id: &str) -> PathBuf {
        self.dir.join(format!("{id}.claim"))
    }

    /// Replaces the record of `job`.
    pub fn write(&self, job: &Job) -> std::io::Result<()> {
        fs::create_dir_all(&self.dir)?;
        let tmp = self
            .dir
            .join(format!(".{}.tmp-{}", job.id, std::process::id()));
        let mut f = fs::File::create(&tmp)?;
        f.write_all(&serde_json::to_vec(job).map_err(std::io::Error::other)?)?;
        drop(f);
        fs::rename(&tmp, self.record(&job.id)).inspect_err(|_| {
            let _ = fs::remove_file(&tmp);
        })
    }

    /// The record of job `id`, if there is one (`None` too for an id that is not one).
    pub fn read(&self, id: &str) -> std::io::Result<Option<Job>> {
        if !is_job_id(id) {
            return Ok(None);
        }
        match fs::read(self.record(id)) {
            Ok(bytes) => serde_json::from_slice(&bytes)
                .map(Some)
                .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(e),
        }
    }

    /// Claims job `id` for `who`, unless it is claimed already: the claim that stands.
    pub fn claim(&self, id: &str, who: Claim) -> std::io::Result<Claim> {
        fs::create_dir_all(&self.dir)?;
        let tmp = self.dir.join(format!(
            ".{id}.claim.tmp-{}-{}",
            std::process::id(),
            rand::random::<u32>()
        ));
        fs::write(&tmp, who.tag())?;
        // A complete file under the claim's name, or an error if there is one already.
        let linked = fs::hard_link(&tmp, self.claim_path(id));
        let _ = fs::remove_file(&tmp);
        match linked {
            Ok(()) => Ok(who),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => self
                .claimed(id)
                .ok_or_else(|| std::io::Error::other("the job's claim vanished")),
            Err(e) => Err(e),
        }
    }

    /// The claim on job `id`, if any.
    pub fn claimed(&self, id: &str) -> Option<Claim> {
        match fs::read(self.claim_path(id)).ok()?.as_slice() {
            b"cancel\n" => Some(Claim::Cancel),
            b"write\n" => Some(Claim::Write),
            _ => None,
        }
    }

    /// Removes job `id`'s claim, once the job has ended.
    pub fn clear_claim(&self, id: &str) {
        let _ = fs::remove_file(self.claim_path(id));
    }

    /// Removes the records of jobs that ended over [`JOB_TTL`] ago and of any job untouched for
    /// a day, with their cancel markers. Errors are left for the next sweep.
    pub fn sweep(&self) {
        let Ok(entries) = fs::read_dir(&self.dir) else {
            return;
        };
        let now = SystemTime::now();
        for entry in entries.flatten() {
            let path = entry.path();
            let age = entry
                .metadata()
                .and_then(|m| m.modified())
                .ok()
                .and_then(|t| now.duration_since(t).ok())
                .unwrap_or_default();
            if age < JOB_TTL {
                continue;
            }
            let name = entry.file_name();
            let name = name.to_string_lossy();
            // A record, or a claim that its job may still need, goes once the job has ended
            // (or has no record) or after a day; temporary files left by a crash at once.
            let id = name
                .strip_suffix(".json")
                .or_else(|| name.strip_suffix(".claim"));
            let remove = match id {
                Some(id) => {
                    age >= STALE
                        || self
                            .read(id)
                            .ok()
                            .flatten()
                            .is_none_or(|j| j.state.is_finished())
                }
                None => true,
            };
            if remove {
                let _ = fs::remove_file(&path);
            }
        }
    }
}
