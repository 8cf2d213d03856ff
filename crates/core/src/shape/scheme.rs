//! Landmark schemes as data: point names, the semantic anchors the geometric method needs, the
//! left-right mirror permutation, and the contour points (those that follow the visible outline
//! of the face in 2D annotations rather than a fixed 3D point).
//!
//! Built in: `ibug68` (Multi-PIE / 300-W order), `inner51` (ibug68 points 17-67, the paper's
//! "50 points") and `five` ([eye centre on image-left, eye centre on image-right, nose tip, mouth
//! corner on image-left, mouth corner on image-right], the RetinaFace / MTCNN order). A model
//! trained on another point set brings its own scheme as JSON ([`Scheme::from_json`]).

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The points whose mean gives each semantic anchor. "Left" and "right" are image-left and
/// image-right for a frontal face (image-left = the subject's right).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Anchors {
    pub eye_left: Vec<usize>,
    pub eye_right: Vec<usize>,
    pub nose_tip: Vec<usize>,
    pub mouth_left: Vec<usize>,
    pub mouth_right: Vec<usize>,
}

impl Anchors {
    /// The five anchors in `five` order.
    pub fn as_array(&self) -> [&[usize]; 5] {
        [
            &self.eye_left,
            &self.eye_right,
            &self.nose_tip,
            &self.mouth_left,
            &self.mouth_right,
        ]
    }
}

/// The most points a scheme may have (training time grows with the square of the points).
/// MediaPipe's face mesh, the densest scheme in use, has 478; the services refuse a face with
/// more points than this before reading it.
pub const MAX_POINTS: usize = 1000;

/// A landmark scheme. Construct with [`Scheme::new`] (validated) or a built-in.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Scheme {
    pub name: String,
    /// One name per point, in order.
    pub points: Vec<String>,
    pub anchors: Anchors,
    /// `mirror[i]` is the point that `i` becomes when the face is mirrored left-right.
    #[serde(default)]
    pub mirror: Option<Vec<usize>>,
    /// Points on the face outline (the jaw line of ibug68).
    #[serde(default)]
    pub contour: Vec<usize>,
}

impl Scheme {
    /// A validated scheme: 3 to [`MAX_POINTS`] points with unique non-empty names, anchors and
    /// contour in range, each anchor non-empty, and `mirror` (if given) an involutive
    /// permutation.
    pub fn new(
        name: impl Into<String>,
        points: Vec<String>,
        anchors: Anchors,
        mirror: Option<Vec<usize>>,
        contour: Vec<usize>,
    ) -> Result<Self> {
        let s = Scheme {
            name: name.into(),
            points,
            anchors,
            mirror,
            contour,
        };
        s.validate()?;
        Ok(s)
    }

    /// Parses and validates a scheme from its JSON form (the fields of this struct).
    pub fn from_json(text: &str) -> Result<Self> {
        let s: Scheme = serde_json::from_str(text).map_err(|e| Error::InvalidScheme {
            scheme: "<json>".into(),
            reason: e.to_string(),
        })?;
        s.validate()?;
        Ok(s)
    }

    fn invalid(&self, reason: impl Into<String>) -> Error {
        Error::InvalidScheme {
            scheme: self.name.clone(),
            reason: reason.into(),
        }
    }

