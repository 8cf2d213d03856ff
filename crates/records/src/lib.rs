//! The JSON records of one face, shared by `facepose estimate` (JSON Lines) and the service's
//! HTTP API: the landmark list a client sends and the pose it gets back. Parsing and formatting
//! only: no I/O, no async. The numbers they carry go to and come from the core
//! (`facepose_core::shape::pixels`, `facepose_core::pose`), which knows no JSON.
//!
//! Landmarks are image pixels (origin top-left, x right, y down), `[x, y]` per point or `null`
//! for a point the client could not find. Angles are degrees (`Pose_Para` convention, see
//! `facepose_core::geometry::convention`) and `rotation` is `R` as row-major nested arrays.

mod conventions;
mod number;
mod write;

pub use conventions::{
    ConventionsRecord, EulerRecord, MediaPipeRecord, OpenCvRecord, QuaternionRecord,
};
pub use write::{push_f64, push_str};

use serde::de;
use serde::{Deserialize, Deserializer, Serialize};

use facepose_core::Result;
use facepose_core::geometry::rotation_rows;
use facepose_core::pose::{Estimate, Method};
use facepose_core::shape::pixels::shape_from_points;
use facepose_core::shape::{MAX_POINTS, Shape2};
use facepose_core::uncertainty::Uncertainty;

/// Landmarks as sent: `[[x, y] | null, ...]`. Deserializing names the first bad landmark by
/// its index ("landmark 3 ...") and says what is expected; the point count is checked against
/// the scheme by the estimator.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Landmarks(pub Vec<Option<[f64; 2]>>);

impl Landmarks {
    /// The shape, with missing points for `null` (see [`shape_from_points`]).
    pub fn to_shape(&self) -> Result<Shape2> {
        shape_from_points(&self.0)
    }

    /// Number of landmarks, present or not.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// Whether there are no landmarks at all.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl Serialize for Landmarks {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        self.0.serialize(s)
    }
}

impl<'de> Deserialize<'de> for Landmarks {
    /// Through [`parse_landmarks`] on the value's raw text: fast-float2 (correctly rounded and
    /// fast) rather than serde_json's float parsing, whose `float_roundtrip` mode, needed by the
    /// model bundles, is several times slower on the 136 numbers of a 68-point face. The
    /// service's one-pass body reader calls [`parse_landmarks_at`] directly.
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let raw = Box::<serde_json::value::RawValue>::deserialize(d)?;
        parse_landmarks(raw.get()).map_err(de::Error::custom)
    }
}

/// Parses the JSON text of a landmark list, `[[x, y] | null, ...]`. Messages name the first bad
/// landmark by index ("landmark 3 y ...") and say what is expected. Never panics, whatever the
/// text.
pub fn parse_landmarks(text: &str) -> std::result::Result<Landmarks, String> {
    let b = text.as_bytes();
    let (points, end) = parse_landmarks_at(b, skip_ws(b, 0))?;
    if skip_ws(b, end) != b.len() {
        return Err("unexpected text after the landmark array".into());
    }
    Ok(points)
}

/// Parses the landmark list that starts at byte `start` of `b` (no leading whitespace) in one
/// pass, numbers where they are found, and returns it with the offset just past its `]`. A list
/// longer than [`MAX_POINTS`] is refused when its first extra point is reached. Strict
/// JSON: what it accepts is valid JSON text, so a caller may take it as such without another
/// scan; errors as [`parse_landmarks`].
pub fn parse_landmarks_at(
    b: &[u8],
    start: usize,
) -> std::result::Result<(Landmarks, usize), String> {
    let mut c = Cursor { b, i: start };
    if c.peek() != Some(b'[') {
        return Err(format!(
            "expected an array of landmarks, each [x, y] (pixels) or null, found {}",
            c.kind()
        ));
    }
    c.i += 1;
    // About 14 bytes a point at the least ("[1.5, 20.25],"), 68 points for most requests.
    let mut points = Vec::with_capacity(68);
    c.ws();
    if c.peek() == Some(b']') {
        return Ok((Landmarks::default(), c.i + 1));
    }
    loop {
        let k = points.len();
        if k == MAX_POINTS {
            return Err(format!(
                "more than {MAX_POINTS} landmarks, the most a scheme may have"
            ));
        }
        points.push(c.point(k)?);
        c.ws();
        match c.peek() {
            Some(b',') => {
                c.i += 1;
                c.ws();
            }
            Some(b']') => break,
            _ => return Err(format!("after landmark {k}: expected , or ]")),
        }
    }
    points.shrink_to_fit();
    Ok((Landmarks(points), c.i + 1))
}

