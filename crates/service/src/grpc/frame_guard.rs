//! The limits of the pose calls' messages checked on their bytes as they arrive, before a
//! message is whole: the faces of an `EstimateBatch` request or a stream `Frame`
//! (`--max-batch`), the landmarks of a face (a scheme's 1000 points at most), its conventions
//! (4 at most, each and the camera orientation within a name's length) and the length of any
//! name. tonic buffers a whole message before the codec sees it, so the codec's walk
//! ([`super::codec::Bounded`]) bounds what a message costs decoded but not the message itself:
//! four callers sending 8 MiB of empty faces held 32 MiB. Here the call ends at the byte that
//! crosses a limit, with the status the codec would give.
//!
//! The guard follows the gRPC framing (a flag byte, a 4-byte length, the message) and walks
//! each message of [`SCAN_FROM`] bytes or more (a shorter one costs little however it is
//! made, and is passed over whole) through its fields and its faces' fields, skipping every
//! other value in bulk; it keeps no values. On anything malformed or compressed it skips to the message's end and leaves the
//! message to the codec and prost, which say what is wrong.

use std::pin::Pin;
use std::task::{Context, Poll};

use axum::body::{Body, Bytes};
use facepose_app::error::ServiceError;
use facepose_core::shape::MAX_POINTS;
use http_body::{Frame, SizeHint};
use tonic::Status;

use super::codec::{SCAN_FROM, marked};
use super::convert::MAX_CONVENTIONS;
use super::error;

/// The most bytes of a string field of a pose message: far above any name (64 characters) or
/// id a client needs.
pub const MAX_STRING: u64 = 64 * 1024;

/// The pose calls whose requests the guard reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rpc {
    /// `EstimateRequest`: `face` (1), `model` (2).
    Estimate,
    /// `EstimateBatchRequest`: `faces` (1), `model` (2).
    EstimateBatch,
    /// `Frame`s: `faces` (3), `model` (4).
    EstimateStream,
}

impl Rpc {
    /// The call at `path`, if it is one the guard reads.
    pub fn of(path: &str) -> Option<Rpc> {
        match path.rsplit('/').next()? {
            "Estimate" => Some(Rpc::Estimate),
            "EstimateBatch" => Some(Rpc::EstimateBatch),
            "EstimateStream" => Some(Rpc::EstimateStream),
            _ => None,
        }
    }

    /// The field of the faces, and the field of the model name.
    fn fields(self) -> (u32, u32) {
        match self {
            Rpc::Estimate | Rpc::EstimateBatch => (1, 2),
            Rpc::EstimateStream => (3, 4),
        }
    }
}

/// Where the reader is in the bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    /// The 5-byte prefix of a message: `got` of them read.
    Prefix { got: u8 },
    /// A field's key (a varint).
    Key,
    /// A varint value.
    Varint { field: u32 },
    /// The length of a length-delimited field (a varint).
    Length { field: u32 },
    /// `left` bytes of a value to pass over; `varints` if it is a packed varint field, whose
    /// values are counted (as bytes without the continuation bit).
    Skip { left: u64, varints: bool },
}

/// A message or a face being read, up to `end` (an offset within the message).
#[derive(Debug, Clone, Copy)]
struct Open {
    end: u64,
    face: bool,
}

/// The guard of one call's request body (see the module doc).
#[derive(Debug)]
pub struct FrameGuard {
    rpc: Rpc,
    max_batch: usize,
    step: Step,
    prefix: [u8; 5],
    /// The varint being read, and its shift.
    acc: u64,
    shift: u32,
    /// Offset within the current message, and its length.
    pos: u64,
    len: u64,
    /// The current message and, within it, the current face.
    open: Vec<Open>,
    /// Faces of the current message; landmarks, packed doubles and missing indices of the
    /// current face.
    faces: usize,
    landmarks: usize,
    doubles: u64,
    missing: u64,
    /// Conventions of the current face.
    conventions: usize,
    /// The status to end the call with, once a limit is crossed.
    breach: Option<Status>,
    /// Messages shorter than this are passed over.
    scan_from: u64,
}

