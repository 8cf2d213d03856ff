//! The protobuf codec of `facepose.v1` (the generated code's `codec_path`): prost's coding, with
//! what a server that takes messages from anyone needs around it.
//!
//! - **A message is bounded before it is decoded.** A repeated message field costs far more
//!   decoded than sent: an empty `Face` is 2 bytes on the wire and about 200 in memory, so an
//!   8 MiB `EstimateBatch` of empty faces would take a gigabyte to decode before its batch limit
//!   could be checked. Messages from [`SCAN_FROM`] bytes up are first walked without
//!   allocating ([`Bounded`]): more faces than `--max-batch`, or more points in a face than a
//!   scheme may have ([`MAX_POINTS`]), and the call ends there, with the status the same limit
//!   gives after decoding; so are a face's conventions (at most [`MAX_CONVENTIONS`], each
//!   with at most [`MAX_PARAMS`] parameters, as the camera orientation's Euler angles), whose
//!   empty map entries are 2 bytes each on the wire. The walk counts in order, so a message that breaks off after a
//!   million faces is refused for its faces before prost sees it.
//! - **Big decodes leave the async workers**: from [`OFF_THE_WORKERS_FROM`] bytes up a decode
//!   runs in `block_in_place`, so a large message does not hold up `/healthz` on its worker.
//! - **A message that does not decode is INVALID_ARGUMENT** (prost's codec says INTERNAL), with
//!   prost's words for what is wrong, as the proto's comments promise.
//!
//! The limits of the serving server reach the decoder through a task-local
//! ([`DecodeLimits::scope`], set around every call by the gRPC edge in `server.rs`): the
//! generated code makes its codec with `Default`, and the decoder is made inside the call.

use std::marker::PhantomData;

use facepose_app::error::ServiceError;
use facepose_core::shape::MAX_POINTS;
use prost::Message;
use prost::bytes::Buf;
use tonic::Status;
use tonic::codec::{Codec, DecodeBuf, Decoder};
use tonic_prost::ProstEncoder;

use super::convert::{MAX_CONVENTIONS, MAX_PARAMS};
use super::error;
use crate::proto;

/// The metadata key that marks a status as the codec's: the gRPC edge counts such a call (it
/// never reached a handler) and removes the key before the client sees it.
pub const REFUSED_BEFORE_DECODING: &str = "x-facepose-refused-by-codec";

/// A status of the codec, marked as such.
pub(super) fn marked(mut status: Status) -> Status {
    status.metadata_mut().insert(
        REFUSED_BEFORE_DECODING,
        tonic::metadata::MetadataValue::from_static("1"),
    );
    status
}

/// Messages this long or longer are walked before they are decoded. Below it, the worst
/// message (8 K empty faces) decodes to under 2 MB.
pub const SCAN_FROM: usize = 16 * 1024;

/// Messages this long or longer are decoded off the async workers.
pub const OFF_THE_WORKERS_FROM: usize = 256 * 1024;

/// The limits a message is held to before it is decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecodeLimits {
    /// Faces in one `EstimateBatch` request or one stream frame (`--max-batch`).
    pub max_batch: usize,
}

impl Default for DecodeLimits {
    /// `--max-batch`'s default, for a decoder made outside any server's call.
    fn default() -> Self {
        DecodeLimits { max_batch: 1000 }
    }
}

tokio::task_local! {
    static LIMITS: DecodeLimits;
}

impl DecodeLimits {
    /// Runs `call` with these limits for every message it decodes.
    pub async fn scope<F: Future>(self, call: F) -> F::Output {
        LIMITS.scope(self, call).await
    }

    fn current() -> DecodeLimits {
        LIMITS.try_with(|l| *l).unwrap_or_default()
    }
}

/// What a message may cost, checked on its bytes before it is decoded.
pub trait Bounded {
    /// `Err` with the status to end the call with when `bytes` holds more than `limits` allow;
    /// `Ok` otherwise, and for malformed bytes, which the decoder then refuses with prost's words.
    fn check(_bytes: &[u8], _limits: &DecodeLimits) -> Result<(), Status> {
        Ok(())
    }
}

/// Messages with nothing repeated that costs more decoded than sent.
macro_rules! unbounded {
    ($($t:ty),* $(,)?) => { $(impl Bounded for $t {})* };
}

