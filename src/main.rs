//! The `facepose` command line: one subcommand per task.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cli;

/// jemalloc: per-thread caches, so the async workers and the blocking pool do not queue on an
/// arena lock as they do with glibc's allocator (4-5% of the server's time under load; the
/// 68-point batch went from 106-126k to 158-161k poses/s; docs/PERFORMANCE.md).
#[cfg(not(target_env = "msvc"))]
#[global_allocator]
static ALLOC: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

/// jemalloc's options, read at its start (`_RJEM_MALLOC_CONF` in the environment overrides
/// them): one arena (the thread caches carry the fast path; more arenas raised the peak resident
/// size under the batch load from 57 to 78 MiB at the same throughput), and a background thread
/// that returns freed pages to the system after `dirty_decay_ms`, so the resident size falls back
/// after a burst of batches without purging on the request path.
#[cfg(not(target_env = "msvc"))]
#[allow(non_upper_case_globals)]
#[unsafe(export_name = "_rjem_malloc_conf")]
pub static malloc_conf: &[u8] = b"narenas:1,background_thread:true,max_background_threads:1,dirty_decay_ms:250,muzzy_decay_ms:0\0";

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
    Serve(facepose_service::config::ServeArgs),
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
            if let Some(f) = e.downcast_ref::<cli::Finished>() {
                return ExitCode::from(f.status);
            }
            // 2 when a command could not do its work; 3 when the service ran and its drain was
            // cut short.
            let status = e
                .downcast_ref::<facepose_service::ServeError>()
                .map_or(2, |e| e.exit_status());
            ExitCode::from(status)
        }
    }
}
