//! The tests of [`super`]: the limits (as the guard of a body had them), what is built is what
//! serde reads, and however a body is cut into chunks the result is the same.

use super::*;
use crate::http::pose::{batch_request, pose_request};
use proptest::prelude::*;

/// A pose body read whole: the request if it was built (not left to serde).
fn read_pose_request(body: &[u8]) -> Option<PoseRequest> {
    let mut r = PoseBody::new(BodyKind::Pose);
    let _ = r.feed(body);
    r.read_whole().then_some(r.pose)
}

/// A batch body read whole: the request if it was built.
fn read_batch_request(body: &[u8], max_faces: usize) -> Option<BatchRequest> {
    let mut r = PoseBody::new(BodyKind::Batch { max_faces });
    let _ = r.feed(body);
    r.read_whole().then_some(r.batch)
}

/// Proptest's cases: `PROPTEST_CASES` if set, else `default` (the debug build of CI pays for
/// each case).
fn cases(default: u32) -> ProptestConfig {
    ProptestConfig::with_cases(
        std::env::var("PROPTEST_CASES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(default),
    )
}

// The limits.

fn fed(kind: BodyKind, body: &str, chunk: usize) -> (Result<(), Breach>, usize) {
    let mut g = PoseBody::new(kind);
    let mut last = Ok(());
    for c in body.as_bytes().chunks(chunk.max(1)) {
        last = g.feed(c);
    }
    (last, g.faces())
}

fn landmark_list(n: usize) -> String {
    format!("[{}]", vec!["[1.5, -2]"; n].join(","))
}

#[test]
fn counts_what_it_should_and_nothing_else() {
    let batch = BodyKind::Batch { max_faces: 2 };
    let face = |n| {
        format!(
            "{{\"id\": \"a]\\\"\", \"landmarks\": {}}}",
            landmark_list(n)
        )
    };
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
        let pose = format!("{{\"landmarks\": {}, \"id\": 7}}", landmark_list(1000));
        assert_eq!(fed(BodyKind::Pose, &pose, chunk).0, Ok(()));
        let over = format!("{{\"landmarks\": {}}}", landmark_list(1001));
        assert_eq!(
            fed(BodyKind::Pose, &over, chunk).0,
            Err(Breach::Points { face: None })
        );
    }
    // Arrays elsewhere, or named so at another depth, are not counted.
    let nested = format!(
        "{{\"camera\": {{\"landmarks\": {}}}, \"faces\": {}, \"landmarks\": []}}",
        landmark_list(1500),
        landmark_list(1500)
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
    let escaped = format!("{{\"land\\u006darks\": {}}}", landmark_list(1500));
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
        let face = format!("{{\"landmarks\": {}, \"id\": {{\"x\": [1]}}}}", landmark_list(points));
        let body = format!("{{\"faces\": [{}]}}", vec![face; faces].join(","));
        let kind = BodyKind::Batch { max_faces: max };
        let whole = fed(kind, &body, body.len());
        prop_assert_eq!(fed(kind, &body, chunk), whole);
        prop_assert_eq!(whole.1, faces.min(max + 1));
        prop_assert_eq!(whole.0.is_err(), faces > max);
    }
}

// The request.

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
    (prop::collection::vec(point(), 0..70), ws()).prop_map(|(p, w)| format!("[{w}{}]", p.join(",")))
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
    #![proptest_config(cases(600))]

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
    let batch =
        br#"{"scheme": "five", "faces": [{"landmarks": []}, {"landmarks": [null], "id": "a"}]}"#;
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

/// What `body` gives fed in chunks cut at `cuts` (offsets, in order): the first breach, the
/// faces counted, whether the request was built, and the request or serde's error.
fn fed_in(kind: BodyKind, body: &[u8], cuts: &[usize]) -> (Option<Breach>, usize, bool, String) {
    let mut r = PoseBody::new(kind);
    let mut breach = None;
    let mut from = 0;
    for &cut in cuts.iter().chain([&body.len()]) {
        let cut = cut.clamp(from, body.len());
        if let Err(b) = r.feed(&body[from..cut]) {
            breach.get_or_insert(b);
        }
        from = cut;
    }
    let (faces, built) = (r.faces(), r.read_whole());
    let result = match kind {
        BodyKind::Pose => format!("{:?}", pose_request(r, body)),
        BodyKind::Batch { .. } => format!("{:?}", batch_request(r, body)),
    };
    (breach, faces, built, result)
}

