//! The protobuf codec of `facepose.v1` (the generated code's `codec_path`): prost's coding, with
//! what a server that takes messages from anyone needs around it.
//!
//! - **A large pose message is read once, as it arrives.** The pose calls' guard
//!   ([`super::frame_guard`]) checks every message of [`SCAN_FROM`] bytes or more against its
//!   limits at the byte that crosses them and builds it in the same pass; the decoder takes
//!   the built message from the call's [`Prebuilt`] instead of decoding the buffer again. A
//!   message the guard did not build (anything unusual) is decoded here by prost as any other,
//!   the guard having checked its limits as far as its bytes read as a message (prost stops
//!   where they stop). Shorter messages cost little however they are made and are decoded here
//!   as they are.
//! - **Big decodes leave the async workers**: from [`OFF_THE_WORKERS_FROM`] bytes up a decode
//!   runs in `block_in_place`, so a large message does not hold up `/healthz` on its worker
//!   (a built message is taken whole, its decoding spread over the chunks it came in).
//! - **A message that does not decode is INVALID_ARGUMENT** (prost's codec says INTERNAL), with
//!   prost's words for what is wrong, as the proto's comments promise.
//!
//! The call's [`Prebuilt`] reaches the decoder through a task-local ([`Prebuilt::scope`], set
//! around every pose call by the gRPC edge, `super::edge`): the generated code makes its codec
//! with `Default`, and the decoder is made inside the call.

use std::any::Any;
use std::collections::VecDeque;
use std::marker::PhantomData;
use std::sync::{Arc, Mutex};

use prost::Message;
use prost::bytes::Buf;
use tonic::Status;
use tonic::codec::{Codec, DecodeBuf, Decoder};
use tonic_prost::ProstEncoder;

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

/// Messages this long or longer are checked and built as they arrive. Below it, the worst
/// message (8 K empty faces) decodes to under 2 MB.
pub const SCAN_FROM: usize = 16 * 1024;

/// Messages this long or longer are decoded off the async workers.
pub const OFF_THE_WORKERS_FROM: usize = 256 * 1024;

/// One walked message: its length, and the message if the guard built it.
struct Entry {
    len: usize,
    message: Option<Box<dyn Any + Send>>,
}

/// The messages of one call that the guard walked, in order, for the call's decoder: each
/// built, or marked for the decoder to decode itself. The guard is at most a chunk ahead of
/// the decoder, so the queue holds a message or two.
#[derive(Clone)]
pub struct Prebuilt {
    from: usize,
    queue: Arc<Mutex<VecDeque<Entry>>>,
}

impl std::fmt::Debug for Prebuilt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Prebuilt")
            .field("from", &self.from)
            .finish_non_exhaustive()
    }
}

impl Default for Prebuilt {
    /// For the messages of [`SCAN_FROM`] bytes and more.
    fn default() -> Self {
        Prebuilt::scanning_from(SCAN_FROM)
    }
}

tokio::task_local! {
    static PREBUILT: Prebuilt;
}

impl Prebuilt {
    /// For the messages of `bytes` and more (e.g. every message, 0, for tests).
    pub fn scanning_from(bytes: usize) -> Self {
        Prebuilt {
            from: bytes,
            queue: Arc::default(),
        }
    }

    /// The length from which messages are walked and come through here.
    pub fn from(&self) -> usize {
        self.from
    }

    /// Runs `call` with this queue for the decoders it makes.
    pub async fn scope<F: Future>(self, call: F) -> F::Output {
        PREBUILT.scope(self, call).await
    }

    fn current() -> Option<Prebuilt> {
        PREBUILT.try_with(Prebuilt::clone).ok()
    }

    /// The next walked message, `len` bytes long, built (`Some`) or not.
    pub fn push(&self, len: usize, message: Option<Box<dyn Any + Send>>) {
        self.lock().push_back(Entry { len, message });
    }

