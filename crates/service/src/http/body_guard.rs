//! The limits of a pose body checked on its bytes as they arrive, before the body is whole:
//! the faces of a batch (`--max-batch`), the landmarks of a face (a scheme's 1000 points at
//! most) and the length of any one string or number. A body over one of them is refused at
//! the byte that crosses it, so that an 8 MB body of empty faces or of `null` landmarks costs
//! a few kilobytes of memory and of parsing, not the whole body held and parsed (which made 20
//! such requests at once take 1 GB, and held the async workers for tens of milliseconds each).
//!
//! The guard is a JSON tokenizer that keeps no values: a stack of the open arrays and objects
//! (with the last key of each object, when it is one the guard counts for) and the length of
//! the current token. It does not validate: on anything that is not JSON it stops looking
//! ([`BodyGuard::feed`] then accepts the rest), and the parser that reads the whole body gives
//! the client the precise error.

/// The most bytes a string (or a number) of a pose body may have: far above any name (64
/// characters) or id a client needs, far below what would cost memory.
pub const MAX_TOKEN: usize = 64 * 1024;

/// Deeper bodies are left to the parser (serde_json refuses them past 128).
const MAX_DEPTH: usize = 128;

/// Which body the guard reads.
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
    /// A face's `landmarks` has more than [`facepose_core::shape::MAX_POINTS`] elements; the
    /// face's index in a batch.
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
    /// object there is refused at once, and nothing else needs the tokenizer. `expect`: an
    /// element may start (after `[` or `,`).
    Points { depth: u32, expect: bool },
    /// Not JSON, or too deep: the parser will say why.
    GaveUp,
}

/// The guard of one body (see the module doc).
#[derive(Debug)]
pub struct BodyGuard {
    kind: BodyKind,
    stack: Vec<Open>,
    state: State,
    /// Bytes of the current token.
    token: usize,
    /// The current key's first bytes, while it may still be a counted one.
    key: [u8; 9],
    key_len: usize,
    /// Elements of the batch's `faces` so far.
    faces: usize,
    breach: Option<Breach>,
}

