//! Weighted, centred moments of a 3D shape against its 2D landmarks: everything the
//! least-squares cost of a weak-perspective camera (`s (R X)ₓᵧ + t`) depends on. The rigid fit
//! iterates on them, and the residual and raw spread of an answer are read off them, each for
//! one pass over the points.

use nalgebra::{Matrix3, Matrix3x2, Matrix4, Rotation3, Vector2, Vector3, Vector4};

use super::image_to_plane;
use crate::estimate::dense::{self, madd};
use crate::shape::Shape2;

/// Weighted, centred first and second moments of the model points and the landmarks (y-up
/// plane coordinates).
#[derive(Debug, Clone, Copy)]
pub struct Moments {
    /// How many points are in use (weight above zero).
    pub n: usize,
    /// Sum of the weights.
    pub sw: f64,
    /// Weighted centroids of the model points and of the landmarks.
    pub cx: Vector3<f64>,
    /// Weighted centroid of the landmarks (y-up plane).
    pub cy: Vector2<f64>,
    /// `Σ w dx dxᵀ` of the centred model points.
    pub xx: Matrix3<f64>,
    /// `Σ w dx dyᵀ`, centred model points against centred landmarks.
    pub xy: Matrix3x2<f64>,
    /// `Σ w |dy|²` of the centred landmarks.
    pub yy: f64,
}

impl Moments {
    /// The moments of `model` against `y`, weighted by `w` (points of weight zero or below, or
    /// NaN, are left out). `model` and `y` must be finite.
    pub fn new(model: &[Vector3<f64>], y: &[Vector2<f64>], w: &[f64]) -> Moments {
        let len = model.len().min(y.len()).min(w.len());
        let (model, y, w) = (&model[..len], &y[..len], &w[..len]);
        let Some(first) = w.iter().position(|&w| w > 0.0) else {
            return Moments::none();
        };
        let origin = (model[first], y[first]);
        Moments::centred(origin, sums_of_points(model, y, w, origin))
    }

    /// The moments of `shape` against the present points of `landmarks` (image pixels, taken
    /// to the y-up plane), weighted by `weights` (one per point; one each when `None`; weights
    /// that are not finite and above zero leave their point out).
    pub fn of_landmarks(
        shape: &[Vector3<f64>],
        landmarks: &Shape2,
        weights: Option<&[f64]>,
    ) -> Moments {
        let (points, present) = (landmarks.points(), landmarks.present());
        let len = shape.len().min(points.len());
        let len = weights.map_or(len, |w| len.min(w.len()));
        let (shape, points, present) = (&shape[..len], &points[..len], &present[..len]);
        let weights = weights.map(|w| &w[..len]);
        let in_use =
            |i: usize| present[i] && weights.is_none_or(|w| w[i] > 0.0 && w[i].is_finite());
        let Some(first) = (0..len).find(|&i| in_use(i)) else {
            return Moments::none();
        };
        let origin = (shape[first], image_to_plane(&points[first]));
        Moments::centred(
            origin,
            sums_of_landmarks(shape, points, present, weights, origin),
        )
    }

    /// No point in use: NaN moments.
    fn none() -> Moments {
        Moments {
            n: 0,
            sw: 0.0,
            cx: Vector3::repeat(f64::NAN),
            cy: Vector2::repeat(f64::NAN),
            xx: Matrix3::repeat(f64::NAN),
            xy: Matrix3x2::repeat(f64::NAN),
            yy: f64::NAN,
        }
    }

    /// The moments from the sums relative to `(x0, p0)` ([`Sums`]).
    fn centred((x0, p0): (Vector3<f64>, Vector2<f64>), s: Sums) -> Moments {
        let sw = s[SW];
        let mx = Vector3::new(s[SX], s[SX + 1], s[SX + 2]) / sw;
        let my = Vector2::new(s[SY], s[SY + 1]) / sw;
        let xx = &s[XX..XX + 6];
        #[rustfmt::skip]
        let raw_xx = Matrix3::new(
            xx[0], xx[3], xx[4],
            xx[3], xx[1], xx[5],
            xx[4], xx[5], xx[2],
        );
        let xy = &s[XY..XY + 6];
        let raw_xy = Matrix3x2::new(xy[0], xy[1], xy[2], xy[3], xy[4], xy[5]);
        Moments {
            // A count of at most the number of points, exact in f64.
            n: s[N] as usize,
            sw,
            cx: x0 + mx,
            cy: p0 + my,
            xx: raw_xx - sw * mx * mx.transpose(),
            xy: raw_xy - sw * mx * my.transpose(),
            yy: (s[YY] - sw * my.norm_squared()).max(0.0),
        }
    }

