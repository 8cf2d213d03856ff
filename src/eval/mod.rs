//! Evaluation protocols and their reports.

pub mod hpr_table;
pub mod sfm_check;
pub mod aflw;