unbounded!(
    proto::EstimateResponse,
    proto::EstimateBatchResponse,
    proto::FrameResult,
    proto::ListModelsRequest,
    proto::ListModelsResponse,
    proto::GetModelRequest,
    proto::ModelInfo,
    proto::RetrainChunk,
    proto::Job,
    proto::GetJobRequest,
    proto::CancelJobRequest,
    proto::ListVersionsRequest,
    proto::ListVersionsResponse,
    proto::ActivateVersionRequest,
    proto::DeleteVersionRequest,
    proto::DeleteVersionResponse,
);

impl Bounded for proto::EstimateRequest {
    fn check(bytes: &[u8], _: &DecodeLimits) -> Result<(), Status> {
        let mut faces = 0;
        for_each_field(bytes, |field, value| {
            if let (1, Value::Bytes(face)) = (field, value) {
                check_face(faces, face)?;
                faces += 1;
            }
            Ok(())
        })
    }
}

impl Bounded for proto::EstimateBatchRequest {
    fn check(bytes: &[u8], limits: &DecodeLimits) -> Result<(), Status> {
        check_faces(bytes, 1, limits)
    }
}

impl Bounded for proto::Frame {
    fn check(bytes: &[u8], limits: &DecodeLimits) -> Result<(), Status> {
        check_faces(bytes, 3, limits)
    }
}

/// The faces of repeated field `field`: at most `max_batch` of them, each within [`check_face`].
fn check_faces(bytes: &[u8], field: u32, limits: &DecodeLimits) -> Result<(), Status> {
    let mut faces = 0;
    for_each_field(bytes, |f, value| {
        if let (true, Value::Bytes(face)) = (f == field, value) {
            if faces == limits.max_batch {
                let counted = count_fields(bytes, field);
                return Err(error::status(&ServiceError::BatchTooLarge {
                    faces: counted,
                    limit: limits.max_batch,
                }));
            }
            check_face(faces, face)?;
            faces += 1;
        }
        Ok(())
    })
}

/// One `Face`: at most [`MAX_POINTS`] landmarks (field 1), missing indices (field 8) and points
/// of `xy` (field 7, two doubles each); at most [`MAX_CONVENTIONS`] conventions (field 10),
/// each with at most [`MAX_PARAMS`] parameters (its field 2), as the Euler angles of the camera
/// orientation (field 11, its field 3, their field 1).
fn check_face(index: usize, bytes: &[u8]) -> Result<(), Status> {
    let (mut landmarks, mut missing, mut doubles) = (0usize, 0usize, 0usize);
    let mut conventions = 0usize;
    for_each_field(bytes, |field, value| {
        match (field, value) {
            (10, Value::Bytes(convention)) => {
                conventions += 1;
                if conventions > MAX_CONVENTIONS {
                    return Err(Status::invalid_argument(format!(
                        "face {index} has more than {MAX_CONVENTIONS} conventions; name each \
                         convention at most once"
                    )));
                }
                check_params(index, convention, 2)?;
            }
            (11, Value::Bytes(orientation)) => for_each_field(orientation, |f, v| match (f, v) {
                (3, Value::Bytes(euler)) => check_params(index, euler, 1),
                _ => Ok(()),
            })?,
            (1, Value::Bytes(_)) => landmarks += 1,
            (7, Value::Bytes(packed)) => doubles += packed.len() / 8,
            (7, Value::Fixed64) => doubles += 1,
            // A packed varint ends at each byte without the continuation bit.
            (8, Value::Bytes(packed)) => {
                missing += packed.iter().filter(|b| *b & 0x80 == 0).count()
            }
            (8, Value::Varint) => missing += 1,
            _ => {}
        }
        let points = landmarks.max(missing).max(doubles.div_ceil(2));
        if points > MAX_POINTS {
            return Err(Status::invalid_argument(format!(
                "face {index} has more than {MAX_POINTS} landmarks, the most a scheme may have"
            )));
        }
        Ok(())
    })
}

/// A convention (or Euler angles) of face `index` whose parameters are map field `field`: at
/// most [`MAX_PARAMS`] of them.
fn check_params(index: usize, bytes: &[u8], field: u32) -> Result<(), Status> {
    let mut params = 0usize;
    for_each_field(bytes, |f, value| {
        if f == field && matches!(value, Value::Bytes(_)) {
            params += 1;
            if params > MAX_PARAMS {
                return Err(Status::invalid_argument(format!(
                    "face {index} has a convention with more than {MAX_PARAMS} parameters"
                )));
            }
        }
        Ok(())
    })
}

