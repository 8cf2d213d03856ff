//! A retraining job from an accepted upload to its end: (structure from motion and validation
//! for multi-view sets), training on the blocking pool, the new version written into the
//! models folder and, unless the upload said otherwise, activated. Every outcome is recorded in
//! the job table; a failure's message says what went wrong and what to do.

use std::sync::Arc;

use tracing::Instrument;

use super::{JobSpec, Prepared, Work, too_few};
use crate::blocking::on_blocking_pool;
use crate::error::ServiceError;
use crate::jobs::{Job, JobStage, JobState, Jobs, Slot, now_rfc3339};
use crate::registry::Registry;
use facepose_core::model::bundle::{Bundle, Provenance, SourceFile};
use facepose_core::model::validate::{
    Dropped, ValidatedShapes, ValidationOptions, reconstruct_subject, validate_shapes,
};
use facepose_core::model::{BasisSource, PoseModel, default_model, train_from_population};
use facepose_core::shape::Shape2;

/// What a job works with: the registry it writes into and the job table it reports to.
#[derive(Debug, Clone)]
pub struct Trainer {
    /// The registry it writes into.
    pub registry: Arc<Registry>,
    /// The job table it reports to.
    pub jobs: Arc<Jobs>,
    /// The span of the server the job runs in (its log lines are the server's).
    pub span: tracing::Span,
    /// How many inactive versions of a model to keep once a job has written one (`None`: all).
    pub keep_inactive: Option<usize>,
}

/// Registers an accepted upload as a job and starts it; the job holds `slot` (taken with
/// [`Jobs::reserve`] before the upload was read) until it ends.
pub fn submit(trainer: &Trainer, p: Prepared, slot: Slot) -> Result<Job, ServiceError> {
    let spec = p.spec;
    if let Some(e) = trainer
        .registry
        .snapshot()
        .name_conflict(&spec.model, &spec.model)
    {
        return Err(e);
    }
    let job = trainer.jobs.create(
        &spec.model,
        spec.kind,
        spec.uploaded,
        spec.activate,
        match &p.work {
            Work::Shapes(v) => Some(v.report.clone()),
            Work::Subjects { .. } => None,
        },
    )?;
    tracing::info!(job = %job.id, model = %spec.model, kind = spec.kind, uploaded = spec.uploaded,
        "retraining job accepted");
    // The job outlives the request: its own span, a child of the server's, not the request's.
    let span = tracing::info_span!(parent: &trainer.span, "job", id = %job.id, model = %spec.model);
    let (trainer, id) = (trainer.clone(), job.id.clone());
    tokio::spawn(
        async move {
            run(&trainer, &id, Arc::new(spec), p.work).await;
            trainer.jobs.task_ended(&id);
            drop(slot);
        }
        .instrument(span),
    );
    Ok(job)
}

/// Rebuilds the subjects by structure from motion and validates the shapes; indices in the
/// report are the subjects' in the upload.
fn reconstruct_all(
    spec: &JobSpec,
    views: &[(usize, Vec<Shape2>)],
    mut dropped: Vec<Dropped>,
    progress: impl Fn(f64),
) -> Result<ValidatedShapes, ServiceError> {
    let mut shapes = Vec::new();
    let mut index = Vec::new();
    for (done, (k, v)) in views.iter().enumerate() {
        match reconstruct_subject(&spec.scheme, v) {
            Ok(s) => {
                shapes.push(s);
                index.push(*k);
            }
            Err((reason, detail)) => dropped.push(Dropped {
                index: *k,
                reason,
                detail,
            }),
        }
        progress((done + 1) as f64 / views.len() as f64);
    }
    let opts = ValidationOptions {
        scale_free: true,
        ..spec.options.validation
    };
    let mut v = validate_shapes(&spec.scheme, &shapes, &opts)?;
    for d in &mut v.report.dropped {
        d.index = index[d.index];
    }
    v.indices = v.indices.iter().map(|&i| index[i]).collect();
    dropped.append(&mut v.report.dropped);
    dropped.sort_by_key(|d| d.index);
    v.report.dropped = dropped;
    v.report.total = spec.uploaded;
    Ok(v)
}

/// Runs an accepted job to its end (after the jobs accepted before it, unless it is cancelled
/// while it waits); every outcome is recorded in the job table.
async fn run(trainer: &Trainer, id: &str, spec: Arc<JobSpec>, work: Work) {
    let jobs = &trainer.jobs;
    let permit = tokio::select! {
        biased;
        () = jobs.cancelled(id) => None,
        permit = jobs.trainer() => permit,
    };
    let Some(_permit) = permit else {
        tracing::info!("retraining job cancelled while queued");
        return;
    };
    match steps(trainer, id, &spec, work).await {
        Ok(Some(version)) => {
            tracing::info!(version = %version, activated = spec.activate, "retraining job succeeded");
            jobs.succeed(id);
        }
        Ok(None) => tracing::info!("retraining job cancelled"),
        Err(e) if jobs.get(id).is_ok_and(|j| j.state == JobState::Cancelled) => {
            tracing::info!(error = %e, "cancelled retraining job stopped on an error");
        }
        Err(e) => {
            tracing::warn!(error = %e, "retraining job failed");
            jobs.fail(id, e.to_string());
        }
    }
}

