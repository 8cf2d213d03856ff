//! The pose calls' messages read in one pass as they arrive: their limits checked at the byte
//! that crosses them, and the message built on the way for the codec, which then has nothing
//! left to read.
//!
//! **Limits.** The faces of an `EstimateBatch` request or a stream `Frame` (`--max-batch`),
//! the landmarks of a face (a scheme's 1000 points at most), its conventions (at most
//! [`MAX_CONVENTIONS`], each with at most [`MAX_PARAMS`] parameters, as the camera
//! orientation's Euler angles) and the length of any name ([`MAX_STRING`]). tonic buffers a
//! whole message before the codec sees it, and a repeated message field costs far more decoded
//! than sent (an empty `Face` is 2 bytes on the wire and about 200 in memory): four callers
//! sending 8 MiB of empty faces held 32 MiB, and decoding one would take a gigabyte. Here the
//! call ends at the byte that crosses a limit (a convention's parameters are counted once the
//! convention, at most [`MAX_STRING`] bytes, is whole), with the status the same limit gives
//! after decoding, marked as the codec's ([`super::codec::REFUSED_BEFORE_DECODING`]). The
//! checks need no values: the guard follows the gRPC framing (a flag byte, a 4-byte length,
//! the message) and walks each message of [`SCAN_FROM`] bytes or more (a shorter one costs
//! little however it is made, and is passed over whole) through its fields and its faces'
//! fields, counting and skipping values in bulk.
//!
//! **The message.** Given a [`Prebuilt`] ([`FrameGuard::building_into`], as the gRPC edge
//! does), the guard also builds each message it walks, in the same pass: a field of a face that
//! is whole in the chunk at hand is decoded in place by the hand-coded `Face`'s own code (its
//! fast paths: packed `xy` copied in bulk, landmarks read where they are), and a field cut by a
//! chunk's end is carried over in a small buffer (`MAX_CARRY`) until it is whole. Each walked
//! message then goes to the codec's decoder in order, built or marked "not built": anything
//! unusual (a malformed or truncated field, a tag 0, a group, a field longer than the carry)
//! stops the building while the limits are still checked to the message's end, and the
//! decoder decodes that message itself with prost, which says what is wrong. What is built is
//! what prost decodes from the same bytes, however the body is cut into chunks (tested below).
//!
//! On anything malformed the walk skips to the message's end and leaves the message to prost.
//! A group (wire types 3 and 4, nested or not) is passed over uncounted, as prost passes over
//! the group of an unknown field and decodes what follows (it refuses a known field in that
//! form): the walk counts what follows too, where it used to stop at a group.
//! A compressed message is passed over whole: the server accepts no compression (tonic is
//! built without it), so tonic refuses such a message before any decoder.

use std::pin::Pin;
use std::task::{Context, Poll};

use axum::body::{Body, Bytes};
use facepose_app::error::ServiceError;
use facepose_core::shape::MAX_POINTS;
use http_body::{Frame, SizeHint};
use prost::Message;
use prost::encoding::{DecodeContext, WireType};
use tonic::Status;

use super::codec::{Prebuilt, SCAN_FROM, marked};
use super::convert::{MAX_CONVENTIONS, MAX_PARAMS};
use super::error;
use crate::proto;

/// The most bytes of a string field of a pose message: far above any name (64 characters) or
/// id a client needs.
pub const MAX_STRING: u64 = 64 * 1024;

/// The most bytes of one field kept while chunk boundaries cut it: any field within the limits
/// (a name or a convention of [`MAX_STRING`] bytes, a face's `xy` of 16 KB) fits. A longer
/// field (an unknown one, say) leaves its message unbuilt.
const MAX_CARRY: usize = MAX_STRING as usize + 16;

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

/// The message being built.
#[derive(Debug)]
enum Build {
    /// None: the message is passed over, or the guard only checks.
    Off,
    /// A walked message left to the codec's decoder.
    Failed,
    /// The message so far.
    On(Box<Building>),
}

/// A request being built, and whether a face is being read (the last of its faces).
#[derive(Debug)]
struct Building {
    request: Request,
    in_face: bool,
}

/// The request of each pose call (in a `Box` with its [`Building`]: the sizes do not matter).
#[derive(Debug)]
#[allow(clippy::large_enum_variant)]
enum Request {
    Estimate(proto::EstimateRequest),
    Batch(proto::EstimateBatchRequest),
    Frame(proto::Frame),
}

impl Building {
    fn new(rpc: Rpc) -> Self {
        let request = match rpc {
            Rpc::Estimate => Request::Estimate(Default::default()),
            Rpc::EstimateBatch => Request::Batch(Default::default()),
            Rpc::EstimateStream => Request::Frame(Default::default()),
        };
        Building {
            request,
            in_face: false,
        }
    }

    /// A face starts: a new element of the faces, or more of `EstimateRequest.face` (prost
    /// merges a repeated singular message). It is built where it stays.
    fn open_face(&mut self) {
        match &mut self.request {
            Request::Estimate(r) => {
                r.face.get_or_insert_with(Default::default);
            }
            Request::Batch(r) => r.faces.push(Default::default()),
            Request::Frame(r) => r.faces.push(Default::default()),
        }
        self.in_face = true;
    }

    fn close_face(&mut self) {
        self.in_face = false;
    }

    /// The face being read.
    fn face(&mut self) -> Option<&mut proto::Face> {
        if !self.in_face {
            return None;
        }
        match &mut self.request {
            Request::Estimate(r) => r.face.as_mut(),
            Request::Batch(r) => r.faces.last_mut(),
            Request::Frame(r) => r.faces.last_mut(),
        }
    }

