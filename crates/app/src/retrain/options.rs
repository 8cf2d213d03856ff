//! Training options of an upload: the pose grid (`wide`, `paper` or a custom one), ridge
//! parameters, served sub-schemes, shape basis size, seed, and the validation thresholds;
//! checked against the scheme with messages naming the option, defaults filled in.

use crate::error::ServiceError;
use facepose_core::model::train::subset_of;
use facepose_core::model::validate::ValidationOptions;
use facepose_core::model::{RegressionParams, TrainOptions};
use facepose_core::shape::Scheme;
use facepose_core::synth::{AngleRange, PoseGrid};

/// Default of `options.min_shapes`.
pub const DEFAULT_MIN_SHAPES: usize = 10;
/// Default of `options.components`.
pub const DEFAULT_COMPONENTS: usize = 40;
/// The most training views a grid may ask for (coarse grid and bins together); the wide grid
/// has 5,421.
pub const MAX_GRID_VIEWS: usize = 50_000;

/// The most fine bins a custom grid may have (the wide grid has 5): each bin is a regression
/// trained and kept in the bundle, whatever its size.
pub const MAX_BINS: usize = 64;

/// A pose grid as sent: `[min, max, step]` per angle; roll `None` is 0 only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawGrid {
    /// Yaw `[min, max, step]`, degrees.
    pub yaw: [f64; 3],
    /// Pitch `[min, max, step]`, degrees.
    pub pitch: [f64; 3],
    /// Roll `[min, max, step]`, degrees (`None`: 0 only).
    pub roll: Option<[f64; 3]>,
}

/// Training options as sent; `None` takes the default.
#[derive(Debug, Clone, Default)]
pub struct RawOptions {
    /// `wide` or `paper`.
    pub grid: Option<String>,
    /// A custom grid (wins over `grid`): the coarse grid and the bins.
    pub custom_grid: Option<(RawGrid, Vec<RawGrid>)>,
    /// Candidate ridge regularizations `ε`.
    pub epsilons: Option<Vec<f64>>,
    /// Sub-schemes to serve besides the model's own.
    pub subsets: Option<Vec<String>>,
    /// Principal components of the shape basis (0: none).
    pub components: Option<usize>,
    /// Seed of the validation views.
    pub seed: Option<u64>,
    /// Fewest usable shapes an upload needs.
    pub min_shapes: Option<usize>,
    /// `k` of the outlier threshold `median + k · 1.4826 · MAD`.
    pub outlier_k: Option<f64>,
}

/// The checked options.
#[derive(Debug, Clone)]
pub struct UploadOptions {
    /// Grid, ε candidates, sub-schemes, seed.
    pub train: TrainOptions,
    /// Principal components of the shape basis (0: none).
    pub components: usize,
    /// Fewest shapes that must pass validation.
    pub min_shapes: usize,
    /// Outlier threshold.
    pub validation: ValidationOptions,
}

fn range(what: &str, r: [f64; 3], limit: f64) -> Result<AngleRange, ServiceError> {
    let [min, max, step] = r;
    if !(min >= -limit && max <= limit) {
        return Err(ServiceError::invalid(format!(
            "options.grid {what}: [{min}, {max}] must lie within ±{limit}°"
        )));
    }
    AngleRange::new(min, max, step)
        .map_err(|e| ServiceError::invalid(format!("options.grid {what}: {e}")))
}

fn grid(what: &str, g: &RawGrid) -> Result<PoseGrid, ServiceError> {
    Ok(PoseGrid {
        yaw: range(&format!("{what} yaw"), g.yaw, 90.0)?,
        pitch: range(&format!("{what} pitch"), g.pitch, 90.0)?,
        roll: match g.roll {
            Some(r) => range(&format!("{what} roll"), r, 180.0)?,
            None => AngleRange::fixed(0.0),
        },
    })
}

/// Views of a grid without overflowing on absurd steps.
fn views(g: &PoseGrid) -> f64 {
    let n = |r: &AngleRange| ((r.max - r.min) / r.step).floor() + 1.0;
    n(&g.yaw) * n(&g.pitch) * n(&g.roll)
}