/// The number of occurrences of length-delimited field `field` in `bytes` (up to where the
/// bytes stop being a message).
fn count_fields(bytes: &[u8], field: u32) -> usize {
    let mut n = 0;
    let _ = for_each_field(bytes, |f, value| {
        if f == field && matches!(value, Value::Bytes(_)) {
            n += 1;
        }
        Ok(())
    });
    n
}

/// A field's value, as much of it as the walk needs.
enum Value<'a> {
    Varint,
    Fixed64,
    Fixed32,
    Bytes(&'a [u8]),
}

/// Calls `f` with each top-level field of the message in `bytes`, in order, and stops at the
/// first error `f` returns. Malformed bytes end the walk with `Ok`: decoding refuses them.
fn for_each_field<'a>(
    mut bytes: &'a [u8],
    mut f: impl FnMut(u32, Value<'a>) -> Result<(), Status>,
) -> Result<(), Status> {
    while !bytes.is_empty() {
        let Some(key) = varint(&mut bytes) else {
            return Ok(());
        };
        let Ok(field) = u32::try_from(key >> 3) else {
            return Ok(());
        };
        let value = match key & 7 {
            0 => match varint(&mut bytes) {
                Some(_) => Value::Varint,
                None => return Ok(()),
            },
            1 => match bytes.split_at_checked(8) {
                Some((_, rest)) => {
                    bytes = rest;
                    Value::Fixed64
                }
                None => return Ok(()),
            },
            2 => {
                let Some(len) = varint(&mut bytes).and_then(|l| usize::try_from(l).ok()) else {
                    return Ok(());
                };
                match bytes.split_at_checked(len) {
                    Some((value, rest)) => {
                        bytes = rest;
                        Value::Bytes(value)
                    }
                    None => return Ok(()),
                }
            }
            5 => match bytes.split_at_checked(4) {
                Some((_, rest)) => {
                    bytes = rest;
                    Value::Fixed32
                }
                None => return Ok(()),
            },
            // Groups (3, 4) and unknown wire types: prost refuses them.
            _ => return Ok(()),
        };
        f(field, value)?;
    }
    Ok(())
}

/// A base-128 varint from the front of `bytes` (at most 10 bytes), advancing past it.
fn varint(bytes: &mut &[u8]) -> Option<u64> {
    let mut value = 0u64;
    for (i, &b) in bytes.iter().enumerate().take(10) {
        value |= u64::from(b & 0x7f) << (7 * i);
        if b & 0x80 == 0 {
            *bytes = &bytes[i + 1..];
            return Some(value);
        }
    }
    None
}

/// prost's coding with the checks of the module doc.
#[derive(Debug, Clone)]
pub struct FaceposeCodec<T, U>(PhantomData<(T, U)>);

impl<T, U> Default for FaceposeCodec<T, U> {
    fn default() -> Self {
        FaceposeCodec(PhantomData)
    }
}

impl<T, U> Codec for FaceposeCodec<T, U>
where
    T: Message + Send + 'static,
    U: Message + Default + Bounded + Send + 'static,
{
    type Encode = T;
    type Decode = U;
    type Encoder = ProstEncoder<T>;
    type Decoder = BoundedDecoder<U>;

    fn encoder(&mut self) -> Self::Encoder {
        ProstEncoder::default()
    }

    fn decoder(&mut self) -> Self::Decoder {
        BoundedDecoder {
            limits: DecodeLimits::current(),
            _message: PhantomData,
        }
    }
}

/// The decoder of [`FaceposeCodec`], with the limits of the call it was made in.
#[derive(Debug)]
pub struct BoundedDecoder<U> {
    limits: DecodeLimits,
    _message: PhantomData<U>,
}

/// Decodes the message in `buf` after the check of its type, if it is long enough for one.
fn decode_checked<U: Message + Default + Bounded>(
    mut buf: impl Buf,
    limits: &DecodeLimits,
) -> Result<U, Status> {
    let len = buf.remaining();
    if len >= SCAN_FROM {
        // tonic buffers a whole message in one contiguous buffer; `copy_to_bytes` splits it
        // off without copying.
        let bytes = buf.copy_to_bytes(len);
        U::check(&bytes, limits)?;
        return U::decode(bytes).map_err(|e| invalid(&e));
    }
    U::decode(buf).map_err(|e| invalid(&e))
}