/// The job's steps; the version written, or `None` when the job was cancelled (checked as
/// each stage starts; the last chance is before writing).
async fn steps(
    trainer: &Trainer,
    id: &str,
    spec: &Arc<JobSpec>,
    work: Work,
) -> Result<Option<String>, ServiceError> {
    let jobs = &trainer.jobs;
    let validated = match work {
        Work::Shapes(v) => v,
        Work::Subjects { views, dropped } => {
            if !jobs.stage(id, JobStage::Validating, 0.0) {
                return Ok(None);
            }
            let (table, jid, sp) = (jobs.clone(), id.to_string(), spec.clone());
            let v = on_blocking_pool("structure from motion", move || {
                reconstruct_all(&sp, &views, dropped, |f| {
                    table.update(&jid, |j| j.progress = 0.3 * f);
                })
            })
            .await?;
            jobs.update(id, |j| j.validation = Some(v.report.clone()));
            if v.report.kept < spec.options.min_shapes {
                return Err(too_few(&v.report, "subject", spec.options.min_shapes));
            }
            v
        }
    };
    if !jobs.stage(id, JobStage::Training, 0.3) {
        return Ok(None);
    }
    let sp = spec.clone();
    let kept = validated.shapes.len();
    let model = on_blocking_pool("training", move || {
        let basis = BasisSource::Pca(sp.options.components);
        let mut model =
            train_from_population(&sp.scheme, &validated.shapes, basis, &sp.options.train)
                .map_err(|e| ServiceError::invalid(format!("training failed: {e}")))?;
        carry_mesh(&mut model)?;
        Ok(model)
    })
    .await?;
    if !jobs.stage(id, JobStage::Writing, 0.85) {
        return Ok(None);
    }
    let (sp, job_id) = (spec.clone(), id.to_string());
    let (version, _) = trainer
        .registry
        .write_version(&spec.model, move |version| {
            Bundle::from_model(
                &model,
                &sp.options.train,
                &sp.model,
                version,
                &now_rfc3339(),
                provenance(&sp, &job_id, kept),
            )
            .map_err(|e| ServiceError::internal(format!("the trained model has no bundle: {e}")))
        })
        .await?;
    jobs.update(id, |j| j.version = Some(version.clone()));
    if spec.activate {
        // Not cancellable once writing: the stage always starts.
        let _ = jobs.stage(id, JobStage::Activating, 0.9);
        trainer
            .registry
            .activate(&spec.model, &version)
            .await
            .map_err(|e| {
                ServiceError::Conflict(format!(
                    "version {version} was written but not activated: {e}; activate it or \
                     another version through the API"
                ))
            })?;
    }
    if let Some(keep) = trainer.keep_inactive {
        // The job's own outcome stands whatever pruning does.
        if let Err(e) = trainer.registry.prune(&spec.model, keep).await {
            tracing::warn!(model = %spec.model, error = %e, "could not prune inactive versions");
        }
    }
    Ok(Some(version))
}

/// An ibug68 model serves MediaPipe input as the default model does: the default model's face
/// mesh (MediaPipe's canonical mesh) re-aligned to the new mean, so that web apps sending
/// MediaPipe's points keep their answers across a retrain. It also takes the default model's
/// uncertainty calibration (of the estimators on real ibug68 faces: uploaded shapes have no
/// ground-truth pose to fit one on), so that answers keep their uncertainty, and its detector
/// regressions (they read a detector's 2D points, whatever the mean shape; uploaded shapes have
/// no detector output to train one on).
fn carry_mesh(model: &mut PoseModel) -> Result<(), ServiceError> {
    if model.scheme.name != "ibug68" {
        return Ok(());
    }
    let (_, default) = default_model()
        .map_err(|e| ServiceError::internal(format!("the embedded default model: {e}")))?;
    if let Some(mesh) = &default.mesh {
        model
            .attach_mesh(mesh.source())
            .map_err(|e| ServiceError::invalid(format!("aligning the face mesh failed: {e}")))?;
    }
    model.calibration = default.calibration.clone();
    model.detectors = default.detectors.clone();
    Ok(())
}

fn provenance(spec: &JobSpec, job: &str, kept: usize) -> Provenance {
    let basis = if spec.options.components == 0 {
        "none".to_string()
    } else {
        format!(
            "up to {} principal components of the shapes",
            spec.options.components
        )
    };
    let mut notes = format!(
        "retrained through the service (job {job}) from {} uploaded {} ({kept} kept after \
         validation); mean by generalized Procrustes analysis; shape basis: {basis}",
        spec.uploaded, spec.kind
    );
    if spec.scheme.name == "ibug68" {
        notes.push_str(
            "; face mesh: the default model's (MediaPipe's canonical face mesh, Apache-2.0), \
             aligned to the new mean; uncertainty calibration and detector regressions: the \
             default model's",
        );
    }
    if !spec.notes.is_empty() {
        notes = format!("{}; {notes}", spec.notes);
    }
    Provenance {
        sources: vec![SourceFile {
            path: format!("upload of job {job}"),
            sha256: spec.sha256.clone(),
            shapes: spec.uploaded,
        }],
        command: spec.origin.to_string(),
        notes,
    }
}
