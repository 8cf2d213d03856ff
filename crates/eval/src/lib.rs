//! facepose's evaluation: the protocols behind every accuracy figure of docs/RESULTS.md, as
//! pure functions over data already loaded, returning rows, grids, Markdown and PNG charts.
//!
//! Used by the `facepose` binary's `eval`, `hpr`, `eval-sfm` and `train --calibrate` commands
//! only: the service does not link it (`cargo tree -p facepose-service` has no plotters or
//! png), so the core stays numbers in, rotation out. Like the core it does no I/O
//! (`clippy.toml`): files are read by `facepose-files` and written by the binary.

pub mod aflw;
pub mod detector_training;
pub mod hpr_table;
pub mod mesh;
pub mod paper;
pub mod plot;
pub mod progress;
pub mod rendered;
pub mod sfm_check;
pub mod tracking;
pub mod uncertainty;