/// Reads the JSON number that starts at byte `start` of `b` (the landmark parser's, correctly
/// rounded): its value (infinite when out of the range of `f64`) and the offset just past it, or
/// `None` if no JSON number starts there. It stops at the first byte that cannot continue the
/// number: what follows is the caller's to check. For readers that parse landmarks as a body
/// arrives (the service's HTTP pose bodies).
#[inline]
pub fn read_number(b: &[u8], start: usize) -> Option<(f64, usize)> {
    number::read(b, start)
}

/// [`read_number`] for the usual landmark coordinate alone (`121.0`, `-37.25`: an optional
/// sign, up to seven integer and fifteen fraction digits and nineteen in all, no exponent,
/// with 16 bytes of `b` from its first digit, 24 past the point for more than seven fraction
/// digits), read in place: its value, always finite, and the offset past it, at most 24 bytes
/// on. `None` when the number at `start` is not of that kind (or the exact shortcuts cannot
/// tell its value): [`read_long_number`] reads it then, as [`read_number`] would.
#[inline(always)]
pub fn read_short_number(b: &[u8], start: usize) -> Option<(f64, usize)> {
    number::short(b, start)
}

/// [`read_number`] without its first try of [`read_short_number`]: for a caller that has
/// tried it already.
#[inline]
pub fn read_long_number(b: &[u8], start: usize) -> Option<(f64, usize)> {
    number::general(b, start)
}

/// The offset of the first byte at or after `i` that is not JSON whitespace.
#[inline]
pub fn skip_ws(b: &[u8], mut i: usize) -> usize {
    while let Some(b' ' | b'\n' | b'\r' | b'\t') = b.get(i) {
        i += 1;
    }
    i
}

struct Cursor<'a> {
    b: &'a [u8],
    i: usize,
}

