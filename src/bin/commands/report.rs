//! `surgvla report`: several evaluations' success rates charted side by side, or a perturbation
//! suite's run as a task x variant heatmap.

use crate::error::CliError;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub(crate) struct ReportArgs {
    /// The results folders of `surgvla eval` runs (each with its results.json), one bar
    /// colour each, in the order given.
    #[arg(required = true, num_args = 1..)]
    results: Vec<PathBuf>,
    /// The chart to write (PNG).
    #[arg(long, value_parser = crate::app::png_path)]
    out: PathBuf,
    /// Also draw the survival cascade here (PNG): per task, the share of trials that reached
    /// each stage of its chain, with its 95 % interval, runs side by side.
    #[arg(long, value_parser = crate::app::png_path)]
    cascade: Option<PathBuf>,
    /// The chart's title. A perturbation suite's run is drawn as a task x variant heatmap
    /// (success, interval and change from the unperturbed run per cell).
    #[arg(long, default_value = "success rate per task, 95 % interval")]
    title: String,
}

/// `surgvla report RESULTS_DIR... --out chart.png`: several policies' success rates side by
/// side, the runs named by their policy (by their folder when two share one).
pub(crate) fn run_report(args: &ReportArgs) -> Result<(), CliError> {
    let runs: Vec<surgvla::eval::chart::RunRates> = args
        .results
        .iter()
        .map(|dir| surgvla::eval::chart::read_results(dir))
        .collect::<Result<_, _>>()?;
    let names: Vec<String> = runs
        .iter()
        .zip(&args.results)
        .map(|(run, dir)| {
            let shared = runs.iter().filter(|r| r.policy == run.policy).count() > 1;
            if shared {
                dir.file_name().map_or_else(
                    || dir.display().to_string(),
                    |n| n.to_string_lossy().into_owned(),
                )
            } else {
                run.policy.clone()
            }
        })
        .collect();
    use surgvla::eval::chart::{Chart, chart_of, heatmap_of, write_chart};
    // A suite's run (a perturbed one) is drawn as its task x variant heatmap.
    let chart = match heatmap_of(&args.title, &runs, &names) {
        Some(map) => Chart::Heatmap(map),
        None => Chart::Rates(chart_of(&args.title, &runs, &names)),
    };
    write_chart(&chart, &args.out)?;
    let what = match &chart {
        Chart::Heatmap(map) => format!(
            "as a heatmap of {} variants over {} tasks",
            map.rows.len(),
            map.columns.len() - 1
        ),
        Chart::Rates(rates) => format!("over {} tasks", rates.categories.len()),
    };
    say!(
        "charted {} runs {what} into {}",
        runs.len(),
        args.out.display()
    );
    if let Some(path) = &args.cascade {
        let title = surgvla::eval::chart::CASCADE_TITLE;
        let Some(cascade) = surgvla::eval::chart::cascade_of(title, &runs, &names) else {
            return Err(CliError::invalid(
                "no run records stages (results of a surgvla older than the cascade)".to_string(),
            ));
        };
        let stages = cascade.categories.len();
        write_chart(&Chart::Rates(cascade), path)?;
        say!(
            "drew the survival cascade ({stages} stages) into {}",
            path.display()
        );
    }
    Ok(())
}