    /// Checks the invariants listed at [`Scheme::new`].
    pub fn validate(&self) -> Result<()> {
        let n = self.points.len();
        if self.name.trim().is_empty() {
            return Err(self.invalid("the name is empty"));
        }
        if n < 3 {
            return Err(self.invalid(format!("needs at least 3 points, has {n}")));
        }
        if n > MAX_POINTS {
            return Err(self.invalid(format!(
                "has {n} points, more than the {MAX_POINTS} a scheme may have"
            )));
        }
        let mut names: Vec<&str> = self.points.iter().map(String::as_str).collect();
        names.sort_unstable();
        if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
            return Err(self.invalid(format!("point name {:?} is used twice", w[0])));
        }
        let labels = [
            "eye_left",
            "eye_right",
            "nose_tip",
            "mouth_left",
            "mouth_right",
        ];
        for (label, idx) in labels.iter().zip(self.anchors.as_array()) {
            if idx.is_empty() {
                return Err(self.invalid(format!("anchor {label} names no point")));
            }
            if let Some(i) = idx.iter().find(|&&i| i >= n) {
                return Err(
                    self.invalid(format!("anchor {label} names point {i}, but there are {n}"))
                );
            }
        }
        if let Some(i) = self.contour.iter().find(|&&i| i >= n) {
            return Err(self.invalid(format!("contour names point {i}, but there are {n}")));
        }
        if let Some(m) = &self.mirror {
            if m.len() != n {
                return Err(self.invalid(format!("mirror has {} entries for {n} points", m.len())));
            }
            if let Some(i) = (0..n).find(|&i| m[i] >= n || m[m[i]] != i) {
                return Err(self.invalid(format!("mirror is not a pairing at point {i}")));
            }
        }
        Ok(())
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the scheme has no points (never true for a validated scheme).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// A built-in scheme by name (`ibug68`, `inner51`, `five`).
    pub fn builtin(name: &str) -> Option<Scheme> {
        match name {
            "ibug68" => Some(ibug68()),
            "inner51" => Some(inner51()),
            "five" => Some(five()),
            _ => None,
        }
    }