/// Checks the options against the scheme and fills in the defaults.
pub fn check_options(raw: &RawOptions, scheme: &Scheme) -> Result<UploadOptions, ServiceError> {
    if let Some((_, bins)) = &raw.custom_grid
        && bins.len() > MAX_BINS
    {
        return Err(ServiceError::invalid(format!(
            "options.grid bins: {} bins; the limit is {MAX_BINS}",
            bins.len()
        )));
    }
    let mut regression = match (&raw.custom_grid, raw.grid.as_deref()) {
        (Some((coarse, bins)), _) => RegressionParams {
            coarse: grid("coarse", coarse)?,
            bins: bins
                .iter()
                .enumerate()
                .map(|(k, b)| grid(&format!("bins[{k}]"), b))
                .collect::<Result<_, _>>()?,
            epsilons: RegressionParams::wide().epsilons,
        },
        (None, None | Some("") | Some("wide")) => RegressionParams::wide(),
        (None, Some("paper")) => RegressionParams::paper(),
        (None, Some(other)) => {
            return Err(ServiceError::invalid(format!(
                "options.grid {other:?}: use \"wide\", \"paper\" or a grid object \
                 {{\"coarse\": {{\"yaw\": [min, max, step], \"pitch\": [...]}}, \"bins\": [...]}}"
            )));
        }
    };
    let total: f64 = regression.grids().map(views).sum();
    if total > MAX_GRID_VIEWS as f64 {
        return Err(ServiceError::invalid(format!(
            "options.grid: {total} training views; the limit is {MAX_GRID_VIEWS} (use larger steps)"
        )));
    }
    if let Some(eps) = &raw.epsilons {
        if eps.is_empty() || eps.len() > 20 {
            return Err(ServiceError::invalid(
                "options.epsilons: give 1 to 20 candidate ridge parameters",
            ));
        }
        if let Some(e) = eps.iter().find(|e| !(e.is_finite() && **e > 0.0)) {
            return Err(ServiceError::invalid(format!(
                "options.epsilons: {e} is not a positive number"
            )));
        }
        regression.epsilons = eps.clone();
    }
    let subsets = match &raw.subsets {
        Some(s) => s.clone(),
        None => facepose_core::shape::builtin::default_subsets(&scheme.name),
    };
    for (k, name) in subsets.iter().enumerate() {
        if *name == scheme.name || subsets[..k].contains(name) {
            return Err(ServiceError::invalid(format!(
                "options.subsets: {name:?} is listed twice or is the model's own scheme"
            )));
        }
        subset_of(scheme, name)
            .map_err(|e| ServiceError::invalid(format!("options.subsets: {e}")))?;
    }
    let components = raw.components.unwrap_or(DEFAULT_COMPONENTS);
    if components > 200 {
        return Err(ServiceError::invalid(format!(
            "options.components: {components}; at most 200"
        )));
    }
    let min_shapes = raw.min_shapes.unwrap_or(DEFAULT_MIN_SHAPES);
    if min_shapes < 3 {
        return Err(ServiceError::invalid(format!(
            "options.min_shapes: {min_shapes}; at least 3"
        )));
    }
    let mut validation = ValidationOptions::default();
    if let Some(k) = raw.outlier_k {
        if !(k.is_finite() && k > 0.0) {
            return Err(ServiceError::invalid(format!(
                "options.outlier_k: {k} is not a positive number"
            )));
        }
        validation.outlier_k = k;
    }
    Ok(UploadOptions {
        train: TrainOptions {
            regression,
            subsets,
            seed: raw.seed.unwrap_or(TrainOptions::default().seed),
        },
        components,
        min_shapes,
        validation,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(raw: RawOptions) -> Result<UploadOptions, ServiceError> {
        check_options(&raw, &facepose_core::shape::ibug68())
    }

    #[test]
    fn options_defaults_and_limits() {
        let o = opts(RawOptions::default()).unwrap();
        assert_eq!(o.train, TrainOptions::default());
        assert_eq!(o.min_shapes, DEFAULT_MIN_SHAPES);
        let wide: f64 = o.train.regression.grids().map(views).sum();
        assert!(wide < MAX_GRID_VIEWS as f64 / 5.0, "{wide}");
        let custom = RawOptions {
            custom_grid: Some((
                RawGrid {
                    yaw: [-60.0, 60.0, 10.0],
                    pitch: [-30.0, 30.0, 10.0],
                    roll: None,
                },
                vec![],
            )),
            subsets: Some(vec!["five".into()]),
            ..Default::default()
        };
        let o = opts(custom).unwrap();
        assert_eq!(views(&o.train.regression.coarse), 13.0 * 7.0);
        for (raw, want) in [
            (
                RawOptions {
                    grid: Some("fine".into()),
                    ..Default::default()
                },
                "options.grid \"fine\"",
            ),
            (
                RawOptions {
                    custom_grid: Some((
                        RawGrid {
                            yaw: [-90.0, 90.0, 0.1],
                            pitch: [-90.0, 90.0, 0.5],
                            roll: None,
                        },
                        vec![],
                    )),
                    ..Default::default()
                },
                "training views; the limit",
            ),
            (
                RawOptions {
                    custom_grid: Some((
                        RawGrid {
                            yaw: [-90.0, 90.0, 1e-6],
                            pitch: [0.0, 0.0, 1.0],
                            roll: None,
                        },
                        vec![],
                    )),
                    ..Default::default()
                },
                "options.grid coarse yaw: invalid parameter angle range",
            ),
            (
                RawOptions {
                    custom_grid: Some((
                        RawGrid {
                            yaw: [-100.0, 90.0, 5.0],
                            pitch: [0.0, 0.0, 1.0],
                            roll: None,
                        },
                        vec![],
                    )),
                    ..Default::default()
                },
                "within ±90",
            ),
            (
                RawOptions {
                    epsilons: Some(vec![1e-5, -1.0]),
                    ..Default::default()
                },
                "options.epsilons: -1",
            ),
            (
                RawOptions {
                    subsets: Some(vec!["mediapipe468".into()]),
                    ..Default::default()
                },
                "options.subsets",
            ),
            (
                RawOptions {
                    custom_grid: Some((
                        RawGrid {
                            yaw: [0.0, 0.0, 1.0],
                            pitch: [0.0, 0.0, 1.0],
                            roll: None,
                        },
                        vec![
                            RawGrid {
                                yaw: [0.0, 0.0, 1.0],
                                pitch: [0.0, 0.0, 1.0],
                                roll: None,
                            };
                            MAX_BINS + 1
                        ],
                    )),
                    ..Default::default()
                },
                "options.grid bins: 65 bins; the limit is 64",
            ),
            (
                RawOptions {
                    min_shapes: Some(1),
                    ..Default::default()
                },
                "options.min_shapes",
            ),
        ] {
            let e = opts(raw).unwrap_err();
            assert!(e.to_string().contains(want), "{want}: {e}");
        }
    }
}
