//! The pose record written as JSON without serde's machinery: the same bytes as serde_json's
//! compact writer (the tests hold the two equal over random records), with the keys written
//! as constants and the 68 or so `visible` flags as a run of literals. Serde's derive goes
//! through a map for the service's flattened answer and escapes every key: about 4,500
//! instructions more for one 68-point face's answer than this (callgrind of the release server,
//! docs/performance-notes.md). The floats are serde_json's own formatting
//! ([`CompactFormatter`]), so the digits cannot differ.

use serde_json::ser::{CompactFormatter, Formatter};

use crate::{AngleUncertainty, PoseRecord};

/// Appends `v` as serde_json writes an `f64`: its shortest round-trip digits, or `null` when it
/// is not finite.
#[inline]
pub fn push_f64(out: &mut Vec<u8>, v: f64) {
    if v.is_finite() {
        // Writing to a `Vec` cannot fail.
        let _ = CompactFormatter.write_f64(out, v);
    } else {
        out.extend_from_slice(b"null");
    }
}

/// Appends `s` as a JSON string, escaped as serde_json escapes it (`"`, `\` and the control
/// characters; the rest as it is).
#[inline]
pub fn push_str(out: &mut Vec<u8>, s: &str) {
    if s.bytes().all(|b| b >= 0x20 && b != b'"' && b != b'\\') {
        out.push(b'"');
        out.extend_from_slice(s.as_bytes());
        out.push(b'"');
    } else {
        // Writing to a `Vec` cannot fail.
        let _ = serde_json::to_writer(&mut *out, s);
    }
}

/// Appends `[a, b, ...]`, each item written by `item`.
#[inline]
fn push_list<T>(out: &mut Vec<u8>, items: &[T], item: impl Fn(&mut Vec<u8>, &T)) {
    out.push(b'[');
    for (i, v) in items.iter().enumerate() {
        if i > 0 {
            out.push(b',');
        }
        item(out, v);
    }
    out.push(b']');
}

/// Appends `[a, b, ...]` of floats.
fn push_floats(out: &mut Vec<u8>, values: &[f64]) {
    push_list(out, values, |out, &v| push_f64(out, v));
}

fn push_angle(out: &mut Vec<u8>, a: &AngleUncertainty) {
    out.extend_from_slice(b"{\"sd\":");
    push_f64(out, a.sd);
    out.extend_from_slice(b",\"interval90\":");
    push_floats(out, &a.interval90);
    out.push(b'}');
}

