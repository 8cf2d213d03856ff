//! Landmarks as clients send them, to the core's pixels: every coordinate finite and in range,
//! and MediaPipe's normalized coordinates (fractions of the image's width and height, see
//! `../shared/DESIGN.md`) scaled by the image size, with the checks that catch normalized
//! coordinates sent as pixels and the reverse. Numbers in, a [`Shape2`] out: the JSON that
//! carries them is `facepose-records`'.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::shape::Shape2;

/// The largest coordinate accepted, pixels: beyond it a value is not a pixel position and the
/// arithmetic of the estimators would overflow.
pub const MAX_COORDINATE: f64 = 1e9;

/// The shape of optional points (`None` = missing), after [`check_coordinates`].
pub fn shape_from_points(points: &[Option<[f64; 2]>]) -> Result<Shape2> {
    check_coordinates(points)?;
    Shape2::from_options(points)
}

/// The size of the image whose width and height normalized landmarks are fractions of
/// (MediaPipe's `x`, `y`), pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImageSize {
    /// Width, pixels.
    pub width: f64,
    /// Height, pixels.
    pub height: f64,
}

/// The largest image side accepted, pixels.
pub const MAX_IMAGE_SIDE: f64 = 100_000.0;

/// How far normalized coordinates may lie outside `[0, 1]`: MediaPipe reports the points of a
/// face that runs off the frame a little outside it.
pub const NORMALIZED_MARGIN: f64 = 0.25;