    /// The next walked message, if it is `len` bytes long and was built as a `U`. A message
    /// the guard did not build is the caller's to decode; so is every later one if the
    /// queue is not in step with the decoder (it always is: see [`super::frame_guard`]).
    pub fn take<U: 'static>(&self, len: usize) -> Option<U> {
        let mut queue = self.lock();
        match queue.pop_front() {
            Some(e) if e.len == len => e.message?.downcast::<U>().ok().map(|m| *m),
            _ => {
                queue.clear();
                None
            }
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, VecDeque<Entry>> {
        // A poisoned queue still holds whole entries: each is pushed and popped in one step.
        self.queue.lock().unwrap_or_else(|e| e.into_inner())
    }
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
    U: Message + Default + Send + 'static,
{
    type Encode = T;
    type Decode = U;
    type Encoder = ProstEncoder<T>;
    type Decoder = FaceposeDecoder<U>;

    fn encoder(&mut self) -> Self::Encoder {
        ProstEncoder::default()
    }

    fn decoder(&mut self) -> Self::Decoder {
        FaceposeDecoder::new(Prebuilt::current())
    }
}

/// The decoder of [`FaceposeCodec`], with the [`Prebuilt`] of the call it was made in.
#[derive(Debug)]
pub struct FaceposeDecoder<U> {
    prebuilt: Option<Prebuilt>,
    _message: PhantomData<U>,
}

impl<U> FaceposeDecoder<U> {
    /// A decoder that takes the messages `prebuilt` holds (as the codec's decoder does with
    /// the call's).
    pub fn new(prebuilt: Option<Prebuilt>) -> Self {
        FaceposeDecoder {
            prebuilt,
            _message: PhantomData,
        }
    }
}

/// Decodes the message in `buf`.
fn decode_message<U: Message + Default>(mut buf: impl Buf) -> Result<U, Status> {
    let len = buf.remaining();
    if len >= SCAN_FROM {
        // tonic buffers a whole message in one contiguous buffer; `copy_to_bytes` splits it
        // off without copying.
        let bytes = buf.copy_to_bytes(len);
        return U::decode(bytes).map_err(|e| invalid(&e));
    }
    U::decode(buf).map_err(|e| invalid(&e))
}

impl<U: Message + Default + 'static> FaceposeDecoder<U> {
    /// The message that is all of `buf`: the one the guard built from its bytes, or else
    /// decoded here.
    pub fn read(&self, mut buf: impl Buf) -> Result<U, Status> {
        let len = buf.remaining();
        if let Some(prebuilt) = &self.prebuilt
            && len >= prebuilt.from
            && let Some(message) = prebuilt.take::<U>(len)
        {
            buf.advance(len);
            return Ok(message);
        }
        let multi_thread = tokio::runtime::Handle::try_current()
            .is_ok_and(|h| h.runtime_flavor() == tokio::runtime::RuntimeFlavor::MultiThread);
        if len >= OFF_THE_WORKERS_FROM && multi_thread {
            tokio::task::block_in_place(|| decode_message(buf))
        } else {
            decode_message(buf)
        }
        .map_err(marked)
    }
}

impl<U: Message + Default + 'static> Decoder for FaceposeDecoder<U> {
    type Item = U;
    type Error = Status;

    fn decode(&mut self, buf: &mut DecodeBuf<'_>) -> Result<Option<U>, Status> {
        self.read(buf).map(Some)
    }
}

/// A message that does not decode, in prost's words.
fn invalid(e: &prost::DecodeError) -> Status {
    Status::invalid_argument(format!("the message is not valid protobuf: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grpc::frame_guard::{FrameGuard, Rpc};
    use crate::proto;

    fn batch(faces: usize) -> Vec<u8> {
        proto::EstimateBatchRequest {
            faces: vec![proto::Face::default(); faces],
            model: String::new(),
        }
        .encode_to_vec()
    }

    /// The message `bytes` of `rpc` as the server reads it: through the guard (building, at
    /// the server's threshold, `--max-batch` 1000) to the decoder.
    fn read<U: Message + Default + 'static>(rpc: Rpc, bytes: &[u8]) -> Result<U, Status> {
        let prebuilt = Prebuilt::default();
        let mut guard = FrameGuard::new(rpc, 1000).building_into(prebuilt.clone());
        let mut framed = vec![0];
        framed.extend_from_slice(&(bytes.len() as u32).to_be_bytes());
        framed.extend_from_slice(bytes);
        guard.feed(&framed)?;
        FaceposeDecoder::<U>::new(Some(prebuilt)).read(bytes)
    }

    #[test]
    fn malformed_bytes_are_invalid_argument_in_prost_words() {
        let short: &[u8] = &[0x0a, 0xff, 0xff, 0xff, 0xff, 0x0f];
        let mut long = batch(20_000);
        long.extend_from_slice(short);
        for bytes in [short, long.as_slice()] {
            let s = read::<proto::EstimateRequest>(Rpc::Estimate, bytes).unwrap_err();
            assert_eq!(s.code(), tonic::Code::InvalidArgument, "{s:?}");
            assert!(s.message().contains("not valid protobuf"), "{s:?}");
            let s = decode_message::<proto::EstimateRequest>(bytes).unwrap_err();
            assert_eq!(s.code(), tonic::Code::InvalidArgument, "{s:?}");
        }
        let big = read::<proto::EstimateBatchRequest>(Rpc::EstimateBatch, long.as_slice());
        assert_eq!(big.unwrap_err().code(), tonic::Code::ResourceExhausted);
        let ok = read::<proto::EstimateBatchRequest>(Rpc::EstimateBatch, &batch(900));
        assert_eq!(ok.unwrap().faces.len(), 900);
    }

    #[test]
    fn a_message_the_guard_did_not_build_is_decoded_here() {
        // Over SCAN_FROM with an unknown group (which the guard does not read): not built,
        // decoded by prost, which skips the group.
        let mut bytes = batch(9_000);
        bytes.extend_from_slice(&[0xfb, 0x01, 0xfc, 0x01]);
        let prebuilt = Prebuilt::default();
        prebuilt.push(bytes.len(), None);
        let d = FaceposeDecoder::<proto::EstimateBatchRequest>::new(Some(prebuilt.clone()));
        assert_eq!(d.read(bytes.as_slice()).unwrap().faces.len(), 9_000);
        // A queue out of step with the decoder is dropped, never used for another message.
        prebuilt.push(7, Some(Box::new(proto::EstimateBatchRequest::default())));
        prebuilt.push(
            bytes.len(),
            Some(Box::new(proto::EstimateBatchRequest::default())),
        );
        assert_eq!(d.read(bytes.as_slice()).unwrap().faces.len(), 9_000);
        assert!(
            prebuilt
                .take::<proto::EstimateBatchRequest>(bytes.len())
                .is_none()
        );
    }
}
