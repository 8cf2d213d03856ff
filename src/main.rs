//! The `facepose` command line: one subcommand per task.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cli;

/// Head pose from 2D facial landmarks.
#[derive(Parser)]
#[command(name = "facepose", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Serve HTTP JSON and gRPC on one port (the long-running service).
    Serve(facepose::service::config::ServeArgs),
    /// Estimate head pose from landmarks (JSON Lines or CSV) to JSON Lines.
    Estimate(cli::estimate::EstimateArgs),
    /// Score hidden-point removal against a dense mesh's true visibility and print the table.
    Hpr(cli::hpr::HprArgs),
    /// Accuracy reports: real faces with ground truth, or the paper's protocol.
    Eval(cli::eval::EvalArgs),
    /// Measure structure from motion on a 3D population seen in synthetic views.
    EvalSfm(cli::eval_sfm::EvalSfmArgs),
    /// Build a model bundle from 3D shape sets or multi-view 2D sets.
    Train(cli::train::TrainArgs),
    /// Rebuild a 3D shape from several 2D views by structure from motion.
    Reconstruct(cli::reconstruct::ReconstructArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Serve(a) => cli::serve::run(a),
        Command::Estimate(a) => cli::estimate::run(a),
        Command::Hpr(a) => cli::hpr::run(a),
        Command::Reconstruct(a) => cli::reconstruct::run(a),
        Command::Eval(a) => cli::eval::run(a),
        Command::EvalSfm(a) => cli::eval_sfm::run(a),
        Command::Train(a) => cli::train::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("facepose: {e:#}");
            ExitCode::from(2)
        }
    }
}
