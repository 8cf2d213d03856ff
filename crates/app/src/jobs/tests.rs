//! The job table alone and two tables sharing a models folder, as two replicas would.

use super::*;
use crate::error::{ErrorKind, NotCancellable};

#[test]
fn the_queue_is_bounded_and_jobs_finish() {
    let jobs = Jobs::new(1);
    // One training and one waiting: two slots, taken before the uploads are read.
    let sa = jobs.reserve().unwrap();
    let sb = jobs.reserve().unwrap();
    let e = jobs.reserve().unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Overloaded);
    assert!(e.to_string().contains("--max-queued-jobs 1"), "{e}");
    assert!(e.to_string().contains("retry later"), "{e}");
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
    assert_eq!(jobs.get("nope").unwrap_err().kind(), ErrorKind::NotFound);
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
    assert_eq!(e.kind(), ErrorKind::Conflict);
    assert!(e.to_string().contains("is writing its version"), "{e}");
    assert!(
        matches!(
            &e,
            ServiceError::NotCancellable { model, why: NotCancellable::Late(JobStage::Writing), .. }
                if model == "m"
        ),
        "{e:?}"
    );
    let e = jobs.cancel(&waiting.id).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Conflict);
    assert!(e.to_string().contains("has already been cancelled"), "{e}");
    jobs.succeed(&writing.id);
    let e = jobs.cancel(&writing.id).unwrap_err();
    assert!(e.to_string().contains("has already succeeded"), "{e}");
    assert_eq!(jobs.cancel("nope").unwrap_err().kind(), ErrorKind::NotFound);
    // The cancelled running job's task is still finishing its stage.
    jobs.task_ended(&waiting.id);
    jobs.task_ended(&writing.id);
    assert_eq!(
        jobs.unfinished(),
        vec![(running.id.clone(), Unfinished::Stopping)]
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
    let mut want = vec![
        (a.id.clone(), Unfinished::Queued),
        (b.id.clone(), Unfinished::Running),
    ];
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
    let replica = |name: &str| {
        Jobs::shared(
            4,
            Some(JobRecords::new(&dir, name.into())),
            name.into(),
            Metrics::new(),
        )
    };
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
    assert_eq!(e.kind(), ErrorKind::Conflict);
    assert!(e.to_string().contains("has already been cancelled"), "{e}");

    // A job writing its version cannot be cancelled from anywhere.
    let late = a.create("m", "shapes", 10, true, None).unwrap();
    assert!(a.stage(&late.id, JobStage::Writing, 0.85));
    let e = b.cancel(&late.id).unwrap_err();
    assert!(e.to_string().contains("is writing its version"), "{e}");
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
    assert_eq!(e.kind(), ErrorKind::Conflict);
    assert!(e.to_string().contains("is writing its version"), "{e}");
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
        assert_eq!(b.get(id).unwrap_err().kind(), ErrorKind::NotFound, "{id}");
        assert_eq!(
            b.cancel(id).unwrap_err().kind(),
            ErrorKind::NotFound,
            "{id}"
        );
    }
    // Without a folder a replica knows its own jobs only.
    assert_eq!(
        Jobs::new(1).get(&job.id).unwrap_err().kind(),
        ErrorKind::NotFound
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_job_whose_replica_stopped_touching_it_is_lost_to_the_others() {
    let dir = records_dir("lost");
    let replica = |name: &str| {
        Jobs::shared(
            4,
            Some(JobRecords::new(&dir, name.into())),
            name.into(),
            Metrics::new(),
        )
    };
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
    assert_eq!(e.kind(), ErrorKind::Conflict, "{e}");
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
    let jobs = Jobs::shared(
        4,
        Some(JobRecords::new(&dir, "a".into())),
        "a".into(),
        Metrics::new(),
    );
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

#[test]
fn a_restarted_replica_ends_the_jobs_that_died_with_its_previous_run() {
    // Its own killed job showed as `running` for a minute after a restart.
    let dir = records_dir("recover");
    let replica = |name: &str| {
        Jobs::shared(
            4,
            Some(JobRecords::new(&dir, name.into())),
            name.into(),
            Metrics::new(),
        )
    };
    // Jobs of "a" left by processes: this one (a container restarted: the same pid), one that
    // has ended, one still alive (another server on the host), and a job of "b".
    let mut alive = std::process::Command::new("sleep")
        .arg("30")
        .spawn()
        .unwrap();
    let mut ended = std::process::Command::new("true").spawn().unwrap();
    ended.wait().unwrap();
    let (previous, b) = (replica("a"), replica("b"));
    let mut jobs = Vec::new();
    for (table, pid) in [
        (&previous, std::process::id()),
        (&previous, ended.id()),
        (&previous, alive.id()),
        (&b, std::process::id()),
    ] {
        let job = table.create("m", "shapes", 10, true, None).unwrap();
        assert!(table.stage(&job.id, JobStage::Training, 0.3));
        let mut record = JobRecords::new(&dir, "x".into())
            .read(&job.id)
            .unwrap()
            .unwrap();
        record.pid = Some(pid);
        JobRecords::new(&dir, "x".into()).write(&record).unwrap();
        JobRecords::new(&dir, "b".into())
            .claim(&job.id, Claim::Cancel)
            .unwrap();
        jobs.push(job.id);
    }
    let finished = previous.create("m", "shapes", 10, true, None).unwrap();
    previous.succeed(&finished.id);
    drop(previous);
    let restarted = replica("a");
    let mut recovered = restarted.recover();
    recovered.sort();
    let mut want = vec![jobs[0].clone(), jobs[1].clone()];
    want.sort();
    assert_eq!(recovered, want);
    let records = JobRecords::new(&dir, "c".into());
    for id in &jobs[..2] {
        let seen = restarted.get(id).unwrap();
        assert_eq!((seen.state, seen.stage), (JobState::Failed, None));
        let why = seen.error.unwrap();
        assert!(
            why.contains("replica a restarted while this job was training"),
            "{why}"
        );
        assert_eq!(records.claimed(id), None);
    }
    for id in &jobs[2..] {
        assert_eq!(restarted.get(id).unwrap().state, JobState::Running);
        assert_eq!(records.claimed(id), Some(Claim::Cancel));
    }
    assert_eq!(
        restarted.get(&finished.id).unwrap().state,
        JobState::Succeeded
    );
    assert!(restarted.recover().is_empty());
    alive.kill().unwrap();
    let _ = alive.wait();
    let _ = std::fs::remove_dir_all(&dir);
}