proptest! {
    #![proptest_config(cases(500))]

    /// A body cut into chunks anywhere (every byte its own, at the most) reads as it does whole:
    /// the same breach, the same request built (never left to serde for being cut) or the same
    /// error.
    #[test]
    fn chunks_do_not_change_the_result(
        body in prop_oneof![pose_body(), batch_body()],
        damage in proptest::option::of((
            any::<prop::sample::Index>(),
            prop::sample::select(b"[]{},:\" -.e0n1\\x\xff".to_vec()),
        )),
        cuts in prop::collection::vec(any::<prop::sample::Index>(), 0..8),
        bytewise in prop::sample::select(vec![false, false, false, true]),
        max_faces in 0usize..4,
    ) {
        let mut body = body.into_bytes();
        if let Some((at, byte)) = damage {
            let at = at.index(body.len());
            body[at] = byte;
        }
        let mut cuts: Vec<usize> = if bytewise {
            (1..body.len()).collect()
        } else {
            cuts.iter().map(|c| c.index(body.len() + 1)).collect()
        };
        cuts.sort_unstable();
        for kind in [BodyKind::Pose, BodyKind::Batch { max_faces }] {
            let whole = fed_in(kind, &body, &[]);
            prop_assert_eq!(fed_in(kind, &body, &cuts), whole);
        }
    }
}

#[test]
fn a_member_or_a_number_cut_by_chunks_is_read() {
    let body = br#"{"scheme": "ibug68", "camera": {"fx": 500, "fy": 500, "cx": 320, "cy": 240}, "landmarks": [[1.25e2, -2], null, [3, 40000.5]], "id": "face-7"}"#;
    let whole = read_pose_request(body).unwrap();
    for chunk in 1..body.len() {
        let mut r = PoseBody::new(BodyKind::Pose);
        for c in body.chunks(chunk) {
            r.feed(c).unwrap();
        }
        assert!(r.read_whole(), "chunks of {chunk}");
        assert_eq!(r.pose, whole, "chunks of {chunk}");
    }
    assert_eq!(whole.landmarks.0[0], Some([125.0, -2.0]));
    assert_eq!(whole.id, serde_json::from_str("\"face-7\"").unwrap());
}

proptest! {
    #![proptest_config(cases(600))]

    /// A name's value is read as serde reads an `Option<String>`, whatever its bytes: quotes,
    /// escapes, control characters, bytes that are not UTF-8.
    #[test]
    fn a_name_is_read_as_serde_reads_it(
        inner in prop::collection::vec(
            prop_oneof![
                4 => prop::char::range('a', 'z').prop_map(|c| vec![c as u8]),
                1 => prop::sample::select(vec![
                    b"\"".to_vec(), b"\\".to_vec(), b"\\n".to_vec(), b"\\u00e9".to_vec(),
                    b"\n".to_vec(), b"\x01".to_vec(), b"\x7f".to_vec(), "é".as_bytes().to_vec(),
                    b"\xff".to_vec(), b"\xc3".to_vec(), b" ".to_vec(),
                ]),
            ],
            0..8,
        ),
        quoted in any::<bool>(),
    ) {
        let inner = inner.concat();
        let v = if quoted { [&b"\""[..], &inner, b"\""].concat() } else { inner };
        prop_assert_eq!(
            name(&v),
            serde_json::from_slice::<Option<String>>(&v).ok(),
            "{:?}",
            String::from_utf8_lossy(&v)
        );
    }
}

#[test]
fn names_plain_escaped_and_not_names() {
    for (v, want) in [
        (&b"\"ibug68\""[..], Some(Some("ibug68"))),
        (b"\"\"", Some(Some(""))),
        (b"null", Some(None)),
        (b"\"a\\u0065\"", Some(Some("ae"))),
        (b"\"\xc3\xa9\"", Some(Some("\u{e9}"))),
        (b"\"a\x01\"", None),
        (b"\"\xff\"", None),
        (b"7", None),
        (b"\"a", None),
    ] {
        assert_eq!(name(v), want.map(|w| w.map(String::from)), "{v:?}");
    }
}
