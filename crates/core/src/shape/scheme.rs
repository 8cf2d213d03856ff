//! Landmark schemes as data: point names, the semantic anchors the geometric method needs, the
//! left-right mirror permutation, and the contour points (those that follow the visible outline
//! of the face in 2D annotations rather than a fixed 3D point).
//!
//! Built in: `ibug68` (Multi-PIE / 300-W order), `inner51` (ibug68 points 17-67, the paper's
//! "50 points"), `five` ([eye centre on image-left, eye centre on image-right, nose tip, mouth
//! corner on image-left, mouth corner on image-right], the RetinaFace / MTCNN / InsightFace
//! order) and `dlib5` (dlib's `shape_predictor_5_face_landmarks`, the one face_recognition uses:
//! [image-right eye outer corner, its inner corner, image-left eye outer corner, its inner
//! corner, nose base], ibug68 points 45, 42, 36, 39, 33). A model trained on another point set
//! brings its own scheme as JSON ([`Scheme::from_json`]).

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The points whose mean gives each semantic anchor. "Left" and "right" are image-left and
/// image-right for a frontal face (image-left = the subject's right).
///
/// The eyes are always named. The nose tip and mouth corners are named together or not at all:
/// a scheme without them (`dlib5`) serves every method but the geometric one, and cannot be a
/// model's own scheme ([`Scheme::check_model_scheme`]).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Anchors {
    /// Points whose mean is the image-left eye centre (the subject's right).
    pub eye_left: Vec<usize>,
    /// Points whose mean is the image-right eye centre (the subject's left).
    pub eye_right: Vec<usize>,
    /// Points whose mean is the nose tip.
    pub nose_tip: Vec<usize>,
    /// Points whose mean is the image-left mouth corner.
    pub mouth_left: Vec<usize>,
    /// Points whose mean is the image-right mouth corner.
    pub mouth_right: Vec<usize>,
}

