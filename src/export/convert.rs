//! Converting a dataset: every episode of an [`EpisodeSource`] into an [`EpisodeSink`] made
//! with the source's [`DatasetInfo`](crate::export::DatasetInfo). Episodes travel in small
//! batches (one per worker thread, so the sink encodes them in parallel and memory stays
//! bounded by a few episodes); a resumed sink skips the episodes it already holds.

use crate::export::{EpisodeSink, EpisodeSource, ExportError, Summary};

/// Copies every episode of `source` into `sink` and finishes it; `progress` is told the
/// number of episodes done after each batch.
pub fn convert(
    source: &mut dyn EpisodeSource,
    sink: &mut dyn EpisodeSink,
    progress: &mut dyn FnMut(u64),
) -> Result<Summary, ExportError> {
    let skip = sink.next_episode_index();
    let batch_size = rayon::current_num_threads().max(1);
    let mut batch = Vec::with_capacity(batch_size);
    let mut done = 0u64;
    while let Some(episode) = source.next_episode() {
        let episode = episode?;
        done += 1;
        if episode.meta.index < skip {
            continue;
        }
        batch.push(episode);
        if batch.len() == batch_size {
            sink.write_batch(&batch)?;
            batch.clear();
            progress(done);
        }
    }
    if !batch.is_empty() {
        sink.write_batch(&batch)?;
    }
    progress(done);
    sink.finish()
}
