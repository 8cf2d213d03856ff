//! The estimation use cases, the same for every transport: one face ([`App::estimate`]), a
//! batch ([`App::estimate_batch`], [`BatchRun`]) and a stream of frames ([`App::open_stream`],
//! [`StreamSession`]). Each owns what its answers have in common: the model snapshot, the batch
//! limit, the deadline, where the work runs (inline or on the blocking pool), the count of faces
//! by outcome and the metrics. A transport decodes its messages into [`FaceInput`]s, calls one
//! use case and encodes what comes back.

use std::sync::Arc;
use std::time::Instant;

use facepose_core::geometry::convention::ConventionRequest;

use crate::blocking::run_maybe_blocking;
use crate::error::ServiceError;
use crate::metrics::{FaceTally, Metrics, Transport};
use crate::pose::{FacePose, FaceSpec, estimate_face};
use crate::registry::{ModelSet, ServedModel};
use crate::tracking::{Filter, Session, Smoothed, track_key};
use crate::{App, Limits, StreamPermit};

/// What a transport may convert a face's values into before the estimator borrows them,
/// reused across a batch's faces. Empty, it holds no memory: a face that needs none of it
/// costs no allocation.
#[derive(Debug, Default)]
pub struct FaceScratch {
    /// The landmarks, for a transport whose landmarks need converting (gRPC's messages).
    pub points: Vec<Option<[f64; 2]>>,
    /// The conventions asked for, for a transport that parses them per face (gRPC's, whose
    /// messages keep their names and parameters as strings).
    pub conventions: Vec<ConventionRequest>,
}

/// A face as a transport decoded it.
pub trait FaceInput {
    /// The face as the estimator takes it. `scratch` is reused across a batch's faces, for a
    /// transport whose values need converting first (gRPC's messages); a transport that holds
    /// them as they are (HTTP's JSON) ignores it. Fails for landmarks or conventions that
    /// cannot be read: that face's own error.
    fn spec<'a>(&'a self, scratch: &'a mut FaceScratch) -> Result<FaceSpec<'a>, ServiceError>;

    /// The client's id of the face's track in a stream ("" when it has none).
    fn track_id(&self) -> &str {
        ""
    }
}

/// One face's outcome: its pose, or its own error (a batch or a frame goes on).
pub type FaceOutcome = Result<FacePose, ServiceError>;

/// Counts one face's outcome in `tally`: its method, or its error's kind.
fn count(tally: &mut FaceTally, outcome: &FaceOutcome) {
    match outcome {
        Ok(p) => tally.ok(p.record.method),
        Err(e) => tally.err(e.kind()),
    }
}

/// A pose with the model that made it.
pub struct Answer {
    /// The face's pose.
    pub pose: FacePose,
    /// The model that made it.
    pub model: Arc<ServedModel>,
}

/// Batches of more faces than this run on the blocking pool, not on the async workers:
/// estimation is microseconds a face, so a thread hop pays off only for batches.
pub const INLINE_FACES: usize = 8;

/// Bodies up to this size (about six 68-point faces in JSON) are decoded and estimated inline.
pub const INLINE_BYTES: usize = 16 * 1024;

/// How big a batch is, as its transport knows it before decoding: where it runs follows.
#[derive(Debug, Clone, Copy)]
pub enum BatchSize {
    /// The number of faces.
    Faces(usize),
    /// The encoded request, for a transport that decodes inside the use case.
    Bytes(usize),
}

impl BatchSize {
    fn inline(self) -> bool {
        match self {
            BatchSize::Faces(n) => n <= INLINE_FACES,
            BatchSize::Bytes(n) => n <= INLINE_BYTES,
        }
    }
}

impl App {
    /// Use case: one face with the model named `model` (the default one when `None` or "").
    pub fn estimate(
        &self,
        transport: Transport,
        model: Option<&str>,
        face: &impl FaceInput,
    ) -> Result<Answer, ServiceError> {
        let model = self.models().get(model)?.clone();
        let mut scratch = FaceScratch::default();
        let outcome = face
            .spec(&mut scratch)
            .and_then(|spec| estimate_face(&model, &spec));
        let mut tally = FaceTally::default();
        count(&mut tally, &outcome);
        self.metrics.faces(&tally, transport);
        outcome.map(|pose| Answer { pose, model })
    }

