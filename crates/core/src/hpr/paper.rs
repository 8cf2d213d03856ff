//! The paper's hidden-point removal (Heo & Savvides 2011, §3.3), for a camera on the +z axis at
//! infinity (weak perspective):
//!
//! 1. triangulate the shape (Delaunay of the frontal shape, [`Triangulation`]);
//! 2. compute each triangle's normal `(S2 - S1) × (S3 - S1)` in the rotated shape;
//! 3. a triangle whose normal makes 90° or more with the viewing direction faces backwards; a
//!    point all of whose triangles face backwards is hidden;
//! 4. a remaining point that projects inside a triangle it does not belong to, and lies behind
//!    that triangle's centre of gravity as seen from the camera, is occluded by it.

use nalgebra::Vector3;

use super::triangulation::Triangulation;
use crate::error::{Error, Result};

/// How step 4 decides that a point is behind a triangle it projects into.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthTest {
    /// The paper's rule: compare with the depth of the triangle's centre of gravity.
    Centroid,
    /// Compare with the triangle's own depth at the point (its plane, interpolated).
    Plane,
}

/// A reusable HPR operator for one shape's triangulation.
#[derive(Debug, Clone)]
pub struct PaperHpr {
    tri: Triangulation,
    depth_test: DepthTest,
    /// Tolerance of step 4, relative to the shape's size.
    rel_eps: f64,
}

/// Per-call work space of [`PaperHpr::visibility_into`], to keep the hot path free of
/// allocation.
#[derive(Debug, Default, Clone)]
pub struct HprScratch {
    /// Each triangle's projected bounding box and centroid depth: `[x0, x1, y0, y1, z]`.
    boxes: Vec<[f64; 5]>,
    /// The triangles by cell of a uniform grid over the boxes (for [`GRID_FROM`] triangles or
    /// more): cell `c` holds `cell_items[cell_start[c]..cell_start[c + 1]]`.
    cell_start: Vec<u32>,
    cell_items: Vec<u32>,
    /// Where the next triangle of each cell goes while the grid fills.
    cell_fill: Vec<u32>,
}

/// From this many triangles step 4 looks a point up in a uniform grid of the triangles'
/// bounding boxes instead of testing every box: a point then costs a few box tests instead of
/// one per triangle. Training computes HPR on its shape or mesh at every view (it took 84% of a
/// retraining job's time, and 45% with a 68-point shape): the 468-vertex mesh's 898 triangles
/// went from 2.19 ms to 106 µs a pose, a 68-point shape's 110 or so from 19.7-22.5 to 7.4-7.8
/// µs (`cargo bench -p facepose-core --bench hpr -- "hpr/paper"`, the grid off and on in one
/// session). Below this, a handful of triangles (a five-point shape), the plain loop is as
/// cheap as building the grid. Either way the same triangles are tested, so the answer is the
/// same bit for bit.
pub const GRID_FROM: usize = 32;

impl PaperHpr {
    /// HPR over a triangulation with the paper's centroid depth test.
    pub fn new(tri: Triangulation) -> Self {
        PaperHpr {
            tri,
            depth_test: DepthTest::Centroid,
            rel_eps: 1e-9,
        }
    }

    /// HPR over the Delaunay triangulation of a frontal shape.
    pub fn from_frontal(frontal: &[Vector3<f64>]) -> Result<Self> {
        Ok(Self::new(Triangulation::delaunay_frontal(frontal)?))
    }

    /// The same operator with another depth test in step 4.
    pub fn with_depth_test(mut self, depth_test: DepthTest) -> Self {
        self.depth_test = depth_test;
        self
    }

    /// The triangulation it works on.
    pub fn triangulation(&self) -> &Triangulation {
        &self.tri
    }

    /// Visibility of each point of `rotated` (the shape already rotated into the camera frame).
    pub fn visibility(&self, rotated: &[Vector3<f64>]) -> Result<Vec<bool>> {
        let mut out = vec![false; rotated.len()];
        self.visibility_into(rotated, &mut HprScratch::default(), &mut out)?;
        Ok(out)
    }

