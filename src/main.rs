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
    Serve(Box<facepose_service::config::ServeArgs>),
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
    /// GET a running server's /readyz (a container's HEALTHCHECK): exit 0 on a 2xx, else 1.
    Healthcheck(cli::healthcheck::HealthcheckArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Serve(a) => cli::serve::run(*a),
        Command::Estimate(a) => cli::estimate::run(a),
        Command::Hpr(a) => cli::hpr::run(a),
        Command::Reconstruct(a) => cli::reconstruct::run(a),
        Command::Eval(a) => cli::eval::run(a),
        Command::EvalSfm(a) => cli::eval_sfm::run(a),
        Command::Train(a) => cli::train::run(a),
        Command::Healthcheck(a) => cli::healthcheck::run(a),
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

#[cfg(test)]
mod tests {
    use super::Cli;
    use clap::CommandFactory;

    /// The options of `cmd`'s subcommands (clap's own --help and --version aside) without a
    /// help text, and their values without one where an option has a closed set (shown under
    /// "Possible values"), as `command --option [value]`; and how many options were seen.
    fn options_without_help(cmd: &clap::Command) -> (Vec<String>, usize) {
        let mut missing = Vec::new();
        let mut seen = 0;
        for sub in cmd.get_subcommands() {
            if sub.get_about().is_none() {
                missing.push(sub.get_name().to_string());
            }
            for arg in sub.get_arguments() {
                let id = arg.get_id().as_str();
                if id == "help" || id == "version" {
                    continue;
                }
                seen += 1;
                let name = format!("{} --{}", sub.get_name(), arg.get_long().unwrap_or(id));
                let help = arg.get_help().or(arg.get_long_help());
                if help.is_none_or(|h| h.to_string().trim().is_empty()) {
                    missing.push(name.clone());
                }
                // A flag's "true" and "false" are not shown.
                let values = match arg.get_action().takes_values() {
                    true => arg.get_possible_values(),
                    false => Vec::new(),
                };
                for v in values {
                    if !v.is_hide_set() && v.get_help().is_none() {
                        missing.push(format!("{name} {}", v.get_name()));
                    }
                }
            }
        }
        (missing, seen)
    }

    /// `facepose <command> --help` describes every option: a new flag without a doc comment
    /// fails here.
    #[test]
    fn every_option_has_help() {
        let cli = Cli::command();
        cli.clone().debug_assert();
        let (missing, seen) = options_without_help(&cli);
        // Every subcommand's flags were walked: serve alone has more than 20.
        assert!(seen > 60, "only {seen} options seen");
        assert!(missing.is_empty(), "options without help: {missing:?}");
    }

    /// The walk finds an option without help, a value without help and a bare subcommand.
    #[test]
    fn options_without_help_are_found() {
        #[derive(clap::ValueEnum, Clone)]
        enum Colour {
            /// Described.
            Red,
            Blue,
        }
        #[derive(clap::Parser)]
        struct Bare {
            #[command(subcommand)]
            command: Sub,
        }
        #[derive(clap::Subcommand)]
        enum Sub {
            /// Described.
            Run {
                /// Described.
                #[arg(long)]
                good: bool,
                #[arg(long)]
                bare: bool,
                /// Described.
                #[arg(long, value_enum)]
                colour: Option<Colour>,
            },
            Other,
        }
        let (missing, seen) = options_without_help(&Bare::command());
        assert_eq!(seen, 3);
        assert_eq!(missing, ["run --bare", "run --colour blue", "other"]);
    }
}
