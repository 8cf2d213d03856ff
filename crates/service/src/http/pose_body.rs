//! The pose request bodies (`POST /v1/pose`, `POST /v1/pose:batch`) read in one pass as they
//! arrive: [`PoseBody`] takes the body chunk by chunk, looks at each byte once, checks the
//! body's limits at the byte that crosses them and builds the request on the way.
//!
//! **Limits.** The faces of a batch (`--max-batch`), the landmarks of a face (a scheme's 1000
//! points at most) and the length of any one string or number ([`MAX_TOKEN`]). A body over one
//! of them is refused at the byte that crosses it, so that an 8 MB body of empty faces or of
//! `null` landmarks costs a few kilobytes of memory and of parsing, not the whole body held and
//! parsed (which made 20 such requests at once take 1 GB, and held the async workers for tens
//! of milliseconds each). The checks need no values: a stack of the open arrays and objects
//! (with the last key of each object, when it is one that is counted) and the length of the
//! current token. They do not validate: on anything that is not JSON they stop looking, and
//! the parser that reads the whole body gives the client the precise error.
//!
//! **The request.** serde's derived reader would take a landmark array twice (serde_json
//! scans it as a raw value, then [`facepose_records::parse_landmarks`] parses its numbers), and
//! a separate guard a third time. Here the landmarks are parsed as they stream into their list
//! (a number cut by a chunk's end is carried over in a small buffer), and every other member
//! (a scheme name, a camera) is kept as its raw bytes and handed to serde_json once whole. Only
//! the usual shape of a request is built: any surprise (an unknown or repeated member, a key
//! with escapes, anything that is not JSON) stops the building, the limits are still checked
//! to the end, and the caller parses the whole body with serde (`http::pose::pose_request`),
//! which gives the client the precise error. What is built is what serde would read (tested
//! below), however the body is cut into chunks.

use serde::de::DeserializeOwned;

use super::error::HttpError;
use super::wire::{BatchFace, BatchRequest, PoseRequest};
use facepose_app::error::ServiceError;
use facepose_core::shape::MAX_POINTS;
use facepose_records::{Landmarks, read_long_number, read_number, read_short_number, skip_ws};

/// The most bytes a string (or a number) of a pose body may have: far above any name (64
/// characters) or id a client needs, far below what would cost memory.
pub const MAX_TOKEN: usize = 64 * 1024;

/// Deeper bodies are left to the parser (serde_json refuses them past 128).
const MAX_DEPTH: usize = 128;

/// The most bytes of a member's value kept while it is cut by chunk boundaries; a longer one is
/// left to serde on the whole body.
const MAX_SPAN: usize = 64 * 1024;

/// The most bytes of a landmark's number (or `null`) kept while it is cut by a chunk boundary;
/// a longer one is left to serde on the whole body.
const MAX_CARRY: usize = 1024;

/// Which body is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BodyKind {
    /// `POST /v1/pose`: `landmarks` of the top object.
    Pose,
    /// `POST /v1/pose:batch`: the `faces` of the top object, and each face's `landmarks`.
    Batch {
        /// The batch limit (`--max-batch`).
        max_faces: usize,
    },
}

/// The first limit a body crossed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Breach {
    /// The batch's `faces` has more than `max_faces` elements.
    Faces,
    /// A face's `landmarks` has more than [`MAX_POINTS`] elements; the face's index in a batch.
    Points {
        /// The face's index in a batch; `None` for a single face.
        face: Option<usize>,
    },
    /// A string or number of more than [`MAX_TOKEN`] bytes.
    Token,
    /// A string or an object among a face's landmarks; the face's index in a batch.
    NotALandmark {
        /// The face's index in a batch; `None` for a single face.
        face: Option<usize>,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Counted {
    Faces,
    Landmarks,
    Other,
}

#[derive(Debug, Clone, Copy)]
enum Open {
    /// An object and its current key, if it is one that names a counted array.
    Object(Counted),
    Array {
        counted: Counted,
        len: usize,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Before a value (after `[`, `,` in an array, `:`, or at the start).
    Value,
    /// Before a key or the end of an object (after `{` or `,` in an object).
    Key,
    /// After a key, before its `:`.
    Colon,
    /// After a value: `,`, `]`, `}` or white space.
    After,
    /// In a string; `key` if it is an object's key.
    Str { key: bool, escaped: bool },
    /// In a number or a literal (`true`, `null`, ...).
    Scalar,
    /// In a counted `landmarks` array, `depth` arrays down (0: between its elements), where
    /// only its elements are counted: a landmark is `[x, y]` or `null`, so a string or an
    /// object there is refused at once. `expect`: an element may start (after `[` or `,`).
    Points { depth: u32, expect: bool },
    /// The body's value is complete: only white space may follow.
    Done,
    /// Not JSON, or too deep: the parser will say why.
    GaveUp,
}

/// A member of a request or of a batch's face.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Field {
    Landmarks,
    Faces,
    Scheme,
    Method,
    Model,
    Camera,
    LandmarkStyle,
    ImageSize,
    Id,
    Conventions,
    CameraOrientation,
}

impl Field {
    fn named(key: &[u8]) -> Option<Field> {
        Some(match key {
            b"landmarks" => Field::Landmarks,
            b"faces" => Field::Faces,
            b"scheme" => Field::Scheme,
            b"method" => Field::Method,
            b"model" => Field::Model,
            b"camera" => Field::Camera,
            b"landmark_style" => Field::LandmarkStyle,
            b"image_size" => Field::ImageSize,
            b"id" => Field::Id,
            b"conventions" => Field::Conventions,
            b"camera_orientation" => Field::CameraOrientation,
            _ => return None,
        })
    }

    fn bit(self) -> u32 {
        1 << self as u32
    }
}

/// The object being built: the request, or a face of a batch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Obj {
    Top,
    Face,
}