    /// [`PaperHpr::visibility`] into `out`, reusing `scratch`.
    pub fn visibility_into(
        &self,
        rotated: &[Vector3<f64>],
        scratch: &mut HprScratch,
        out: &mut [bool],
    ) -> Result<()> {
        let n = self.tri.n_points();
        if rotated.len() != n || out.len() != n {
            return Err(Error::PointCount {
                what: "HPR shape".into(),
                expected: n,
                got: rotated.len().min(out.len()),
            });
        }
        if rotated.iter().any(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(Error::non_finite("HPR points"));
        }
        let tris = self.tri.triangles();
        scratch.boxes.clear();
        // Steps 2-3: normals and back-facing test; a point is visible if any of its
        // triangles faces the camera.
        out.fill(false);
        let mut extent = 0.0f64;
        for t in tris {
            let (a, b, c) = (rotated[t[0]], rotated[t[1]], rotated[t[2]]);
            let nz = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
            if nz > 0.0 {
                for &i in t {
                    out[i] = true;
                }
            }
            let (x0, x1) = (a.x.min(b.x).min(c.x), a.x.max(b.x).max(c.x));
            let (y0, y1) = (a.y.min(b.y).min(c.y), a.y.max(b.y).max(c.y));
            extent = extent.max(x1 - x0).max(y1 - y0);
            scratch
                .boxes
                .push([x0, x1, y0, y1, (a.z + b.z + c.z) / 3.0]);
        }
        // Step 4: depth test of the remaining points against triangles they project into.
        let eps = self.rel_eps * extent.max(1e-300);
        let grid = if tris.len() >= GRID_FROM {
            Grid::build(scratch)
        } else {
            None
        };
        for (i, p) in rotated.iter().enumerate() {
            if !out[i] {
                continue;
            }
            let occluded = match &grid {
                Some(g) => g.cell_of(p).is_some_and(|c| {
                    let range = scratch.cell_start[c] as usize..scratch.cell_start[c + 1] as usize;
                    scratch.cell_items[range]
                        .iter()
                        .any(|&k| self.occludes(k as usize, i, p, rotated, &scratch.boxes, eps))
                }),
                None => {
                    (0..tris.len()).any(|k| self.occludes(k, i, p, rotated, &scratch.boxes, eps))
                }
            };
            if occluded {
                out[i] = false;
            }
        }
        Ok(())
    }

    /// Whether triangle `k` (not one of point `i`'s own) hides point `i` at `p`: `p` projects
    /// strictly inside it and lies behind it by more than `eps`.
    fn occludes(
        &self,
        k: usize,
        i: usize,
        p: &Vector3<f64>,
        rotated: &[Vector3<f64>],
        boxes: &[[f64; 5]],
        eps: f64,
    ) -> bool {
        let [x0, x1, y0, y1, zc] = boxes[k];
        let t = &self.tri.triangles()[k];
        if p.x < x0 || p.x > x1 || p.y < y0 || p.y > y1 || t.contains(&i) {
            return false;
        }
        let (a, b, c) = (rotated[t[0]], rotated[t[1]], rotated[t[2]]);
        let Some((wa, wb, wc)) = barycentric(p, &a, &b, &c, eps) else {
            return false;
        };
        let depth = match self.depth_test {
            DepthTest::Centroid => zc,
            DepthTest::Plane => wa * a.z + wb * b.z + wc * c.z,
        };
        depth > p.z + eps
    }
}

/// A uniform grid over the triangles' bounding boxes, its cells filled into the scratch's
/// `cell_start`/`cell_items`. Cell indices are `floor((x - x0) / width)`, which never
/// decreases as `x` grows, so a box that holds a point always lists its triangle in the point's
/// cell.
struct Grid {
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    cell_w: f64,
    cell_h: f64,
    side: usize,
}

impl Grid {
    /// The grid of `scratch.boxes` (about two triangles a cell), or `None` for boxes with no
    /// area between them (then every box is tested).
    fn build(scratch: &mut HprScratch) -> Option<Grid> {
        let boxes = &scratch.boxes;
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for b in boxes {
            x0 = x0.min(b[0]);
            x1 = x1.max(b[1]);
            y0 = y0.min(b[2]);
            y1 = y1.max(b[3]);
        }
        let side = ((boxes.len() as f64 / 2.0).sqrt().ceil() as usize).clamp(1, 64);
        let (cell_w, cell_h) = ((x1 - x0) / side as f64, (y1 - y0) / side as f64);
        if !(cell_w > 0.0 && cell_h > 0.0) {
            return None;
        }
        let g = Grid {
            x0,
            x1,
            y0,
            y1,
            cell_w,
            cell_h,
            side,
        };
        let cells = side * side;
        scratch.cell_start.clear();
        scratch.cell_start.resize(cells + 1, 0);
        for b in boxes {
            g.for_cells(b, |c| scratch.cell_start[c + 1] += 1);
        }
        for c in 0..cells {
            scratch.cell_start[c + 1] += scratch.cell_start[c];
        }
        scratch.cell_items.clear();
        scratch
            .cell_items
            .resize(scratch.cell_start[cells] as usize, 0);
        scratch.cell_fill.clear();
        scratch
            .cell_fill
            .extend_from_slice(&scratch.cell_start[..cells]);
        for (k, b) in boxes.iter().enumerate() {
            g.for_cells(b, |c| {
                scratch.cell_items[scratch.cell_fill[c] as usize] = k as u32;
                scratch.cell_fill[c] += 1;
            });
        }
        Some(g)
    }

