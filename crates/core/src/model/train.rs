//! Training a [`PoseModel`] from a frontal mean 3D shape: HPR over its Delaunay triangulation,
//! the visibility map, the geometric constants, and for each subset the regression's training
//! views over the pose grids (synthesized lazily, one bin at a time) with `ε` chosen on
//! validation views.

use nalgebra::{Vector2, Vector3};
use rand::{Rng, SeedableRng, rngs::StdRng};
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::{PoseModel, Subset, SubsetMap};
use crate::error::{Error, Result};
use crate::estimate::geometric::GeometryConstants;
use crate::estimate::morph_fit::MorphableBasis;
use crate::estimate::regression::{RegressionModel, TrainingView, ViewBin};
use crate::estimate::visibility_map::VisibilityMap;
use crate::geometry::{EulerAngles, WeakPerspective};
use crate::hpr::PaperHpr;
use crate::parallel;
use crate::shape::builtin::{BuiltinScheme, PointMap, default_subsets};
use crate::shape::{Scheme, Shape2, Shape3};
use crate::synth::{AngleRange, PoseGrid, ViewSynthesizer, image_of};

/// Pose grids and ridge parameter of the regressions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegressionParams {
    /// The coarse model over the whole range (bin 0).
    pub coarse: PoseGrid,
    /// The fine bins; the coarse estimate picks the one whose centre is nearest.
    pub bins: Vec<PoseGrid>,
    /// Candidate ridge parameters; the one with the lowest validation error is kept.
    pub epsilons: Vec<f64>,
}

impl RegressionParams {
    /// The paper's set-up: one model on the ±40° grid at 2°.
    pub fn paper() -> Self {
        RegressionParams {
            coarse: PoseGrid::paper(),
            bins: vec![],
            epsilons: default_epsilons(),
        }
    }

    /// Wide range: a coarse model over yaw ±90°, pitch ±60° at 6°, and five yaw bins at 2°.
    pub fn wide() -> Self {
        let g = |min: f64, max: f64| PoseGrid {
            yaw: AngleRange {
                min,
                max,
                step: 2.0,
            },
            pitch: AngleRange {
                min: -40.0,
                max: 40.0,
                step: 2.0,
            },
            roll: AngleRange::fixed(0.0),
        };
        RegressionParams {
            coarse: PoseGrid {
                yaw: AngleRange {
                    min: -90.0,
                    max: 90.0,
                    step: 6.0,
                },
                pitch: AngleRange {
                    min: -60.0,
                    max: 60.0,
                    step: 6.0,
                },
                roll: AngleRange::fixed(0.0),
            },
            bins: vec![
                g(-90.0, -46.0),
                g(-56.0, -14.0),
                g(-30.0, 30.0),
                g(14.0, 56.0),
                g(46.0, 90.0),
            ],
            epsilons: default_epsilons(),
        }
    }
}

impl RegressionParams {
    /// The most training views all grids together may hold (about 1 kB each for 68 points).
    pub const MAX_VIEWS: usize = 200_000;

    /// The regression grids: the coarse one (bin 0), then the fine bins.
    pub fn grids(&self) -> impl Iterator<Item = &PoseGrid> + Clone + '_ {
        std::iter::once(&self.coarse).chain(&self.bins)
    }

    /// Checks what the angle ranges alone cannot: no roll in any grid (the regression de-rolls
    /// by the eye line and learns the roll-free pose), a bounded number of views, and positive
    /// ridge candidates.
    pub fn validate(&self) -> Result<()> {
        for (k, g) in self.grids().enumerate() {
            if g.roll.min != 0.0 || g.roll.max != 0.0 {
                return Err(Error::param(
                    format!("regression grid {k} roll"),
                    format!(
                        "must be 0..0 (the regression de-rolls by the eye line), got {}..{}",
                        g.roll.min, g.roll.max
                    ),
                ));
            }
        }
        let views: usize = self.grids().map(PoseGrid::len).sum();
        if views > Self::MAX_VIEWS {
            return Err(Error::param(
                "regression grids",
                format!(
                    "{views} training views, over the limit of {}: use larger steps",
                    Self::MAX_VIEWS
                ),
            ));
        }
        if let Some(e) = self.epsilons.iter().find(|e| !(e.is_finite() && **e > 0.0)) {
            return Err(Error::param(
                "epsilons",
                format!("ridge candidates must be positive, got {e}"),
            ));
        }
        Ok(())
    }
}

fn default_epsilons() -> Vec<f64> {
    vec![1e-7, 1e-6, 1e-5, 1e-4, 1e-3]
}

