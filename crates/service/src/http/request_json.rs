//! One-pass readers of the pose request bodies (`POST /v1/pose`, `POST /v1/pose:batch`).
//!
//! serde's derived reader would take a landmark array twice: serde_json scans it as a raw value,
//! then [`facepose_records::parse_landmarks`] parses its numbers (serde_json's own float parsing,
//! in the `float_roundtrip` mode the model bundles need, is slower still). These readers walk
//! the body once: they parse the landmarks where they find them and hand every other member (a
//! scheme name, a camera) to serde_json on its own bytes. They read the usual shape of a request
//! and nothing else: any surprise (an unknown or repeated member, a key with escapes, any error
//! at all) returns `None`, and the caller parses the body with serde, which gives the client
//! the precise error. What they accept they read exactly as serde would (tested below).

use serde::de::DeserializeOwned;

use super::wire::{BatchFace, BatchRequest, PoseRequest};
use facepose_records::{Landmarks, parse_landmarks_at, skip_ws};

/// Reads a `POST /v1/pose` body, or `None` (see the module doc).
pub fn read_pose_request(body: &[u8]) -> Option<PoseRequest> {
    let mut r = Reader {
        b: body,
        i: 0,
        max_faces: 0,
    };
    r.ws();
    let req = r.pose_request()?;
    r.ws();
    (r.i == body.len()).then_some(req)
}

/// Reads a `POST /v1/pose:batch` body of at most `max_faces` faces, or `None` (see the module
/// doc; one face more is a surprise too, found without reading the rest).
pub fn read_batch_request(body: &[u8], max_faces: usize) -> Option<BatchRequest> {
    let mut r = Reader {
        b: body,
        i: 0,
        max_faces,
    };
    r.ws();
    let req = r.batch_request()?;
    r.ws();
    (r.i == body.len()).then_some(req)
}

/// Reads the members of the object at the reader into the fields of `$out` named as their keys:
/// `$required` (read by the reader's method of that name) must be there, the `$field`s (read by
/// serde) may be; each at most once and no other member, or the enclosing function returns
/// `None`.
macro_rules! members {
    ($r:expr, $out:ident, $required:ident, [$($field:ident),* $(,)?]) => {{
        let mut seen = 0u32;
        $r.object(|r, key| {
            if key == stringify!($required).as_bytes() {
                first_time(&mut seen, 0)?;
                $out.$required = r.$required()?;
                return Some(());
            }
            let mut bit = 0;
            $(
                bit += 1;
                if key == stringify!($field).as_bytes() {
                    first_time(&mut seen, bit)?;
                    $out.$field = r.value()?;
                    return Some(());
                }
            )*
            let _ = bit;
            None
        })?;
        if seen & 1 == 0 {
            return None;
        }
    }};
}

struct Reader<'a> {
    b: &'a [u8],
    i: usize,
    /// The most faces a batch may have.
    max_faces: usize,
}

/// Marks member `bit` of an object as seen; `None` if it was already (serde refuses repeats).
fn first_time(seen: &mut u32, bit: u32) -> Option<()> {
    let fresh = *seen & (1 << bit) == 0;
    *seen |= 1 << bit;
    fresh.then_some(())
}

impl<'a> Reader<'a> {
    fn ws(&mut self) {
        self.i = skip_ws(self.b, self.i);
    }

    fn eat(&mut self, c: u8) -> Option<()> {
        (self.b.get(self.i) == Some(&c)).then(|| self.i += 1)
    }

    /// Walks an object, calling `member` with each key once the reader stands on its value;
    /// `member` reads the value.
    fn object(&mut self, mut member: impl FnMut(&mut Self, &'a [u8]) -> Option<()>) -> Option<()> {
        self.eat(b'{')?;
        self.ws();
        if self.eat(b'}').is_some() {
            return Some(());
        }
        loop {
            let key = self.key()?;
            self.ws();
            self.eat(b':')?;
            self.ws();
            member(self, key)?;
            self.ws();
            if self.eat(b',').is_some() {
                self.ws();
            } else {
                return self.eat(b'}');
            }
        }
    }

    /// A key of plain printable ASCII (no escapes).
    fn key(&mut self) -> Option<&'a [u8]> {
        self.eat(b'"')?;
        let start = self.i;
        let len = self.b[start..].iter().position(|&c| c == b'"')?;
        let key = &self.b[start..start + len];
        if key
            .iter()
            .any(|&c| c == b'\\' || !(0x20..0x7f).contains(&c))
        {
            return None;
        }
        self.i = start + len + 1;
        Some(key)
    }

    /// Any other member's value, read by serde_json from its own bytes.
    fn value<T: DeserializeOwned>(&mut self) -> Option<T> {
        let mut values = serde_json::Deserializer::from_slice(&self.b[self.i..]).into_iter::<T>();
        let v = values.next()?.ok()?;
        self.i += values.byte_offset();
        Some(v)
    }

