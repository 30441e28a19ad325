//! What a format's reader is to its callers: [`EpisodeSource`], a dataset's [`DatasetInfo`] and
//! its episodes in order, one at a time, or in parts ([`EpisodePart`]) where a source makes
//! long episodes as it reads them; and what a reader needs that a dataset may not say
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
    /// From now on, leaves each episode's rows in the source's files where a sink of the same
    /// format can copy them ([`Episode::stored_rows`]; their pixels then stay there): what an
    /// edit writing the input's format asks. Sources that cannot ignore it.
    fn leave_rows_stored(&mut self) {}
    /// Says that of the episodes from here on, only `episodes` (by index) will be read, the
    /// others passed over ([`EpisodeSource::skip_episode`]): a source that reads its files
    /// ahead then reads ahead theirs alone, and the others' bytes stay on the disk (an edit
    /// dropping episodes). Sources that do not read ahead ignore it.
    fn taking_only(&mut self, _episodes: std::sync::Arc<std::collections::BTreeSet<u64>>) {}
    /// Passes over the next episode (None after the last): what a shard does with the
    /// episodes before its range. Reading and dropping it by default; a source that can skip
    /// without decoding does so.
    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.next().map(|e| e.map(|_| ()))
    }
    /// Whether the source makes its episodes in parts as it reads them
    /// ([`EpisodeSource::next_part`]); a conversion into a sink that writes parts then takes
    /// them so.
    fn makes_parts(&self) -> bool {
        false
    }
    /// The next part of the episode being read (see [`EpisodePart`]), for a sink that writes
    /// episodes in parts ([`crate::export::EpisodeSink::writes_parts`]); None after the last.
    /// By default each episode is one part. Parts and whole episodes are not to be mixed
    /// within an episode.
    fn next_part(&mut self) -> Option<Result<EpisodePart, ExportError>> {
        self.next().map(|e| e.map(EpisodePart::whole))
    }
    /// The next episode's metadata and length without its images (None after the last): what
    /// `edit` chooses episodes by. Reading the episode and dropping its steps by default; a
    /// source that can leave its images unread does so.
    fn skim(&mut self) -> Option<Result<Skimmed, ExportError>> {
        self.next().map(|e| {
            e.map(|e| Skimmed {
                steps: e.steps.len() as u64,
                meta: e.meta,
            })
        })
    }
}

/// An episode's metadata and length, as [`EpisodeSource::skim`] reads them.
#[derive(Clone, Debug, PartialEq)]
pub struct Skimmed {
    pub meta: crate::episode::EpisodeMeta,
    pub steps: u64,
}

/// A stretch of consecutive steps of an episode, as a source that makes long episodes while it
/// reads them hands them on (a recording), so that no one holds a whole episode: `episode`'s
/// steps are the episode's from `first_step` on; its metadata is what is known so far (index,
/// instruction, task changes numbered in the whole episode's steps, and each image feature's
/// statistics over the steps so far where the source carries them); the last part's is the
/// episode's.
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodePart {
    pub episode: Episode,
    pub first_step: usize,
    pub last: bool,
}

impl EpisodePart {
    /// A whole episode as its only part.
    pub fn whole(episode: Episode) -> EpisodePart {
        EpisodePart {
            episode,
            first_step: 0,
            last: true,
        }
    }

    /// The episode's steps up to the end of this part.
    pub fn steps_so_far(&self) -> usize {
        self.first_step + self.episode.steps.len()
    }
}

/// Gathers an episode's parts into the whole episode (for a sink that writes whole episodes).
#[derive(Default)]
pub struct Gathering {
    episode: Option<Episode>,
}

impl Gathering {
    /// Takes the next part; the last gives the whole episode. A part that does not continue
    /// the episode gathered so far is an internal error.
    pub fn take(&mut self, part: EpisodePart) -> Result<Option<Episode>, ExportError> {
        let EpisodePart {
            episode: mut piece,
            first_step,
            last,
        } = part;
        let so_far = self.episode.as_ref().map_or(0, |e| e.steps.len());
        if first_step != so_far
            || self
                .episode
                .as_ref()
                .is_some_and(|e| e.meta.index != piece.meta.index)
        {
            return Err(ExportError::Internal(format!(
                "episode {}: a part from step {first_step} arrived after {so_far} steps",
                piece.meta.index
            )));
        }
        if let Some(mut gathered) = self.episode.take() {
            gathered.steps.append(&mut piece.steps);
            piece.steps = gathered.steps;
        }
        if last {
            return Ok(Some(piece));
        }
        self.episode = Some(piece);
        Ok(None)
    }
}

/// One feature made of one or more of the input's keys, concatenated (`convert --map`; the
/// Open X-Embodiment rules of [`crate::export::rlds::mapping`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Joined {
    /// The LeRobot name, `action` or `observation.state`.
    pub name: String,
    /// RLDS keys, in concatenation order.
    pub keys: Vec<String>,
    /// One name per value, as a map file gives them; empty: each part's name (indexed).
    pub names: Vec<String>,
}

/// What a reader needs to know that a dataset may not say.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SourceOptions {
    /// Steps per second, for datasets that store none (RLDS another tool wrote).
    pub fps: Option<u32>,
    /// The robot type of such datasets ("unknown" when not given).
    pub robot_type: Option<String>,
    /// Features of an RLDS dataset another tool wrote, made of its keys (`convert --map`), in
    /// place of or beside those [`crate::export::rlds::mapping::Mapping`]'s rules find.
    pub map: Vec<Joined>,
    /// Read another tool's float64 LeRobot features as float32 (`convert --cast float32`);
    /// without it they are refused by name, since surgvla's vectors are float32.
    pub float64_as_float32: bool,
    /// The features the user leaves out (`convert --without`), for a reader that must leave
    /// one out before reading it: video in a codec surgvla has no decoder for (HEVC, VP9),
    /// which is otherwise refused at opening. Such features are named in
    /// [`crate::export::info::DatasetInfo::omitted`].
    pub without: Vec<String>,
}
