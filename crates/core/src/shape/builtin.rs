//! The built-in landmark schemes, in one table: each scheme's name, its number of points, what
//! it is, how a model serves it (its own points, a subset of them, or its face mesh), whether a
//! model serves it by default and the kind of points it has for the uncertainty's calibration.
//! Lookups, name lists, the default sub-schemes of training and the calibration's point class
//! are read off [`BUILTIN_SCHEMES`]; the docs that cannot be are checked against it by a test
//! (`tests/integration/registries.rs`).
//!
//! Adding a scheme: its row in [`BUILTIN_SCHEMES`] and the function that builds it (for a
//! subset, its point map in the row is enough).

use serde::{Deserialize, Serialize};

use super::scheme::{DLIB5_IN_IBUG68, Scheme, dlib5, five, ibug68};

/// What kind of landmarks an estimate stands on, for the uncertainty's calibration: the dense
/// schemes (68, 51, MediaPipe's mesh) and each five-point scheme apart (their points differ,
/// and so do their errors).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PointClass {
    /// Dense schemes (68, 51 points, MediaPipe's mesh).
    Dense,
    /// Eye centres, nose tip, mouth corners (`five`), and any other scheme of five points or
    /// fewer.
    Five,
    /// dlib's five points (eye corners, nose base).
    Dlib5,
}

impl PointClass {
    /// The class of scheme `name` of `n` points: a built-in scheme's own, else by the count.
    pub fn of_scheme(name: &str, n: usize) -> Self {
        match BuiltinScheme::find(name) {
            Some(b) => b.class,
            None if n <= 5 => PointClass::Five,
            None => PointClass::Dense,
        }
    }

    /// Every class, in the order of calibrations.
    pub const ALL: [PointClass; 3] = [PointClass::Dense, PointClass::Five, PointClass::Dlib5];

    /// Its name in bundles and reports.
    pub fn name(self) -> &'static str {
        match self {
            PointClass::Dense => "dense",
            PointClass::Five => "five",
            PointClass::Dlib5 => "dlib5",
        }
    }
}

/// Which model schemes a sub-scheme is taken from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parent {
    /// Every scheme with the five anchors.
    Any,
    /// The scheme of this name.
    Named(&'static str),
}

/// How a sub-scheme's points come from its parent's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointMap {
    /// Each point the mean of an anchor's points (eye centres, nose tip, mouth corners); the
    /// sub-scheme is its own definition.
    Anchors,
    /// The parent's points `start..end`, keeping the parent's definition of them (names,
    /// anchors, mirror pairs, contour).
    Range(usize, usize),
    /// The parent's points at these indices, in this order; the sub-scheme is its own
    /// definition (dlib5 names other anchors than its parent's).
    Indices(&'static [usize]),
}

impl PointMap {
    /// The parent's indices of a `Range` or `Indices` map (`None` for `Anchors`).
    pub fn indices(self) -> Option<Vec<usize>> {
        match self {
            PointMap::Anchors => None,
            PointMap::Range(a, b) => Some((a..b).collect()),
            PointMap::Indices(idx) => Some(idx.to_vec()),
        }
    }
}

/// How a model serves a built-in scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Served {
    /// As a model's own scheme: the points a model is trained on.
    Own,
    /// As a subset of a model's own points.
    Subset {
        /// The scheme it is a subset of.
        parent: Parent,
        /// How its points come from the parent's.
        map: PointMap,
        /// Served unless the training options say otherwise.
        by_default: bool,
    },
    /// Through the model's dense face mesh (`crate::model::mesh`), which builds the scheme.
    Mesh,
}

/// One built-in scheme.
pub struct BuiltinScheme {
    /// The scheme's name.
    pub name: &'static str,
    /// Number of points.
    pub points: usize,
    /// One line for listings and `--help`.
    pub summary: &'static str,
    /// How a model serves it.
    pub served: Served,
    /// Its class for the uncertainty's calibration.
    pub class: PointClass,
    /// Builds it (`None` for the mesh schemes, which the mesh builds).
    build: Option<fn() -> Scheme>,
}

/// Every built-in scheme, in the order of the docs and of listings.
pub const BUILTIN_SCHEMES: [BuiltinScheme; 6] = [
    BuiltinScheme {
        name: "ibug68",
        points: 68,
        summary: "the 68-point iBUG / Multi-PIE / 300-W markup (dlib's 68-point predictor)",
        served: Served::Own,
        class: PointClass::Dense,
        build: Some(ibug68),
    },
    BuiltinScheme {
        name: "inner51",
        points: 51,
        summary: "ibug68 without the jaw (points 17-67)",
        served: Served::Subset {
            parent: Parent::Named("ibug68"),
            map: PointMap::Range(17, 68),
            by_default: true,
        },
        class: PointClass::Dense,
        build: Some(inner51),
    },
    BuiltinScheme {
        name: "five",
        points: 5,
        summary: "eye centres, nose tip, mouth corners (image-left first)",
        served: Served::Subset {
            parent: Parent::Any,
            map: PointMap::Anchors,
            by_default: true,
        },
        class: PointClass::Five,
        build: Some(five),
    },
    BuiltinScheme {
        name: "dlib5",
        points: 5,
        summary: "dlib's 5-point predictor: eye corners and nose base",
        served: Served::Subset {
            parent: Parent::Named("ibug68"),
            map: PointMap::Indices(&DLIB5_IN_IBUG68),
            by_default: true,
        },
        class: PointClass::Dlib5,
        build: Some(dlib5),
    },
    BuiltinScheme {
        name: "mediapipe468",
        points: 468,
        summary: "MediaPipe Face Mesh's vertices",
        served: Served::Mesh,
        class: PointClass::Dense,
        build: None,
    },
    BuiltinScheme {
        name: "mediapipe478",
        points: 478,
        summary: "MediaPipe Face Landmarker's points: the mesh, then 10 iris points",
        served: Served::Mesh,
        class: PointClass::Dense,
        build: None,
    },
];

