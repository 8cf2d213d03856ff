//! Evaluation protocols and their reports.

pub mod aflw;
pub mod hpr_table;
pub mod mesh;
pub mod paper;
pub mod plot;
pub mod sfm_check;
pub mod tracking;
pub mod uncertainty;