    /// The translation that is optimal for `(r, s)`: centroid onto centroid.
    pub fn translation(&self, r: &Rotation3<f64>, s: f64) -> Vector2<f64> {
        self.cy - s * (r * self.cx).xy()
    }

    /// The scale that is optimal for `r` (with the optimal translation), and the cost there,
    /// `Σ w |s (R x)ₓᵧ + t - y|²`; `None` when the rotated points have no spread in the image
    /// plane.
    pub fn best_scale(&self, r: &Rotation3<f64>) -> Option<(f64, f64)> {
        let m = r.matrix();
        // (R M Rᵀ)₁₁ + (R M Rᵀ)₂₂ and r₁·eₓ + r₂·e_y, with eₓ, e_y the columns of `xy`.
        let rows = [0, 1].map(|k| m.row(k).transpose());
        let q_xy: f64 = rows.iter().map(|r| (self.xx * r).dot(r)).sum();
        let fit = rows[0].dot(&self.xy.column(0)) + rows[1].dot(&self.xy.column(1));
        // NaN moments have no best scale either.
        if q_xy.is_nan() || q_xy <= 0.0 {
            return None;
        }
        let s = fit / q_xy;
        Some((s, (self.yy - s * fit).max(0.0)))
    }

    /// `Σ w |s (R x)ₓᵧ + t - y|²` at the optimal translation, the `JᵀJ` and `Jᵀr` of the
    /// Gauss-Newton step in `(ω, s)` (`R ← exp([ω]×) R`; the translation decouples once the
    /// points are centred), from the moments alone.
    ///
    /// With `Q = R M Rᵀ` (`M` the model's second moment), `eₓ, e_y` the columns of `Σ w dx dyᵀ`
    /// and `rᵢ` the rows of `R`: the cost is `Σw|dy|² - 2 s (r₁·eₓ + r₂·e_y) + s² (Q₁₁ + Q₂₂)`;
    /// the Jacobian rows of a point, `(0, s q_z, -s q_y, q_x)` and `(-s q_z, 0, s q_x, q_y)` with
    /// `q = R dx`, sum to the terms below.
    pub fn normal_equations(
        &self,
        r: &Rotation3<f64>,
        s: f64,
    ) -> (f64, Matrix4<f64>, Vector4<f64>) {
        let m = r.matrix();
        let q = m * self.xx * m.transpose();
        let e = m * self.xy; // row i: rᵢ·eₓ, rᵢ·e_y
        let (q11, q22, q33) = (q[(0, 0)], q[(1, 1)], q[(2, 2)]);
        let (q13, q23) = (q[(0, 2)], q[(1, 2)]);
        let fit = e[(0, 0)] + e[(1, 1)];
        let cost = self.yy - 2.0 * s * fit + s * s * (q11 + q22);
        let s2 = s * s;
        #[rustfmt::skip]
        let jtj = Matrix4::new(
            s2 * q33,  0.0,       -s2 * q13,         -s * q23,
            0.0,       s2 * q33,  -s2 * q23,         s * q13,
            -s2 * q13, -s2 * q23, s2 * (q11 + q22),  0.0,
            -s * q23,  s * q13,   0.0,               q11 + q22,
        );
        let g = Vector4::new(
            s * e[(2, 1)] - s2 * q23,
            s2 * q13 - s * e[(2, 0)],
            s * (e[(1, 0)] - e[(0, 1)]),
            s * (q11 + q22) - fit,
        );
        (cost, jtj, g)
    }
}