/// Where a landmark list being built stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Lm {
    /// After its `[`.
    Open,
    /// After a `,` between landmarks.
    Next,
    /// After a landmark.
    After,
    /// After a landmark's `[`.
    X,
    /// After a landmark's x.
    AfterX,
    /// After the `,` of a landmark.
    Y,
    /// After a landmark's y.
    AfterY,
}

/// The reader of one pose body (see the module doc): [`feed`](Self::feed) it the chunks as they
/// arrive, then take the request with [`read_pose`](Self::read_pose) or
/// [`read_batch`](Self::read_batch).
#[derive(Debug)]
pub struct PoseBody {
    kind: BodyKind,
    stack: Vec<Open>,
    state: State,
    /// Bytes of the current token.
    token: usize,
    /// The current key's first bytes, while it may still be one that is counted or built.
    key: [u8; 20],
    key_len: usize,
    /// Elements of the batch's `faces` so far.
    faces: usize,
    breach: Option<Breach>,
    /// Whether the request is still being built (no surprise so far).
    building: bool,
    /// The top object closed while building.
    complete: bool,
    /// The offset in the chunk at hand of the byte being read.
    at: usize,
    /// The member whose key was just read, in an object being built.
    field: Option<Field>,
    /// Members seen so far, of the request and of the current face.
    seen: [u32; 2],
    /// The member whose value is being kept as bytes, and the depth of its object.
    capture: Option<(Field, usize)>,
    /// Where the kept value starts in the chunk at hand.
    span_start: usize,
    /// The kept value's bytes from earlier chunks.
    span: Vec<u8>,
    /// Inside the batch's `faces`, being built.
    in_faces: bool,
    /// A landmark list is being built.
    lm_build: bool,
    lm: Lm,
    x: f64,
    points: Vec<Option<[f64; 2]>>,
    /// A landmark's token cut by the last chunk's end.
    carry: Vec<u8>,
    pose: PoseRequest,
    batch: BatchRequest,
    face: BatchFace,
}

impl PoseBody {
    /// A reader for a body of `kind`.
    pub fn new(kind: BodyKind) -> Self {
        PoseBody {
            kind,
            stack: Vec::new(),
            state: State::Value,
            token: 0,
            key: [0; 20],
            key_len: 0,
            faces: 0,
            breach: None,
            building: true,
            complete: false,
            at: 0,
            field: None,
            seen: [0; 2],
            capture: None,
            span_start: 0,
            span: Vec::new(),
            in_faces: false,
            lm_build: false,
            lm: Lm::Open,
            x: 0.0,
            points: Vec::new(),
            carry: Vec::new(),
            pose: PoseRequest::default(),
            batch: BatchRequest::default(),
            face: BatchFace::default(),
        }
    }

    /// The most faces a batch may have (`None` for a single pose).
    pub fn max_faces(&self) -> Option<usize> {
        match self.kind {
            BodyKind::Pose => None,
            BodyKind::Batch { max_faces } => Some(max_faces),
        }
    }

    /// The faces of the batch's `faces` array counted so far.
    pub fn faces(&self) -> usize {
        self.faces
    }