impl ImageSize {
    /// Checks that both sides are finite, positive and at most [`MAX_IMAGE_SIDE`].
    pub fn validate(&self) -> Result<()> {
        for (side, v) in [("width", self.width), ("height", self.height)] {
            if !(v.is_finite() && v > 0.0 && v <= MAX_IMAGE_SIDE) {
                return Err(Error::param(
                    "image_size",
                    format!(
                        "{side} = {v} must be a positive number of pixels, at most \
                         {MAX_IMAGE_SIDE}: send [width, height] of the image the landmarks \
                         were found in"
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// The landmarks in pixels from what a client sent. With `image_size`, they are normalized
/// coordinates (MediaPipe's): each must lie within `[0, 1]` (give or take
/// [`NORMALIZED_MARGIN`]) and is scaled by the width or height. Without it they are pixels, and
/// refused when every one lies within that range: normalized coordinates sent without the image
/// size would be taken for a face less than two pixels wide.
pub fn pixel_shape(points: &[Option<[f64; 2]>], image_size: Option<ImageSize>) -> Result<Shape2> {
    check_coordinates(points)?;
    let lo = -NORMALIZED_MARGIN;
    let hi = 1.0 + NORMALIZED_MARGIN;
    let inside = |v: f64| (lo..=hi).contains(&v);
    match image_size {
        Some(size) => {
            size.validate()?;
            let mut px = Vec::with_capacity(points.len());
            for (i, p) in points.iter().enumerate() {
                if let Some([x, y]) = *p {
                    if let Some((c, v)) =
                        [("x", x), ("y", y)].into_iter().find(|&(_, v)| !inside(v))
                    {
                        return Err(Error::param(
                            "landmarks",
                            format!(
                                "landmark {i} {c} = {v} is not a normalized coordinate: with \
                                 image_size, x and y are fractions of the image's width and \
                                 height, within [0, 1] (a face running off the frame may \
                                 reach {lo} to {hi}); for pixels, leave image_size out"
                            ),
                        ));
                    }
                    px.push(Some([x * size.width, y * size.height]));
                } else {
                    px.push(None);
                }
            }
            Shape2::from_options(&px)
        }
        None => {
            // In one pass over the present points, with no copy of them (a collected copy
            // regrew five times for 68 points: 3,500 of a pose request's instructions).
            let mut present = points.iter().flatten();
            let first = present.next().copied();
            let (mut n, mut spread, mut all_inside) = (0, false, true);
            if let Some(first) = first {
                n = 1;
                all_inside = inside(first[0]) && inside(first[1]);
                for p in present {
                    n += 1;
                    // Points all at one place are degenerate, which the estimator says.
                    spread |= *p != first;
                    all_inside &= inside(p[0]) & inside(p[1]);
                }
            }
            if n >= 3 && spread && all_inside {
                return Err(Error::param(
                    "landmarks",
                    "every landmark lies within [0, 1]: these look like normalized coordinates \
                     (MediaPipe's x, y), not pixels; send the image's size with them as \
                     image_size [width, height], or send pixels",
                ));
            }
            Shape2::from_options(points)
        }
    }
}

/// Checks that every coordinate of `points` is finite and within ±[`MAX_COORDINATE`]; errors
/// name the landmark.
pub fn check_coordinates(points: &[Option<[f64; 2]>]) -> Result<()> {
    // The usual case in one branch-light pass (a NaN fails `<=`, so it is never let through):
    // 28 instructions a point with the loop below, 11 with this one (callgrind).
    if points
        .iter()
        .flatten()
        .all(|[x, y]| x.abs() <= MAX_COORDINATE && y.abs() <= MAX_COORDINATE)
    {
        return Ok(());
    }
    for (i, p) in points.iter().enumerate() {
        for (c, v) in ["x", "y"].iter().zip(p.iter().flatten()) {
            if !v.is_finite() {
                return Err(Error::NonFinite {
                    what: format!("landmark {i} {c}"),
                });
            }
            if v.abs() > MAX_COORDINATE {
                return Err(Error::InvalidParameter {
                    name: "landmarks".into(),
                    reason: format!(
                        "landmark {i} {c} = {v:e} is out of range: pixel coordinates must be within ±{MAX_COORDINATE:e}"
                    ),
                });
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn size(width: f64, height: f64) -> Option<ImageSize> {
        Some(ImageSize { width, height })
    }

    #[test]
    fn normalized_landmarks_become_pixels_of_the_image() {
        let pts = [Some([0.25, 0.5]), None, Some([1.0, 0.0]), Some([0.5, 0.75])];
        let s = pixel_shape(&pts, size(1280.0, 720.0)).unwrap();
        assert_eq!(s.get(0).unwrap(), &nalgebra::Vector2::new(320.0, 360.0));
        assert!(s.get(1).is_none());
        assert_eq!(s.get(2).unwrap(), &nalgebra::Vector2::new(1280.0, 0.0));
        assert_eq!(s.get(3).unwrap(), &nalgebra::Vector2::new(640.0, 540.0));
        // A face running a little off the frame is still normalized.
        assert!(pixel_shape(&[Some([-0.1, 1.2])], size(640.0, 480.0)).is_ok());
    }

    #[test]
    fn pixels_said_to_be_normalized_are_refused() {
        let pts = [Some([0.3, 0.4]), Some([312.0, 0.5])];
        let e = pixel_shape(&pts, size(1280.0, 720.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("landmark 1 x = 312"), "{e}");
        assert!(e.contains("leave image_size out"), "{e}");
        for bad in [[0.0, 720.0], [f64::NAN, 720.0], [-5.0, 720.0], [2e5, 720.0]] {
            let e = pixel_shape(&pts[..1], size(bad[0], bad[1]))
                .unwrap_err()
                .to_string();
            assert!(e.contains("image_size"), "{e}");
        }
    }

    #[test]
    fn normalized_landmarks_sent_as_pixels_are_refused() {
        // MediaPipe's x, y from a 16:9 frame, sent without the image size.
        let pts = [
            Some([0.41, 0.38]),
            Some([0.55, 0.37]),
            Some([0.48, 0.5]),
            None,
        ];
        let e = pixel_shape(&pts, None).unwrap_err().to_string();
        assert!(e.contains("normalized") && e.contains("image_size"), "{e}");
        // A real face in pixels passes, as do fewer than three points (the estimator decides).
        assert!(
            pixel_shape(
                &[
                    Some([301.0, 240.0]),
                    Some([341.0, 240.0]),
                    Some([321.0, 265.0])
                ],
                None
            )
            .is_ok()
        );
        assert!(pixel_shape(&[Some([0.3, 0.4])], None).is_ok());
    }

    #[test]
    fn coordinates_must_be_finite_pixels() {
        let err = shape_from_points(&[Some([1.0, 2.0]), Some([3.0, f64::NAN])]).unwrap_err();
        assert!(err.to_string().contains("landmark 1 y"), "{err}");
        let err = shape_from_points(&[None, Some([1e308, 2.0])]).unwrap_err();
        assert!(
            err.to_string()
                .contains("landmark 1 x = 1e308 is out of range"),
            "{err}"
        );
        assert!(shape_from_points(&[Some([-1e9, 1e9]), None]).is_ok());
        let err = shape_from_points(&[Some([1.0, f64::NEG_INFINITY])]).unwrap_err();
        assert!(err.to_string().contains("landmark 0 y"), "{err}");
    }

    use proptest::strategy::Strategy;

    proptest::proptest! {
        /// Accepted exactly when every coordinate is finite and within the bound, and a refusal
        /// names the first coordinate that is not.
        #[test]
        fn coordinates_are_accepted_exactly_within_the_bound(
            points in proptest::collection::vec(
                proptest::option::of(proptest::array::uniform2(proptest::prop_oneof![
                    8 => -2e3f64..2e3,
                    1 => proptest::sample::select(vec![
                        MAX_COORDINATE, -MAX_COORDINATE, MAX_COORDINATE * (1.0 + 1e-15),
                        -1.5 * MAX_COORDINATE, f64::NAN, f64::INFINITY, f64::NEG_INFINITY,
                    ]),
                ])),
                0..80,
            )
        ) {
            let bad = points.iter().enumerate().find_map(|(i, p)| {
                p.iter().flatten().zip(["x", "y"]).find_map(|(v, c)| {
                    (!(v.is_finite() && v.abs() <= MAX_COORDINATE)).then(|| format!("landmark {i} {c}"))
                })
            });
            match (check_coordinates(&points), bad) {
                (Ok(()), None) => {}
                (Err(e), Some(at)) => proptest::prop_assert!(e.to_string().contains(&at), "{e} / {at}"),
                (got, want) => proptest::prop_assert!(false, "{got:?} where the first bad one is {want:?}"),
            }
        }

        /// Pixels are refused as normalized coordinates exactly when at least three points are
        /// present, not all at one place, and every coordinate is within the normalized range;
        /// else they come back as sent.
        #[test]
        fn pixels_are_refused_as_normalized_exactly_by_the_rule(
            points in proptest::prop_oneof![
                proptest::collection::vec(
                    proptest::option::of(proptest::array::uniform2(proptest::prop_oneof![
                        2 => proptest::sample::select(vec![0.0, 0.5, 1.0, -0.25, 1.25]),
                        2 => -0.3f64..1.3,
                        1 => -500.0f64..500.0,
                    ])),
                    0..12,
                ),
                // One point again and again, with gaps: no spread.
                (
                    proptest::array::uniform2(proptest::prop_oneof![-0.3f64..1.3, -500.0f64..500.0]),
                    proptest::collection::vec(proptest::bool::ANY, 0..12),
                )
                    .prop_map(|(p, on)| -> Vec<Option<[f64; 2]>> {
                        on.into_iter().map(|on| on.then_some(p)).collect()
                    }),
            ]
        ) {
            let present: Vec<[f64; 2]> = points.iter().flatten().copied().collect();
            let normalized = present.len() >= 3
                && present.iter().any(|p| *p != present[0])
                && present
                    .iter()
                    .flatten()
                    .all(|v| (-NORMALIZED_MARGIN..=1.0 + NORMALIZED_MARGIN).contains(v));
            match pixel_shape(&points, None) {
                Err(e) => proptest::prop_assert!(
                    normalized && e.to_string().contains("look like normalized"),
                    "{e}"
                ),
                Ok(s) => {
                    proptest::prop_assert!(!normalized);
                    proptest::prop_assert_eq!(s, Shape2::from_options(&points).unwrap());
                }
            }
        }
    }
}