/// What [`train`] builds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainOptions {
    /// The regression's training parameters.
    pub regression: RegressionParams,
    /// Sub-schemes to serve besides the model's own (`inner51`, `five`, `dlib5` for ibug68).
    pub subsets: Vec<String>,
    /// Seed of the validation views.
    pub seed: u64,
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            regression: RegressionParams::wide(),
            subsets: default_subsets("ibug68"),
            seed: 2011,
        }
    }
}

/// Trains a model for `scheme` from a frontal mean shape (mm). `validation` shapes (other faces
/// of the population, same scheme) choose the ridge parameter; without them the mean shape with
/// landmark noise is used. `morph` is an optional morphable basis over the scheme.
pub fn train(
    scheme: &Scheme,
    mean: &[Vector3<f64>],
    validation: &[Vec<Vector3<f64>>],
    morph: Option<MorphableBasis>,
    opts: &TrainOptions,
) -> Result<PoseModel> {
    scheme.check_model_scheme()?;
    if mean.len() != scheme.len() {
        return Err(Error::PointCount {
            what: "mean shape".into(),
            expected: scheme.len(),
            got: mean.len(),
        });
    }
    let frontal = Shape3::full(mean.to_vec())?.frontalized(scheme)?;
    let mean: Vec<Vector3<f64>> = frontal.points().to_vec();
    let hpr = PaperHpr::from_frontal(&mean)?;
    let visibility = VisibilityMap::build_default(&mean, &hpr)?;
    let geometry = geometry_of(scheme, &mean)?;

    let mut subsets = Vec::new();
    let mut names = vec![scheme.name.clone()];
    names.extend(opts.subsets.iter().cloned());
    let own_bins = synthesize_bins(&mean, &hpr, &opts.regression)?;
    for name in names {
        let (sub_scheme, map) = subset_of(scheme, &name)?;
        let sub_mean = map.map_points(scheme, &mean);
        let bins = map_bins(&own_bins, scheme, &map);
        let eyes = (
            sub_scheme.anchors.eye_left.clone(),
            sub_scheme.anchors.eye_right.clone(),
        );
        let base = RegressionModel::new(sub_scheme.len(), eyes.0, eyes.1, bins, 1e-5)?;
        let val = validation_views(scheme, &map, &mean, validation, &opts.regression, opts.seed)?;
        let regression = choose_epsilon(base, &val, &opts.regression.epsilons)?;
        subsets.push(Subset {
            scheme: sub_scheme,
            map,
            mean: sub_mean,
            regression,
        });
    }
    Ok(PoseModel {
        scheme: scheme.clone(),
        mean,
        hpr,
        visibility,
        geometry,
        subsets,
        morph,
        mesh: None,
        calibration: None,
        detectors: vec![],
    })
}

/// Where the shape fit's basis comes from.
#[derive(Debug, Clone)]
pub enum BasisSource<'a> {
    /// No basis: the model has no `fit-shape`.
    None,
    /// Up to this many principal components of the training shapes.
    Pca(usize),
    /// A published morphable model over the same points, with its expression prior widened by
    /// `expression_spread` (see [`super::basis::morphable_basis`]).
    Morphable {
        /// The morphable model.
        model: &'a super::basis::MorphableModel,
        /// Factor widening the expression prior.
        expression_spread: f64,
    },
}

/// Trains from a population of 3D shapes (mm, model frame, all points): the mean by generalized
/// Procrustes analysis, frontalized, and the shape fit's basis from `basis`. Every shape also
/// serves as validation for `ε`.
pub fn train_from_population(
    scheme: &Scheme,
    shapes: &[Vec<Vector3<f64>>],
    basis: BasisSource<'_>,
    opts: &TrainOptions,
) -> Result<PoseModel> {
    scheme.check_model_scheme()?;
    if shapes.len() < 2 {
        return Err(Error::too_few("training shapes", 2, shapes.len()));
    }
    let gpa = crate::geometry::generalized_procrustes(
        shapes,
        crate::geometry::procrustes::GpaOptions::default(),
    )?;
    let mean = Shape3::full(gpa)?.frontalized(scheme)?.points().to_vec();
    let basis = match basis {
        BasisSource::None | BasisSource::Pca(0) => None,
        BasisSource::Pca(k) => Some(super::basis::pca_basis(shapes, &mean, k, 0.999)?),
        BasisSource::Morphable {
            model,
            expression_spread,
        } => Some(super::basis::morphable_basis(
            model,
            &mean,
            expression_spread,
        )?),
    };
    train(scheme, &mean, shapes, basis, opts)
}