    /// Reads the next bytes of the body: the first breach, once it is crossed (and again for
    /// every later chunk, which it no longer reads).
    pub fn feed(&mut self, chunk: &[u8]) -> Result<(), Breach> {
        let n = chunk.len();
        let mut i = 0;
        self.span_start = 0;
        // Numbers and string contents, most of a body, are passed over in runs; the landmarks
        // in their own loop; the rest byte by byte.
        while i < n && self.breach.is_none() {
            match self.state {
                State::GaveUp => {
                    self.surprise();
                    break;
                }
                State::Done => {
                    if self.building && !chunk[i..].iter().all(|&b| is_json_ws(b)) {
                        self.surprise();
                    }
                    break;
                }
                State::Scalar => {
                    let run = run_len(&chunk[i..], is_scalar_byte);
                    self.grow_token(run);
                    i += run;
                    if i < n {
                        self.state = State::After;
                        self.span_ends(chunk, i);
                    }
                }
                State::Points { .. } => {
                    i = self.points(chunk, i);
                    self.span_ends(chunk, i);
                }
                State::Str {
                    key,
                    escaped: false,
                } => {
                    let run = run_len(&chunk[i..], |b| b != b'"' && b != b'\\');
                    if key {
                        self.key_run(&chunk[i..i + run]);
                    }
                    self.grow_token(run);
                    i += run;
                    if let Some(&b) = chunk.get(i) {
                        self.at = i;
                        self.byte(b);
                        i += 1;
                        self.span_ends(chunk, i);
                    }
                }
                _ => {
                    self.at = i;
                    self.byte(chunk[i]);
                    i += 1;
                    self.span_ends(chunk, i);
                }
            }
        }
        if self.capture.is_some() && self.building {
            // A member's value cut by the chunk's end: kept, within bounds.
            if self.span.len() + (n - self.span_start) > MAX_SPAN {
                self.surprise();
            } else {
                self.span.extend_from_slice(&chunk[self.span_start..]);
            }
        }
        self.breach.map_or(Ok(()), Err)
    }

    /// The request, if the whole body was read in the usual shape (else the caller parses the
    /// body with serde, which gives the precise error: `http::pose::pose_request`).
    pub fn read_pose(self) -> Option<PoseRequest> {
        (self.kind == BodyKind::Pose && self.read_whole()).then_some(self.pose)
    }

    /// [`read_pose`](Self::read_pose) for a batch (`http::pose::batch_request`).
    pub fn read_batch(self) -> Option<BatchRequest> {
        (self.kind != BodyKind::Pose && self.read_whole()).then_some(self.batch)
    }

    /// Whether the request was built from the whole body.
    fn read_whole(&self) -> bool {
        self.building && self.complete && self.state == State::Done
    }

    /// What a body that crossed a limit gets: 413 for too many faces, 422 for the rest.
    pub fn breach_error(&self, breach: Breach) -> HttpError {
        match breach {
            Breach::Faces => ServiceError::BatchOverLimit {
                at_least: self.faces(),
                limit: self.max_faces().unwrap_or_default(),
            }
            .into(),
            Breach::Points { face } => HttpError::invalid(format!(
                "{}landmarks: more than {MAX_POINTS} landmarks, the most a scheme may have",
                face.map_or(String::new(), |i| format!("faces[{i}].")),
            )),
            Breach::NotALandmark { face } => HttpError::invalid(format!(
                "{}landmarks: a landmark is [x, y] (two numbers) or null",
                face.map_or(String::new(), |i| format!("faces[{i}].")),
            )),
            Breach::Token => HttpError::invalid(format!(
                "a string or number of more than {} KiB: names have at most 64 characters",
                MAX_TOKEN / 1024
            )),
        }
    }

    /// Something the usual shape does not have: stop building (the limits are still checked).
    #[cold]
    fn surprise(&mut self) {
        if self.building {
            self.building = false;
            self.lm_build = false;
            self.capture = None;
            self.field = None;
            self.points = Vec::new();
            self.carry = Vec::new();
            self.span = Vec::new();
        }
    }

    fn grow_token(&mut self, n: usize) {
        self.token += n;
        if self.token > MAX_TOKEN {
            self.crossed(Breach::Token);
        }
    }

    fn crossed(&mut self, breach: Breach) {
        self.breach.get_or_insert(breach);
        self.surprise();
    }

    /// The object being built that the reader stands in, if any.
    fn obj(&self) -> Option<Obj> {
        if !self.building || self.capture.is_some() {
            return None;
        }
        match self.stack.len() {
            1 => Some(Obj::Top),
            3 if self.in_faces => Some(Obj::Face),
            _ => None,
        }
    }

