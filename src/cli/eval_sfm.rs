//! `facepose eval-sfm`: the structure-from-motion accuracy table on a bfm68 population.

use std::path::PathBuf;

use clap::Args;
use facepose_core::shape::ibug68;
use facepose_eval::sfm_check::{SfmCondition, sfm_check, sfm_markdown};
use facepose_files::data::load_population;

use super::progress::{QuietArg, Reporter};
use super::{CliError, DataArg};

#[derive(Args)]
pub struct EvalSfmArgs {
    /// Population file (default: the shared data's bfm68/population_249.json).
    #[arg(long)]
    population: Option<PathBuf>,
    /// Random seed of the views.
    #[arg(long, default_value_t = 2011)]
    seed: u64,
    #[command(flatten)]
    data: DataArg,
    #[command(flatten)]
    quiet: QuietArg,
}

pub fn run(a: EvalSfmArgs) -> Result<(), CliError> {
    let progress = Reporter::new(&a.quiet);
    let path = a
        .data
        .or_file(a.population.as_deref(), "bfm68/population_249.json")?;
    progress.stage(format_args!("reading {}", path.display()));
    let pop = load_population(&path)?;
    if pop.scheme != "ibug68" {
        return Err(format!(
            "{}: scheme {:?}, expected ibug68",
            path.display(),
            pop.scheme
        )
        .into());
    }
    let conditions = [
        (0.0, 0),
        (0.0, 6),
        (0.005, 0),
        (0.005, 6),
        (0.01, 0),
        (0.02, 0),
    ]
    .map(|(noise_iod, missing_per_view)| SfmCondition {
        noise_iod,
        missing_per_view,
    });
    let rows = sfm_check(&pop.shapes, &ibug68(), &conditions, a.seed, &progress)?;
    println!(
        "Structure from motion on {} ({} shapes), five views within ±30° yaw, seed {}\n",
        path.display(),
        pop.shapes.len(),
        a.seed
    );
    print!("{}", sfm_markdown(&rows));
    progress.stage("done");
    Ok(())
}