/// ibug68 points 17-67 (no jaw): the paper's 50-point set plus the inner mouth corner it lacks.
pub fn inner51() -> Scheme {
    let (a, b) = (17, 68);
    ibug68()
        .subset("inner51", &(a..b).collect::<Vec<_>>())
        .expect("inner51 keeps every anchor of ibug68")
}

impl BuiltinScheme {
    /// The built-in scheme called `name`.
    pub fn find(name: &str) -> Option<&'static BuiltinScheme> {
        BUILTIN_SCHEMES.iter().find(|b| b.name == name)
    }

    /// The scheme, for those not built by a mesh.
    pub fn build(&self) -> Option<Scheme> {
        self.build.map(|f| f())
    }

    /// Whether it is a subset of a model whose own scheme is `model_scheme`.
    pub fn is_subset_of(&self, model_scheme: &str) -> Option<PointMap> {
        match self.served {
            Served::Subset { parent, map, .. } if self.name != model_scheme => match parent {
                Parent::Any => Some(map),
                Parent::Named(p) if p == model_scheme => Some(map),
                Parent::Named(_) => None,
            },
            _ => None,
        }
    }
}

/// The names of the built-in schemes, in table order.
pub const BUILTIN_NAMES: [&str; BUILTIN_SCHEMES.len()] = {
    let mut names = [""; BUILTIN_SCHEMES.len()];
    let mut i = 0;
    while i < names.len() {
        names[i] = BUILTIN_SCHEMES[i].name;
        i += 1;
    }
    names
};

/// The sub-schemes a model of scheme `model_scheme` serves unless told otherwise: every
/// built-in subset of it served by default (ibug68: inner51, five, dlib5; any other scheme with
/// the anchors: five).
pub fn default_subsets(model_scheme: &str) -> Vec<String> {
    BUILTIN_SCHEMES
        .iter()
        .filter(|b| {
            matches!(
                b.served,
                Served::Subset {
                    by_default: true,
                    ..
                }
            )
        })
        .filter(|b| b.is_subset_of(model_scheme).is_some())
        .map(|b| b.name.to_string())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_row_builds_its_scheme_with_its_count() {
        for b in &BUILTIN_SCHEMES {
            match b.build() {
                Some(s) => {
                    assert_eq!(s.name, b.name);
                    assert_eq!(s.len(), b.points, "{}", b.name);
                    assert!(s.validate().is_ok(), "{}", b.name);
                }
                None => assert_eq!(b.served, Served::Mesh, "{}", b.name),
            }
            assert_eq!(BuiltinScheme::find(b.name).unwrap().name, b.name);
        }
    }

    /// A subset's point map, applied to its parent, gives the scheme it builds: the table and
    /// the builders agree.
    #[test]
    fn subset_maps_pick_the_built_schemes_points() {
        for b in &BUILTIN_SCHEMES {
            let Served::Subset {
                parent: Parent::Named(p),
                map,
                ..
            } = b.served
            else {
                continue;
            };
            let parent = BuiltinScheme::find(p).unwrap().build().unwrap();
            let idx = map.indices().unwrap();
            assert_eq!(idx.len(), b.points, "{}", b.name);
            let built = b.build().unwrap();
            if b.name == "inner51" {
                let picked: Vec<&String> = idx.iter().map(|&i| &parent.points[i]).collect();
                assert_eq!(picked, built.points.iter().collect::<Vec<_>>());
            }
        }
    }

    #[test]
    fn default_subsets_are_those_of_the_training_defaults() {
        assert_eq!(default_subsets("ibug68"), ["inner51", "five", "dlib5"]);
        assert!(default_subsets("five").is_empty());
        assert_eq!(default_subsets("my_points"), ["five"]);
    }

    #[test]
    fn point_classes() {
        assert_eq!(PointClass::of_scheme("dlib5", 5), PointClass::Dlib5);
        assert_eq!(PointClass::of_scheme("five", 5), PointClass::Five);
        assert_eq!(PointClass::of_scheme("my_five", 4), PointClass::Five);
        assert_eq!(
            PointClass::of_scheme("mediapipe478", 478),
            PointClass::Dense
        );
        assert_eq!(PointClass::of_scheme("my_dense", 30), PointClass::Dense);
    }
}