    /// Use case: a batch. `job` decodes the request, runs its faces through the [`BatchRun`]
    /// and encodes the answer; it runs inline for a small batch, else on the blocking pool, and
    /// its faces stop at `deadline`. The faces are counted in the metrics whatever `job`
    /// returns.
    pub async fn estimate_batch<T, E>(
        self: &Arc<Self>,
        transport: Transport,
        size: BatchSize,
        deadline: Instant,
        job: impl FnOnce(&mut BatchRun) -> Result<T, E> + Send + 'static,
    ) -> Result<T, E>
    where
        T: Send + 'static,
        E: From<ServiceError> + Send + 'static,
    {
        let mut run = BatchRun::new(
            self.models(),
            self.limits,
            Some(deadline),
            self.metrics.clone(),
            transport,
        );
        run_maybe_blocking(size.inline(), move || {
            let answer = job(&mut run);
            run.finish();
            answer
        })
        .await?
    }

    /// Use case: a stream of frames, each a batch whose face tracks the session may smooth.
    /// Takes one of the `--max-streams` places (refused when they are all taken or the server
    /// drains) until the session is dropped.
    pub fn open_stream(
        self: &Arc<Self>,
        transport: Transport,
    ) -> Result<StreamSession, ServiceError> {
        let permit = self.stream_permit()?;
        self.metrics.stream_opened();
        Ok(StreamSession {
            app: self.clone(),
            transport,
            tracks: Session::default(),
            _permit: permit,
        })
    }
}

/// A batch in progress: the model snapshot it runs on, its limits and deadline, and the count
/// of its faces by outcome, recorded in the metrics by [`BatchRun::finish`].
pub struct BatchRun {
    models: Arc<ModelSet>,
    limits: Limits,
    deadline: Option<Instant>,
    metrics: Metrics,
    transport: Transport,
    tally: FaceTally,
}

impl BatchRun {
    /// A batch on `models`. [`App::estimate_batch`] makes one; so does a benchmark that runs
    /// batches with no server (`loadgen ceiling`).
    pub fn new(
        models: Arc<ModelSet>,
        limits: Limits,
        deadline: Option<Instant>,
        metrics: Metrics,
        transport: Transport,
    ) -> Self {
        BatchRun {
            models,
            limits,
            deadline,
            metrics,
            transport,
            tally: FaceTally::default(),
        }
    }

    /// Refuses more faces than `--max-batch`.
    pub fn check_size(&self, faces: usize) -> Result<(), ServiceError> {
        check_batch_size(faces, self.limits.max_batch)
    }

    /// The most faces a batch may have (`--max-batch`).
    pub fn max_faces(&self) -> usize {
        self.limits.max_batch
    }

    /// The model named `name` in the batch's snapshot.
    pub fn model(&self, name: Option<&str>) -> Result<Arc<ServedModel>, ServiceError> {
        self.models.get(name).cloned()
    }

    /// Estimates `faces` in order with `model`, each with its own outcome, which `answer` turns
    /// into the transport's result. Stops with [`ServiceError::Timeout`] once the deadline has
    /// passed (checked every 16 faces), so that a timed-out batch does not keep a core busy.
    pub fn estimate_each<F: FaceInput, R>(
        &mut self,
        model: &ServedModel,
        faces: impl IntoIterator<Item = F>,
        mut answer: impl FnMut(F, FaceOutcome) -> R,
    ) -> Result<Vec<R>, ServiceError> {
        let faces = faces.into_iter();
        let mut out = Vec::with_capacity(faces.size_hint().0);
        let mut scratch = FaceScratch::default();
        for (i, face) in faces.enumerate() {
            if i % 16 == 15 && self.deadline.is_some_and(|d| Instant::now() > d) {
                return Err(ServiceError::Timeout {
                    limit: self.limits.request_timeout,
                });
            }
            let outcome = face
                .spec(&mut scratch)
                .and_then(|spec| estimate_face(model, &spec));
            count(&mut self.tally, &outcome);
            out.push(answer(face, outcome));
        }
        Ok(out)
    }