impl BodyGuard {
    /// A guard for a body of `kind`.
    pub fn new(kind: BodyKind) -> Self {
        BodyGuard {
            kind,
            stack: Vec::new(),
            state: State::Value,
            token: 0,
            key: [0; 9],
            key_len: 0,
            faces: 0,
            breach: None,
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
    pub fn feed(&mut self, bytes: &[u8]) -> Result<(), Breach> {
        let mut i = 0;
        // Numbers and string contents, most of a body, are passed over in runs; the rest
        // byte by byte.
        while i < bytes.len() && self.breach.is_none() {
            match self.state {
                State::GaveUp => break,
                State::Scalar => {
                    let run = run_len(&bytes[i..], is_scalar_byte);
                    self.grow_token(run);
                    i += run;
                    if i < bytes.len() {
                        self.state = State::After;
                    }
                }
                State::Points { .. } => i += self.points(&bytes[i..]),
                State::Str {
                    key: false,
                    escaped: false,
                } => {
                    let run = run_len(&bytes[i..], |b| b != b'"' && b != b'\\');
                    self.grow_token(run);
                    i += run;
                    if let Some(&b) = bytes.get(i) {
                        self.byte(b);
                        i += 1;
                    }
                }
                _ => {
                    self.byte(bytes[i]);
                    i += 1;
                }
            }
        }
        self.breach.map_or(Ok(()), Err)
    }

    fn grow_token(&mut self, n: usize) {
        self.token += n;
        if self.token > MAX_TOKEN {
            self.crossed(Breach::Token);
        }
    }

    fn crossed(&mut self, breach: Breach) {
        self.breach.get_or_insert(breach);
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
                        let counted = self.counted_key();
                        if let Some(Open::Object(k)) = self.stack.last_mut() {
                            *k = counted;
                        }
                    }
                } else if key && self.key_len < self.key.len() {
                    self.key[self.key_len] = b;
                    self.key_len += 1;
                } else {
                    self.key_len = usize::MAX;
                }
            }
            State::Scalar => {
                if is_scalar_byte(b) {
                    self.token += 1;
                    if self.token > MAX_TOKEN {
                        self.crossed(Breach::Token);
                    }
                } else {
                    self.state = State::After;
                    self.byte(b);
                }
            }
            _ if b.is_ascii_whitespace() => {}
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
                b'}' => self.close(),
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
            State::GaveUp | State::Points { .. } => {}
        }
    }

    /// The key just read, if it names an array the guard counts at this place.
    fn counted_key(&self) -> Counted {
        let key = match self.key_len {
            n if n <= self.key.len() => &self.key[..n],
            _ => return Counted::Other,
        };
        let depth = self.stack.len();
        match (self.kind, key) {
            (BodyKind::Pose, b"landmarks") if depth == 1 => Counted::Landmarks,
            (BodyKind::Batch { .. }, b"faces") if depth == 1 => Counted::Faces,
            (BodyKind::Batch { .. }, b"landmarks") if depth == 3 => Counted::Landmarks,
            _ => Counted::Other,
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
                Counted::Landmarks if *len > facepose_core::shape::MAX_POINTS => {
                    crossed = Some(Breach::Points {
                        face: match self.kind {
                            BodyKind::Pose => None,
                            BodyKind::Batch { .. } => Some(self.faces.saturating_sub(1)),
                        },
                    });
                }
                _ => {}
            }
        }
        if let Some(breach) = crossed {
            self.crossed(breach);
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

    /// The face a breach is in: `None` for a single pose.
    fn face(&self) -> Option<usize> {
        match self.kind {
            BodyKind::Pose => None,
            BodyKind::Batch { .. } => Some(self.faces.saturating_sub(1)),
        }
    }

    /// Reads the bytes of a `landmarks` array (see [`State::Points`]) until it closes or
    /// `bytes` end; the bytes used.
    fn points(&mut self, bytes: &[u8]) -> usize {
        let State::Points {
            mut depth,
            mut expect,
        } = self.state
        else {
            return 0;
        };
        let mut i = 0;
        while i < bytes.len() && self.breach.is_none() {
            let b = bytes[i];
            let starts = depth == 0 && expect && !b.is_ascii_whitespace();
            if starts && !matches!(b, b']' | b',') {
                expect = false;
                if let Some(Open::Array { len, .. }) = self.stack.last_mut() {
                    *len += 1;
                    if *len > facepose_core::shape::MAX_POINTS {
                        self.crossed(Breach::Points { face: self.face() });
                        break;
                    }
                }
            }
            if is_scalar_byte(b) {
                let run = run_len(&bytes[i..], is_scalar_byte);
                self.grow_token(run);
                i += run;
                continue;
            }
            self.token = 0;
            match b {
                b'[' => depth += 1,
                b']' if depth == 0 => {
                    self.close();
                    return i + 1;
                }
                b']' => depth -= 1,
                b',' if depth == 0 => expect = true,
                b'"' | b'{' => self.crossed(Breach::NotALandmark { face: self.face() }),
                b if b.is_ascii_whitespace() || b == b',' => {}
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

    fn close(&mut self) {
        self.stack.pop();
        self.state = if self.stack.is_empty() {
            State::GaveUp // the body's value is complete: what follows is the parser's to judge
        } else {
            State::After
        };
    }
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
fn is_scalar_byte(b: u8) -> bool {
    SCALAR[usize::from(b)]
}

/// How many bytes from the start of `bytes` satisfy `f`.
fn run_len(bytes: &[u8], f: impl Fn(u8) -> bool) -> usize {
    bytes.iter().position(|&b| !f(b)).unwrap_or(bytes.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn fed(kind: BodyKind, body: &str, chunk: usize) -> (Result<(), Breach>, usize) {
        let mut g = BodyGuard::new(kind);
        let mut last = Ok(());
        for c in body.as_bytes().chunks(chunk.max(1)) {
            last = g.feed(c);
        }
        (last, g.faces())
    }

    fn landmarks(n: usize) -> String {
        format!("[{}]", vec!["[1.5, -2]"; n].join(","))
    }

    #[test]
    fn counts_what_it_should_and_nothing_else() {
        let batch = BodyKind::Batch { max_faces: 2 };
        let face = |n| format!("{{\"id\": \"a]\\\"\", \"landmarks\": {}}}", landmarks(n));
        let body = |faces: &[String]| {
            format!(
                "{{\"scheme\": \"five\", \"faces\": [{}]}}",
                faces.join(", ")
            )
        };
        let two = body(&[face(3), face(1000)]);
        let three = body(&[face(3), face(1), face(2)]);
        for chunk in [1, 7, 4096] {
            assert_eq!(fed(batch, &two, chunk), (Ok(()), 2));
            assert_eq!(fed(batch, &three, chunk), (Err(Breach::Faces), 3));
            assert_eq!(
                fed(batch, &body(&[face(2), face(1001)]), chunk).0,
                Err(Breach::Points { face: Some(1) })
            );
            let pose = format!("{{\"landmarks\": {}, \"id\": 7}}", landmarks(1000));
            assert_eq!(fed(BodyKind::Pose, &pose, chunk).0, Ok(()));
            let over = format!("{{\"landmarks\": {}}}", landmarks(1001));
            assert_eq!(
                fed(BodyKind::Pose, &over, chunk).0,
                Err(Breach::Points { face: None })
            );
        }
        // Arrays elsewhere, or named so at another depth, are not counted.
        let nested = format!(
            "{{\"camera\": {{\"landmarks\": {}}}, \"faces\": {}, \"landmarks\": []}}",
            landmarks(1500),
            landmarks(1500)
        );
        assert_eq!(fed(BodyKind::Pose, &nested, 13).0, Ok(()));
        // A landmark that is a string or an object is refused at once (its list is counted
        // without the tokenizer, which strings could mislead).
        for bad in ["\"a]\"", "{\"x\": 1}"] {
            let body = format!("{{\"landmarks\": [[1, 2], {bad}, null]}}");
            assert_eq!(
                fed(BodyKind::Pose, &body, 5).0,
                Err(Breach::NotALandmark { face: None })
            );
        }
        let body = "{\"landmarks\": [[1, 2], null,[3,4] ], \"id\": \"]\"}";
        assert_eq!(fed(BodyKind::Pose, body, 2).0, Ok(()));
        let escaped = format!("{{\"land\\u006darks\": {}}}", landmarks(1500));
        assert_eq!(fed(BodyKind::Pose, &escaped, 13).0, Ok(()));
    }

    #[test]
    fn long_tokens_and_non_json() {
        let long = format!("{{\"scheme\": \"{}\"}}", "s".repeat(MAX_TOKEN + 1));
        assert_eq!(fed(BodyKind::Pose, &long, 999).0, Err(Breach::Token));
        let fine = format!("{{\"scheme\": \"{}\"}}", "s".repeat(MAX_TOKEN));
        assert_eq!(fed(BodyKind::Pose, &fine, 999).0, Ok(()));
        let number = format!("{{\"id\": 1{}}}", "0".repeat(MAX_TOKEN));
        assert_eq!(fed(BodyKind::Pose, &number, 999).0, Err(Breach::Token));
        // Not JSON: the guard stops looking; the parser refuses the body.
        let broken = format!("{{\"landmarks\" [{}", "null,".repeat(5000));
        assert_eq!(fed(BodyKind::Pose, &broken, 64).0, Ok(()));
        let deep = "[".repeat(10_000);
        assert_eq!(fed(BodyKind::Pose, &deep, 64).0, Ok(()));
    }

    proptest! {
        /// Any split of a body into chunks gives the same verdict and count.
        #[test]
        fn chunking_does_not_matter(faces in 0usize..6, points in 0usize..3, max in 0usize..5,
                                    chunk in 1usize..40) {
            let face = format!("{{\"landmarks\": {}, \"id\": {{\"x\": [1]}}}}", landmarks(points));
            let body = format!("{{\"faces\": [{}]}}", vec![face; faces].join(","));
            let kind = BodyKind::Batch { max_faces: max };
            let whole = fed(kind, &body, body.len());
            prop_assert_eq!(fed(kind, &body, chunk), whole);
            prop_assert_eq!(whole.1, faces.min(max + 1));
            prop_assert_eq!(whole.0.is_err(), faces > max);
        }
    }
}