impl Cursor<'_> {
    #[inline]
    fn peek(&self) -> Option<u8> {
        self.b.get(self.i).copied()
    }

    #[inline]
    fn ws(&mut self) {
        self.i = skip_ws(self.b, self.i);
    }

    /// What the next value is, for messages.
    fn kind(&self) -> &'static str {
        match self.peek() {
            None => "nothing",
            Some(b'[') => "an array",
            Some(b'{') => "an object",
            Some(b'"') => "a string",
            Some(b't' | b'f') => "a boolean",
            Some(b'n') => "null",
            Some(b'-' | b'0'..=b'9') => "a number",
            Some(_) => "something that is not JSON",
        }
    }

    /// Landmark `k`: `[x, y]` or `null`.
    fn point(&mut self, k: usize) -> std::result::Result<Option<[f64; 2]>, String> {
        match self.peek() {
            Some(b'[') => {}
            Some(b'n') if self.b.get(self.i..self.i + 4) == Some(b"null") => {
                self.i += 4;
                return Ok(None);
            }
            _ => {
                return Err(format!(
                    "landmark {k} must be [x, y] numbers or null, found {}",
                    self.kind()
                ));
            }
        }
        self.i += 1;
        self.ws();
        let short =
            || format!("landmark {k} must be [x, y] numbers or null: it has fewer than 2 values");
        if self.peek() == Some(b']') {
            return Err(short());
        }
        let x = self.number(k, "x")?;
        self.ws();
        if self.peek() != Some(b',') {
            return Err(short());
        }
        self.i += 1;
        self.ws();
        let y = self.number(k, "y")?;
        self.ws();
        match self.peek() {
            Some(b']') => {
                self.i += 1;
                Ok(Some([x, y]))
            }
            Some(b',') => Err(format!(
                "landmark {k} must be [x, y] numbers or null: it has more than 2 values"
            )),
            _ => Err(format!("landmark {k}: expected ]")),
        }
    }

    /// Coordinate `c` of landmark `k`: a JSON number, correctly rounded ([`number::read`]).
    fn number(&mut self, k: usize, c: &str) -> std::result::Result<f64, String> {
        let start = self.i;
        let Some((v, end)) = number::read(self.b, start) else {
            return Err(self.not_a_number(k, c));
        };
        self.i = end;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!(
                "landmark {k} {c} = {} is out of range for a 64-bit float",
                String::from_utf8_lossy(&self.b[start..end])
            ))
        }
    }

    /// The message for a coordinate that is not a JSON number.
    fn not_a_number(&self, k: usize, c: &str) -> String {
        let rest = &self.b[self.i..];
        match rest.first() {
            Some(b'"') => {
                let len = rest[1..].iter().position(|&b| b == b'"').unwrap_or(0);
                let v = String::from_utf8_lossy(&rest[1..1 + len]);
                let t = v.trim().trim_start_matches(['+', '-']).to_ascii_lowercase();
                if t == "nan" || t.starts_with("inf") {
                    format!(
                        "landmark {k} {c} is {v:?}: not a finite number (send null for a missing point)"
                    )
                } else {
                    format!("landmark {k} {c} is the string {v:?}: send a JSON number")
                }
            }
            Some(b'-' | b'0'..=b'9') => {
                let len = rest
                    .iter()
                    .position(|b| !matches!(b, b'0'..=b'9' | b'-' | b'+' | b'.' | b'e' | b'E'))
                    .unwrap_or(rest.len());
                let text = String::from_utf8_lossy(&rest[..len]);
                format!("landmark {k} {c}: {text:?} is not a JSON number")
            }
            _ => format!("landmark {k} {c} must be a number, found {}", self.kind()),
        }
    }
}

/// One pose as JSON: what `facepose estimate` prints per face and the core of every pose the
/// service returns.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct PoseRecord {
    /// Degrees; > 0 the nose turns towards image-left.
    pub yaw: f64,
    /// Degrees; > 0 chin up.
    pub pitch: f64,
    /// Degrees; > 0 the face turns clockwise on screen.
    pub roll: f64,
    /// `R = Rx(pitch) · Ry(yaw) · Rz(roll)`, row-major: `rotation[i][j]` is row `i`, column `j`.
    pub rotation: [[f64; 3]; 3],
    /// Per input landmark: visible at the estimated pose.
    pub visible: Vec<bool>,
    /// RMS reprojection error over the present landmarks divided by the projected inter-ocular
    /// distance (unitless; below ~0.05 for a good fit).
    pub residual: f64,
    /// The method that produced the estimate (never `auto`).
    #[cfg_attr(feature = "openapi", schema(value_type = String, example = "fit"))]
    pub method: Method,
    /// With camera intrinsics only: the model origin in the camera frame, mm (x right, y up,
    /// z towards the viewer; the face is at negative z).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation: Option<[f64; 3]>,
    /// What the caller should know about this answer, e.g. that the landmarks fit a face in
    /// their scheme poorly (empty when there is nothing to say).
    #[serde(default)]
    pub warnings: Vec<String>,
    /// How far to trust each angle (absent when the model has no calibration).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<UncertaintyRecord>,
    /// The pose in the conventions the request named (absent when it named none). Boxed: the
    /// answers are about 600 bytes, which a pose that names none would otherwise carry and move.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub conventions: Option<Box<ConventionsRecord>>,
}

/// How far to trust one angle, degrees.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct AngleUncertainty {
    /// Standard deviation: the 90% interval is the angle ± 1.645 of them.
    pub sd: f64,
    /// The interval that holds the true angle for 90% of faces, `[low, high]` around the
    /// angle (not wrapped to ±180°; a half-width of 180° says the angle is undetermined).
    pub interval90: [f64; 2],
}