    /// The faces estimated so far, by outcome.
    pub fn tally(&self) -> &FaceTally {
        &self.tally
    }

    /// Records the batch's faces in the metrics.
    pub fn finish(&mut self) {
        self.metrics.faces(&self.tally, self.transport);
        self.tally = FaceTally::default();
    }
}

/// Refuses a batch or frame of more than `limit` faces (`--max-batch`).
pub fn check_batch_size(faces: usize, limit: usize) -> Result<(), ServiceError> {
    if faces > limit {
        return Err(ServiceError::BatchTooLarge { faces, limit });
    }
    Ok(())
}

/// One frame of a stream as a transport decoded it.
pub struct Frame<F> {
    /// The model to use ("" for the default).
    pub model: String,
    /// When it was taken, µs (0: not given): the smoothing's time step.
    pub timestamp_us: i64,
    /// A change of the smoothing (`Some(None)`: off), which restarts every track's filter.
    pub smoothing: Option<Option<Filter>>,
    /// The faces, as the transport decoded them.
    pub faces: Vec<F>,
}

/// One frame's answer: each face's result in order, and the model that made them (its name as
/// asked and no version when it is not served: every face then carries that error).
pub struct FrameAnswer<R> {
    /// The model's name, as asked.
    pub model: String,
    /// The version that answered (empty when the model is not served).
    pub model_version: String,
    /// Each face's result, in order.
    pub faces: Vec<R>,
}

/// A stream's session: its face tracks and their smoothing, and its place among the open
/// streams, released when it is dropped.
pub struct StreamSession {
    app: Arc<App>,
    transport: Transport,
    tracks: Session,
    _permit: StreamPermit,
}

impl StreamSession {
    /// Answers one frame: every face estimated with the frame's model (read from the server's
    /// current set), each track smoothed when the session's filter is on; `answer` turns each
    /// face's outcome and what smoothing did into the transport's result. Fails, which ends
    /// the stream, only for a frame of more than `--max-batch` faces or an unusable smoothing.
    pub fn frame<F: FaceInput, R>(
        &mut self,
        frame: Frame<F>,
        mut answer: impl FnMut(F, FaceOutcome, Smoothed) -> R,
    ) -> Result<FrameAnswer<R>, ServiceError> {
        check_batch_size(frame.faces.len(), self.app.limits.max_batch)?;
        if let Some(filter) = frame.smoothing {
            self.tracks.configure(filter)?;
        }
        self.tracks.begin_frame(frame.timestamp_us);
        let models = self.app.models();
        let model = models.get(Some(&frame.model));
        let (model_name, model_version) = match &model {
            Ok(m) => (m.name.clone(), m.version.clone()),
            Err(_) => (frame.model.clone(), String::new()),
        };
        let mut tally = FaceTally::default();
        let mut faces = Vec::with_capacity(frame.faces.len());
        let mut scratch = FaceScratch::default();
        for (i, face) in frame.faces.into_iter().enumerate() {
            let mut outcome = model.as_ref().map_err(|e| e.clone()).and_then(|m| {
                let spec = face.spec(&mut scratch)?;
                estimate_face(m, &spec)
            });
            count(&mut tally, &outcome);
            let smoothed = match &mut outcome {
                Ok(p) => self.tracks.smooth(track_key(face.track_id(), i), p),
                Err(_) => Smoothed::default(),
            };
            faces.push(answer(face, outcome, smoothed));
        }
        self.tracks.end_frame();
        self.app.metrics.faces(&tally, self.transport);
        Ok(FrameAnswer {
            model: model_name,
            model_version,
            faces,
        })
    }
}

impl Drop for StreamSession {
    fn drop(&mut self) {
        self.app.metrics.stream_closed();
    }
}