impl FrameGuard {
    /// A guard of `rpc`'s messages, at most `max_batch` faces each.
    pub fn new(rpc: Rpc, max_batch: usize) -> Self {
        FrameGuard {
            rpc,
            max_batch,
            step: Step::Prefix { got: 0 },
            prefix: [0; 5],
            acc: 0,
            shift: 0,
            pos: 0,
            len: 0,
            open: Vec::with_capacity(2),
            faces: 0,
            landmarks: 0,
            doubles: 0,
            missing: 0,
            conventions: 0,
            breach: None,
            scan_from: SCAN_FROM as u64,
        }
    }

    /// The guard walking messages from `bytes` long up ([`SCAN_FROM`] by default), e.g. every
    /// message (0) for tests.
    pub fn scanning_from(mut self, bytes: u64) -> Self {
        self.scan_from = bytes;
        self
    }

    /// Reads the next bytes of the body; the status to end the call with once a limit is
    /// crossed (and for every later chunk, which it no longer reads).
    pub fn feed(&mut self, mut bytes: &[u8]) -> Result<(), Status> {
        while !bytes.is_empty() && self.breach.is_none() {
            let used = self.step(bytes);
            bytes = &bytes[used..];
        }
        match &self.breach {
            Some(s) => Err(s.clone()),
            None => Ok(()),
        }
    }

    /// Reads from the front of `bytes` (not empty); the bytes used.
    fn step(&mut self, bytes: &[u8]) -> usize {
        if let Step::Prefix { got } = self.step {
            self.prefix[usize::from(got)] = bytes[0];
            self.step = if got == 4 {
                self.start_message()
            } else {
                Step::Prefix { got: got + 1 }
            };
            return 1;
        }
        let used = match self.step {
            Step::Skip { left, varints } => {
                let n = left.min(bytes.len() as u64) as usize;
                if varints {
                    self.missing += bytes[..n].iter().filter(|b| *b & 0x80 == 0).count() as u64;
                    self.check_points();
                }
                self.pos += n as u64;
                self.step = if left == n as u64 {
                    Step::Key
                } else {
                    Step::Skip {
                        left: left - n as u64,
                        varints,
                    }
                };
                n
            }
            Step::Key | Step::Varint { .. } | Step::Length { .. } => {
                let b = bytes[0];
                self.pos += 1;
                if self.shift >= 64 {
                    self.give_up();
                } else {
                    self.acc |= u64::from(b & 0x7f) << self.shift;
                    self.shift += 7;
                    if b & 0x80 == 0 {
                        let value = std::mem::take(&mut self.acc);
                        self.shift = 0;
                        self.varint_done(value);
                    }
                }
                1
            }
            Step::Prefix { .. } => unreachable!("handled above"),
        };
        self.settle();
        used
    }

    /// After a step: at the message's end the next message's prefix comes (a value cut off by
    /// it is prost's to refuse); before a key, the faces that ended are closed.
    fn settle(&mut self) {
        if matches!(self.step, Step::Prefix { .. }) {
            return;
        }
        if self.pos >= self.len {
            self.step = Step::Prefix { got: 0 };
            (self.acc, self.shift) = (0, 0);
            return;
        }
        if self.step == Step::Key {
            while self.open.len() > 1 {
                let end = self.open.last().map_or(0, |o| o.end);
                if end > self.pos {
                    break;
                }
                if end < self.pos {
                    // A value ran past its face's end: not a message.
                    return self.give_up();
                }
                self.open.pop();
            }
        }
    }

    /// A message's prefix is read: its walk starts (or, compressed, it is passed over whole).
    fn start_message(&mut self) -> Step {
        let len = u64::from(u32::from_be_bytes([
            self.prefix[1],
            self.prefix[2],
            self.prefix[3],
            self.prefix[4],
        ]));
        (self.pos, self.len) = (0, len);
        (self.faces, self.landmarks, self.doubles, self.missing) = (0, 0, 0, 0);
        self.open.clear();
        self.open.push(Open {
            end: len,
            face: false,
        });
        match (self.prefix[0], len) {
            (_, 0) => Step::Prefix { got: 0 },
            // A short message costs little however it is made (the codec's rule too).
            (0, len) if len >= self.scan_from => Step::Key,
            // Compressed: its faces are the codec's to count once it is decompressed.
            _ => Step::Skip {
                left: len,
                varints: false,
            },
        }
    }