impl PoseRecord {
    /// Appends the record's members, from `"yaw":` to the last, without the braces: the bytes
    /// serde_json writes for them, alone (`{` and `}` around them give
    /// `serde_json::to_vec(self)`) or flattened into an answer with more members.
    pub fn write_json_members(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(b"\"yaw\":");
        push_f64(out, self.yaw);
        out.extend_from_slice(b",\"pitch\":");
        push_f64(out, self.pitch);
        out.extend_from_slice(b",\"roll\":");
        push_f64(out, self.roll);
        out.extend_from_slice(b",\"rotation\":");
        push_list(out, &self.rotation, |out, row| push_floats(out, row));
        out.extend_from_slice(b",\"visible\":[");
        for (i, &v) in self.visible.iter().enumerate() {
            let item: &[u8] = match (i > 0, v) {
                (false, true) => b"true",
                (false, false) => b"false",
                (true, true) => b",true",
                (true, false) => b",false",
            };
            out.extend_from_slice(item);
        }
        out.extend_from_slice(b"],\"residual\":");
        push_f64(out, self.residual);
        out.extend_from_slice(b",\"method\":");
        push_str(out, self.method.name());
        if let Some(t) = &self.translation {
            out.extend_from_slice(b",\"translation\":");
            push_floats(out, t);
        }
        out.extend_from_slice(b",\"warnings\":");
        push_list(out, &self.warnings, |out, w| push_str(out, w));
        if let Some(u) = &self.uncertainty {
            out.extend_from_slice(b",\"uncertainty\":{\"yaw\":");
            push_angle(out, &u.yaw);
            out.extend_from_slice(b",\"pitch\":");
            push_angle(out, &u.pitch);
            out.extend_from_slice(b",\"roll\":");
            push_angle(out, &u.roll);
            out.push(b'}');
        }
        if let Some(c) = &self.conventions {
            // Named by few requests: serde's writing as it is.
            out.extend_from_slice(b",\"conventions\":");
            let _ = serde_json::to_writer(&mut *out, c);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ConventionsRecord, UncertaintyRecord};
    use facepose_core::pose::Method;
    use proptest::prelude::*;

    fn number() -> impl Strategy<Value = f64> {
        prop_oneof![
            6 => -400.0f64..400.0,
            2 => any::<f64>(),
            1 => prop::sample::select(vec![
                0.0, -0.0, 1.0, 1e-300, 5e-324, f64::MAX, f64::NAN, f64::INFINITY,
                f64::NEG_INFINITY, 1e21, 1e22, 123456789012345680.0,
            ]),
        ]
    }

    fn text() -> impl Strategy<Value = String> {
        prop_oneof![
            "[a-z0-9 _.-]{0,24}",
            any::<String>(),
            prop::collection::vec(prop::char::range('\0', '\u{7f}'), 0..12)
                .prop_map(|c| c.into_iter().collect()),
        ]
    }

    fn angle() -> impl Strategy<Value = AngleUncertainty> {
        (number(), number(), number()).prop_map(|(sd, a, b)| AngleUncertainty {
            sd,
            interval90: [a, b],
        })
    }

    prop_compose! {
        fn record()(
            angles in prop::array::uniform3(number()),
            rotation in prop::array::uniform3(prop::array::uniform3(number())),
            visible in prop::collection::vec(any::<bool>(), 0..80),
            residual in number(),
            method in prop::sample::select(Method::ALL.to_vec()),
            translation in prop::option::of(prop::array::uniform3(number())),
            warnings in prop::collection::vec(text(), 0..3),
            uncertainty in prop::option::of((angle(), angle(), angle())),
            conventions in prop::option::of(number()),
        ) -> PoseRecord {
            PoseRecord {
                yaw: angles[0],
                pitch: angles[1],
                roll: angles[2],
                rotation,
                visible,
                residual,
                method,
                translation,
                warnings,
                uncertainty: uncertainty.map(|(yaw, pitch, roll)| UncertaintyRecord { yaw, pitch, roll }),
                conventions: conventions.map(|v| {
                    Box::new(ConventionsRecord {
                        quaternion: Some(crate::QuaternionRecord { w: v, x: 0.5, y: -0.25, z: 1.0 }),
                        ..ConventionsRecord::default()
                    })
                }),
            }
        }
    }

    proptest! {
        /// The members in braces are serde_json's writing of the record, byte for byte.
        #[test]
        fn the_members_are_serde_jsons_bytes(r in record()) {
            let mut out = vec![b'{'];
            r.write_json_members(&mut out);
            out.push(b'}');
            let want = serde_json::to_vec(&r).unwrap();
            prop_assert_eq!(String::from_utf8_lossy(&out), String::from_utf8_lossy(&want));
        }

        /// Strings are escaped as serde_json escapes them.
        #[test]
        fn strings_are_escaped_as_serde_escapes_them(s in text()) {
            let mut out = Vec::new();
            push_str(&mut out, &s);
            prop_assert_eq!(out, serde_json::to_vec(&s).unwrap());
        }
    }

    #[test]
    fn a_record_with_every_member_and_none() {
        let full = PoseRecord {
            yaw: 12.5,
            pitch: -3.25,
            roll: 0.1,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            visible: vec![true, false, true],
            residual: 0.031,
            method: Method::FitShape,
            translation: Some([1.0, -2.0, -600.0]),
            warnings: vec!["a \"quoted\" warning\n".into()],
            uncertainty: None,
            conventions: None,
        };
        let mut out = vec![b'{'];
        full.write_json_members(&mut out);
        out.push(b'}');
        assert_eq!(out, serde_json::to_vec(&full).unwrap());
        assert!(
            String::from_utf8(out)
                .unwrap()
                .contains(r#""method":"fit-shape","translation":[1.0,-2.0,-600.0],"warnings":["a \"quoted\" warning\n"]"#)
        );
    }
}
