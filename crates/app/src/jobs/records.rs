//! Retraining jobs as every replica sharing a models folder sees them: each job's record in
//! `MODELS/.jobs/<id>.json`, written by the replica that runs the job, read by the others.
//!
//! - The replica that accepted an upload keeps the job in memory ([`super::Jobs`]) and writes
//!   its record at every change of state or stage (progress at most once a second). A record
//!   is replaced whole (temporary file, then rename), so a reader never sees half of one.
//! - Another replica answers `GET /v1/models/jobs/{id}` from the record, and a cancel by
//!   claiming the job for a cancel: the running replica acts on it at the job's next stage (a
//!   queued job never trains). Before writing its version the running replica claims the job
//!   for the write. The claim (`<id>.claim`) is made by a hard link, which only one can make,
//!   so a cancel and a write never both win: the loser learns which claim won.
//! - While a job is queued or running its replica touches the record every [`HEARTBEAT`].
//!   A record of such a job untouched for [`LOST_AFTER`] is a job whose replica stopped
//!   without ending it (killed, out of memory, cut off from the folder): the other replicas
//!   answer it as failed, saying so, and refuse to cancel it, instead of showing it running
//!   and accepting a cancel nobody will carry out.
//! - Records untouched for [`JOB_TTL`](super::JOB_TTL) (jobs that ended then, or were
//!   lost) are removed when a job is created, with their claims; a claim goes with its job's
//!   record, or after a day.
//! - The hidden folder is skipped by the model catalog, as the folder's other hidden entries.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use super::{JOB_TTL, Job};

/// The folder of job records within a models folder.
pub const JOBS_DIR: &str = ".jobs";

/// A claim untouched for this long is removed whatever its job's record says.
const STALE: Duration = Duration::from_secs(24 * 3600);

/// How often the replica running a job touches its record, changes or not.
pub const HEARTBEAT: Duration = Duration::from_secs(10);

/// A record of a queued or running job untouched for this long is taken as lost: six
/// heartbeats, so that a busy volume or clocks a little apart do not make a live job lost.
pub const LOST_AFTER: Duration = Duration::from_secs(60);

/// Who claimed a job: a cancel through another replica, or the running replica's write of the
/// job's version. The first claim stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Claim {
    /// A cancel, through any replica.
    Cancel,
    /// The running replica's write of the job's version.
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

/// Whether a process `pid` exists on this host (it may be another program that reuses a dead
/// server's id: then the job is left to [`LOST_AFTER`]).
pub fn process_alive(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    // SAFETY: signal 0 sends nothing; kill only checks that the process exists.
    let rc = unsafe { libc::kill(pid, 0) };
    rc == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
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
        Ok(self.read_aged(id)?.map(|(job, _)| job))
    }

    /// [`JobRecords::read`], with the time since the record was last written or touched.
    pub fn read_aged(&self, id: &str) -> std::io::Result<Option<(Job, Duration)>> {
        if !is_job_id(id) {
            return Ok(None);
        }
        let mut f = match fs::File::open(self.record(id)) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e),
        };
        // The age of the file that is read, not of one renamed over it since.
        let modified = f.metadata()?.modified()?;
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut f, &mut bytes)?;
        let job = serde_json::from_slice(&bytes)
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
        let age = SystemTime::now()
            .duration_since(modified)
            .unwrap_or_default();
        Ok(Some((job, age)))
    }

    /// The ids of every record (in no order).
    pub fn ids(&self) -> Vec<String> {
        let Ok(entries) = fs::read_dir(&self.dir) else {
            return vec![];
        };
        entries
            .flatten()
            .filter_map(|e| {
                let name = e.file_name().into_string().ok()?;
                let id = name.strip_suffix(".json")?;
                is_job_id(id).then(|| id.to_string())
            })
            .collect()
    }

    /// Marks the record of job `id` as current (its modification time), without rewriting
    /// it. `NotFound` when there is no record to touch.
    pub fn touch(&self, id: &str) -> std::io::Result<()> {
        fs::File::options()
            .write(true)
            .open(self.record(id))?
            .set_modified(SystemTime::now())
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

    /// Removes the records untouched for [`JOB_TTL`] (jobs that ended then, or were lost: a
    /// live job's record is touched every [`HEARTBEAT`]), and claims whose job has no live
    /// record, or untouched for a day. Errors are left for the next sweep.
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
            // A record goes; a claim that its job may still need once the job has ended (or
            // has no record) or after a day; temporary files left by a crash at once.
            let remove = match name.strip_suffix(".claim") {
                Some(id) => {
                    age >= STALE
                        || self
                            .read_aged(id)
                            .ok()
                            .flatten()
                            .is_none_or(|(j, age)| j.state.is_finished() || age >= JOB_TTL)
                }
                None => true,
            };
            if remove {
                let _ = fs::remove_file(&path);
            }
        }
    }
}