/// The sub-scheme called `name` of `scheme` and how its points map.
pub fn subset_of(scheme: &Scheme, name: &str) -> Result<(Scheme, SubsetMap)> {
    if name == scheme.name {
        return Ok((scheme.clone(), SubsetMap::Own));
    }
    let Some((built_in, map)) =
        BuiltinScheme::find(name).and_then(|b| Some((b, b.is_subset_of(&scheme.name)?)))
    else {
        return Err(Error::InvalidScheme {
            scheme: name.into(),
            reason: format!("not a known subset of {}", scheme.name),
        });
    };
    let own = || {
        built_in.build().ok_or_else(|| Error::InvalidScheme {
            scheme: name.into(),
            reason: "a built-in subset without its definition".into(),
        })
    };
    match map {
        PointMap::Anchors => Ok((own()?, SubsetMap::Anchors)),
        PointMap::Range(a, b) => {
            let idx: Vec<usize> = (a..b).collect();
            Ok((scheme.subset(name, &idx)?, SubsetMap::Indices(idx)))
        }
        PointMap::Indices(idx) => Ok((own()?, SubsetMap::Indices(idx.to_vec()))),
    }
}

/// The geometric method's constants of a frontal mean shape over `scheme`.
pub(crate) fn geometry_of(scheme: &Scheme, mean: &[Vector3<f64>]) -> Result<GeometryConstants> {
    let five = SubsetMap::Anchors.map_points(scheme, mean);
    GeometryConstants::from_mean(&[five[0], five[1], five[2], five[3], five[4]])
}

/// The training views of the model's own scheme over the coarse grid and the fine bins:
/// projections of the frontal mean with HPR visibility. Subsets take theirs from these with
/// [`map_bins`] rather than synthesizing again.
pub(crate) fn synthesize_bins(
    mean: &[Vector3<f64>],
    hpr: &PaperHpr,
    p: &RegressionParams,
) -> Result<Vec<ViewBin>> {
    p.validate()?;
    let synth = ViewSynthesizer::new(mean, hpr)?;
    p.grids()
        .map(|&grid| {
            let poses: Vec<EulerAngles> = grid.poses().collect();
            let views = parallel::map_with(
                &poses,
                || synth.clone(),
                |synth, &angles| {
                    let v = synth.view(angles)?;
                    Ok(TrainingView {
                        angles: v.angles,
                        points: v.projected.iter().map(|q| [q.x, q.y]).collect(),
                        visible: v.visible,
                    })
                },
            )
            .into_iter()
            .collect::<Result<Vec<_>>>()?;
            Ok(ViewBin { grid, views })
        })
        .collect()
}

/// The training views of [`synthesize_bins`] with their visibility given (as a bundle stores
/// it: per grid, every view's `mean.len()` flags in grid order) instead of computed by HPR.
pub(crate) fn bins_with_visibility(
    mean: &[Vector3<f64>],
    p: &RegressionParams,
    visibility: &[Vec<bool>],
) -> Result<Vec<ViewBin>> {
    p.validate()?;
    let grids: Vec<PoseGrid> = p.grids().copied().collect();
    if visibility.len() != grids.len() {
        return Err(Error::param(
            "visibility",
            format!(
                "{} view grids' visibility for {} regression grids",
                visibility.len(),
                grids.len()
            ),
        ));
    }
    let n = mean.len();
    grids
        .into_iter()
        .zip(visibility)
        .enumerate()
        .map(|(k, (grid, flags))| {
            if flags.len() != grid.len() * n {
                return Err(Error::PointCount {
                    what: format!("visibility flags of regression grid {k}"),
                    expected: grid.len() * n,
                    got: flags.len(),
                });
            }
            let views = grid
                .poses()
                .zip(flags.chunks(n))
                .map(|(angles, visible)| {
                    let r = angles.to_rotation();
                    TrainingView {
                        angles,
                        points: mean
                            .iter()
                            .map(|x| {
                                let q = image_of(&(r * x));
                                [q.x, q.y]
                            })
                            .collect(),
                        visible: visible.to_vec(),
                    }
                })
                .collect();
            Ok(ViewBin { grid, views })
        })
        .collect()
}

/// A subset's training views from the model scheme's.
pub(crate) fn map_bins(bins: &[ViewBin], scheme: &Scheme, map: &SubsetMap) -> Vec<ViewBin> {
    if *map == SubsetMap::Own {
        return bins.to_vec();
    }
    bins.iter()
        .map(|b| ViewBin {
            grid: b.grid,
            views: b
                .views
                .iter()
                .map(|v| {
                    let pts: Vec<Vector3<f64>> = v
                        .points
                        .iter()
                        .map(|q| Vector3::new(q[0], q[1], 0.0))
                        .collect();
                    TrainingView {
                        angles: v.angles,
                        points: map
                            .map_points(scheme, &pts)
                            .iter()
                            .map(|q| [q.x, q.y])
                            .collect(),
                        visible: map.map_visibility(scheme, &v.visible),
                    }
                })
                .collect(),
        })
        .collect()
}

