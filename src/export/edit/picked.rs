//! [`Picked`]: the input's chosen episodes in the output's order, renumbered from 0, with
//! features renamed and instructions changed ([`Changes`]). Episodes not chosen are skipped
//! without reading their images; an order that goes back opens the input again. Video that
//! cannot be copied (an episode starting mid-GOP) is refused by name, or encoded again when
//! allowed.

use crate::episode::{Episode, FeatureKind};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::source::EpisodeSource;
use std::sync::{Arc, Mutex};

/// Opens the input again, from its first episode.
pub type Opener = Box<dyn FnMut() -> Result<Box<dyn EpisodeSource + Send>, ExportError> + Send>;

/// What an edit changes in the episodes it keeps.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Changes {
    /// (old, new) feature keys.
    pub renames: Vec<(String, String)>,
    /// Every episode's instruction (`--set-task`).
    pub set_task: Option<String>,
    /// (old, new) instructions (`--map-tasks`), matched exactly.
    pub task_map: Vec<(String, String)>,
}

impl Changes {
    /// `info` with the features renamed; a rename of a feature the input lacks, onto a key it
    /// has, or of one of surgvla's roles other than the camera is refused by name.
    pub fn apply_to_info(&self, info: &mut DatasetInfo) -> Result<(), String> {
        for (old, new) in &self.renames {
            let keys: Vec<String> = info.features.iter().map(|f| f.name.clone()).collect();
            if info.features.iter().any(|f| &f.name == new) {
                return Err(format!(
                    "--rename-feature {old}={new}: the input has a feature {new} already"
                ));
            }
            let feature = (info.features.iter_mut())
                .find(|f| &f.name == old)
                .ok_or_else(|| {
                    format!(
                        "--rename-feature {old}={new}: the input has no feature {old} (its features: {})",
                        keys.join(", ")
                    )
                })?;
            if !matches!(feature.kind, FeatureKind::Other | FeatureKind::Rgb) {
                return Err(format!(
                    "--rename-feature {old}={new}: {old} is the dataset's {:?}, whose name surgvla's readers look for",
                    feature.kind
                ));
            }
            if new.is_empty() || new.contains('/') || new.chars().any(char::is_control) {
                return Err(format!(
                    "--rename-feature {old}={new}: a feature key is a non-empty name without '/'"
                ));
            }
            feature.name = new.clone();
        }
        Ok(())
    }

    /// The instruction `text` becomes.
    fn instruction(&self, text: &str) -> String {
        if let Some(task) = &self.set_task {
            return task.clone();
        }
        (self.task_map.iter())
            .find(|(old, _)| old == text)
            .map_or_else(|| text.to_string(), |(_, new)| new.clone())
    }

    /// Changes one episode (renumbered `index`).
    fn apply(&self, episode: &mut Episode, index: u64) {
        episode.meta.index = index;
        episode.meta.instruction = self.instruction(&episode.meta.instruction);
        if self.set_task.is_some() {
            episode.meta.task_changes.clear();
        }
        for change in &mut episode.meta.task_changes {
            change.instruction = self.instruction(&change.instruction);
        }
        for (old, new) in &self.renames {
            for encoded in episode.encoded.iter_mut().filter(|e| &e.feature == old) {
                encoded.feature = new.clone();
            }
            for (name, _) in episode.image_stats.iter_mut().filter(|(n, _)| n == old) {
                *name = new.clone();
            }
            if let Some(stored) = &mut episode.stored_rows {
                for (_, now) in stored.columns.iter_mut().filter(|(_, n)| n == old) {
                    *now = new.clone();
                }
            }
        }
    }
}

/// What to do with video that cannot be copied.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Uncopyable {
    /// Refuse it, naming the episode (the default).
    Refuse,
    /// Encode the episode's video again at this quality (`--allow-reencode`).
    Reencode { quality: u32 },
}

/// The chosen episodes of an input (see the module overview).
pub struct Picked {
    open: Opener,
    inner: Box<dyn EpisodeSource + Send>,
    /// The input index the inner source reads next.
    position: u64,
    /// Input indices, in output order.
    order: Vec<u64>,
    /// The same, as a set: told to the inner source, which reads ahead theirs alone.
    taken: Arc<std::collections::BTreeSet<u64>>,
    /// The output index of the next episode.
    next: usize,
    info: DatasetInfo,
    changes: Changes,
    uncopyable: Uncopyable,
    /// (output index, feature) of every episode whose video was encoded again.
    reencoded: Arc<Mutex<Vec<(u64, String)>>>,
    /// Stored encodings the sink does not copy, told again to a reopened input.
    unused: Vec<crate::episode::ImageEncoding>,
}

impl Picked {
    /// The episodes `order` names (input indices) of the source `open` opens, changed by
    /// `changes`; `info` is the output's (features renamed, splits set by the caller).
    pub fn new(
        mut open: Opener,
        order: Vec<u64>,
        info: DatasetInfo,
        changes: Changes,
        uncopyable: Uncopyable,
    ) -> Result<Self, ExportError> {
        let mut inner = open()?;
        let taken = Arc::new(order.iter().copied().collect());
        inner.taking_only(Arc::clone(&taken));
        Ok(Picked {
            open,
            inner,
            position: 0,
            order,
            taken,
            next: 0,
            info,
            changes,
            uncopyable,
            reencoded: Arc::default(),
            unused: Vec::new(),
        })
    }

