//! Validating a dataset on disk, ours or not: [`validate`] finds the format through the
//! registry ([`crate::export::registry::detect`]), runs that format's checks (structure against
//! the JSON Schemas of [`crate::export::schema`], then content: every frame unless
//! [`ValidateOptions::quick`]) and returns a [`Report`] of [`Finding`]s, each naming the file,
//! episode, frame and check.
//!
//! A path that holds any file of a known format is a dataset, however broken: its defects are
//! findings. [`validate`] fails (an `Err`) only when it cannot run: the path does not exist,
//! cannot be read, or holds nothing recognisable. The manifest our writers leave
//! (`surgvla_manifest.json`) is verified when present; without it the data is judged on content
//! alone. Our own datasets (with surgvla metadata) also get the semantic checks of
//! [`check_semantics`]. What the checks report into lives in [`crate::export::findings`].

use crate::export::error::ExportError;
pub use crate::export::findings::{
    At, FINDINGS_PER_CHECK, Facts, FeatureFact, Finding, Findings, Report, Semantics,
    ValidateOptions, check_manifest, check_semantics,
};
use crate::export::registry::Detected;
use std::path::Path;

/// Validates the dataset at `path` (see the module overview).
pub fn validate(path: &Path, options: &ValidateOptions) -> Result<Report, ExportError> {
    let Detected { format, found, .. } = crate::export::registry::detect(path)?;
    let findings = Findings::new(&found.root);
    let pool = crate::threads::pool(options.threads)?;
    let counts = pool.install(|| format.check(&found, options, &findings));
    // The card sits in the dataset's folder (above an RLDS version folder, none for one file).
    if let Some(folder) = format.card_folder(&found) {
        crate::export::card::check(folder, counts.episodes, counts.frames, &findings);
    }
    Ok(findings.into_report(found.layout, counts))
}
