//! The integration tests of the workspace that need the `facepose` binary or the shared data:
//! the command line as a user runs it, the service as a process (start-up errors, signals, exit
//! statuses, kill -9), and the numeric core against real data. One test
//! binary, one module per subject (the files beside this one).

mod common;

mod architecture;
mod cli;
mod cli_estimate;
mod contour_style;
mod conventions_aflw;
mod detectors;
mod dockerfile_stubs;
mod eval_paper;
mod healthcheck;
mod hpr_mesh;
mod mediapipe;
mod model_bundle;
mod opencv_frame;
mod registries;
mod service_process;
mod sfm_bfm;
mod uncertainty_aflw;