impl<U: Message + Default + Bounded> Decoder for BoundedDecoder<U> {
    type Item = U;
    type Error = Status;

    fn decode(&mut self, buf: &mut DecodeBuf<'_>) -> Result<Option<U>, Status> {
        let multi_thread = tokio::runtime::Handle::try_current()
            .is_ok_and(|h| h.runtime_flavor() == tokio::runtime::RuntimeFlavor::MultiThread);
        if buf.remaining() >= OFF_THE_WORKERS_FROM && multi_thread {
            tokio::task::block_in_place(|| decode_checked(buf, &self.limits))
        } else {
            decode_checked(buf, &self.limits)
        }
        .map(Some)
        .map_err(marked)
    }
}

/// A message that does not decode, in prost's words.
fn invalid(e: &prost::DecodeError) -> Status {
    Status::invalid_argument(format!("the message is not valid protobuf: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn face_bytes(face: &proto::Face) -> Vec<u8> {
        face.encode_to_vec()
    }

    fn batch(faces: usize) -> Vec<u8> {
        proto::EstimateBatchRequest {
            faces: vec![proto::Face::default(); faces],
            model: String::new(),
        }
        .encode_to_vec()
    }

    #[test]
    fn a_batch_at_the_limit_passes_and_one_more_face_is_refused_with_its_count() {
        let limits = DecodeLimits { max_batch: 10_000 };
        assert!(proto::EstimateBatchRequest::check(&batch(10_000), &limits).is_ok());
        let s = proto::EstimateBatchRequest::check(&batch(10_001), &limits).unwrap_err();
        assert_eq!(s.code(), tonic::Code::ResourceExhausted, "{s:?}");
        assert!(s.message().contains("10001"), "{s:?}");
        assert!(s.message().contains("10000"), "{s:?}");
    }

    #[test]
    fn faces_before_a_break_count_against_the_limit() {
        let mut bytes = batch(2_000);
        bytes.extend_from_slice(&[0x0a, 0xff, 0xff, 0xff, 0xff, 0x0f]);
        let limits = DecodeLimits { max_batch: 1_000 };
        let s = proto::EstimateBatchRequest::check(&bytes, &limits).unwrap_err();
        assert_eq!(s.code(), tonic::Code::ResourceExhausted, "{s:?}");
        // Under the limit, the broken tail is left to prost, which refuses it.
        let limits = DecodeLimits { max_batch: 5_000 };
        assert!(proto::EstimateBatchRequest::check(&bytes, &limits).is_ok());
        assert!(proto::EstimateBatchRequest::decode(bytes.as_slice()).is_err());
    }

    #[test]
    fn frames_count_their_faces_in_field_3() {
        let frame = proto::Frame {
            faces: vec![proto::Face::default(); 3],
            ..Default::default()
        }
        .encode_to_vec();
        assert!(proto::Frame::check(&frame, &DecodeLimits { max_batch: 3 }).is_ok());
        let s = proto::Frame::check(&frame, &DecodeLimits { max_batch: 2 }).unwrap_err();
        assert_eq!(s.code(), tonic::Code::ResourceExhausted);
    }

    #[test]
    fn a_face_with_more_points_than_a_scheme_may_have_is_refused_in_every_form() {
        let limits = DecodeLimits::default();
        let landmarks = proto::Face {
            landmarks: vec![proto::Landmark::default(); MAX_POINTS + 1],
            ..Default::default()
        };
        let xy = proto::Face {
            xy: vec![0.5; 2 * MAX_POINTS + 1],
            ..Default::default()
        };
        let missing = proto::Face {
            xy: vec![0.5; 10],
            missing: (0..=MAX_POINTS as u32).collect(),
            ..Default::default()
        };
        for face in [landmarks, xy, missing] {
            let req = proto::EstimateRequest {
                face: Some(face.clone()),
                model: String::new(),
            }
            .encode_to_vec();
            let s = proto::EstimateRequest::check(&req, &limits).unwrap_err();
            assert_eq!(s.code(), tonic::Code::InvalidArgument, "{s:?}");
            assert!(s.message().contains("face 0"), "{s:?}");
            let s = check_face(7, &face_bytes(&face)).unwrap_err();
            assert!(s.message().contains("face 7"), "{s:?}");
        }
        let ok = proto::Face {
            landmarks: vec![proto::Landmark::default(); MAX_POINTS],
            ..Default::default()
        };
        assert!(check_face(0, &face_bytes(&ok)).is_ok());
    }

    fn convention(name: &str, params: usize) -> proto::Convention {
        proto::Convention {
            name: name.into(),
            params: (0..params).map(|i| (format!("p{i}"), "v".into())).collect(),
        }
    }

    #[test]
    fn conventions_and_their_parameters_are_bounded_before_decoding() {
        let face = |conventions: Vec<proto::Convention>, euler_params: usize| proto::Face {
            conventions,
            camera_orientation: Some(proto::CameraOrientation {
                rotation: Some(proto::camera_orientation::Rotation::Euler(
                    proto::EulerAngles {
                        params: convention("", euler_params).params,
                        angles: vec![0.0; 3],
                    },
                )),
                axes: String::new(),
            }),
            ..Default::default()
        };
        let most = vec![convention("euler", MAX_PARAMS); MAX_CONVENTIONS];
        assert!(check_face(0, &face_bytes(&face(most.clone(), MAX_PARAMS))).is_ok());
        let mut five = most.clone();
        five.push(convention("quaternion", 0));
        let refused = [
            face(five, 0),
            face(vec![convention("euler", MAX_PARAMS + 1)], 0),
            face(most, MAX_PARAMS + 1),
        ];
        for f in refused {
            let s = check_face(3, &face_bytes(&f)).unwrap_err();
            assert_eq!(s.code(), tonic::Code::InvalidArgument, "{s:?}");
            assert!(s.message().contains("face 3"), "{s:?}");
        }
    }

    proptest! {
        /// The walk counts what prost decodes: for any faces, the count of field 1 is the
        /// batch's length, and a limit at that count passes while one below it does not.
        #[test]
        fn the_walk_counts_the_faces_prost_decodes(
            sizes in proptest::collection::vec((0usize..20, 0usize..40, 0usize..20), 0..30),
        ) {
            let faces: Vec<proto::Face> = sizes
                .iter()
                .map(|&(l, xy, m)| proto::Face {
                    landmarks: vec![proto::Landmark { x: 1.0, y: 2.0, missing: false }; l],
                    xy: vec![3.5; xy],
                    missing: (0..m as u32).map(|i| i * 300).collect(),
                    id: "a".repeat(l),
                    ..Default::default()
                })
                .collect();
            let bytes = proto::EstimateBatchRequest { faces: faces.clone(), model: "m".into() }
                .encode_to_vec();
            prop_assert_eq!(count_fields(&bytes, 1), faces.len());
            let n = faces.len();
            let at_the_count = DecodeLimits { max_batch: n };
            prop_assert!(proto::EstimateBatchRequest::check(&bytes, &at_the_count).is_ok());
            if n > 0 {
                let limits = DecodeLimits { max_batch: n - 1 };
                prop_assert!(proto::EstimateBatchRequest::check(&bytes, &limits).is_err());
            }
        }

        /// Arbitrary bytes never panic the walk.
        #[test]
        fn the_walk_takes_any_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
            let limits = DecodeLimits { max_batch: 3 };
            let _ = proto::EstimateBatchRequest::check(&bytes, &limits);
            let _ = proto::EstimateRequest::check(&bytes, &limits);
            let _ = proto::Frame::check(&bytes, &limits);
        }
    }

    #[test]
    fn malformed_bytes_are_invalid_argument_in_prost_words() {
        let limits = DecodeLimits::default();
        let short: &[u8] = &[0x0a, 0xff, 0xff, 0xff, 0xff, 0x0f];
        let mut long = batch(20_000);
        long.extend_from_slice(short);
        for bytes in [short, long.as_slice()] {
            let s = decode_checked::<proto::EstimateRequest>(bytes, &limits).unwrap_err();
            assert_eq!(s.code(), tonic::Code::InvalidArgument, "{s:?}");
            assert!(s.message().contains("not valid protobuf"), "{s:?}");
        }
        let big = decode_checked::<proto::EstimateBatchRequest>(long.as_slice(), &limits);
        assert_eq!(big.unwrap_err().code(), tonic::Code::ResourceExhausted);
        let ok = decode_checked::<proto::EstimateBatchRequest>(batch(900).as_slice(), &limits);
        assert_eq!(ok.unwrap().faces.len(), 900);
    }
}