    /// Field `tag` of the face (or of the request), from `raw`: the field's bytes after its
    /// key. `false` unless prost's code for it takes exactly those bytes.
    fn merge(&mut self, in_face: bool, tag: u32, wire: WireType, raw: &[u8]) -> bool {
        let ctx = DecodeContext::default();
        let mut raw = Raw(raw);
        let merged = if in_face {
            match self.face() {
                Some(face) => face.merge_field(tag, wire, &mut raw, ctx),
                None => return false,
            }
        } else {
            match &mut self.request {
                Request::Estimate(r) => r.merge_field(tag, wire, &mut raw, ctx),
                Request::Batch(r) => r.merge_field(tag, wire, &mut raw, ctx),
                Request::Frame(r) => r.merge_field(tag, wire, &mut raw, ctx),
            }
        };
        merged.is_ok() && raw.0.is_empty()
    }

    fn finish(self) -> Box<dyn std::any::Any + Send> {
        match self.request {
            Request::Estimate(r) => Box::new(r),
            Request::Batch(r) => Box::new(r),
            Request::Frame(r) => Box::new(r),
        }
    }
}

/// A field's bytes, as prost reads them: a type of its own, so that prost's code is compiled
/// for the guard apart from the decoder's (`&[u8]`), whose inlining stays as it was.
struct Raw<'a>(&'a [u8]);

impl prost::bytes::Buf for Raw<'_> {
    #[inline]
    fn remaining(&self) -> usize {
        self.0.len()
    }

    #[inline]
    fn chunk(&self) -> &[u8] {
        self.0
    }

    #[inline]
    fn advance(&mut self, n: usize) {
        self.0 = &self.0[n..];
    }
}