    fn landmarks(&mut self) -> Option<Landmarks> {
        let (points, end) = parse_landmarks_at(self.b, self.i).ok()?;
        self.i = end;
        Some(points)
    }

    fn pose_request(&mut self) -> Option<PoseRequest> {
        let mut req = PoseRequest::default();
        members!(
            self,
            req,
            landmarks,
            [
                scheme,
                method,
                model,
                camera,
                landmark_style,
                image_size,
                id,
                conventions,
                camera_orientation
            ]
        );
        Some(req)
    }

    fn batch_face(&mut self) -> Option<BatchFace> {
        let mut face = BatchFace::default();
        members!(
            self,
            face,
            landmarks,
            [
                scheme,
                method,
                camera,
                landmark_style,
                image_size,
                id,
                conventions,
                camera_orientation
            ]
        );
        Some(face)
    }

    fn faces(&mut self) -> Option<Vec<BatchFace>> {
        self.eat(b'[')?;
        self.ws();
        let mut faces = Vec::new();
        if self.eat(b']').is_some() {
            return Some(faces);
        }
        loop {
            if faces.len() == self.max_faces {
                return None;
            }
            faces.push(self.batch_face()?);
            self.ws();
            if self.eat(b',').is_some() {
                self.ws();
            } else {
                self.eat(b']')?;
                return Some(faces);
            }
        }
    }

    fn batch_request(&mut self) -> Option<BatchRequest> {
        let mut req = BatchRequest::default();
        members!(
            self,
            req,
            faces,
            [
                scheme,
                method,
                camera,
                landmark_style,
                image_size,
                model,
                conventions,
                camera_orientation
            ]
        );
        Some(req)
    }
}

