//! What a format's reader is to its callers: [`EpisodeSource`], a dataset's [`DatasetInfo`] and
//! its episodes in order, one at a time; and what a reader needs that a dataset may not say
//! ([`SourceOptions`]).

use crate::episode::Episode;
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;

/// Reads a dataset back: its [`DatasetInfo`] and, as an iterator, its episodes in order, one at
/// a time (memory bounded by one episode); a read that fails is an `Err` item.
pub trait EpisodeSource: Iterator<Item = Result<Episode, ExportError>> {
    fn info(&self) -> &DatasetInfo;
    /// Episodes in the dataset.
    fn len(&self) -> u64;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Leaves the stored still images (PNG, TIFF, JPEG) of the `unused` encodings out of the
    /// episodes' [`Episode::encoded`] from now on: a conversion whose target would encode them
    /// again says so before reading, so that no episode in flight holds its frames twice.
    /// Sources that keep none ignore it.
    fn drop_stored(&mut self, _unused: &[crate::episode::ImageEncoding]) {}
    /// Passes over the next episode (None after the last): what a shard does with the
    /// episodes before its range. Reading and dropping it by default; a source that can skip
    /// without decoding does so.
    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.next().map(|e| e.map(|_| ()))
    }
}

/// What a reader needs to know that a dataset may not say.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SourceOptions {
    /// Steps per second, for datasets that store none (RLDS another tool wrote).
    pub fps: Option<u32>,
    /// The robot type of such datasets ("unknown" when not given).
    pub robot_type: Option<String>,
}
