//! The JSON of a request's `conventions` and `camera_orientation` (docs/API.md, "Answers in
//! your convention"), read into the core's values as the request is decoded, so that a bad one
//! is refused (422) with the core's message before any face is estimated.

use facepose_core::geometry::convention::request::check_unique;
use facepose_core::geometry::convention::{Axes, CameraOrientation, ConventionRequest, EulerSpec};
use serde::Deserialize;
use serde::de::Error as _;
use serde_json::{Map, Value};
use utoipa::openapi::RefOr;
use utoipa::openapi::schema::{ArrayBuilder, ObjectBuilder, OneOfBuilder, Schema, Type};

/// The conventions a request names, each a name (`"quaternion"`) or an object with its name
/// and string parameters (`{"name": "euler", "order": "zyx", "units": "radians"}`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Conventions(pub Vec<ConventionRequest>);

/// The longest list: one of each convention.
const MAX_CONVENTIONS: usize = ConventionRequest::NAMES.len();

impl<'de> Deserialize<'de> for Conventions {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let items = Vec::<Value>::deserialize(d)?;
        if items.len() > MAX_CONVENTIONS {
            return Err(D::Error::custom(format!(
                "conventions: {} items; name each convention at most once (there are {MAX_CONVENTIONS})",
                items.len()
            )));
        }
        let mut out = Vec::with_capacity(items.len());
        for item in &items {
            let request = match item {
                Value::String(name) => ConventionRequest::parse(name, &[]),
                Value::Object(members) => {
                    let (name, params) = name_and_params(members, "conventions")?;
                    ConventionRequest::parse(
                        &name,
                        &params
                            .iter()
                            .map(|(k, v)| (k.as_str(), v.as_str()))
                            .collect::<Vec<_>>(),
                    )
                }
                other => {
                    return Err(D::Error::custom(format!(
                        "conventions: each item is a name or {{\"name\": ..., parameters}}, found {other}"
                    )));
                }
            };
            out.push(request.map_err(D::Error::custom)?);
        }
        check_unique(&out).map_err(D::Error::custom)?;
        Ok(Conventions(out))
    }
}

/// An object's `name` and its other members, each a string.
fn name_and_params<E: serde::de::Error>(
    members: &Map<String, Value>,
    what: &str,
) -> Result<(String, Vec<(String, String)>), E> {
    let mut name = None;
    let mut params = Vec::with_capacity(members.len());
    for (k, v) in members {
        let Value::String(v) = v else {
            return Err(E::custom(format!(
                "{what}: {k} must be a string, found {v}"
            )));
        };
        if k == "name" {
            name = Some(v.clone());
        } else {
            params.push((k.clone(), v.clone()));
        }
    }
    let name = name.ok_or_else(|| E::custom(format!("{what}: an object item needs a \"name\"")))?;
    Ok((name, params))
}

impl utoipa::PartialSchema for Conventions {
    fn schema() -> RefOr<Schema> {
        let names: Vec<Value> = ConventionRequest::NAMES.iter().map(|&n| n.into()).collect();
        let by_name = ObjectBuilder::new()
            .schema_type(Type::String)
            .enum_values(Some(names.clone()));
        let with_params = ObjectBuilder::new()
            .property(
                "name",
                ObjectBuilder::new()
                    .schema_type(Type::String)
                    .enum_values(Some(names)),
            )
            .required("name")
            .additional_properties(Some(ObjectBuilder::new().schema_type(Type::String)));
        ArrayBuilder::new()
            .items(OneOfBuilder::new().item(by_name).item(with_params))
            .max_items(Some(MAX_CONVENTIONS))
            .description(Some(
                "The conventions to answer in besides facepose's own, each a name or \
                 {\"name\": ..., parameters as strings}: quaternion, euler (preset, order, kind, \
                 units, axes, matrices), opencv (object_frame), mediapipe. The answer gains one \
                 object per name under `conventions`.",
            ))
            .into()
    }
}

impl utoipa::ToSchema for Conventions {}

/// The camera's orientation in the world: `{"matrix": [[...], [...], [...]]}`,
/// `{"quaternion": {"w": .., "x": .., "y": .., "z": ..}}` (each with an optional `"axes"`,
/// default `RUB`) or
/// `{"euler": {Euler parameters as for the euler convention, "angles": [a, b, c]}}`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Orientation(pub CameraOrientation);

