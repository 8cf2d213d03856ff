//! Evaluation protocols and their reports.

pub mod aflw;
pub mod hpr_table;
pub mod sfm_check;