    /// Ends the kept value of a member when it is whole (the reader after it, at its object's
    /// depth), `end` the offset just past it in `chunk`.
    #[inline]
    fn span_ends(&mut self, chunk: &[u8], end: usize) {
        if let Some((field, depth)) = self.capture
            && self.state == State::After
            && self.stack.len() == depth
        {
            self.capture = None;
            let piece = &chunk[self.span_start..end];
            let set = if self.span.is_empty() {
                self.set(field, depth == 3, piece)
            } else {
                let mut span = std::mem::take(&mut self.span);
                span.extend_from_slice(piece);
                let set = self.set(field, depth == 3, &span);
                span.clear();
                self.span = span;
                set
            };
            if set.is_none() {
                self.surprise();
            }
        }
    }

    /// Sets member `field` of the request (or of the current face) to the value `v`: by serde,
    /// but a name (a plain string or `null`) directly, as serde would read it.
    fn set(&mut self, field: Field, face: bool, v: &[u8]) -> Option<()> {
        fn de<T: DeserializeOwned>(v: &[u8]) -> Option<T> {
            serde_json::from_slice(v).ok()
        }
        macro_rules! assign {
            ($target:expr, names: [$($n_variant:ident => $n_name:ident),* $(,)?],
             [$($variant:ident => $name:ident),* $(,)?]) => {
                match field {
                    $(Field::$n_variant => $target.$n_name = name(v)?,)*
                    $(Field::$variant => $target.$name = de(v)?,)*
                    _ => return None,
                }
            };
        }
        match (self.kind, face) {
            (BodyKind::Pose, _) => assign!(
                self.pose,
                names: [
                    Scheme => scheme,
                    Method => method,
                    Model => model,
                    LandmarkStyle => landmark_style,
                ],
                [
                    Camera => camera,
                    ImageSize => image_size,
                    Id => id,
                    Conventions => conventions,
                    CameraOrientation => camera_orientation,
                ]
            ),
            (BodyKind::Batch { .. }, false) => assign!(
                self.batch,
                names: [
                    Scheme => scheme,
                    Method => method,
                    Model => model,
                    LandmarkStyle => landmark_style,
                ],
                [
                    Camera => camera,
                    ImageSize => image_size,
                    Conventions => conventions,
                    CameraOrientation => camera_orientation,
                ]
            ),
            (BodyKind::Batch { .. }, true) => assign!(
                self.face,
                names: [
                    Scheme => scheme,
                    Method => method,
                    LandmarkStyle => landmark_style,
                ],
                [
                    Camera => camera,
                    ImageSize => image_size,
                    Id => id,
                    Conventions => conventions,
                    CameraOrientation => camera_orientation,
                ]
            ),
        }
        Some(())
    }

    fn byte(&mut self, b: u8) {
        match self.state {
            State::Str { key, escaped } => {
                if escaped || b != b'"' {
                    self.token += 1;
                    if self.token > MAX_TOKEN {
                        self.crossed(Breach::Token);
                    }
                }
                if escaped {
                    self.state = State::Str {
                        key,
                        escaped: false,
                    };
                    self.key_len = usize::MAX;
                } else if b == b'\\' {
                    self.state = State::Str { key, escaped: true };
                } else if b == b'"' {
                    self.state = if key { State::Colon } else { State::After };
                    if key {
                        self.key_read();
                    }
                } else if key && self.key_len < self.key.len() && (0x20..0x7f).contains(&b) {
                    self.key[self.key_len] = b;
                    self.key_len += 1;
                } else {
                    self.key_len = usize::MAX;
                }
            }
            State::Scalar => {
                if is_scalar_byte(b) {
                    self.grow_token(1);
                } else {
                    self.state = State::After;
                    self.byte(b);
                }
            }
            _ if b.is_ascii_whitespace() => {
                if !is_json_ws(b) {
                    self.surprise();
                }
            }
            State::Value => self.value(b),
            State::Key => match b {
                b'"' => {
                    self.token = 0;
                    self.key_len = 0;
                    self.state = State::Str {
                        key: true,
                        escaped: false,
                    };
                }
                b'}' => {
                    // `{"a": 1,}`: the checks let it pass; JSON does not.
                    if let Some(obj) = self.obj()
                        && self.seen[obj as usize] != 0
                    {
                        self.surprise();
                    }
                    self.close();
                }
                _ => self.state = State::GaveUp,
            },
            State::Colon => {
                self.state = if b == b':' {
                    State::Value
                } else {
                    State::GaveUp
                }
            }
            State::After => match (b, self.stack.last()) {
                (b',', Some(Open::Object(_))) => self.state = State::Key,
                (b',', Some(Open::Array { .. })) => self.state = State::Value,
                (b'}', Some(Open::Object(_))) | (b']', Some(Open::Array { .. })) => self.close(),
                _ => self.state = State::GaveUp,
            },
            State::GaveUp | State::Done | State::Points { .. } => {}
        }
    }

