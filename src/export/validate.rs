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

use crate::export::check::Check;
use crate::export::dir::INCOMPLETE_MARKER;
use crate::export::error::ExportError;
pub use crate::export::findings::{
    At, FINDINGS_PER_CHECK, Facts, FeatureFact, Finding, Findings, Profile, Report, Semantics,
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
    if options.profile == Some(crate::export::findings::Profile::OpenH) {
        crate::export::lerobot::openh::check(&found.root, found.layout, &findings);
    }
    // The card sits in the dataset's folder (above an RLDS version folder, none for one file).
    if let Some(folder) = format.card_folder(&found) {
        crate::export::card::check(folder, counts.episodes, counts.frames, &findings);
    }
    let report = findings.into_report(found.layout, counts);
    Ok(match interrupted_at(&found.root) {
        Some(out) => report.interrupted(&out),
        None => report,
    })
}

/// The folder whose writer was interrupted (it holds our [`INCOMPLETE_MARKER`]): the dataset's
/// root, or the output folder above it (an RLDS version folder's).
fn interrupted_at(root: &Path) -> Option<std::path::PathBuf> {
    root.ancestors()
        .take(3)
        .find(|folder| folder.join(INCOMPLETE_MARKER).is_file())
        .map(Path::to_path_buf)
}

impl Report {
    /// The report of a dataset a writer left interrupted in `out`: one finding saying so, what
    /// is missing and how to finish it, in place of the defects of an unfinished write (a
    /// full check of one finds them by the thousand).
    pub fn interrupted(mut self, out: &Path) -> Report {
        let missing: Vec<String> = (self.errors.iter())
            .filter(|f| f.check == Check::Present)
            .filter_map(|f| f.file.clone())
            .take(5)
            .collect();
        let failed: std::collections::BTreeSet<&'static str> =
            self.errors.iter().map(|f| f.check.name()).collect();
        let mut message = format!(
            "an interrupted run: surgvla stopped before it finished writing this dataset (its marker {INCOMPLETE_MARKER} is in {})",
            out.display()
        );
        if !missing.is_empty() {
            message.push_str(&format!("; missing: {}", missing.join(", ")));
        }
        if !failed.is_empty() {
            let names: Vec<&str> = failed.into_iter().collect();
            message.push_str(&format!(
                "; what is there fails the checks {}, as an unfinished write does",
                names.join(", ")
            ));
        }
        message.push_str(&format!(
            ". Finish it: run the command that wrote it again with --resume (the same inputs and options, --out {}), or delete the folder",
            out.display()
        ));
        self.valid = false;
        self.warnings.clear();
        self.errors = vec![Finding {
            file: Some(INCOMPLETE_MARKER.into()),
            episode: None,
            frame: None,
            check: Check::Interrupted,
            message,
        }];
        self
    }
}