/// The sums over the points in use, relative to an origin point (`x0`, `p0`): the count, `Σ w`,
/// `Σ w dx` (3), `Σ w dp` (2), `Σ w dx dxᵀ` (xx, yy, zz, xy, xz, yz), `Σ w dx dpᵀ` (row by row)
/// and `Σ w |dp|²`.
type Sums = [f64; 20];
const N: usize = 0;
const SW: usize = 1;
const SX: usize = 2;
const SY: usize = 5;
const XX: usize = 7;
const XY: usize = 13;
const YY: usize = 19;

/// Points a pass takes at a time, one a lane.
const LANES: usize = 4;

/// Adds four points (weights at or below zero, and NaN, count as zero) to the lanes of `acc`.
#[inline(always)]
fn add_lanes<const FMA: bool>(
    acc: &mut [[f64; LANES]; 20],
    x: &[Vector3<f64>; LANES],
    p: &[Vector2<f64>; LANES],
    w: &[f64; LANES],
    (x0, p0): (Vector3<f64>, Vector2<f64>),
) {
    for l in 0..LANES {
        let wl = if w[l] > 0.0 { w[l] } else { 0.0 };
        let (dx, dy, dz) = (x[l].x - x0.x, x[l].y - x0.y, x[l].z - x0.z);
        let (u, v) = (p[l].x - p0.x, p[l].y - p0.y);
        let (wx, wy, wz) = (wl * dx, wl * dy, wl * dz);
        acc[N][l] += f64::from(u8::from(wl > 0.0));
        acc[SW][l] += wl;
        acc[SX][l] += wx;
        acc[SX + 1][l] += wy;
        acc[SX + 2][l] += wz;
        acc[SY][l] = madd::<FMA>(wl, u, acc[SY][l]);
        acc[SY + 1][l] = madd::<FMA>(wl, v, acc[SY + 1][l]);
        acc[XX][l] = madd::<FMA>(wx, dx, acc[XX][l]);
        acc[XX + 1][l] = madd::<FMA>(wy, dy, acc[XX + 1][l]);
        acc[XX + 2][l] = madd::<FMA>(wz, dz, acc[XX + 2][l]);
        acc[XX + 3][l] = madd::<FMA>(wx, dy, acc[XX + 3][l]);
        acc[XX + 4][l] = madd::<FMA>(wx, dz, acc[XX + 4][l]);
        acc[XX + 5][l] = madd::<FMA>(wy, dz, acc[XX + 5][l]);
        acc[XY][l] = madd::<FMA>(wx, u, acc[XY][l]);
        acc[XY + 1][l] = madd::<FMA>(wx, v, acc[XY + 1][l]);
        acc[XY + 2][l] = madd::<FMA>(wy, u, acc[XY + 2][l]);
        acc[XY + 3][l] = madd::<FMA>(wy, v, acc[XY + 3][l]);
        acc[XY + 4][l] = madd::<FMA>(wz, u, acc[XY + 4][l]);
        acc[XY + 5][l] = madd::<FMA>(wz, v, acc[XY + 5][l]);
        acc[YY][l] = madd::<FMA>(wl, madd::<FMA>(u, u, v * v), acc[YY][l]);
    }
}

/// The lanes' sums.
#[inline(always)]
fn reduce(acc: &[[f64; LANES]; 20]) -> Sums {
    acc.map(|a| (a[0] + a[2]) + (a[1] + a[3]))
}

dense::kernel! {
    /// [`Sums`] of `model` against `y` (plane coordinates) weighted by `w`, four points at a
    /// time (the last group padded with the origin at weight zero).
    fn sums_of_points / sums_of_points_generic(
        model: &[Vector3<f64>],
        y: &[Vector2<f64>],
        w: &[f64],
        origin: (Vector3<f64>, Vector2<f64>)
    ) -> Sums {
        let mut acc = [[0.0; LANES]; 20];
        let (xs, x_rest) = model.as_chunks::<LANES>();
        let (ys, y_rest) = y.as_chunks::<LANES>();
        let (ws, w_rest) = w.as_chunks::<LANES>();
        for ((x4, y4), w4) in xs.iter().zip(ys).zip(ws) {
            add_lanes::<FMA>(&mut acc, x4, y4, w4, origin);
        }
        let (mut x4, mut y4, mut w4) = ([origin.0; LANES], [origin.1; LANES], [0.0; LANES]);
        x4[..x_rest.len()].copy_from_slice(x_rest);
        y4[..y_rest.len()].copy_from_slice(y_rest);
        w4[..w_rest.len()].copy_from_slice(w_rest);
        add_lanes::<FMA>(&mut acc, &x4, &y4, &w4, origin);
        reduce(&acc)
    }
}