/// Per angle, how far to trust it: calibrated on real faces (docs/API.md, "Uncertainty").
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct UncertaintyRecord {
    /// Yaw's uncertainty.
    pub yaw: AngleUncertainty,
    /// Pitch's uncertainty.
    pub pitch: AngleUncertainty,
    /// Roll's uncertainty.
    pub roll: AngleUncertainty,
}

impl From<&Uncertainty> for UncertaintyRecord {
    fn from(u: &Uncertainty) -> Self {
        let angle = |k: usize| AngleUncertainty {
            sd: u.sd[k],
            interval90: u.interval90[k],
        };
        // Uncertainty is pitch, yaw, roll.
        UncertaintyRecord {
            pitch: angle(0),
            yaw: angle(1),
            roll: angle(2),
        }
    }
}

impl UncertaintyRecord {
    fn numbers(&self) -> impl Iterator<Item = f64> + '_ {
        [&self.yaw, &self.pitch, &self.roll]
            .into_iter()
            .flat_map(|a| [a.sd, a.interval90[0], a.interval90[1]])
    }
}

impl PoseRecord {
    /// Whether every number is finite (JSON has no NaN or infinity).
    pub fn is_finite(&self) -> bool {
        [self.yaw, self.pitch, self.roll, self.residual]
            .iter()
            .chain(self.rotation.iter().flatten())
            .chain(self.translation.iter().flatten())
            .copied()
            .chain(self.uncertainty.iter().flat_map(UncertaintyRecord::numbers))
            .chain(self.conventions.iter().flat_map(|c| c.numbers()))
            .all(|v| v.is_finite())
    }
}

impl From<Estimate> for PoseRecord {
    fn from(e: Estimate) -> Self {
        PoseRecord {
            yaw: e.angles.yaw,
            pitch: e.angles.pitch,
            roll: e.angles.roll,
            rotation: rotation_rows(&e.rotation),
            visible: e.visible,
            residual: e.residual,
            method: e.method,
            translation: e.translation.map(|t| [t.x, t.y, t.z]),
            warnings: e.warnings.iter().map(ToString::to_string).collect(),
            uncertainty: e.uncertainty.as_ref().map(UncertaintyRecord::from),
            conventions: None,
        }
    }
}

