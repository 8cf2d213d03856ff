//! Subcommands of the `facepose` binary: argument parsing, files and printing around the library.

pub mod eval_sfm;
pub mod hpr;
pub mod reconstruct;

/// An error of a subcommand, printed with its context chain.
pub type CliError = Box<dyn std::error::Error + Send + Sync>;