    /// Plain bytes of a key (no quote, no escape), as [`byte`](Self::byte) takes them one by
    /// one: kept while the key may still be one that is counted or built.
    #[inline]
    fn key_run(&mut self, bytes: &[u8]) {
        let end = self.key_len.saturating_add(bytes.len());
        if end <= self.key.len() && bytes.iter().all(|b| (0x20..0x7f).contains(b)) {
            self.key[self.key_len..end].copy_from_slice(bytes);
            self.key_len = end;
        } else if !bytes.is_empty() {
            self.key_len = usize::MAX;
        }
    }

    /// A key was read: whether it names a counted array, and, in an object being built, the
    /// member it is.
    fn key_read(&mut self) {
        let key = match self.key_len {
            n if n <= self.key.len() => &self.key[..n],
            _ => &[][..],
        };
        let depth = self.stack.len();
        let counted = match (self.kind, key) {
            (BodyKind::Pose, b"landmarks") if depth == 1 => Counted::Landmarks,
            (BodyKind::Batch { .. }, b"faces") if depth == 1 => Counted::Faces,
            (BodyKind::Batch { .. }, b"landmarks") if depth == 3 => Counted::Landmarks,
            _ => Counted::Other,
        };
        if let Some(Open::Object(k)) = self.stack.last_mut() {
            *k = counted;
        }
        let Some(obj) = self.obj() else {
            return;
        };
        let allowed = match (Field::named(key), self.kind, obj) {
            (Some(Field::Faces | Field::Landmarks), _, _) => counted != Counted::Other,
            (Some(Field::Id), BodyKind::Batch { .. }, Obj::Top)
            | (Some(Field::Model), BodyKind::Batch { .. }, Obj::Face) => false,
            (f, ..) => f.is_some(),
        };
        let field = Field::named(key).filter(|_| allowed);
        match field {
            Some(f) if self.seen[obj as usize] & f.bit() == 0 => {
                self.seen[obj as usize] |= f.bit();
                self.field = Some(f);
            }
            _ => self.surprise(),
        }
    }

    /// A value starts with `b`.
    fn value(&mut self, b: u8) {
        let mut crossed = None;
        if let Some(Open::Array { counted, len }) = self.stack.last_mut() {
            if b == b']' && *len == 0 {
                self.close();
                return;
            }
            *len += 1;
            match *counted {
                Counted::Faces => {
                    self.faces = *len;
                    if let BodyKind::Batch { max_faces } = self.kind
                        && *len > max_faces
                    {
                        crossed = Some(Breach::Faces);
                    }
                }
                Counted::Landmarks if *len > MAX_POINTS => {
                    crossed = Some(Breach::Points { face: self.face() });
                }
                _ => {}
            }
        }
        if let Some(breach) = crossed {
            self.crossed(breach);
        }
        if self.building {
            self.building_value(b);
        }
        let counted = match self.stack.last() {
            Some(Open::Object(k)) => *k,
            _ => Counted::Other,
        };
        match b {
            b'{' | b'[' if self.stack.len() == MAX_DEPTH => self.state = State::GaveUp,
            b'{' => {
                self.stack.push(Open::Object(Counted::Other));
                self.state = State::Key;
            }
            b'[' => {
                self.stack.push(Open::Array { counted, len: 0 });
                self.state = if counted == Counted::Landmarks {
                    State::Points {
                        depth: 0,
                        expect: true,
                    }
                } else {
                    State::Value
                };
            }
            b'"' => {
                self.token = 0;
                self.state = State::Str {
                    key: false,
                    escaped: false,
                };
            }
            b'-' | b'0'..=b'9' | b't' | b'f' | b'n' => {
                self.token = 1;
                self.state = State::Scalar;
            }
            _ => self.state = State::GaveUp,
        }
    }