/// A field whose bytes are kept until it is whole: to build it, or to count a convention's
/// parameters.
#[derive(Debug, Clone, Copy)]
struct Capture {
    tag: u32,
    wire: WireType,
    in_face: bool,
    /// Where its bytes (after the key) start in the current chunk; `None`: in the carry.
    from: Option<usize>,
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
    t: Tally,
    /// Messages shorter than this are passed over.
    scan_from: u64,
    /// Groups being passed over (nested): their fields are not counted.
    group: u32,
    /// Where built messages go; `None`: the guard only checks.
    sink: Option<Prebuilt>,
    build: Build,
    capture: Option<Capture>,
    /// The bytes of the captured field from earlier chunks.
    carry: Vec<u8>,
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
            t: Tally::default(),
            scan_from: SCAN_FROM as u64,
            group: 0,
            sink: None,
            build: Build::Off,
            capture: None,
            carry: Vec::new(),
        }
    }

    /// The guard walking messages from `bytes` long up ([`SCAN_FROM`] by default), e.g. every
    /// message (0) for tests.
    pub fn scanning_from(mut self, bytes: u64) -> Self {
        self.scan_from = bytes;
        self
    }

    /// The guard building each message it walks into `sink`, for the codec's decoder of the
    /// same call; it walks the messages `sink` expects ([`Prebuilt::from`] bytes and longer).
    pub fn building_into(mut self, sink: Prebuilt) -> Self {
        self.scan_from = sink.from() as u64;
        self.sink = Some(sink);
        self
    }

    /// Reads the next bytes of the body; the status to end the call with once a limit is
    /// crossed (and for every later chunk, which it no longer reads).
    pub fn feed(&mut self, chunk: &[u8]) -> Result<(), Status> {
        let mut at = 0;
        while at < chunk.len() && self.t.breach.is_none() {
            at += self.step(chunk, at);
        }
        if self.t.breach.is_none()
            && let Some(c) = &mut self.capture
        {
            // The captured field goes on in the next chunk.
            let from = c.from.take().unwrap_or(0);
            self.carry.extend_from_slice(&chunk[from..]);
            if self.carry.len() > MAX_CARRY {
                self.capture = None;
                self.carry.clear();
                self.unbuilt();
            }
        }
        match &self.t.breach {
            Some(s) => Err(s.clone()),
            None => Ok(()),
        }
    }

    /// Reads from `chunk` at `at` (before its end); the bytes used.
    fn step(&mut self, chunk: &[u8], at: usize) -> usize {
        let bytes = &chunk[at..];
        match self.step {
            Step::Prefix { got } => {
                self.prefix[usize::from(got)] = bytes[0];
                self.step = if got == 4 {
                    self.start_message()
                } else {
                    Step::Prefix { got: got + 1 }
                };
                return 1;
            }
            Step::Key if self.shift == 0 && self.group == 0 && self.in_face() => {
                let used = self.face_fields(chunk, at);
                if used > 0 {
                    self.settle();
                    return used;
                }
            }
            _ => {}
        }
        let used = match self.step {
            Step::Skip { left, varints } => {
                // Never past the message's end: a value it cuts off is prost's to refuse.
                let n = left.min(bytes.len() as u64).min(self.len - self.pos) as usize;
                if varints {
                    self.t.missing += bytes[..n].iter().filter(|b| *b & 0x80 == 0).count() as u64;
                    self.t.check_points();
                }
                self.pos += n as u64;
                if left == n as u64 {
                    self.step = Step::Key;
                    self.value_done(chunk, at + n);
                } else {
                    self.step = Step::Skip {
                        left: left - n as u64,
                        varints,
                    };
                }
                n
            }
            Step::Key | Step::Varint { .. } | Step::Length { .. } => {
                let b = bytes[0];
                self.pos += 1;
                if self.shift >= 63 && (self.shift >= 64 || b > 1) {
                    // An 11th byte is not a varint; a 10th above 1 overflows, which prost
                    // refuses (the guard reads on, with the bits that fit).
                    self.unbuilt();
                    if self.shift >= 64 {
                        self.give_up();
                        self.settle();
                        return 1;
                    }
                }
                self.acc |= u64::from(b & 0x7f) << self.shift;
                self.shift += 7;
                if b & 0x80 == 0 {
                    let value = std::mem::take(&mut self.acc);
                    self.shift = 0;
                    self.varint_done(value, chunk, at + 1);
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
            let whole = self.step == Step::Key && self.shift == 0 && self.group == 0;
            self.message_done(whole);
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
                if end < self.pos || self.group > 0 || self.shift > 0 {
                    // A value, a group or a key's varint ran past its face's end: not a
                    // message (prost refuses a key cut by its face's end; read on, its bytes
                    // would join the next ones into another key).
                    return self.give_up();
                }
                self.open.pop();
                if let Build::On(b) = &mut self.build {
                    b.close_face();
                }
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
        (
            self.t.faces,
            self.t.landmarks,
            self.t.doubles,
            self.t.missing,
        ) = (0, 0, 0, 0);
        self.open.clear();
        self.open.push(Open {
            end: len,
            face: false,
        });
        (self.capture, self.build, self.group) = (None, Build::Off, 0);
        self.carry.clear();
        match (self.prefix[0], len) {
            // A short message costs little however it is made (the codec's rule too).
            (0, len) if len >= self.scan_from => {
                if self.sink.is_some() {
                    self.build = Build::On(Box::new(Building::new(self.rpc)));
                }
                if len == 0 {
                    self.message_done(true);
                    Step::Prefix { got: 0 }
                } else {
                    Step::Key
                }
            }
            (_, 0) => Step::Prefix { got: 0 },
            // Compressed: never decoded (see the module doc), so never counted either.
            _ => Step::Skip {
                left: len,
                varints: false,
            },
        }
    }

    /// The current message is whole (`whole`: its last field too): built, or not, it goes to
    /// the decoder, if the guard builds.
    fn message_done(&mut self, whole: bool) {
        let built = match std::mem::replace(&mut self.build, Build::Off) {
            Build::Off => return,
            Build::Failed => None,
            Build::On(mut b) => {
                // A face that ends with the message is closed with it.
                if whole && self.open[1..].iter().all(|o| o.end == self.len) {
                    b.close_face();
                    Some(b.finish())
                } else {
                    None
                }
            }
        };
        self.capture = None;
        self.carry.clear();
        if let Some(sink) = &self.sink {
            sink.push(self.len as usize, built);
        }
    }

    /// The current message will not be built: the decoder decodes it.
    fn unbuilt(&mut self) {
        if let Build::On(_) = self.build {
            self.build = Build::Failed;
        }
    }

    /// Passes over the rest of the current message, whose bytes do not read as one.
    fn give_up(&mut self) {
        self.unbuilt();
        (self.capture, self.group) = (None, 0);
        self.open.truncate(1);
        (self.acc, self.shift) = (0, 0);
        if self.pos >= self.len {
            self.message_done(false);
            self.step = Step::Prefix { got: 0 };
        } else {
            self.step = Step::Skip {
                left: self.len - self.pos,
                varints: false,
            };
        }
    }

    fn in_face(&self) -> bool {
        self.open.last().is_some_and(|o| o.face)
    }

    /// A varint is read; the value, if any, ends at `end` in `chunk`.
    fn varint_done(&mut self, value: u64, chunk: &[u8], end: usize) {
        match self.step {
            Step::Key => {
                let Ok(field) = u32::try_from(value >> 3) else {
                    return self.give_up();
                };
                let wire = match value & 7 {
                    0 => WireType::Varint,
                    1 => WireType::SixtyFourBit,
                    2 => WireType::LengthDelimited,
                    5 => WireType::ThirtyTwoBit,
                    // A group: prost passes over one of an unknown field and reads on (and
                    // refuses a known field in that form), so its fields are passed over
                    // uncounted, and what follows it counted. The message is prost's to build.
                    3 => {
                        self.unbuilt();
                        self.group += 1;
                        return;
                    }
                    4 if self.group > 0 => {
                        self.group -= 1;
                        return;
                    }
                    _ => return self.give_up(),
                };
                if value > u64::from(u32::MAX) || field == 0 {
                    // prost refuses such a key.
                    self.unbuilt();
                }
                let in_face = self.in_face() && self.group == 0;
                if self.group > 0 {
                    // Passed over: a value the next steps skip, uncounted.
                } else if matches!(self.build, Build::On(_))
                    || (in_face && matches!(field, 10 | 11))
                {
                    self.carry.clear();
                    self.capture = Some(Capture {
                        tag: field,
                        wire,
                        in_face,
                        from: Some(end),
                    });
                }
                self.step = match wire {
                    WireType::Varint => Step::Varint { field },
                    WireType::SixtyFourBit => {
                        if in_face && field == 7 {
                            self.t.doubles += 1;
                            self.t.check_points();
                        }
                        Step::Skip {
                            left: 8,
                            varints: false,
                        }
                    }
                    WireType::LengthDelimited => Step::Length { field },
                    _ => Step::Skip {
                        left: 4,
                        varints: false,
                    },
                };
            }
            Step::Varint { field } => {
                if self.in_face() && self.group == 0 && field == 8 {
                    self.t.missing += 1;
                    self.t.check_points();
                }
                self.step = Step::Key;
                self.value_done(chunk, end);
            }
            Step::Length { field } => {
                self.length_done(field, value);
                if matches!(self.step, Step::Skip { left: 0, .. }) {
                    self.step = Step::Key;
                    self.value_done(chunk, end);
                }
            }
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
        self.step = if self.group > 0 {
            skip(len)
        } else if self.in_face() {
            self.t.face_field(field, len)
        } else if field == faces_field {
            self.t.faces += 1;
            if self.rpc != Rpc::Estimate && self.t.faces > self.max_batch {
                self.t.breach = Some(marked(error::status(&ServiceError::BatchOverLimit {
                    at_least: self.t.faces,
                    limit: self.max_batch,
                })));
            }
            (self.t.landmarks, self.t.doubles, self.t.missing) = (0, 0, 0);
            self.t.conventions = 0;
            self.open.push(Open { end, face: true });
            // A face is not kept whole: its fields are.
            self.capture = None;
            self.carry.clear();
            if let Build::On(b) = &mut self.build {
                b.open_face();
            }
            Step::Key
        } else if field == model_field {
            self.t.string(len)
        } else {
            skip(len)
        };
    }

    /// The fields of the current face that are whole in `chunk` from `at`, read at once:
    /// counted as [`Tally::face_field`] counts them, and built. Stops before the
    /// first field that is not whole there or not of the plain kind (a key of more than a
    /// byte, a tag 0, a group), which the byte-by-byte steps read. The bytes used.
    fn face_fields(&mut self, chunk: &[u8], at: usize) -> usize {
        let face_end = self.open.last().map_or(0, |o| o.end);
        let avail = (chunk.len() - at).min(face_end.saturating_sub(self.pos) as usize);
        let rest = &chunk[at..at + avail];
        let FrameGuard { t, build, .. } = self;
        // The face being built (a face is open: it is there).
        let mut face = match build {
            Build::On(b) => b.face(),
            _ => None,
        };
        let mut failed = false;
        let mut i = 0;
        while i < rest.len() && t.breach.is_none() {
            let key = rest[i];
            let start = i + 1;
            let (field, wire, end) = match (key, rest.get(start)) {
                // A landmark under 128 bytes, as every writer sends one: counted (a landmark
                // more cannot cross the limit unless the landmarks do).
                (0x0a, Some(&len)) if len < 0x80 && start + 1 + usize::from(len) <= rest.len() => {
                    t.landmarks += 1;
                    if t.landmarks > MAX_POINTS {
                        t.check_points();
                    }
                    (1, WireType::LengthDelimited, start + 1 + usize::from(len))
                }
                (0x08..0x80, _) => {
                    let Some((wire, end)) = t.plain_field(key, &rest[start..]) else {
                        break;
                    };
                    (u32::from(key >> 3), wire, start + end)
                }
                _ => break,
            };
            if let Some(f) = face.as_deref_mut() {
                let mut raw = Raw(&rest[start..end]);
                if f.merge_field(field, wire, &mut raw, DecodeContext::default())
                    .is_err()
                    || !raw.0.is_empty()
                {
                    (face, failed) = (None, true);
                }
            }
            i = end;
        }
        if failed {
            *build = Build::Failed;
        }
        self.pos += i as u64;
        i
    }

    /// The captured field, if any, is whole at `end` in `chunk`: its parameters counted, and
    /// built.
    fn value_done(&mut self, chunk: &[u8], end: usize) {
        let Some(c) = self.capture.take() else {
            return;
        };
        let mut carry = std::mem::take(&mut self.carry);
        let raw = match c.from {
            Some(from) => &chunk[from..end],
            None => {
                carry.extend_from_slice(&chunk[..end]);
                &carry[..]
            }
        };
        if c.in_face && matches!(c.tag, 10 | 11) && c.wire == WireType::LengthDelimited {
            let mut value = raw;
            if prost::encoding::decode_varint(&mut value).is_ok() {
                self.t.check_params(c.tag, value);
            }
        }
        if let Build::On(b) = &mut self.build
            && !b.merge(c.in_face, c.tag, c.wire, raw)
        {
            self.build = Build::Failed;
        }
        carry.clear();
        self.carry = carry;
    }
}

/// The counts of the current message and face, and the first limit they crossed.
#[derive(Debug, Default)]
struct Tally {
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
}

impl Tally {
    /// A length-delimited field of a face, `len` bytes: counted, and refused past a limit.
    /// The step that passes over it (a packed `missing` is counted as it passes).
    fn face_field(&mut self, field: u32, len: u64) -> Step {
        match field {
            1 => {
                self.landmarks += 1;
                self.check_points();
            }
            7 => {
                self.doubles += len / 8;
                self.check_points();
            }
            8 => {
                return Step::Skip {
                    left: len,
                    varints: true,
                };
            }
            2 | 3 | 5 | 6 | 11 => {
                self.string(len);
            }
            // A convention: a few names and numbers.
            10 => {
                self.conventions += 1;
                if self.conventions > MAX_CONVENTIONS && self.breach.is_none() {
                    self.breach = Some(marked(Status::invalid_argument(format!(
                        "face {} has more than {MAX_CONVENTIONS} conventions; name each \
                         convention at most once",
                        self.faces.saturating_sub(1)
                    ))));
                }
                self.string(len);
            }
            _ => {}
        }
        skip(len)
    }

    /// The field of one-byte `key` whose value starts `value` (the rest of the face in the
    /// chunk): counted as [`face_field`](Self::face_field) counts it, and its wire type and
    /// the end of its value; `None` if the value is not whole there.
    #[inline]
    fn plain_field(&mut self, key: u8, value: &[u8]) -> Option<(WireType, usize)> {
        let field = u32::from(key >> 3);
        Some(match key & 7 {
            0 => {
                let n = varint_len(value)?;
                if field == 8 {
                    self.missing += 1;
                    self.check_points();
                }
                (WireType::Varint, n)
            }
            1 => {
                if value.len() < 8 {
                    return None;
                }
                if field == 7 {
                    self.doubles += 1;
                    self.check_points();
                }
                (WireType::SixtyFourBit, 8)
            }
            2 => {
                let n = varint_len(value)?;
                let len = varint_value(&value[..n]);
                let end = usize::try_from(len)
                    .ok()
                    .and_then(|l| n.checked_add(l))
                    .filter(|&e| e <= value.len())?;
                self.face_field(field, len);
                let bytes = &value[n..end];
                if field == 8 {
                    let ends = bytes.iter().filter(|b| *b & 0x80 == 0).count();
                    self.missing += ends as u64;
                    self.check_points();
                }
                if matches!(field, 10 | 11) && self.breach.is_none() {
                    self.check_params(field, bytes);
                }
                (WireType::LengthDelimited, end)
            }
            5 => {
                if value.len() < 4 {
                    return None;
                }
                (WireType::ThirtyTwoBit, 4)
            }
            _ => return None,
        })
    }

    /// A convention (`field` 10) or the camera orientation (11) of the current face: at most
    /// [`MAX_PARAMS`] parameters each (a convention's field 2, the orientation's Euler angles'
    /// field 1, in its field 3).
    fn check_params(&mut self, field: u32, value: &[u8]) {
        let face = self.faces.saturating_sub(1);
        let checked = match field {
            10 => check_params(face, value, 2),
            _ => for_each_field(value, |f, v| match (f, v) {
                (3, Value::Bytes(euler)) => check_params(face, euler, 1),
                _ => Ok(()),
            }),
        };
        if let Err(s) = checked
            && self.breach.is_none()
        {
            self.breach = Some(marked(s));
        }
    }

    /// A name of `len` bytes: refused past [`MAX_STRING`], passed over otherwise.
    fn string(&mut self, len: u64) -> Step {
        if len > MAX_STRING {
            self.breach = Some(marked(Status::invalid_argument(format!(
                "a string of {len} bytes; names have at most 64 characters"
            ))));
        }
        skip(len)
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

/// Passes over `len` bytes of a value.
fn skip(len: u64) -> Step {
    Step::Skip {
        left: len,
        varints: false,
    }
}

/// The bytes of the varint at the start of `b`, if it ends within `b` and 10 bytes.
#[inline]
fn varint_len(b: &[u8]) -> Option<usize> {
    b.iter().take(10).position(|b| b & 0x80 == 0).map(|i| i + 1)
}

/// The value of the whole varint `b` (the bits that fit, as the byte-by-byte steps read it).
#[inline]
fn varint_value(b: &[u8]) -> u64 {
    b.iter()
        .enumerate()
        .fold(0, |v, (i, b)| v | u64::from(b & 0x7f) << (7 * i))
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

/// A field's value, as much of it as the walk needs.
enum Value<'a> {
    Scalar,
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
                Some(_) => Value::Scalar,
                None => return Ok(()),
            },
            1 | 5 => {
                let n = if key & 7 == 1 { 8 } else { 4 };
                match bytes.split_at_checked(n) {
                    Some((_, rest)) => {
                        bytes = rest;
                        Value::Scalar
                    }
                    None => return Ok(()),
                }
            }
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
            // A group: passed over, as prost passes over an unknown one.
            3 => match skip_group(&mut bytes) {
                Some(()) => continue,
                None => return Ok(()),
            },
            // An end of group with none open, unknown wire types: prost refuses them here.
            _ => return Ok(()),
        };
        f(field, value)?;
    }
    Ok(())
}

/// Passes over the fields of a group whose start was just read, up to its end (a group's
/// nested groups with it); `None` if `bytes` ends first or does not read as fields.
fn skip_group(bytes: &mut &[u8]) -> Option<()> {
    let mut depth = 0u32;
    loop {
        let key = varint(bytes)?;
        let n = match key & 7 {
            0 => varint(bytes).map(|_| 0)?,
            1 => 8,
            2 => usize::try_from(varint(bytes)?).ok()?,
            3 => {
                depth += 1;
                0
            }
            4 if depth == 0 => return Some(()),
            4 => {
                depth -= 1;
                0
            }
            5 => 4,
            _ => return None,
        };
        *bytes = bytes.get(n..)?;
    }
}

/// A base-128 varint from the front of `bytes` (at most 10 bytes), advancing past it.
fn varint(bytes: &mut &[u8]) -> Option<u64> {
    let n = varint_len(bytes)?;
    let value = varint_value(&bytes[..n]);
    *bytes = &bytes[n..];
    Some(value)
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
    use crate::grpc::codec::FaceposeDecoder;
    use crate::proto;
    use proptest::prelude::*;
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

    // The codec's walk before decoding, which the guard replaced: its assertions, on the guard.

    /// `n` empty faces, an `EstimateBatch` request.
    fn empty_faces(n: usize) -> Vec<u8> {
        batch(vec![proto::Face::default(); n], "")
    }

    /// The guard's verdict on the one message `bytes` of `rpc`, walked whole.
    fn walked(rpc: Rpc, max: usize, bytes: &[u8]) -> Result<(), Status> {
        FrameGuard::new(rpc, max)
            .scanning_from(0)
            .feed(&body(&[bytes.to_vec()]))
    }

    #[test]
    fn a_batch_at_the_limit_passes_and_one_more_face_is_refused_with_its_count() {
        let b = Rpc::EstimateBatch;
        assert!(walked(b, 10_000, &empty_faces(10_000)).is_ok());
        let s = walked(b, 10_000, &empty_faces(10_001)).unwrap_err();
        assert_eq!(s.code(), Code::ResourceExhausted, "{s:?}");
        assert!(s.message().contains("10001"), "{s:?}");
        assert!(s.message().contains("10000"), "{s:?}");
    }

    #[test]
    fn faces_before_a_break_count_against_the_limit() {
        let mut bytes = empty_faces(2_000);
        bytes.extend_from_slice(&[0x0a, 0xff, 0xff, 0xff, 0xff, 0x0f]);
        let s = walked(Rpc::EstimateBatch, 1_000, &bytes).unwrap_err();
        assert_eq!(s.code(), Code::ResourceExhausted, "{s:?}");
        // Under the limit, the broken tail is left to prost, which refuses it.
        assert!(walked(Rpc::EstimateBatch, 5_000, &bytes).is_ok());
        assert!(proto::EstimateBatchRequest::decode(bytes.as_slice()).is_err());
    }

    #[test]
    fn frames_count_their_faces_in_field_3() {
        let frame = proto::Frame {
            faces: vec![proto::Face::default(); 3],
            ..Default::default()
        }
        .encode_to_vec();
        assert!(walked(Rpc::EstimateStream, 3, &frame).is_ok());
        let s = walked(Rpc::EstimateStream, 2, &frame).unwrap_err();
        assert_eq!(s.code(), Code::ResourceExhausted);
    }

    /// `face` after `index` empty faces in a batch: the guard's verdict.
    fn as_face(index: usize, face: &proto::Face) -> Result<(), Status> {
        let mut faces = vec![proto::Face::default(); index];
        faces.push(face.clone());
        walked(Rpc::EstimateBatch, 1000, &batch(faces, ""))
    }

    #[test]
    fn a_face_with_more_points_than_a_scheme_may_have_is_refused_in_every_form() {
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
            let s = walked(Rpc::Estimate, 1000, &req).unwrap_err();
            assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
            assert!(s.message().contains("face 0"), "{s:?}");
            let s = as_face(7, &face).unwrap_err();
            assert!(s.message().contains("face 7"), "{s:?}");
        }
        let ok = proto::Face {
            landmarks: vec![proto::Landmark::default(); MAX_POINTS],
            ..Default::default()
        };
        assert!(as_face(0, &ok).is_ok());
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
        assert!(as_face(0, &face(most.clone(), MAX_PARAMS)).is_ok());
        let mut five = most.clone();
        five.push(convention("quaternion", 0));
        let refused = [
            face(five, 0),
            face(vec![convention("euler", MAX_PARAMS + 1)], 0),
            face(most, MAX_PARAMS + 1),
        ];
        for f in refused {
            let s = as_face(3, &f).unwrap_err();
            assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
            assert!(s.message().contains("face 3"), "{s:?}");
            // However the chunks cut the conventions.
            let bytes = body(&[batch(vec![proto::Face::default(), f], "")]);
            for chunk in [1, 7] {
                assert_eq!(
                    verdict(Rpc::EstimateBatch, 4, &bytes, chunk),
                    Err(Code::InvalidArgument)
                );
            }
        }
    }

    // The message built on the way.

    /// Polls `f` once: every body here is whole in memory, so it is ready.
    fn ready<F: Future>(f: F) -> F::Output {
        let mut f = std::pin::pin!(f);
        let mut cx = Context::from_waker(std::task::Waker::noop());
        match f.as_mut().poll(&mut cx) {
            Poll::Ready(v) => v,
            Poll::Pending => panic!("an in-memory body is always ready"),
        }
    }

    /// A body already received, in these chunks.
    struct Chunks(std::collections::VecDeque<Bytes>);

    impl http_body::Body for Chunks {
        type Data = Bytes;
        type Error = std::convert::Infallible;

        fn poll_frame(
            mut self: Pin<&mut Self>,
            _: &mut Context<'_>,
        ) -> Poll<Option<Result<Frame<Bytes>, Self::Error>>> {
            Poll::Ready(self.0.pop_front().map(|b| Ok(Frame::data(b))))
        }
    }

    /// `bytes` cut at `cuts` (offsets in any order; out of range ones wrap).
    fn cut(bytes: &[u8], cuts: &[usize]) -> Vec<Bytes> {
        let mut at: Vec<usize> = cuts.iter().map(|c| c % (bytes.len() + 1)).collect();
        at.extend([0, bytes.len()]);
        at.sort_unstable();
        at.dedup();
        let whole = Bytes::copy_from_slice(bytes);
        at.windows(2).map(|w| whole.slice(w[0]..w[1])).collect()
    }

    /// The messages of `chunks` as the server reads them: through the guard of `rpc` (building
    /// them, or only checking), tonic's framing and the codec's decoder; every message decoded
    /// up to the first error, and that error.
    fn served<U: Message + Default + 'static>(
        rpc: Rpc,
        max: usize,
        chunks: Vec<Bytes>,
        build: bool,
    ) -> (Vec<U>, Option<Status>) {
        let prebuilt = Prebuilt::scanning_from(0);
        let mut guard = FrameGuard::new(rpc, max).scanning_from(0);
        if build {
            guard = guard.building_into(prebuilt.clone());
        }
        let body = GuardedBody::new(Body::new(Chunks(chunks.into())), guard);
        let decoder = FaceposeDecoder::<U>::new(build.then_some(prebuilt));
        let mut stream = tonic::codec::Streaming::new_request(decoder, body, None, None);
        let mut out = Vec::new();
        loop {
            match ready(stream.message()) {
                Ok(Some(m)) => out.push(m),
                Ok(None) => return (out, None),
                Err(s) => return (out, Some(s)),
            }
        }
    }

    /// What the guard building into a queue made of the one message `bytes`, cut at `cuts`:
    /// `Some(built)`, `None` if it left the message to the decoder; `Err` if it refused it.
    fn built<U: Message + Default + 'static>(
        rpc: Rpc,
        max: usize,
        bytes: &[u8],
        cuts: &[usize],
    ) -> Result<Option<U>, Code> {
        let prebuilt = Prebuilt::scanning_from(0);
        let mut g = FrameGuard::new(rpc, max).building_into(prebuilt.clone());
        for c in cut(&body(&[bytes.to_vec()]), cuts) {
            g.feed(&c).map_err(|s| s.code())?;
        }
        Ok(prebuilt.take::<U>(bytes.len()))
    }

    /// The reference of what the server answers for the one message `bytes`: the guard's
    /// verdict (only checking, in one chunk), else prost's derived decoding (`R`), as the
    /// encoding of the message or the status.
    fn expected<R: Message + Default>(
        rpc: Rpc,
        max: usize,
        bytes: &[u8],
    ) -> Result<Vec<u8>, (Code, String)> {
        if let Err(s) = walked(rpc, max, bytes) {
            return Err((s.code(), s.message().to_string()));
        }
        match R::decode(bytes) {
            Ok(m) => Ok(m.encode_to_vec()),
            Err(e) => Err((
                Code::InvalidArgument,
                format!("the message is not valid protobuf: {e}"),
            )),
        }
    }

    /// The server's answer for the one message `bytes` cut at `cuts`, as [`expected`] gives it.
    fn answered<U: Message + Default + 'static>(
        rpc: Rpc,
        max: usize,
        bytes: &[u8],
        cuts: &[usize],
    ) -> Result<Vec<u8>, (Code, String)> {
        match served::<U>(rpc, max, cut(&body(&[bytes.to_vec()]), cuts), true) {
            (m, None) if m.len() == 1 => Ok(m[0].encode_to_vec()),
            (m, Some(s)) if m.is_empty() => Err((s.code(), s.message().to_string())),
            (m, s) => panic!("{} messages and {s:?}", m.len()),
        }
    }

    /// Both ways of reading `bytes` as a `U` (ours) and an `R` (prost's derived code) agree,
    /// cut at `cuts` and at every byte; and what the guard builds is prost's message.
    fn reads_as_prost<U: Message + Default + 'static, R: Message + Default>(
        rpc: Rpc,
        max: usize,
        bytes: &[u8],
        cuts: &[usize],
    ) -> Result<(), TestCaseError> {
        let want = expected::<R>(rpc, max, bytes);
        let every_byte: Vec<usize> = (0..bytes.len() + 5).collect();
        for cuts in [cuts, &every_byte[..]] {
            prop_assert_eq!(&answered::<U>(rpc, max, bytes, cuts), &want);
            match built::<U>(rpc, max, bytes, cuts) {
                Ok(Some(m)) => prop_assert_eq!(Ok(m.encode_to_vec()), want.clone()),
                Ok(None) => prop_assert!(want.is_err(), "a valid message left unbuilt"),
                Err(code) => prop_assert_eq!(Some(code), want.clone().err().map(|e| e.0)),
            }
        }
        Ok(())
    }

    use crate::proto::hand_coded::tests::{corrupted, faces, reference};

    prop_compose! {
        fn batches()(
            faces in prop::collection::vec(faces(), 0..4),
            model in "[a-z]{0,3}",
        ) -> reference::EstimateBatchRequest {
            reference::EstimateBatchRequest {
                faces: faces.into_iter().map(|(_, f)| f).collect(),
                model,
            }
        }
    }

    prop_compose! {
        fn frames()(
            faces in prop::collection::vec(faces(), 0..4),
            frame_id in any::<u64>(),
            timestamp_us in any::<i64>(),
            model in "[a-z]{0,3}",
            smoothing in prop::option::of(any::<bool>()),
        ) -> reference::Frame {
            reference::Frame {
                frame_id,
                timestamp_us,
                faces: faces.into_iter().map(|(_, f)| f).collect(),
                model,
                smoothing: smoothing.map(|enabled| reference::Smoothing {
                    enabled,
                    ..Default::default()
                }),
            }
        }
    }

    prop_compose! {
        fn requests()(
            face in prop::option::of(faces()),
            model in "[a-z]{0,3}",
        ) -> reference::EstimateRequest {
            reference::EstimateRequest { face: face.map(|(_, f)| f), model }
        }
    }

    fn cuts() -> impl Strategy<Value = Vec<usize>> {
        prop::collection::vec(any::<usize>(), 0..12)
    }

    fn edits() -> impl Strategy<Value = Vec<(usize, u8)>> {
        prop::collection::vec((any::<usize>(), any::<u8>()), 0..4)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        /// A batch built as it arrives is prost's, however it is cut; over the limits, the
        /// same status as the guard alone.
        #[test]
        fn batches_are_built_as_prost_decodes_them(
            b in batches(), max in 0usize..5, cuts in cuts(),
        ) {
            let bytes = b.encode_to_vec();
            reads_as_prost::<proto::EstimateBatchRequest, reference::EstimateBatchRequest>(
                Rpc::EstimateBatch, max, &bytes, &cuts,
            )?;
        }

        #[test]
        fn frames_and_requests_are_built_as_prost_decodes_them(
            f in frames(), r in requests(), cuts in cuts(),
        ) {
            reads_as_prost::<proto::Frame, reference::Frame>(
                Rpc::EstimateStream, 4, &f.encode_to_vec(), &cuts,
            )?;
            reads_as_prost::<proto::EstimateRequest, reference::EstimateRequest>(
                Rpc::Estimate, 0, &r.encode_to_vec(), &cuts,
            )?;
        }

        /// Corrupted bytes: built only when prost decodes them, then to prost's message;
        /// otherwise the status is the guard's, or prost's words.
        #[test]
        fn corrupted_messages_are_answered_as_before(
            b in batches(), f in frames(), r in requests(),
            edits in edits(), cut_end in 0usize..3, cuts in cuts(),
        ) {
            let b = corrupted(&b.encode_to_vec(), &edits, cut_end);
            reads_as_prost::<proto::EstimateBatchRequest, reference::EstimateBatchRequest>(
                Rpc::EstimateBatch, 2, &b, &cuts,
            )?;
            let f = corrupted(&f.encode_to_vec(), &edits, cut_end);
            reads_as_prost::<proto::Frame, reference::Frame>(Rpc::EstimateStream, 2, &f, &cuts)?;
            let r = corrupted(&r.encode_to_vec(), &edits, cut_end);
            reads_as_prost::<proto::EstimateRequest, reference::EstimateRequest>(
                Rpc::Estimate, 0, &r, &cuts,
            )?;
        }

        /// A stream's frames, several to a chunk or cut anywhere, each built and taken in
        /// order by the decoder.
        #[test]
        fn a_stream_of_frames_is_built_in_order(
            frames in prop::collection::vec(frames(), 1..4), cuts in cuts(),
        ) {
            let messages: Vec<Vec<u8>> = frames.iter().map(Message::encode_to_vec).collect();
            let (got, error) =
                served::<proto::Frame>(Rpc::EstimateStream, 4, cut(&body(&messages), &cuts), true);
            prop_assert!(error.is_none(), "{:?}", error);
            let got: Vec<Vec<u8>> = got.iter().map(Message::encode_to_vec).collect();
            prop_assert_eq!(got, messages);
        }

        /// The walk counts the faces prost decodes: a limit at that count passes while one
        /// below it does not.
        #[test]
        fn the_walk_counts_the_faces_prost_decodes(
            sizes in prop::collection::vec((0usize..20, 0usize..40, 0usize..20), 0..30),
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
            let bytes = batch(faces.clone(), "m");
            let n = faces.len();
            let got = built::<proto::EstimateBatchRequest>(Rpc::EstimateBatch, n, &bytes, &[]);
            prop_assert_eq!(got.map(|b| b.map(|b| b.faces.len())), Ok(Some(n)));
            if n > 0 {
                prop_assert!(walked(Rpc::EstimateBatch, n - 1, &bytes).is_err());
            }
        }

        /// Arbitrary bytes never panic the guard or the decoder, and are answered as prost
        /// answers them.
        #[test]
        fn any_bytes_are_read_as_prost_reads_them(
            bytes in prop::collection::vec(any::<u8>(), 0..512), cuts in cuts(),
        ) {
            reads_as_prost::<proto::EstimateBatchRequest, reference::EstimateBatchRequest>(
                Rpc::EstimateBatch, 3, &bytes, &cuts,
            )?;
            reads_as_prost::<proto::EstimateRequest, reference::EstimateRequest>(
                Rpc::Estimate, 3, &bytes, &cuts,
            )?;
            reads_as_prost::<proto::Frame, reference::Frame>(
                Rpc::EstimateStream, 3, &bytes, &cuts,
            )?;
        }
    }

    #[test]
    fn a_large_batch_is_built_once_and_taken_by_the_decoder() {
        // 64 faces of 68 packed points: about 71 KB, walked at the server's threshold, in the
        // 16 KiB chunks of HTTP/2.
        let face = proto::Face {
            xy: (0..136).map(f64::from).collect(),
            scheme: "ibug68".into(),
            ..Default::default()
        };
        let request = proto::EstimateBatchRequest {
            faces: vec![face; 64],
            model: "default".into(),
        };
        let bytes = request.encode_to_vec();
        assert!(bytes.len() >= SCAN_FROM);
        let framed = body(std::slice::from_ref(&bytes));
        let prebuilt = Prebuilt::default();
        let mut g = FrameGuard::new(Rpc::EstimateBatch, 64).building_into(prebuilt.clone());
        for c in framed.chunks(16 * 1024) {
            g.feed(c).unwrap();
        }
        let taken = prebuilt.take::<proto::EstimateBatchRequest>(bytes.len());
        assert_eq!(taken.as_ref(), Some(&request));
        // Nothing more, and a short message is never queued.
        assert_eq!(
            prebuilt.take::<proto::EstimateBatchRequest>(bytes.len()),
            None
        );
        let mut g = FrameGuard::new(Rpc::EstimateBatch, 64).building_into(prebuilt.clone());
        g.feed(&body(&[batch(vec![proto::Face::default(); 3], "")]))
            .unwrap();
        assert_eq!(prebuilt.take::<proto::EstimateBatchRequest>(6), None);
    }

    #[test]
    fn a_key_cut_by_its_face_end_is_left_to_prost() {
        // A face whose one byte starts a key, then bytes that would end that key as another
        // field's: prost refuses the face (found by the proto_face fuzz target).
        let bytes = [0x1a, 0x01, 0x80, 0x53, 0x00];
        assert!(reference::Frame::decode(&bytes[..]).is_err());
        let every_byte: Vec<usize> = (1..bytes.len() + 5).collect();
        for cuts in [&[][..], &every_byte] {
            let got = built::<proto::Frame>(Rpc::EstimateStream, 8, &bytes, cuts);
            assert_eq!(got, Ok(None), "left to prost, cut at {cuts:?}");
        }
        let (faces, err) = served::<proto::Frame>(
            Rpc::EstimateStream,
            8,
            cut(&body(&[bytes.to_vec()]), &every_byte),
            true,
        );
        assert!(faces.is_empty());
        assert_eq!(err.map(|s| s.code()), Some(Code::InvalidArgument));
    }

    #[test]
    fn unknown_groups_are_passed_over_and_what_follows_counted() {
        // prost skips a group of an unknown field and decodes on: the faces after it count.
        let group = [0x7b, 0x0a, 0x00, 0x13, 0x08, 0x01, 0x14, 0x7c];
        let mut bytes = group.to_vec();
        bytes.extend(empty_faces(2_000));
        assert_eq!(
            proto::EstimateBatchRequest::decode(bytes.as_slice()).map(|b| b.faces.len()),
            Ok(2_000)
        );
        let s = walked(Rpc::EstimateBatch, 1_000, &bytes).unwrap_err();
        assert_eq!(s.code(), Code::ResourceExhausted, "{s:?}");
        // A face inside the group is no face (prost skips it), nor a face's field there.
        let mut bytes = group.to_vec();
        bytes.extend(empty_faces(2));
        assert!(walked(Rpc::EstimateBatch, 2, &bytes).is_ok());
        let got = built::<proto::EstimateBatchRequest>(Rpc::EstimateBatch, 2, &bytes, &[]);
        assert_eq!(got, Ok(None), "left to prost");
        // In a face, and in a convention before its parameters.
        let field = |key: u8, bytes: &[u8]| {
            let mut out = vec![key];
            prost::encoding::encode_varint(bytes.len() as u64, &mut out);
            out.extend_from_slice(bytes);
            out
        };
        let landmarks = |n| {
            proto::Face {
                landmarks: vec![proto::Landmark::default(); n],
                ..Default::default()
            }
            .encode_to_vec()
        };
        let face = [
            vec![0x7b],
            landmarks(5),
            vec![0x7c],
            landmarks(MAX_POINTS + 1),
        ]
        .concat();
        let s = walked(Rpc::Estimate, 1, &field(0x0a, &face)).unwrap_err();
        assert!(s.message().contains("more than 1000 landmarks"), "{s:?}");
        let convention = [
            vec![0x7b, 0x7c],
            convention("euler", MAX_PARAMS + 1).encode_to_vec(),
        ]
        .concat();
        let face = field(0x52, &convention);
        let f = proto::Face::decode(face.as_slice()).expect("prost skips the group");
        assert_eq!(f.conventions[0].params.len(), MAX_PARAMS + 1);
        let s = walked(Rpc::EstimateBatch, 1, &field(0x0a, &face)).unwrap_err();
        assert!(s.message().contains("more than 8 parameters"), "{s:?}");
    }
}