dense::kernel! {
    /// [`Sums`] of `shape` against the present `points` (image pixels, taken to the y-up plane)
    /// weighted by `weights` (one each when `None`; weights that are not finite leave their
    /// point out), four points at a time.
    fn sums_of_landmarks / sums_of_landmarks_generic(
        shape: &[Vector3<f64>],
        points: &[Vector2<f64>],
        present: &[bool],
        weights: Option<&[f64]>,
        origin: (Vector3<f64>, Vector2<f64>)
    ) -> Sums {
        let mut acc = [[0.0; LANES]; 20];
        let weight = |on: bool, w: f64| if on && w.is_finite() { w } else { 0.0 };
        let (xs, x_rest) = shape.as_chunks::<LANES>();
        let (ps, p_rest) = points.as_chunks::<LANES>();
        let (ons, on_rest) = present.as_chunks::<LANES>();
        let plane = |p4: &[Vector2<f64>; LANES]| p4.map(|p| image_to_plane(&p));
        match weights {
            None => {
                for ((x4, p4), on4) in xs.iter().zip(ps).zip(ons) {
                    let w4 = on4.map(|on| f64::from(u8::from(on)));
                    add_lanes::<FMA>(&mut acc, x4, &plane(p4), &w4, origin);
                }
            }
            Some(w) => {
                for (((x4, p4), on4), w4) in xs.iter().zip(ps).zip(ons).zip(w.as_chunks::<LANES>().0) {
                    let w4 = std::array::from_fn(|l| weight(on4[l], w4[l]));
                    add_lanes::<FMA>(&mut acc, x4, &plane(p4), &w4, origin);
                }
            }
        }
        // The last points, padded with the origin at weight zero.
        let (mut x4, mut p4, mut w4) = ([origin.0; LANES], [origin.1; LANES], [0.0; LANES]);
        let first = LANES * xs.len();
        for l in 0..x_rest.len() {
            x4[l] = x_rest[l];
            p4[l] = image_to_plane(&p_rest[l]);
            w4[l] = weight(on_rest[l], weights.map_or(1.0, |w| w[first + l]));
        }
        add_lanes::<FMA>(&mut acc, &x4, &p4, &w4, origin);
        reduce(&acc)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::EulerAngles;

    fn points() -> (Vec<Vector3<f64>>, Vec<Vector2<f64>>, Vec<f64>) {
        let x: Vec<Vector3<f64>> = (0..12)
            .map(|i| {
                let f = f64::from(i);
                Vector3::new(
                    30.0 * (0.7 * f).sin(),
                    25.0 * (1.3 * f).cos(),
                    10.0 * (0.4 * f).sin(),
                )
            })
            .collect();
        // Landmarks far from the origin, as image coordinates are.
        let y: Vec<Vector2<f64>> = x
            .iter()
            .enumerate()
            .map(|(i, p)| Vector2::new(5e4 + 2.0 * p.x + (i % 3) as f64, -7e4 + 2.0 * p.y))
            .collect();
        let w = (0..12).map(|i| [1.0, 0.5, 0.0, 2.0][i % 4]).collect();
        (x, y, w)
    }

    /// The one-pass moments equal the two-pass definition: centroids first, then the sums of
    /// the centred points.
    #[test]
    fn one_pass_moments_equal_the_centred_sums() {
        let (x, y, w) = points();
        let m = Moments::new(&x, &y, &w);
        let sw: f64 = w.iter().sum();
        let cx = x.iter().zip(&w).map(|(p, &w)| w * p).sum::<Vector3<f64>>() / sw;
        let cy = y.iter().zip(&w).map(|(p, &w)| w * p).sum::<Vector2<f64>>() / sw;
        let (mut xx, mut xy, mut yy) = (Matrix3::zeros(), Matrix3x2::zeros(), 0.0);
        for ((p, q), &wi) in x.iter().zip(&y).zip(&w) {
            let (dx, dq) = (p - cx, q - cy);
            xx += wi * dx * dx.transpose();
            xy += wi * dx * dq.transpose();
            yy += wi * dq.norm_squared();
        }
        assert_eq!((m.n, m.sw), (9, sw));
        assert!((m.cx - cx).norm() < 1e-12 && (m.cy - cy).norm() < 1e-9);
        assert!((m.xx - xx).norm() < 1e-9 * xx.norm());
        assert!((m.xy - xy).norm() < 1e-9 * xy.norm());
        assert!((m.yy - yy).abs() < 1e-9 * yy);
    }

    /// Landmarks that are an exact view at scale 2: the best scale for the true rotation is 2
    /// and leaves no residual.
    #[test]
    fn best_scale_of_an_exact_view() {
        let (x, _, w) = points();
        let r = EulerAngles::new(20.0, -35.0, 10.0).unwrap().to_rotation();
        let y: Vec<Vector2<f64>> = x
            .iter()
            .map(|p| 2.0 * (r * p).xy() + Vector2::new(300.0, -200.0))
            .collect();
        let m = Moments::new(&x, &y, &w);
        let (s, cost) = m.best_scale(&r).unwrap();
        assert!((s - 2.0).abs() < 1e-12, "{s}");
        assert!(cost < 1e-9 * m.yy, "{cost}");
        assert!((m.translation(&r, s) - Vector2::new(300.0, -200.0)).norm() < 1e-9);
        assert!(m.normal_equations(&r, s).0.abs() < 1e-9 * m.yy);
    }

    /// Moments of landmarks (image pixels, some missing, weights some of which leave their
    /// point out) equal those of the same points in the plane with those points at weight zero,
    /// whatever the count's remainder by four.
    #[test]
    fn landmark_moments_equal_the_masked_ones() {
        let (x, y, _) = points();
        for len in [4, 5, 6, 7, 12] {
            let x = &x[..len];
            let image: Vec<Option<[f64; 2]>> = y[..len]
                .iter()
                .enumerate()
                .map(|(i, p)| (i % 5 != 1).then_some([p.x, -p.y]))
                .collect();
            let lm = Shape2::from_options(&image).unwrap();
            let w: Vec<f64> = [2.0, 1.0, f64::NAN, 0.5, f64::INFINITY, -1.0, 3.0]
                .into_iter()
                .cycle()
                .take(len)
                .collect();
            let masked = |w: &dyn Fn(usize) -> f64| -> Vec<f64> {
                (0..len)
                    .map(|i| {
                        if lm.present()[i] && w(i).is_finite() {
                            w(i)
                        } else {
                            0.0
                        }
                    })
                    .collect()
            };
            for (weights, want) in [(None, masked(&|_| 1.0)), (Some(&w[..]), masked(&|i| w[i]))] {
                let got = Moments::of_landmarks(x, &lm, weights);
                let want = Moments::new(x, &y[..len], &want);
                assert_eq!((got.n, got.sw), (want.n, want.sw), "{len} points");
                assert!((got.cx - want.cx).norm() < 1e-9 && (got.cy - want.cy).norm() < 1e-6);
                assert!((got.xx - want.xx).norm() < 1e-9 * want.xx.norm().max(1.0));
                assert!((got.xy - want.xy).norm() < 1e-9 * want.xy.norm().max(1.0));
                assert!((got.yy - want.yy).abs() < 1e-9 * want.yy.max(1.0));
            }
        }
    }

    #[test]
    fn no_point_in_use_gives_nan() {
        let (x, y, _) = points();
        let m = Moments::new(&x, &y, &[0.0; 12]);
        assert_eq!((m.n, m.sw), (0, 0.0));
        assert!(m.yy.is_nan() && m.xx[(0, 0)].is_nan());
    }
}