    /// Passes over the rest of the current message, whose bytes do not read as one.
    fn give_up(&mut self) {
        self.open.truncate(1);
        (self.acc, self.shift) = (0, 0);
        self.step = if self.pos >= self.len {
            Step::Prefix { got: 0 }
        } else {
            Step::Skip {
                left: self.len - self.pos,
                varints: false,
            }
        };
    }

    fn in_face(&self) -> bool {
        self.open.last().is_some_and(|o| o.face)
    }

    fn varint_done(&mut self, value: u64) {
        match self.step {
            Step::Key => {
                let Ok(field) = u32::try_from(value >> 3) else {
                    return self.give_up();
                };
                self.step = match value & 7 {
                    0 => Step::Varint { field },
                    1 => {
                        if self.in_face() && field == 7 {
                            self.doubles += 1;
                            self.check_points();
                        }
                        Step::Skip {
                            left: 8,
                            varints: false,
                        }
                    }
                    2 => Step::Length { field },
                    5 => Step::Skip {
                        left: 4,
                        varints: false,
                    },
                    _ => return self.give_up(),
                };
            }
            Step::Varint { field } => {
                if self.in_face() && field == 8 {
                    self.missing += 1;
                    self.check_points();
                }
                self.step = Step::Key;
            }
            Step::Length { field } => self.length_done(field, value),
            _ => {}
        }
    }

    /// A length-delimited field of `len` bytes starts at `pos`.
    fn length_done(&mut self, field: u32, len: u64) {
        let end = self.pos.saturating_add(len);
        if self.open.last().is_none_or(|o| end > o.end) {
            return self.give_up();
        }
        let (faces_field, model_field) = self.rpc.fields();
        let skip = |varints| Step::Skip { left: len, varints };
        self.step = if self.in_face() {
            match field {
                1 => {
                    self.landmarks += 1;
                    self.check_points();
                    skip(false)
                }
                7 => {
                    self.doubles += len / 8;
                    self.check_points();
                    skip(false)
                }
                8 => skip(true),
                2 | 3 | 5 | 6 => self.string(len),
                // A convention, or the camera orientation: a few names and numbers.
                10 => {
                    self.conventions += 1;
                    if self.conventions > MAX_CONVENTIONS && self.breach.is_none() {
                        self.breach = Some(marked(Status::invalid_argument(format!(
                            "face {} has more than {MAX_CONVENTIONS} conventions; name each \
                             convention at most once",
                            self.faces.saturating_sub(1)
                        ))));
                    }
                    self.string(len)
                }
                11 => self.string(len),
                _ => skip(false),
            }
        } else if field == faces_field {
            self.faces += 1;
            if self.rpc != Rpc::Estimate && self.faces > self.max_batch {
                self.breach = Some(marked(error::status(&ServiceError::BatchOverLimit {
                    at_least: self.faces,
                    limit: self.max_batch,
                })));
            }
            (self.landmarks, self.doubles, self.missing) = (0, 0, 0);
            self.conventions = 0;
            self.open.push(Open { end, face: true });
            Step::Key
        } else if field == model_field {
            self.string(len)
        } else {
            skip(false)
        };
    }

    /// A name of `len` bytes: refused past [`MAX_STRING`], passed over otherwise.
    fn string(&mut self, len: u64) -> Step {
        if len > MAX_STRING {
            self.breach = Some(marked(Status::invalid_argument(format!(
                "a string of {len} bytes; names have at most 64 characters"
            ))));
        }
        Step::Skip {
            left: len,
            varints: false,
        }
    }

    fn check_points(&mut self) {
        let points = (self.landmarks as u64)
            .max(self.missing)
            .max(self.doubles.div_ceil(2));
        if points > MAX_POINTS as u64 && self.breach.is_none() {
            self.breach = Some(marked(Status::invalid_argument(format!(
                "face {} has more than {MAX_POINTS} landmarks, the most a scheme may have",
                self.faces.saturating_sub(1)
            ))));
        }
    }
}

/// A request body read through a [`FrameGuard`]: the body's error, once a limit is crossed,
/// is the status tonic ends the call with.
pub struct GuardedBody {
    inner: Body,
    guard: FrameGuard,
}

