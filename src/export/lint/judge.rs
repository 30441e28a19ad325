//! The lint's entry: every check of [`super::motion`], [`super::episodes`],
//! [`super::surgical`] and [`super::cameras`] over a dataset's series.

use super::cameras::{self, CameraFrames};
use super::series::{EpisodeSeries, Lint, LintDataset};
use crate::export::findings::Findings;

/// Judges a dataset's episodes (in episode order) and camera frames; findings name `file`
/// (the data folder, relative to the dataset).
pub fn lint(
    dataset: &LintDataset,
    episodes: &[EpisodeSeries],
    cameras: &[CameraFrames],
    file: &str,
    findings: &Findings,
) {
    let mut lint = Lint::new(findings, file, episodes.len());
    if episodes.is_empty() {
        return;
    }
    super::motion::check(&mut lint, dataset, episodes);
    super::episodes::check(&mut lint, dataset, episodes);
    super::surgical::check(&mut lint, dataset, episodes);
    if !cameras.is_empty() {
        cameras::check(&mut lint, dataset, episodes, cameras);
    }
}
