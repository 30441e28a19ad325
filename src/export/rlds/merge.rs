//! RLDS's merge: every input's records read back and written again through one
//! [`RldsWriter`](super::writer::RldsWriter) with the options the inputs recorded, so each record is
//! re-encoded with its new episode index, shards roll at the same size as one run rolls them
//! and are renamed `-of-NNNNN` once at the end. The records hold the images as the inputs
//! stored them (PNG, JPEG: copied, not encoded again), so N of N merged are the single run's
//! bytes.

use crate::export::collection::Collection;
use crate::export::convert::ConvertError;
use crate::export::format::{MergeError, MergeRequest};
use crate::export::merge::{Part, plan, reports, write_through};
use crate::export::sink::Summary;
use crate::export::source::EpisodeSource;
use crate::export::source::SourceOptions;
use std::path::Path;

/// Merges the request's RLDS datasets into a new one at its `out` (or continues an
/// interrupted merge of the same inputs).
pub fn merge(request: &mut MergeRequest<'_>) -> Result<Summary, MergeError> {
    let read = |e| MergeError::Convert(ConvertError::Read(e));
    let mut parts = Vec::new();
    for path in request.inputs {
        let folder = super::read::version_dir(path).map_err(read)?;
        let data_dir = folder
            .parent()
            .and_then(Path::parent)
            .unwrap_or(path.as_path())
            .to_path_buf();
        let manifest = data_dir.join(super::options::MANIFEST);
        let surgvla = folder.join(super::options::SURGVLA_JSON);
        let collection = if surgvla.is_file() {
            let metadata = crate::export::bounded::read_json(&surgvla).map_err(read)?;
            Collection::from_json(&metadata["collection"])
        } else {
            None
        };
        parts.push((Part::read(path, &manifest, collection)?, folder, data_dir));
    }
    let plan = plan(parts.iter().map(|(p, _, _)| p.clone()).collect())?;
    let Some(options) = super::options::RldsOptions::from_run_options(&plan.options) else {
        return Err(MergeError::Unsupported {
            path: plan.parts[0].path.clone(),
            problem: "its manifest does not record RLDS options".into(),
        });
    };
    // Sources in the plan's order; another tool's records are read with the frame rate and
    // robot the inputs recorded.
    let text = |key: &str| {
        plan.options
            .get(key)
            .and_then(|v| v.as_str())
            .map(String::from)
    };
    let source_options = SourceOptions {
        fps: plan
            .options
            .get("fps")
            .and_then(|v| v.as_u64())
            .and_then(|f| u32::try_from(f).ok()),
        robot_type: text("robot_type"),
        ..Default::default()
    };
    let mut sources: Vec<Box<dyn EpisodeSource + Send>> = Vec::new();
    let mut data_dirs = Vec::new();
    for part in &plan.parts {
        let Some((_, folder, data_dir)) = parts.iter().find(|(p, _, _)| p.path == part.path) else {
            continue;
        };
        sources.push(super::foreign::open_any(folder, &source_options).map_err(read)?);
        data_dirs.push(data_dir.clone());
    }
    let mut info = sources
        .first()
        .map(|s| s.info().clone())
        .ok_or(MergeError::NoInput)?;
    info.collection = plan.collection.clone();
    let identities: Vec<String> = data_dirs
        .iter()
        .map(|d| crate::export::identity::of(d))
        .collect::<Result<_, _>>()
        .map_err(read)?;
    info.input = Some(identities.join("; "));
    let write = |e| MergeError::Convert(ConvertError::Write(e));
    let resuming = crate::export::dir::resumes(request.out, request.resume);
    let mut sink =
        super::writer::RldsWriter::boxed(request.out, &info, options, resuming).map_err(write)?;
    let dirs: Vec<&Path> = data_dirs.iter().map(|d| d.as_path()).collect();
    let reports = reports(&dirs).map(|r| (r, plan.shard()));
    write_through(
        sources,
        sink.as_mut(),
        request.threads,
        reports,
        &mut *request.progress,
    )
}