/// Validation views: other shapes (or the mean with 2% landmark noise) at random poses within
/// the fine bins, in image pixels, with their true angles, every point present (the common
/// query; one missing pattern keeps the choice of `ε` cheap).
fn validation_views(
    scheme: &Scheme,
    map: &SubsetMap,
    mean: &[Vector3<f64>],
    shapes: &[Vec<Vector3<f64>>],
    p: &RegressionParams,
    seed: u64,
) -> Result<Vec<(Shape2, EulerAngles)>> {
    let mut rng = StdRng::seed_from_u64(seed);
    let grids: Vec<PoseGrid> = if p.bins.is_empty() {
        vec![p.coarse]
    } else {
        p.bins.clone()
    };
    let noisy_mean = shapes.is_empty();
    let count = if noisy_mean {
        200
    } else {
        shapes.len().clamp(50, 300)
    };
    let noise = Normal::new(0.0, if noisy_mean { 0.02 } else { 0.0 })
        .map_err(|e| Error::param("noise", e.to_string()))?;
    let mut out = Vec::with_capacity(count);
    for k in 0..count {
        let shape = if noisy_mean {
            mean
        } else {
            &shapes[k % shapes.len()][..]
        };
        if shape.len() != mean.len() {
            return Err(Error::PointCount {
                what: format!("validation shape {k}"),
                expected: mean.len(),
                got: shape.len(),
            });
        }
        let g = grids[k % grids.len()];
        let a = EulerAngles::new(
            rng.random_range(g.yaw.min..=g.yaw.max),
            rng.random_range(g.pitch.min..=g.pitch.max),
            rng.random_range(-15.0..15.0),
        )?;
        let r = a.to_rotation();
        let cam = WeakPerspective::new(r, 2.0, Vector2::new(225.0, -225.0))?;
        let size = 2.0 * 60.0;
        let pts: Vec<Vector3<f64>> = shape
            .iter()
            .map(|x| {
                let q = cam.project(x)
                    + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng)) * size;
                Vector3::new(q.x, q.y, 0.0)
            })
            .collect();
        let sub: Vec<Option<[f64; 2]>> = map
            .map_points(scheme, &pts)
            .iter()
            .map(|q| Some([q.x, q.y]))
            .collect();
        out.push((Shape2::from_options(&sub)?, a));
    }
    Ok(out)
}

/// Keeps the candidate `ε` with the lowest geodesic error on the validation views (one pass, no
/// hidden-point second pass: every validation point is present).
fn choose_epsilon(
    mut model: RegressionModel,
    val: &[(Shape2, EulerAngles)],
    candidates: &[f64],
) -> Result<RegressionModel> {
    let none = |_: f64, _: f64, _: &mut [bool]| {};
    let mut best: Option<(f64, f64)> = None;
    for &eps in candidates {
        let mut err = 0.0;
        for (shape, truth) in val {
            err += match model.estimate_with(shape, &none, eps) {
                Ok(e) => crate::geometry::geodesic_deg(&e.rotation, &truth.to_rotation()),
                Err(_) => 90.0,
            };
        }
        if best.is_none_or(|(b, _)| err < b) {
            best = Some((err, eps));
        }
    }
    let (_, eps) =
        best.ok_or_else(|| Error::param("epsilons", "no candidate ridge parameter given"))?;
    model.set_epsilon(eps)?;
    Ok(model)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regression_grids_refuse_roll_huge_grids_and_bad_ridges() {
        RegressionParams::wide().validate().unwrap();
        let mut p = RegressionParams::paper();
        p.bins.push(PoseGrid {
            roll: AngleRange::new(-10.0, 10.0, 5.0).unwrap(),
            ..PoseGrid::paper()
        });
        assert!(p.validate().unwrap_err().to_string().contains("roll"));
        let mut p = RegressionParams::paper();
        p.coarse.yaw = AngleRange::new(-90.0, 90.0, 0.1).unwrap();
        p.coarse.pitch = AngleRange::new(-60.0, 60.0, 0.1).unwrap();
        assert!(
            p.validate()
                .unwrap_err()
                .to_string()
                .contains("training views")
        );
        let mut p = RegressionParams::paper();
        p.epsilons = vec![1e-4, 0.0];
        assert!(p.validate().unwrap_err().to_string().contains("epsilons"));
    }
}