/// The number of elements of the `faces` array of a batch body, counted without keeping them
/// (serde skips each one in place), up to where the body stops being valid JSON. For a body the
/// one-pass reader left to serde: so that its batch limit is checked before serde builds the
/// faces.
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
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A JSON number in one of the forms clients send.
    fn number() -> impl Strategy<Value = String> {
        prop_oneof![
            (-5000i64..5000).prop_map(|v| v.to_string()),
            (-5000.0f64..5000.0).prop_map(|v| v.to_string()),
            (-5000.0f64..5000.0).prop_map(|v| format!("{v:.14}")),
            (-5000.0f64..5000.0).prop_map(|v| format!("{v:e}")),
            (-5000.0f64..5000.0).prop_map(|v| format!("{v:E}")),
            prop::sample::select(vec![
                "-0",
                "0",
                "0.0",
                "1e2",
                "1E+2",
                "2.5e-3",
                "1e308",
                "1e400",
                "-1e-400",
                "123456789012345678901234567890",
            ])
            .prop_map(String::from),
        ]
    }

    /// JSON whitespace, usually none.
    fn ws() -> impl Strategy<Value = String> {
        prop_oneof![
            4 => Just(String::new()),
            1 => prop::sample::select(vec![" ", "\n", "\t ", "\r\n  "]).prop_map(String::from),
        ]
    }

    fn point() -> impl Strategy<Value = String> {
        prop_oneof![
            1 => ws().prop_map(|w| format!("null{w}")),
            6 => (ws(), number(), ws(), ws(), number(), ws())
                .prop_map(|(a, x, b, c, y, d)| format!("[{a}{x}{b},{c}{y}{d}]")),
        ]
    }

    fn landmarks() -> impl Strategy<Value = String> {
        (prop::collection::vec(point(), 0..70), ws())
            .prop_map(|(p, w)| format!("[{w}{}]", p.join(",")))
    }

    /// The members a pose request (or a face of a batch) may have, besides `landmarks`, some of
    /// them the reader leaves to serde (an escaped key, an unknown or repeated member).
    fn member() -> impl Strategy<Value = String> {
        let text = prop::sample::select(vec![
            "\"ibug68\"",
            "\"five\"",
            "null",
            "\"fit\"",
            "\"a \\\"quoted\\\" \\u00e9 name\"",
            "7",
        ]);
        prop_oneof![
            text.clone().prop_map(|v| format!("\"scheme\": {v}")),
            text.clone().prop_map(|v| format!("\"method\":{v}")),
            text.clone()
                .prop_map(|v| format!("\"landmark_style\" : {v}")),
            (number(), number()).prop_map(|(f, c)| format!(
                "\"camera\": {{\"fx\": {f}, \"fy\": {f}, \"cx\": {c}, \"cy\": 240}}"
            )),
            Just("\"camera\": null".to_string()),
            Just("\"camera\": {\"fx\": 1}".to_string()),
            text.prop_map(|v| format!("\"id\": {v}")),
            number().prop_map(|v| format!("\"id\": {v}")),
            Just("\"m\\u0065thod\": \"fit\"".to_string()),
            Just("\"unknown\": [1, {\"a\": null}]".to_string()),
        ]
    }

    /// A pose request: landmarks and other members in any order (`model` too for a single pose).
    fn pose_body() -> impl Strategy<Value = String> {
        (
            landmarks(),
            prop::collection::vec(
                prop_oneof![
                    9 => member(),
                    1 => Just("\"model\": \"default\"".to_string()),
                ],
                0..4,
            ),
            any::<prop::sample::Index>(),
            ws(),
            ws(),
        )
            .prop_map(|(lm, mut members, at, w1, w2)| {
                let at = at.index(members.len() + 1);
                members.insert(at, format!("\"landmarks\":{w1}{lm}"));
                format!("{w2}{{{}}}{w2}", members.join(&format!(",{w1}")))
            })
    }

    fn batch_body() -> impl Strategy<Value = String> {
        (
            prop::collection::vec(
                (landmarks(), prop::collection::vec(member(), 0..2)).prop_map(|(lm, mut m)| {
                    m.push(format!("\"landmarks\": {lm}"));
                    format!("{{{}}}", m.join(","))
                }),
                0..5,
            ),
            prop::collection::vec(member(), 0..3),
            ws(),
        )
            .prop_map(|(faces, mut members, w)| {
                members.push(format!("\"faces\":{w}[{}]", faces.join(&format!(",{w}"))));
                members.reverse();
                format!("{{{}}}", members.join(","))
            })
    }

    /// What the reader accepts, serde reads to the same request.
    fn agrees_with_serde<T: DeserializeOwned + PartialEq + std::fmt::Debug>(
        body: &[u8],
        read: fn(&[u8]) -> Option<T>,
    ) -> std::result::Result<bool, TestCaseError> {
        let Some(fast) = read(body) else {
            return Ok(false);
        };
        let slow = serde_json::from_slice::<T>(body);
        prop_assert!(
            slow.is_ok(),
            "read {:?}, serde refused: {slow:?}",
            String::from_utf8_lossy(body)
        );
        prop_assert_eq!(fast, slow.unwrap());
        Ok(true)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn pose_requests_read_as_serde_reads_them(body in pose_body()) {
            let read = agrees_with_serde(body.as_bytes(), read_pose_request)?;
            // The usual shape is read, not left to serde.
            let usual = !body.contains("\\u0065") && !body.contains("unknown")
                && !body.contains("e400") && !body.contains("\"fx\": 1}")
                && !body.contains("\"id\": null");
            if usual && serde_json::from_str::<PoseRequest>(&body).is_ok() {
                prop_assert!(read, "left to serde: {body}");
            }
        }

        #[test]
        fn batch_requests_read_as_serde_reads_them(body in batch_body()) {
            agrees_with_serde(body.as_bytes(), |b| read_batch_request(b, usize::MAX))?;
        }

        #[test]
        fn damaged_bodies_are_never_misread(
            body in pose_body(),
            at in any::<prop::sample::Index>(),
            byte in prop::sample::select(b"[]{},:\" -.e0n1\\x\xff".to_vec()),
            cut in any::<bool>(),
        ) {
            let mut b = body.into_bytes();
            let at = at.index(b.len());
            if cut { b.truncate(at) } else { b[at] = byte }
            agrees_with_serde(&b, read_pose_request)?;
            agrees_with_serde(&b, |b| read_batch_request(b, usize::MAX))?;
        }
    }

    #[test]
    fn a_usual_request_is_read() {
        let body = br#"{"landmarks": [[1.5, -2], null, [3e2, 4.25]], "scheme": "five", "id": 7}"#;
        let req = read_pose_request(body).unwrap();
        assert_eq!(
            req.landmarks.0,
            vec![Some([1.5, -2.0]), None, Some([300.0, 4.25])]
        );
        assert_eq!(req.scheme.as_deref(), Some("five"));
        let batch = br#"{"scheme": "five", "faces": [{"landmarks": []}, {"landmarks": [null], "id": "a"}]}"#;
        assert_eq!(read_batch_request(batch, 2).unwrap().faces.len(), 2);
        assert!(read_batch_request(batch, 1).is_none());
        assert_eq!(count_batch_faces(batch), 2);
    }

    #[test]
    fn surprises_are_left_to_serde() {
        for body in [
            &br#"{"landmarks": [[1, 2]], "landmarks": [[1, 2]]}"#[..],
            br#"{"scheme": "five"}"#,
            br#"{"landmarks": [[1, 2]], "extra": 1}"#,
            br#"{"landmarks": [[1, 2]]} x"#,
            br#"{"landmarks": [[1, 2], [3]]}"#,
            br#"{"landmarks": [[01, 2]]}"#,
            br#"[{"landmarks": [[1, 2]]}]"#,
            b"",
        ] {
            assert!(
                read_pose_request(body).is_none(),
                "{}",
                String::from_utf8_lossy(body)
            );
        }
    }
}