impl From<&Estimate> for PoseRecord {
    fn from(e: &Estimate) -> Self {
        PoseRecord::from(e.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> std::result::Result<Landmarks, String> {
        serde_json::from_str(s).map_err(|e| e.to_string())
    }

    #[test]
    fn points_and_nulls() {
        let l = parse(" [ [1, 2.5] ,null, [-0.0, 1e3], [0.1E-2,-7] ] ").unwrap();
        assert_eq!(
            l.0,
            vec![
                Some([1.0, 2.5]),
                None,
                Some([-0.0, 1000.0]),
                Some([0.001, -7.0])
            ]
        );
        assert_eq!(parse("[]").unwrap().len(), 0);
        // Correctly rounded, like serde_json's float_roundtrip.
        let v = parse("[[0.1, 312.34567891234567]]").unwrap().0[0].unwrap();
        assert_eq!(v, [0.1, 312.34567891234567]);
        let s = l.to_shape().unwrap();
        assert_eq!(s.len(), 4);
        assert_eq!(s.n_present(), 3);
    }

    #[test]
    fn lists_longer_than_a_scheme_may_be_stop_at_the_first_extra_point() {
        let list = |n: usize| format!("[{}]", vec!["null"; n].join(","));
        assert_eq!(parse(&list(MAX_POINTS)).unwrap().len(), MAX_POINTS);
        let e = parse(&list(MAX_POINTS + 1)).unwrap_err();
        assert!(
            e.contains(&format!("more than {MAX_POINTS} landmarks")),
            "{e}"
        );
        // A million points are refused as fast as one more: the rest is never read, and may
        // even be malformed.
        let text = format!("[{}, oops", vec!["[1,2]"; 1_000_000].join(","));
        let e = parse_landmarks(&text).unwrap_err();
        assert!(e.contains("more than"), "{e}");
    }

    #[test]
    fn messages_name_the_landmark() {
        let cases = [
            (
                "[[1, 2], [3]]",
                "landmark 1 must be [x, y] numbers or null: it has fewer",
            ),
            (
                "[[1, 2], []]",
                "landmark 1 must be [x, y] numbers or null: it has fewer",
            ),
            (
                "[[1, 2, 3]]",
                "landmark 0 must be [x, y] numbers or null: it has more",
            ),
            (
                "[[1, 2], 5]",
                "landmark 1 must be [x, y] numbers or null, found a number",
            ),
            ("[[1, \"a\"]]", "landmark 0 y is the string \"a\""),
            (
                "[[\"NaN\", 1]]",
                "landmark 0 x is \"NaN\": not a finite number",
            ),
            ("[[1, \"-Infinity\"]]", "not a finite number"),
            (
                "[[1, [2]]]",
                "landmark 0 y must be a number, found an array",
            ),
            (
                "[[1, true]]",
                "landmark 0 y must be a number, found a boolean",
            ),
            (
                "[null, {\"x\": 1}]",
                "landmark 1 must be [x, y] numbers or null, found an object",
            ),
            ("{\"a\": 1}", "an array of landmarks"),
            (
                "\"abc\"",
                "an array of landmarks, each [x, y] (pixels) or null, found a string",
            ),
            ("[[1, 1e400]]", "landmark 0 y = 1e400 is out of range"),
        ];
        for (input, want) in cases {
            let err = parse(input).unwrap_err();
            assert!(err.contains(want), "{input}: {err}");
        }
    }

    #[test]
    fn never_panics_on_truncated_or_odd_text() {
        let text = "[[1.5, 2], null, [\"x\", 3], [4, [5]], {\"a\": [1, 2]}]";
        for end in 0..=text.len() {
            let _ = parse_landmarks(&text[..end]);
        }
        for odd in [
            "[[1, \"unterminated",
            "[[-, 1]]",
            "[[1e, 2]]",
            "[[1,2]] x",
            "[nul]",
            "[[1 2]]",
            "[[01, 2]]",
            "[[1., 2]]",
            "[[.5, 2]]",
            "[[+1, 2]]",
            "[[1.e5, 2]]",
            "[[1e+, 2]]",
            "[[--1, 2]]",
            "[[0x10, 2]]",
            "[[1, 2]",
            "[[1, 2],]",
        ] {
            assert!(parse_landmarks(odd).is_err(), "{odd}");
        }
    }

    proptest::proptest! {
        #[test]
        fn numbers_read_as_std_reads_them(bits in proptest::prelude::any::<u64>(), digits in 0usize..25) {
            let v = f64::from_bits(bits);
            proptest::prop_assume!(v.is_finite());
            // Shortest round trip, scientific, and rounded to a number of digits (which is
            // where a parser that is not correctly rounded goes wrong).
            for text in [format!("{v:?}"), format!("{v:e}"), format!("{v:.digits$e}")] {
                let json = format!("[[{text}, -{text}]]").replace("--", "");
                let want: f64 = text.parse().unwrap();
                let got = parse_landmarks(&json).unwrap().0[0].unwrap();
                proptest::prop_assert_eq!(got[0].to_bits(), want.to_bits(), "{}", text);
                proptest::prop_assert_eq!(got[1].to_bits(), (-want).to_bits(), "{}", text);
            }
        }
    }

    #[test]
    fn works_from_a_json_value_too() {
        let v = serde_json::json!([[1, 2], null]);
        let l = Landmarks::deserialize(&v).unwrap();
        assert_eq!(l.len(), 2);
        let v = serde_json::json!([[1, true]]);
        let err = Landmarks::deserialize(&v).unwrap_err().to_string();
        assert!(err.contains("landmark 0 y must be a number"), "{err}");
    }
}
