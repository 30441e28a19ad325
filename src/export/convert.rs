//! Converting a dataset: every episode of an [`EpisodeSource`] into an [`EpisodeSink`] made
//! with the source's [`DatasetInfo`](crate::export::DatasetInfo). Episodes travel in small
//! batches (one per worker thread, so the sink encodes them in parallel and memory stays
//! bounded by a few episodes); a resumed sink skips the episodes it already holds.

use crate::error::ErrorKind;
use crate::export::{EpisodeSink, EpisodeSource, ExportError, Summary};

/// Which side of a conversion failed.
#[derive(Debug, thiserror::Error)]
pub enum ConvertError {
    /// The input dataset is unreadable or invalid (resuming will not help until it is
    /// repaired).
    #[error("reading the input dataset")]
    Read(#[source] ExportError),
    /// Writing the output failed (a full disk: resume once there is space).
    #[error("writing the output dataset")]
    Write(#[source] ExportError),
}

impl ConvertError {
    pub fn kind(&self) -> ErrorKind {
        match self {
            ConvertError::Read(error) | ConvertError::Write(error) => error.kind(),
        }
    }

    /// Whether the output's disk (or quota) is full.
    pub fn is_disk_full(&self) -> bool {
        matches!(self, ConvertError::Write(error) if error.is_disk_full())
    }
}

/// Copies every episode of `source` into `sink` on `threads` worker threads (0: one per core)
/// and finishes it; `progress` is told the number of episodes done after each batch.
pub fn convert(
    source: &mut (dyn EpisodeSource + Send),
    sink: &mut (dyn EpisodeSink + Send),
    threads: usize,
    progress: &mut (dyn FnMut(u64) + Send),
) -> Result<Summary, ConvertError> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| {
            ConvertError::Write(ExportError::Internal(format!("no worker threads: {e}")))
        })?;
    pool.install(|| copy(source, sink, progress))
}

fn copy(
    source: &mut (dyn EpisodeSource + Send),
    sink: &mut (dyn EpisodeSink + Send),
    progress: &mut (dyn FnMut(u64) + Send),
) -> Result<Summary, ConvertError> {
    let skip = sink.next_episode_index();
    let batch_size = rayon::current_num_threads().max(1);
    let mut batch = Vec::with_capacity(batch_size);
    let mut done = 0u64;
    while let Some(episode) = source.next_episode() {
        let episode = episode.map_err(ConvertError::Read)?;
        done += 1;
        if episode.meta.index < skip {
            continue;
        }
        batch.push(episode);
        if batch.len() == batch_size {
            sink.write_batch(&batch).map_err(ConvertError::Write)?;
            batch.clear();
            progress(done);
        }
    }
    if !batch.is_empty() {
        sink.write_batch(&batch).map_err(ConvertError::Write)?;
    }
    progress(done);
    sink.finish().map_err(ConvertError::Write)
}