    /// A value starts with `b` while building: the request, a face, a member's value.
    fn building_value(&mut self, b: u8) {
        if self.capture.is_some() {
            return;
        }
        if let Some(field) = self.field.take() {
            match field {
                Field::Landmarks if b == b'[' => {
                    self.lm_build = true;
                    self.lm = Lm::Open;
                    self.points = Vec::with_capacity(68);
                }
                Field::Faces if b == b'[' => self.in_faces = true,
                Field::Landmarks | Field::Faces => self.surprise(),
                _ => {
                    self.capture = Some((field, self.stack.len()));
                    self.span_start = self.at;
                }
            }
        } else if self.stack.is_empty() {
            if b != b'{' {
                self.surprise();
            }
        } else if self.in_faces && self.stack.len() == 2 {
            if b == b'{' {
                self.seen[Obj::Face as usize] = 0;
            } else {
                self.surprise();
            }
        }
    }

    /// The face a breach is in: `None` for a single pose.
    fn face(&self) -> Option<usize> {
        match self.kind {
            BodyKind::Pose => None,
            BodyKind::Batch { .. } => Some(self.faces.saturating_sub(1)),
        }
    }

    /// Reads the bytes of a `landmarks` array (see [`State::Points`]) from offset `i` of
    /// `chunk` until it closes or the chunk ends, building the list if it is being built; the
    /// offset reached.
    fn points(&mut self, chunk: &[u8], mut i: usize) -> usize {
        let State::Points {
            mut depth,
            mut expect,
        } = self.state
        else {
            return i;
        };
        if !self.carry.is_empty() {
            // A token cut by the last chunk's end goes on.
            let run = run_len(&chunk[i..], is_scalar_byte);
            self.grow_token(run);
            if self.carry.len() + run > MAX_CARRY {
                self.surprise();
            } else {
                self.carry.extend_from_slice(&chunk[i..i + run]);
            }
            i += run;
            if i == chunk.len() || self.breach.is_some() {
                return i;
            }
            let token = std::mem::take(&mut self.carry);
            self.landmark_token(&token);
            if self.lm_build {
                self.carry = token;
                self.carry.clear();
            }
        }
        while i < chunk.len() && self.breach.is_none() {
            let b = chunk[i];
            let starts = depth == 0 && expect && !b.is_ascii_whitespace();
            if starts && !matches!(b, b']' | b',') {
                expect = false;
                if let Some(Open::Array { len, .. }) = self.stack.last_mut() {
                    *len += 1;
                    if *len > MAX_POINTS {
                        self.crossed(Breach::Points { face: self.face() });
                        break;
                    }
                }
            }
            if is_scalar_byte(b) {
                i = self.scalar(chunk, i);
                continue;
            }
            self.token = 0;
            match b {
                b'[' => {
                    if self.lm_build
                        && depth == 0
                        && matches!(self.lm, Lm::Open | Lm::Next)
                        && let Some(Open::Array { len, .. }) = self.stack.last_mut()
                    {
                        // The usual landmarks, whole in the chunk: nothing in them a limit
                        // counts (their numbers are short), read in one go, and counted as
                        // the checks count them (this one already is).
                        let (end, read) = point_run(chunk, i, &mut self.points, MAX_POINTS - *len);
                        if read > 0 {
                            *len += read - 1;
                            self.lm = Lm::After;
                            i = end;
                            continue;
                        }
                    }
                    depth += 1;
                    if self.lm_build {
                        if depth == 1 && matches!(self.lm, Lm::Open | Lm::Next) {
                            self.lm = Lm::X;
                        } else {
                            self.surprise();
                        }
                    }
                }
                b']' if depth == 0 => {
                    if self.lm_build {
                        self.landmarks_end();
                    }
                    self.close();
                    return i + 1;
                }
                b']' => {
                    depth -= 1;
                    if self.lm_build {
                        if self.lm == Lm::AfterY {
                            self.lm = Lm::After;
                        } else {
                            self.surprise();
                        }
                    }
                }
                b',' => {
                    if depth == 0 {
                        expect = true;
                    }
                    if self.lm_build {
                        match (depth, self.lm) {
                            (0, Lm::After) => self.lm = Lm::Next,
                            (1, Lm::AfterX) => self.lm = Lm::Y,
                            _ => self.surprise(),
                        }
                    }
                }
                b'"' | b'{' => self.crossed(Breach::NotALandmark { face: self.face() }),
                b if b.is_ascii_whitespace() => {
                    if !is_json_ws(b) {
                        self.surprise();
                    }
                }
                _ => {
                    self.state = State::GaveUp;
                    return i + 1;
                }
            }
            i += 1;
        }
        self.state = State::Points { depth, expect };
        i
    }