    fn column(&self, x: f64) -> usize {
        (((x - self.x0) / self.cell_w) as usize).min(self.side - 1)
    }

    fn row(&self, y: f64) -> usize {
        (((y - self.y0) / self.cell_h) as usize).min(self.side - 1)
    }

    /// Calls `f` with every cell that box `b` overlaps.
    fn for_cells(&self, b: &[f64; 5], mut f: impl FnMut(usize)) {
        for r in self.row(b[2])..=self.row(b[3]) {
            for c in self.column(b[0])..=self.column(b[1]) {
                f(r * self.side + c);
            }
        }
    }

    /// The cell of `p`, or `None` outside the grid (then no box holds it).
    fn cell_of(&self, p: &Vector3<f64>) -> Option<usize> {
        let inside = p.x >= self.x0 && p.x <= self.x1 && p.y >= self.y0 && p.y <= self.y1;
        inside.then(|| self.row(p.y) * self.side + self.column(p.x))
    }
}

/// Barycentric coordinates of `p`'s projection in the triangle's projection, if it lies
/// strictly inside (by more than `eps`); `None` outside or for a degenerate projection.
fn barycentric(
    p: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
    eps: f64,
) -> Option<(f64, f64, f64)> {
    let det = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
    if det.abs() < eps * eps {
        return None;
    }
    let wb = ((p.x - a.x) * (c.y - a.y) - (p.y - a.y) * (c.x - a.x)) / det;
    let wc = ((b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)) / det;
    let wa = 1.0 - wb - wc;
    let tol = 1e-12;
    (wa > tol && wb > tol && wc > tol).then_some((wa, wb, wc))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::EulerAngles;

    /// A pyramid: a square base at z = 0 and an apex at z = 10 in front of it.
    fn pyramid() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(-10.0, -10.0, 0.0),
            Vector3::new(10.0, -10.0, 0.0),
            Vector3::new(10.0, 10.0, 0.0),
            Vector3::new(-10.0, 10.0, 0.0),
            Vector3::new(0.0, 0.0, 10.0),
        ]
    }

    #[test]
    fn frontal_view_sees_everything() {
        let hpr = PaperHpr::from_frontal(&pyramid()).unwrap();
        assert_eq!(hpr.visibility(&pyramid()).unwrap(), vec![true; 5]);
    }

    #[test]
    fn turned_away_hides_everything() {
        let hpr = PaperHpr::from_frontal(&pyramid()).unwrap();
        let r = EulerAngles::new(0.0, 180.0, 0.0).unwrap().to_rotation();
        let rotated: Vec<_> = pyramid().iter().map(|p| r * p).collect();
        assert_eq!(hpr.visibility(&rotated).unwrap(), vec![false; 5]);
    }

    #[test]
    fn a_point_behind_a_facing_triangle_is_occluded() {
        // Three points in front (z = 10) around a fourth far behind them (z = -50).
        let frontal = vec![
            Vector3::new(-10.0, -10.0, 10.0),
            Vector3::new(10.0, -10.0, 10.0),
            Vector3::new(0.0, 10.0, 10.0),
            Vector3::new(30.0, 0.0, -50.0),
        ];
        let hpr = PaperHpr::from_frontal(&frontal).unwrap();
        // Slide point 3 behind the big triangle (as a rotation would) and test.
        let mut moved = frontal.clone();
        moved[3] = Vector3::new(0.0, -2.0, -50.0);
        for test in [DepthTest::Centroid, DepthTest::Plane] {
            let v = hpr
                .clone()
                .with_depth_test(test)
                .visibility(&moved)
                .unwrap();
            assert!(!v[3], "{test:?}");
            assert!(v[0] && v[1] && v[2]);
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let hpr = PaperHpr::from_frontal(&pyramid()).unwrap();
        assert!(hpr.visibility(&pyramid()[..4]).is_err());
        let mut nan = pyramid();
        nan[0].x = f64::NAN;
        assert!(hpr.visibility(&nan).is_err());
    }

    /// A bumpy surface of 21 x 21 points (a dome with ripples), dense enough for the grid
    /// ([`GRID_FROM`]) and rough enough to hide points behind others when turned.
    fn bumpy() -> Vec<Vector3<f64>> {
        bumpy_of(21)
    }

    /// The same surface sampled `side` x `side` times: 9 x 9 points have about as many
    /// triangles as a 68-point face.
    fn bumpy_of(side: usize) -> Vec<Vector3<f64>> {
        let step = 100.0 / (side - 1) as f64;
        let mut v = Vec::new();
        for r in 0..side {
            for c in 0..side {
                let (x, y) = (
                    c as f64 * step - 50.0,
                    r as f64 * step - 50.0 + 0.37 * c as f64,
                );
                let z = 30.0 * (-(x * x + y * y) / 300.0).exp()
                    + 10.0 * (x / 8.0).sin() * (y / 9.0).cos();
                v.push(Vector3::new(x, y, z));
            }
        }
        v
    }

    /// Step 4 over every triangle, the plain loop the grid must agree with.
    fn every_triangle(hpr: &PaperHpr, rotated: &[Vector3<f64>]) -> Vec<bool> {
        let mut scratch = HprScratch::default();
        let mut out = vec![false; rotated.len()];
        // Steps 2-3 and the boxes, from the operator itself on the same points.
        hpr.visibility_into(rotated, &mut scratch, &mut out)
            .unwrap();
        let mut extent = 0.0f64;
        for b in &scratch.boxes {
            extent = extent.max(b[1] - b[0]).max(b[3] - b[2]);
        }
        let eps = hpr.rel_eps * extent.max(1e-300);
        let tris = hpr.tri.triangles();
        let mut facing = vec![false; rotated.len()];
        for t in tris {
            let (a, b, c) = (rotated[t[0]], rotated[t[1]], rotated[t[2]]);
            if (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x) > 0.0 {
                for &i in t {
                    facing[i] = true;
                }
            }
        }
        (0..rotated.len())
            .map(|i| {
                facing[i]
                    && !(0..tris.len())
                        .any(|k| hpr.occludes(k, i, &rotated[i], rotated, &scratch.boxes, eps))
            })
            .collect()
    }

    #[test]
    fn a_face_sized_mesh_uses_the_grid() {
        let tris = PaperHpr::from_frontal(&bumpy_of(9))
            .unwrap()
            .triangulation()
            .triangles()
            .len();
        assert!((GRID_FROM..200).contains(&tris), "{tris}");
    }

    #[test]
    fn the_grid_is_used_and_hides_points() {
        let shape = bumpy();
        let hpr = PaperHpr::from_frontal(&shape).unwrap();
        assert!(hpr.triangulation().triangles().len() >= GRID_FROM);
        let r = EulerAngles::new(60.0, 20.0, 10.0).unwrap().to_rotation();
        let rotated: Vec<_> = shape.iter().map(|p| r * p).collect();
        let v = hpr.visibility(&rotated).unwrap();
        assert_eq!(v, every_triangle(&hpr, &rotated));
        // Some points face the camera yet are hidden by step 4 (not only back-facing ones).
        let mut scratch = HprScratch::default();
        let mut out = vec![false; shape.len()];
        hpr.visibility_into(&rotated, &mut scratch, &mut out)
            .unwrap();
        let hidden_by_step_4 = (0..shape.len())
            .filter(|&i| {
                !v[i]
                    && hpr.tri.triangles().iter().any(|t| {
                        t.contains(&i) && {
                            let (a, b, c) = (rotated[t[0]], rotated[t[1]], rotated[t[2]]);
                            (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x) > 0.0
                        }
                    })
            })
            .count();
        assert!(hidden_by_step_4 >= 5, "{hidden_by_step_4}");
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]

        /// The grid tests the same triangles as the plain loop: the same answer at any pose,
        /// with either depth test, on a dense mesh and on one of a face's 68 points' size.
        #[test]
        fn the_grid_answers_as_every_triangle_does(
            yaw in -120.0f64..120.0,
            pitch in -80.0f64..80.0,
            roll in -180.0f64..180.0,
            plane in proptest::bool::ANY,
            side in proptest::sample::select(vec![9usize, 21]),
        ) {
            let shape = bumpy_of(side);
            let test = if plane { DepthTest::Plane } else { DepthTest::Centroid };
            let hpr = PaperHpr::from_frontal(&shape).unwrap().with_depth_test(test);
            let r = EulerAngles::new(yaw, pitch, roll).unwrap().to_rotation();
            let rotated: Vec<_> = shape.iter().map(|p| r * p).collect();
            proptest::prop_assert_eq!(hpr.visibility(&rotated).unwrap(), every_triangle(&hpr, &rotated));
        }
    }
}