impl<'de> Deserialize<'de> for Orientation {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let members = Map::<String, Value>::deserialize(d)?;
        let what = "camera_orientation";
        let axes = match members.get("axes") {
            None => Axes::FACEPOSE,
            Some(Value::String(a)) => Axes::parse(a).map_err(D::Error::custom)?,
            Some(other) => {
                return Err(D::Error::custom(format!(
                    "{what}: axes must be a string, found {other}"
                )));
            }
        };
        let forms: Vec<&str> = ["matrix", "quaternion", "euler"]
            .into_iter()
            .filter(|k| members.contains_key(*k))
            .collect();
        if let Some(k) = members
            .keys()
            .find(|k| !["matrix", "quaternion", "euler", "axes"].contains(&k.as_str()))
        {
            return Err(D::Error::custom(format!(
                "{what}: unknown member {k:?}; give one of matrix, quaternion or euler (and axes)"
            )));
        }
        let orientation = match forms.as_slice() {
            ["matrix"] => {
                let rows: [[f64; 3]; 3] = serde_json::from_value(members["matrix"].clone())
                    .map_err(|_| {
                        D::Error::custom(format!("{what}: matrix must be 3 rows of 3 numbers"))
                    })?;
                CameraOrientation::from_rows(rows, axes)
            }
            ["quaternion"] => {
                let q = &members["quaternion"];
                let parts: [Option<f64>; 4] = match q {
                    Value::Object(_) => {
                        ["w", "x", "y", "z"].map(|k| q.get(k).and_then(Value::as_f64))
                    }
                    Value::Array(a) if a.len() == 4 => std::array::from_fn(|i| a[i].as_f64()),
                    _ => [None; 4],
                };
                let [Some(w), Some(x), Some(y), Some(z)] = parts else {
                    return Err(D::Error::custom(format!(
                        "{what}: quaternion must be {{\"w\": .., \"x\": .., \"y\": .., \"z\": ..}} \
                         (or [w, x, y, z]), numbers"
                    )));
                };
                CameraOrientation::from_quaternion(w, x, y, z, axes)
            }
            ["euler"] => {
                let Value::Object(euler) = &members["euler"] else {
                    return Err(D::Error::custom(format!(
                        "{what}: euler must be an object of Euler parameters with \"angles\""
                    )));
                };
                let angles: [f64; 3] = euler
                    .get("angles")
                    .and_then(|a| serde_json::from_value(a.clone()).ok())
                    .ok_or_else(|| {
                        D::Error::custom(format!("{what}: euler needs \"angles\": [a, b, c]"))
                    })?;
                let mut params = Vec::new();
                for (k, v) in euler.iter().filter(|(k, _)| *k != "angles") {
                    let Value::String(v) = v else {
                        return Err(D::Error::custom(format!(
                            "{what}: euler {k} must be a string, found {v}"
                        )));
                    };
                    params.push((k.as_str(), v.as_str()));
                }
                let spec = EulerSpec::from_params(&params).map_err(D::Error::custom)?;
                CameraOrientation::from_euler(&spec, angles)
            }
            _ => {
                return Err(D::Error::custom(format!(
                    "{what}: give exactly one of matrix, quaternion or euler"
                )));
            }
        };
        orientation.map(Orientation).map_err(D::Error::custom)
    }
}

impl utoipa::PartialSchema for Orientation {
    fn schema() -> RefOr<Schema> {
        let number = || ObjectBuilder::new().schema_type(Type::Number);
        let row = ArrayBuilder::new()
            .items(number())
            .min_items(Some(3))
            .max_items(Some(3));
        let axes = || ObjectBuilder::new().schema_type(Type::String);
        OneOfBuilder::new()
            .item(
                ObjectBuilder::new()
                    .property(
                        "matrix",
                        ArrayBuilder::new()
                            .items(row)
                            .min_items(Some(3))
                            .max_items(Some(3)),
                    )
                    .property("axes", axes())
                    .required("matrix"),
            )
            .item(
                ObjectBuilder::new()
                    .property(
                        "quaternion",
                        ObjectBuilder::new()
                            .property("w", number())
                            .property("x", number())
                            .property("y", number())
                            .property("z", number())
                            .required("w")
                            .required("x")
                            .required("y")
                            .required("z"),
                    )
                    .property("axes", axes())
                    .required("quaternion"),
            )
            .item(
                ObjectBuilder::new()
                    .property(
                        "euler",
                        ObjectBuilder::new()
                            .property(
                                "angles",
                                ArrayBuilder::new()
                                    .items(number())
                                    .min_items(Some(3))
                                    .max_items(Some(3)),
                            )
                            .required("angles"),
                    )
                    .required("euler"),
            )
            .description(Some(
                "The camera's orientation in the world (a tilted webcam, a car's camera): the \
                 conventions' answers then give the head's pose in the world.",
            ))
            .into()
    }
}

impl utoipa::ToSchema for Orientation {}