impl Anchors {
    /// Whether the nose tip and mouth corners are named (what the geometric method and a
    /// model's own scheme need).
    pub fn has_nose_and_mouth(&self) -> bool {
        !self.nose_tip.is_empty()
    }

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
    /// The scheme's name.
    pub name: String,
    /// One name per point, in order.
    pub points: Vec<String>,
    /// The points the anchors stand on.
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
    /// contour in range, both eye anchors non-empty, the nose tip and mouth corners all named
    /// or all empty, and `mirror` (if given) an involutive permutation.
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
        let optional = !self.anchors.has_nose_and_mouth();
        for (k, (label, idx)) in labels.iter().zip(self.anchors.as_array()).enumerate() {
            if idx.is_empty() && (k < 2 || !optional) {
                return Err(self.invalid(if k < 2 {
                    format!("anchor {label} names no point")
                } else {
                    format!(
                        "anchor {label} names no point: name the nose tip and both mouth \
                         corners, or none of them"
                    )
                }));
            }
            if k >= 2 && !idx.is_empty() && optional {
                return Err(self.invalid(format!(
                    "anchor {label} names points but nose_tip names none: name the nose tip \
                     and both mouth corners, or none of them"
                )));
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

    /// Checks what a model's own scheme needs beyond [`Scheme::validate`]: the nose tip and
    /// mouth corners, from which training derives the face's frame and the geometric method's
    /// constants.
    pub fn check_model_scheme(&self) -> Result<()> {
        if self.anchors.has_nose_and_mouth() {
            return Ok(());
        }
        Err(self.invalid(
            "names no nose tip and mouth corners, which a model's own scheme needs (the face's \
             frame and the geometric method come from them); train on a scheme that has them \
             (ibug68) and serve this one as a subset",
        ))
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the scheme has no points (never true for a validated scheme).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// A built-in scheme by name ([`super::builtin::BUILTIN_SCHEMES`], the mesh schemes aside:
    /// a model's face mesh builds those).
    pub fn builtin(name: &str) -> Option<Scheme> {
        super::builtin::BuiltinScheme::find(name)?.build()
    }

    /// The names [`Scheme::builtin`] knows: the built-in schemes a set of shapes can be in.
    pub fn builtin_names() -> Vec<&'static str> {
        super::builtin::BUILTIN_SCHEMES
            .iter()
            .filter(|b| b.build().is_some())
            .map(|b| b.name)
            .collect()
    }

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

/// The ibug68 points that dlib's 5-point predictor finds, in its order (found by running both
/// of dlib's predictors on one photograph: each of the five lies within 1.4 px of its ibug68
/// point, docs/SCHEMES.md).
pub const DLIB5_IN_IBUG68: [usize; 5] = [45, 42, 36, 39, 33];

/// dlib's five-point scheme (`shape_predictor_5_face_landmarks`, used by face_recognition): the
/// image-right eye's outer and inner corners, the image-left eye's outer and inner corners, and
/// the base of the nose (ibug68 points [`DLIB5_IN_IBUG68`]). It names no nose tip or mouth
/// corners, so the geometric method does not take it.
pub fn dlib5() -> Scheme {
    let points = [
        "eye_right_outer",
        "eye_right_inner",
        "eye_left_outer",
        "eye_left_inner",
        "nose_base",
    ]
    .map(String::from)
    .to_vec();
    let anchors = Anchors {
        eye_left: vec![2, 3],
        eye_right: vec![0, 1],
        nose_tip: vec![],
        mouth_left: vec![],
        mouth_right: vec![],
    };
    Scheme::new("dlib5", points, anchors, Some(vec![2, 3, 0, 1, 4]), vec![])
        .expect("the built-in dlib5 scheme is valid")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape::inner51;

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
        assert_eq!(dlib5().len(), 5);
        let i51 = inner51();
        assert_eq!(i51.anchors.nose_tip, vec![13]);
        assert_eq!(i51.anchors.mouth_left, vec![31]);
        assert!(i51.contour.is_empty());
        assert_eq!(
            Scheme::builtin_names(),
            ["ibug68", "inner51", "five", "dlib5"]
        );
        for name in Scheme::builtin_names() {
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
    fn dlib5_is_ibug68_points_with_its_mirror() {
        // The mirror of dlib5 must be the mirror of the ibug68 points it takes.
        let (d, i) = (dlib5(), ibug68());
        let im = i.mirror.unwrap();
        for (k, &p) in DLIB5_IN_IBUG68.iter().enumerate() {
            let partner = d.mirror.as_ref().unwrap()[k];
            assert_eq!(DLIB5_IN_IBUG68[partner], im[p], "point {k}");
        }
        // Its eye anchors are ibug68's eyes: the image-left eye is 36-41.
        assert!(
            d.anchors
                .eye_left
                .iter()
                .all(|&k| (36..42).contains(&DLIB5_IN_IBUG68[k]))
        );
        assert!(
            d.anchors
                .eye_right
                .iter()
                .all(|&k| (42..48).contains(&DLIB5_IN_IBUG68[k]))
        );
    }

    #[test]
    fn nose_and_mouth_are_named_together_or_not_at_all() {
        assert!(dlib5().validate().is_ok());
        assert!(!dlib5().anchors.has_nose_and_mouth());
        let mut half = dlib5();
        half.anchors.nose_tip = vec![4];
        let e = half.validate().unwrap_err().to_string();
        assert!(
            e.contains("mouth_left") && e.contains("or none of them"),
            "{e}"
        );
        let mut no_mouth = five();
        no_mouth.anchors.mouth_right = vec![];
        let e = no_mouth.validate().unwrap_err().to_string();
        assert!(e.contains("mouth_right names no point"), "{e}");
        let mut no_eye = dlib5();
        no_eye.anchors.eye_left = vec![];
        assert!(no_eye.validate().is_err());
        let e = dlib5().check_model_scheme().unwrap_err().to_string();
        assert!(e.contains("dlib5") && e.contains("subset"), "{e}");
        assert!(ibug68().check_model_scheme().is_ok());
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