    /// A number or literal among landmarks, at offset `i` of `chunk`: the offset past it.
    #[inline]
    fn scalar(&mut self, chunk: &[u8], i: usize) -> usize {
        if self.lm_build && matches!(self.lm, Lm::X | Lm::Y) {
            // The usual case: a number, parsed where it stands.
            if let Some((v, end)) = read_number(chunk, i)
                && chunk.get(end).is_some_and(|&c| !is_scalar_byte(c))
                && v.is_finite()
            {
                self.grow_token(end - i);
                self.coordinate(v);
                return end;
            }
        }
        let run = run_len(&chunk[i..], is_scalar_byte);
        self.grow_token(run);
        let end = i + run;
        if self.lm_build {
            if end == chunk.len() {
                if run > MAX_CARRY {
                    self.surprise();
                } else {
                    self.carry.extend_from_slice(&chunk[i..end]);
                }
            } else {
                self.landmark_token(&chunk[i..end]);
            }
        }
        end
    }

    /// A whole token (a number or a literal) of the landmark list being built.
    fn landmark_token(&mut self, token: &[u8]) {
        match self.lm {
            Lm::Open | Lm::Next if token == b"null" => {
                self.points.push(None);
                self.lm = Lm::After;
            }
            Lm::X | Lm::Y => match read_number(token, 0) {
                Some((v, end)) if end == token.len() && v.is_finite() => self.coordinate(v),
                _ => self.surprise(),
            },
            _ => self.surprise(),
        }
    }

    /// A landmark's coordinate.
    #[inline]
    fn coordinate(&mut self, v: f64) {
        if self.lm == Lm::X {
            self.x = v;
            self.lm = Lm::AfterX;
        } else {
            self.points.push(Some([self.x, v]));
            self.lm = Lm::AfterY;
        }
    }

    /// The landmark list being built closes.
    fn landmarks_end(&mut self) {
        if !matches!(self.lm, Lm::Open | Lm::After) {
            self.surprise();
            return;
        }
        self.lm_build = false;
        let mut points = std::mem::take(&mut self.points);
        points.shrink_to_fit();
        match self.kind {
            BodyKind::Pose => self.pose.landmarks = Landmarks(points),
            BodyKind::Batch { .. } => self.face.landmarks = Landmarks(points),
        }
    }

    fn close(&mut self) {
        if self.building && self.capture.is_none() {
            self.closing();
        }
        self.stack.pop();
        self.state = if self.stack.is_empty() {
            State::Done // what follows is the parser's to judge
        } else {
            State::After
        };
    }

    /// The array or object on top of the stack closes, while building.
    fn closing(&mut self) {
        let required = |kind| match kind {
            BodyKind::Pose => Field::Landmarks.bit(),
            BodyKind::Batch { .. } => Field::Faces.bit(),
        };
        match (self.stack.len(), self.in_faces) {
            (1, _) => {
                if self.seen[Obj::Top as usize] & required(self.kind) == 0 {
                    self.surprise();
                } else {
                    self.complete = true;
                }
            }
            (2, true) => self.in_faces = false,
            (3, true) => {
                if self.seen[Obj::Face as usize] & Field::Landmarks.bit() == 0 {
                    self.surprise();
                } else {
                    let face = std::mem::take(&mut self.face);
                    self.batch.faces.push(face);
                }
            }
            _ => {}
        }
    }
}

/// An optional name's value `v` as serde reads it into an `Option<String>`: `null`, or a string
/// with no escape and no control character read directly (370 instructions less for a body's
/// scheme and method, `scripts/instructions.sh parse-pose-body`); anything else by serde, which
/// also gives its error.
fn name(v: &[u8]) -> Option<Option<String>> {
    if v == b"null" {
        return Some(None);
    }
    if let [b'"', inner @ .., b'"'] = v
        && inner.iter().all(|&b| b >= 0x20 && b != b'"' && b != b'\\')
        && let Ok(s) = std::str::from_utf8(inner)
    {
        return Some(Some(s.to_owned()));
    }
    serde_json::from_slice(v).ok()
}

/// The run of usual landmarks `[x, y], [x, y], ...` that starts at offset `i` of `chunk` (a
/// `[`), each whole there ([`whole_point`]), pushed onto `points`: at most `room` more after the
/// first. The offset past the last one read, and how many were read (0: the first is not whole
/// in the chunk, or not usual). One loop with its counts in registers: the reader's own state
/// is written once for the run.
#[inline]
fn point_run(
    chunk: &[u8],
    i: usize,
    points: &mut Vec<Option<[f64; 2]>>,
    room: usize,
) -> (usize, usize) {
    let Some((x, y, mut end)) = whole_point(chunk, i) else {
        return (i, 0);
    };
    points.push(Some([x, y]));
    let mut read = 1;
    while read <= room {
        let comma = skip_ws(chunk, end);
        if chunk.get(comma) != Some(&b',') {
            break;
        }
        let start = skip_ws(chunk, comma + 1);
        if chunk.get(start) != Some(&b'[') {
            break;
        }
        let Some((x, y, past)) = whole_point(chunk, start) else {
            break;
        };
        points.push(Some([x, y]));
        read += 1;
        end = past;
    }
    (end, read)
}