impl GuardedBody {
    /// `inner` read through `guard`.
    pub fn new(inner: Body, guard: FrameGuard) -> Self {
        GuardedBody { inner, guard }
    }
}

impl http_body::Body for GuardedBody {
    type Data = Bytes;
    type Error = Box<dyn std::error::Error + Send + Sync>;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Self::Error>>> {
        let this = self.get_mut();
        match Pin::new(&mut this.inner).poll_frame(cx) {
            Poll::Ready(Some(Ok(frame))) => {
                if let Some(data) = frame.data_ref()
                    && let Err(status) = this.guard.feed(data)
                {
                    return Poll::Ready(Some(Err(Box::new(status))));
                }
                Poll::Ready(Some(Ok(frame)))
            }
            Poll::Ready(Some(Err(e))) => Poll::Ready(Some(Err(Box::new(e)))),
            other => other.map(|f| f.map(|r| r.map_err(|e| Box::new(e) as Self::Error))),
        }
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::proto;
    use proptest::prelude::*;
    use prost::Message;
    use tonic::Code;

    /// `messages` as a gRPC body (uncompressed).
    fn body(messages: &[Vec<u8>]) -> Vec<u8> {
        let mut out = Vec::new();
        for m in messages {
            out.push(0);
            out.extend_from_slice(&(m.len() as u32).to_be_bytes());
            out.extend_from_slice(m);
        }
        out
    }

    /// The guard's verdict on `bytes` fed in chunks of `chunk`.
    fn verdict(rpc: Rpc, max: usize, bytes: &[u8], chunk: usize) -> Result<(), Code> {
        let mut g = FrameGuard::new(rpc, max).scanning_from(0);
        let mut last = Ok(());
        for c in bytes.chunks(chunk.max(1)) {
            last = g.feed(c).map_err(|s| s.code());
        }
        last
    }

    fn face(points: usize, xy: usize, scheme: &str) -> proto::Face {
        proto::Face {
            landmarks: vec![
                proto::Landmark {
                    x: 1.5,
                    y: -2.0,
                    missing: false
                };
                points
            ],
            xy: vec![0.25; xy],
            scheme: scheme.into(),
            id: "f".into(),
            ..Default::default()
        }
    }

    fn batch(faces: Vec<proto::Face>, model: &str) -> Vec<u8> {
        proto::EstimateBatchRequest {
            faces,
            model: model.into(),
        }
        .encode_to_vec()
    }

    #[test]
    fn faces_points_and_names_are_counted_where_they_are() {
        let long = "m".repeat(MAX_STRING as usize + 1);
        for chunk in [1, 3, 7, 4096] {
            let v = |rpc, max, messages: &[Vec<u8>]| verdict(rpc, max, &body(messages), chunk);
            let b = Rpc::EstimateBatch;
            assert_eq!(v(b, 2, &[batch(vec![face(68, 0, ""); 2], "")]), Ok(()));
            assert_eq!(
                v(b, 2, &[batch(vec![face(0, 0, ""); 3], "")]),
                Err(Code::ResourceExhausted)
            );
            let at_limit = face(MAX_POINTS, 2 * MAX_POINTS, "five");
            assert_eq!(v(b, 2, &[batch(vec![at_limit], "")]), Ok(()));
            for over in [face(MAX_POINTS + 1, 0, ""), face(0, 2 * MAX_POINTS + 1, "")] {
                assert_eq!(
                    v(b, 2, &[batch(vec![face(1, 0, ""), over], "")]),
                    Err(Code::InvalidArgument)
                );
            }
            assert_eq!(v(b, 2, &[batch(vec![], &long)]), Err(Code::InvalidArgument));
            assert_eq!(
                v(b, 2, &[batch(vec![face(5, 0, &long)], "")]),
                Err(Code::InvalidArgument)
            );
            // One face in `Estimate`, however many faces --max-batch allows.
            let one = proto::EstimateRequest {
                face: Some(face(68, 0, "")),
                model: "default".into(),
            }
            .encode_to_vec();
            assert_eq!(v(Rpc::Estimate, 0, &[one]), Ok(()));
            // Streams: every frame is held to the limits, the second one here.
            let frame = |n| {
                proto::Frame {
                    frame_id: 7,
                    faces: vec![face(5, 0, ""); n],
                    ..Default::default()
                }
                .encode_to_vec()
            };
            let s = Rpc::EstimateStream;
            assert_eq!(v(s, 3, &[frame(3), frame(3), frame(0)]), Ok(()));
            assert_eq!(v(s, 3, &[frame(3), frame(4)]), Err(Code::ResourceExhausted));
        }
    }

    #[test]
    fn conventions_are_counted_and_their_bytes_bounded() {
        let with = |names: &[&str], name_len: usize| proto::Face {
            conventions: names
                .iter()
                .map(|n| proto::Convention {
                    name: n.repeat(name_len),
                    params: [("order".to_string(), "zyx".to_string())].into(),
                })
                .collect(),
            camera_orientation: Some(proto::CameraOrientation {
                axes: "RDF".into(),
                ..Default::default()
            }),
            ..face(68, 0, "")
        };
        let four = ["quaternion", "euler", "opencv", "mediapipe"];
        for chunk in [1, 5, 4096] {
            let v = |f: proto::Face| {
                verdict(
                    Rpc::EstimateBatch,
                    4,
                    &body(&[batch(vec![face(5, 0, ""), f], "")]),
                    chunk,
                )
            };
            assert_eq!(v(with(&four, 1)), Ok(()));
            assert_eq!(v(with(&[four[0]; 5], 1)), Err(Code::InvalidArgument));
            assert_eq!(
                v(with(&["e"], MAX_STRING as usize + 1)),
                Err(Code::InvalidArgument)
            );
            // Counted per face: two faces of four each pass.
            assert_eq!(
                verdict(
                    Rpc::EstimateBatch,
                    4,
                    &body(&[batch(vec![with(&four, 1); 2], "")]),
                    chunk
                ),
                Ok(())
            );
        }
    }

    #[test]
    fn short_messages_are_passed_over() {
        let over = body(&[batch(vec![face(0, 0, ""); 5], "")]);
        let mut g = FrameGuard::new(Rpc::EstimateBatch, 2);
        assert!(g.feed(&over).is_ok());
        let long = body(&[batch(vec![face(0, 0, ""); SCAN_FROM / 2], "")]);
        let mut g = FrameGuard::new(Rpc::EstimateBatch, 2);
        assert_eq!(g.feed(&long).unwrap_err().code(), Code::ResourceExhausted);
    }

    #[test]
    fn compressed_and_malformed_messages_are_left_to_the_codec() {
        let over = batch(vec![face(0, 0, ""); 5], "");
        let mut compressed = body(std::slice::from_ref(&over));
        compressed[0] = 1;
        assert_eq!(verdict(Rpc::EstimateBatch, 2, &compressed, 5), Ok(()));
        // A face whose length runs past the message, then a message over the limit: the
        // first is passed over, the second still counted.
        let broken = vec![0x0a, 0x7f, 0x0a, 0x00];
        let bytes = body(&[broken, over]);
        assert_eq!(
            verdict(Rpc::EstimateBatch, 2, &bytes, 3),
            Err(Code::ResourceExhausted)
        );
        let varint = vec![0x08; 1]
            .into_iter()
            .chain([0xff; 11])
            .collect::<Vec<_>>();
        assert_eq!(verdict(Rpc::EstimateBatch, 2, &body(&[varint]), 1), Ok(()));
    }

    proptest! {
        /// Any chunking gives the same verdict, and messages within the limits pass.
        #[test]
        fn chunking_does_not_matter(
            faces in prop::collection::vec((0usize..4, 0usize..5, "[a-z]{0,3}"), 0..5),
            max in 0usize..5,
            chunk in 1usize..64,
        ) {
            let faces: Vec<_> = faces.iter().map(|(p, xy, s)| face(*p, *xy, s)).collect();
            let bytes = body(&[batch(faces.clone(), "m")]);
            let whole = verdict(Rpc::EstimateBatch, max, &bytes, bytes.len());
            prop_assert_eq!(verdict(Rpc::EstimateBatch, max, &bytes, chunk), whole);
            prop_assert_eq!(whole.is_ok(), faces.len() <= max);
        }
    }
}