    /// The names of the built-in schemes.
    pub const BUILTIN: [&'static str; 3] = ["ibug68", "inner51", "five"];

    /// The sub-scheme made of `indices` of this one (anchors, mirror and contour carried over).
    /// Fails when an anchor or a mirror partner is not among the kept points.
    pub fn subset(&self, name: &str, indices: &[usize]) -> Result<Scheme> {
        if let Some(&i) = indices.iter().find(|&&i| i >= self.len()) {
            return Err(self.invalid(format!(
                "subset {name}: no point {i} (the scheme has {})",
                self.len()
            )));
        }
        let pos = |i: usize| indices.iter().position(|&k| k == i);
        let map = |v: &[usize], what: &str| -> Result<Vec<usize>> {
            v.iter()
                .map(|&i| {
                    pos(i).ok_or_else(|| {
                        self.invalid(format!("subset {name} drops point {i} of {what}"))
                    })
                })
                .collect()
        };
        let a = &self.anchors;
        let anchors = Anchors {
            eye_left: map(&a.eye_left, "eye_left")?,
            eye_right: map(&a.eye_right, "eye_right")?,
            nose_tip: map(&a.nose_tip, "nose_tip")?,
            mouth_left: map(&a.mouth_left, "mouth_left")?,
            mouth_right: map(&a.mouth_right, "mouth_right")?,
        };
        let mirror = match &self.mirror {
            Some(m) => Some(map(
                &indices.iter().map(|&i| m[i]).collect::<Vec<_>>(),
                "mirror",
            )?),
            None => None,
        };
        let contour = self.contour.iter().filter_map(|&i| pos(i)).collect();
        let points = indices.iter().map(|&i| self.points[i].clone()).collect();
        Scheme::new(name, points, anchors, mirror, contour)
    }
}

/// The 68-point iBUG / Multi-PIE scheme (0-based: jaw 0-16, brows 17-26, nose 27-35 with the
/// tip at 30, eyes 36-41 and 42-47, mouth 48-67 with corners 48 and 54).
pub fn ibug68() -> Scheme {
    let mut points = Vec::with_capacity(68);
    points.extend((0..17).map(|i| format!("jaw_{i}")));
    points.extend((0..5).map(|i| format!("brow_left_{i}")));
    points.extend((0..5).map(|i| format!("brow_right_{i}")));
    points.extend((0..4).map(|i| format!("nose_bridge_{i}")));
    points.extend((0..5).map(|i| format!("nose_base_{i}")));
    points.extend((0..6).map(|i| format!("eye_left_{i}")));
    points.extend((0..6).map(|i| format!("eye_right_{i}")));
    points.extend((0..12).map(|i| format!("mouth_outer_{i}")));
    points.extend((0..8).map(|i| format!("mouth_inner_{i}")));
    let mut mirror = vec![0; 68];
    let mut pair = |a: usize, b: usize| {
        mirror[a] = b;
        mirror[b] = a;
    };
    for i in 0..17 {
        pair(i, 16 - i);
    }
    for i in 0..5 {
        pair(17 + i, 26 - i);
    }
    for i in 27..31 {
        pair(i, i);
    }
    for i in 0..5 {
        pair(31 + i, 35 - i);
    }
    // Eyes: 36..41 <-> 45,44,43,42,47,46.
    for (a, b) in [(36, 45), (37, 44), (38, 43), (39, 42), (40, 47), (41, 46)] {
        pair(a, b);
    }
    // Outer mouth 48..59: 48<->54, 49<->53, 50<->52, 51, 55<->59, 56<->58, 57.
    for (a, b) in [
        (48, 54),
        (49, 53),
        (50, 52),
        (51, 51),
        (55, 59),
        (56, 58),
        (57, 57),
    ] {
        pair(a, b);
    }
    // Inner mouth 60..67: 60<->64, 61<->63, 62, 65<->67, 66.
    for (a, b) in [(60, 64), (61, 63), (62, 62), (65, 67), (66, 66)] {
        pair(a, b);
    }
    let anchors = Anchors {
        eye_left: (36..42).collect(),
        eye_right: (42..48).collect(),
        nose_tip: vec![30],
        mouth_left: vec![48],
        mouth_right: vec![54],
    };
    Scheme::new("ibug68", points, anchors, Some(mirror), (0..17).collect())
        .expect("the built-in ibug68 scheme is valid")
}

/// ibug68 points 17-67 (no jaw): the paper's 50-point set plus the inner mouth corner it lacks.
pub fn inner51() -> Scheme {
    ibug68()
        .subset("inner51", &(17..68).collect::<Vec<_>>())
        .expect("inner51 keeps every anchor of ibug68")
}

/// The five-point scheme: eye centres, nose tip, mouth corners (image-left first).
pub fn five() -> Scheme {
    let points = [
        "eye_left",
        "eye_right",
        "nose_tip",
        "mouth_left",
        "mouth_right",
    ]
    .map(String::from)
    .to_vec();
    let anchors = Anchors {
        eye_left: vec![0],
        eye_right: vec![1],
        nose_tip: vec![2],
        mouth_left: vec![3],
        mouth_right: vec![4],
    };
    Scheme::new("five", points, anchors, Some(vec![1, 0, 2, 4, 3]), vec![])
        .expect("the built-in five scheme is valid")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_subset_past_the_end_is_an_error() {
        let e = ibug68().subset("x", &[17, 68]).unwrap_err().to_string();
        assert!(e.contains("no point 68"), "{e}");
    }

    #[test]
    fn builtins_are_valid_and_sized() {
        assert_eq!(ibug68().len(), 68);
        assert_eq!(inner51().len(), 51);
        assert_eq!(five().len(), 5);
        let i51 = inner51();
        assert_eq!(i51.anchors.nose_tip, vec![13]);
        assert_eq!(i51.anchors.mouth_left, vec![31]);
        assert!(i51.contour.is_empty());
        for name in Scheme::BUILTIN {
            assert_eq!(Scheme::builtin(name).unwrap().name, name);
        }
        assert!(Scheme::builtin("mediapipe").is_none());
    }

    #[test]
    fn json_round_trip_and_validation() {
        let s = ibug68();
        let text = serde_json::to_string(&s).unwrap();
        assert_eq!(Scheme::from_json(&text).unwrap(), s);
        let mut bad = five();
        bad.anchors.nose_tip = vec![9];
        let err = Scheme::from_json(&serde_json::to_string(&bad).unwrap()).unwrap_err();
        assert!(err.to_string().contains("nose_tip"), "{err}");
        let mut bad = five();
        bad.mirror = Some(vec![1, 0, 2, 3, 3]);
        assert!(bad.validate().is_err());
        assert!(Scheme::from_json("{not json").is_err());
    }

    #[test]
    fn subset_that_drops_an_anchor_is_an_error() {
        assert!(
            ibug68()
                .subset("no_nose", &(0..30).collect::<Vec<_>>())
                .is_err()
        );
    }
}