/// The landmark `[x, y]` that starts at offset `i` of `chunk` (its `[`), if it is whole there
/// with numbers of at most [`MAX_TOKEN`] bytes: its coordinates and the offset past its `]`.
#[inline(always)]
fn whole_point(chunk: &[u8], i: usize) -> Option<(f64, f64, usize)> {
    let (x, end) = point_number(chunk, skip_ws(chunk, i + 1))?;
    let j = skip_ws(chunk, end);
    if chunk.get(j) != Some(&b',') {
        return None;
    }
    let (y, end) = point_number(chunk, skip_ws(chunk, j + 1))?;
    let j = skip_ws(chunk, end);
    (chunk.get(j) == Some(&b']')).then_some((x, y, j + 1))
}

/// A coordinate of [`whole_point`] at offset `j` of `chunk`: finite, of at most [`MAX_TOKEN`]
/// bytes.
#[inline(always)]
fn point_number(chunk: &[u8], j: usize) -> Option<(f64, usize)> {
    // The usual coordinate: finite and short by construction.
    if let Some(read) = read_short_number(chunk, j) {
        return Some(read);
    }
    let (v, end) = read_long_number(chunk, j)?;
    (v.is_finite() && end - j <= MAX_TOKEN).then_some((v, end))
}

/// JSON's white space (`is_ascii_whitespace` has form feed too).
fn is_json_ws(b: u8) -> bool {
    matches!(b, b' ' | b'\n' | b'\r' | b'\t')
}

/// The bytes of numbers and literals, by value.
const SCALAR: [bool; 256] = {
    let mut t = [false; 256];
    let mut b = 0;
    while b < 256 {
        let c = b as u8;
        t[b] = c.is_ascii_alphanumeric() || matches!(c, b'-' | b'+' | b'.');
        b += 1;
    }
    t
};

/// A byte of a number or a literal.
#[inline]
fn is_scalar_byte(b: u8) -> bool {
    SCALAR[usize::from(b)]
}

/// How many bytes from the start of `bytes` satisfy `f`.
#[inline]
fn run_len(bytes: &[u8], f: impl Fn(u8) -> bool) -> usize {
    bytes.iter().position(|&b| !f(b)).unwrap_or(bytes.len())
}

/// The number of elements of the `faces` array of a batch body, counted without keeping them
/// (serde skips each one in place), up to where the body stops being valid JSON. For a body
/// left to serde: so that its batch limit is checked before serde builds the faces.
pub fn count_batch_faces(body: &[u8]) -> usize {
    use serde::de::{DeserializeSeed, IgnoredAny, MapAccess, SeqAccess, Visitor};
    use std::borrow::Cow;
    use std::cell::Cell;

    struct Body<'c>(&'c Cell<usize>);
    struct Faces<'c>(&'c Cell<usize>);

    impl<'de> DeserializeSeed<'de> for Body<'_> {
        type Value = ();
        fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
            d.deserialize_map(self)
        }
    }
    impl<'de> Visitor<'de> for Body<'_> {
        type Value = ();
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a batch body")
        }
        fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<(), A::Error> {
            while let Some(key) = map.next_key::<Cow<'de, str>>()? {
                if key == "faces" {
                    map.next_value_seed(Faces(self.0))?;
                } else {
                    map.next_value::<IgnoredAny>()?;
                }
            }
            Ok(())
        }
    }
    impl<'de> DeserializeSeed<'de> for Faces<'_> {
        type Value = ();
        fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
            d.deserialize_seq(self)
        }
    }
    impl<'de> Visitor<'de> for Faces<'_> {
        type Value = ();
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("an array of faces")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
            while seq.next_element::<IgnoredAny>()?.is_some() {
                self.0.set(self.0.get() + 1);
            }
            Ok(())
        }
    }

    let count = Cell::new(0);
    let mut de = serde_json::Deserializer::from_slice(body);
    let _ = Body(&count).deserialize(&mut de);
    count.get()
}

#[cfg(test)]
#[path = "pose_body_tests.rs"]
mod tests;