    /// Where the episodes encoded again are listed, (output index, feature).
    pub fn reencoded(&self) -> Arc<Mutex<Vec<(u64, String)>>> {
        self.reencoded.clone()
    }

    /// Brings the inner source to input episode `wanted`.
    fn seek(&mut self, wanted: u64) -> Result<(), ExportError> {
        if wanted < self.position {
            self.inner = (self.open)()?;
            self.inner.drop_stored(&self.unused);
            self.inner.taking_only(Arc::clone(&self.taken));
            self.position = 0;
        }
        while self.position < wanted {
            match self.inner.skip_episode() {
                Some(skipped) => skipped?,
                None => {
                    return Err(ExportError::Internal(format!(
                        "the input ended before episode {wanted}"
                    )));
                }
            }
            self.position += 1;
        }
        Ok(())
    }

    fn read(&mut self, wanted: u64, index: u64) -> Result<Episode, ExportError> {
        self.seek(wanted)?;
        let mut episode = self.inner.next().ok_or_else(|| {
            ExportError::Internal(format!("the input ended before episode {wanted}"))
        })??;
        self.position += 1;
        let stuck = episode
            .encoded
            .iter()
            .find(|e| {
                e.shown.is_some() && matches!(e.encoding, crate::episode::ImageEncoding::Video(_))
            })
            .map(|e| e.feature.clone());
        if let Some(feature) = stuck {
            let Uncopyable::Reencode { quality } = self.uncopyable else {
                return Err(ExportError::InvalidOptions(format!(
                    "input episode {wanted}: its {feature} video does not start on a keyframe or is not one frame per row, so its samples cannot be copied alone; give --allow-reencode to encode this episode's video again (the others are still copied)"
                )));
            };
            let input_info = self.inner.info().clone();
            let done =
                crate::export::decoded::reencode_uncopyable(&mut episode, &input_info, quality)?;
            let mut reencoded = self.reencoded.lock().unwrap_or_else(|e| e.into_inner());
            reencoded.extend(done.into_iter().map(|f| (index, f)));
        }
        self.changes.apply(&mut episode, index);
        Ok(episode)
    }
}

impl Iterator for Picked {
    type Item = Result<Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        let wanted = *self.order.get(self.next)?;
        let index = self.next as u64;
        self.next += 1;
        let episode = self.read(wanted, index);
        if episode.is_err() {
            self.next = self.order.len();
        }
        Some(episode)
    }
}

impl EpisodeSource for Picked {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.order.len() as u64
    }

    /// Nothing is read: the next episode wanted moves on.
    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.order.get(self.next)?;
        self.next += 1;
        Some(Ok(()))
    }

    fn drop_stored(&mut self, unused: &[crate::episode::ImageEncoding]) {
        self.unused = unused.to_vec();
        self.inner.drop_stored(unused);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeSet;

    /// A source of `count` empty episodes that notes what it is told it will take.
    struct Told {
        info: DatasetInfo,
        next: u64,
        count: u64,
        told: Arc<Mutex<Vec<BTreeSet<u64>>>>,
    }

    impl Iterator for Told {
        type Item = Result<Episode, ExportError>;

        fn next(&mut self) -> Option<Self::Item> {
            (self.next < self.count).then(|| {
                self.next += 1;
                Ok(crate::episode::empty_episode(self.next - 1, 0))
            })
        }
    }

    impl EpisodeSource for Told {
        fn info(&self) -> &DatasetInfo {
            &self.info
        }

        fn len(&self) -> u64 {
            self.count
        }

        fn taking_only(&mut self, episodes: Arc<BTreeSet<u64>>) {
            let mut told = self.told.lock().unwrap();
            told.push(episodes.as_ref().clone());
        }
    }

    /// The source is told the episodes the edit takes when it is opened, and again when it is
    /// opened anew to go back (an output whose episodes are not in the input's order).
    #[test]
    fn the_input_is_told_the_episodes_taken_each_time_it_opens() {
        let info = DatasetInfo::from_surgvla_json(&serde_json::Value::Null, 5, "r", Vec::new());
        let told: Arc<Mutex<Vec<BTreeSet<u64>>>> = Arc::default();
        let (opened_info, opened_told) = (info.clone(), Arc::clone(&told));
        let open: Opener = Box::new(move || {
            Ok(Box::new(Told {
                info: opened_info.clone(),
                next: 0,
                count: 6,
                told: Arc::clone(&opened_told),
            }) as Box<dyn EpisodeSource + Send>)
        });
        let mut picked = Picked::new(
            open,
            vec![4, 1],
            info,
            Changes::default(),
            Uncopyable::Refuse,
        )
        .expect("opens");
        let taken: BTreeSet<u64> = [1, 4].into_iter().collect();
        assert_eq!(*told.lock().unwrap(), vec![taken.clone()]);
        let read: Vec<u64> = (picked.by_ref())
            .map(|e| e.expect("episode").meta.index)
            .collect();
        assert_eq!(read, vec![0, 1], "numbered in the output's order");
        assert_eq!(
            *told.lock().unwrap(),
            vec![taken.clone(), taken],
            "told again"
        );
    }
}
