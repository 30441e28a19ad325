//! Splitting one run across machines: [`Sharded`], the source that reads one [`Shard`] ("I/N",
//! the I-th of N contiguous ranges, what `collect --shard` and `convert --shard` take; defined
//! with the collection record that stores it) of a dataset's episodes. Shards in order hold exactly the episodes of the whole run,
//! and `merge` joins them back ([`crate::export::registry::merge`]).
//!
//! A shard records itself where the dataset records how it was made: the `shard` key of its
//! collection ([`crate::export::info::DatasetInfo::collection`]), so a merge can put shards in order
//! and, given all N of N, say "0/1" again, as the single run does. A dataset another tool made
//! has no collection: its shards record nothing, and a merge keeps the order it is given.

use crate::episode::Episode;
use crate::export::collection::{RecordedShard, Shard};
use crate::export::error::ExportError;
use crate::export::info::DatasetInfo;
use crate::export::source::EpisodeSource;

/// One shard of a source's episodes, numbered from 0 again; its info's collection says which
/// shard it is (when the dataset has a collection).
pub struct Sharded {
    inner: Box<dyn EpisodeSource + Send>,
    info: DatasetInfo,
    range: std::ops::Range<u64>,
    /// Episodes of `inner` read so far (skipped or returned).
    read: u64,
}

impl Sharded {
    /// The `shard` of `inner`'s episodes. Refuses a shard that would hold no episode, and a
    /// dataset that is itself a part of a larger run (its collection says a shard other than
    /// "0/1": merge the parts first).
    pub fn new(inner: Box<dyn EpisodeSource + Send>, shard: Shard) -> Result<Self, ExportError> {
        let total = inner.len();
        let range = shard.range(total as usize);
        let range = range.start as u64..range.end as u64;
        if range.is_empty() {
            return Err(ExportError::InvalidOptions(format!(
                "shard {shard} would hold no episode: the input has {total}; use at most {total} shards"
            )));
        }
        let mut info = inner.info().clone();
        if let Some(collection) = &mut info.collection {
            if let Some(part) = collection.shard_text()
                && part != Shard::default().to_string()
            {
                return Err(ExportError::InvalidOptions(format!(
                    "the input is itself shard {part} of a larger run: merge its shards first, then shard the whole"
                )));
            }
            collection.set_shard(&RecordedShard::Part(shard));
        }
        // The input's named splits, as they fall in the shard.
        info.splits = (info.splits.iter())
            .filter_map(|(name, split)| {
                let from = split.start.max(range.start) - range.start;
                let to = split.end.min(range.end).saturating_sub(range.start);
                (from < to).then(|| (name.clone(), from..to))
            })
            .collect();
        // What a resume compares besides the options: another shard of the same input is
        // another input (a dataset another tool made has no collection to say it).
        info.input = Some(match &info.input {
            Some(input) => format!("{input}, shard {shard}"),
            None => format!("shard {shard}"),
        });
        Ok(Sharded {
            inner,
            info,
            range,
            read: 0,
        })
    }
}
impl Iterator for Sharded {
    type Item = Result<Episode, ExportError>;

    fn next(&mut self) -> Option<Self::Item> {
        while self.read < self.range.start {
            match self.inner.skip_episode()? {
                Ok(()) => self.read += 1,
                Err(error) => return Some(Err(error)),
            }
        }
        if self.read >= self.range.end {
            return None;
        }
        let episode = self.inner.next()?;
        self.read += 1;
        let start = self.range.start;
        Some(episode.map(|mut e| {
            e.meta.index -= start;
            e
        }))
    }
}

impl EpisodeSource for Sharded {
    fn info(&self) -> &DatasetInfo {
        &self.info
    }

    fn len(&self) -> u64 {
        self.range.end - self.range.start
    }

    fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
        self.next().map(|e| e.map(|_| ()))
    }

    fn drop_stored(&mut self, unused: &[crate::episode::ImageEncoding]) {
        self.inner.drop_stored(unused);
    }

    fn leave_rows_stored(&mut self) {
        self.inner.leave_rows_stored();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU64, Ordering};

    /// Episodes 0..total with nothing in them; counts what was decoded and what skipped.
    struct Numbers {
        info: DatasetInfo,
        total: u64,
        next: u64,
        decoded: Arc<AtomicU64>,
        skipped: Arc<AtomicU64>,
    }

    fn numbers(total: u64, collection: serde_json::Value) -> Numbers {
        let surgvla = json!({ "collection": collection });
        Numbers {
            info: DatasetInfo::from_surgvla_json(&surgvla, 5, "robot", Vec::new()),
            total,
            next: 0,
            decoded: Arc::default(),
            skipped: Arc::default(),
        }
    }
    impl Iterator for Numbers {
        type Item = Result<Episode, ExportError>;

        fn next(&mut self) -> Option<Self::Item> {
            (self.next < self.total).then(|| {
                self.next += 1;
                self.decoded.fetch_add(1, Ordering::Relaxed);
                Ok(crate::episode::empty_episode(self.next - 1, self.next - 1))
            })
        }
    }

    impl EpisodeSource for Numbers {
        fn info(&self) -> &DatasetInfo {
            &self.info
        }

        fn len(&self) -> u64 {
            self.total
        }

        fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
            (self.next < self.total).then(|| {
                self.next += 1;
                self.skipped.fetch_add(1, Ordering::Relaxed);
                Ok(())
            })
        }
    }

    /// Seeded sizes: the shards of 1..=40 episodes in N = 1..=total parts hold every episode
    /// once, in order, each numbered from 0, decoding only its own.
    #[test]
    fn shards_in_order_hold_every_episode_once_and_decode_only_their_own() {
        let mut rng = crate::rng::SplitMix64::new(27);
        for _ in 0..60 {
            let total = 1 + rng.next_u64() % 40;
            let count = 1 + (rng.next_u64() % total) as u32;
            let mut seeds = Vec::new();
            for index in 0..count {
                let shard = Shard { index, count };
                let inner = numbers(total, json!({"seed": 0, "shard": "0/1"}));
                let (decoded, skipped) = (inner.decoded.clone(), inner.skipped.clone());
                let mut sharded = Sharded::new(Box::new(inner), shard).expect("a shard");
                let collection = sharded.info().collection.as_ref().expect("recorded");
                assert_eq!(collection.shard_text(), Some(shard.to_string().as_str()));
                assert_eq!(collection.shard(), Some(RecordedShard::Part(shard)));
                let mut k = 0;
                for episode in sharded.by_ref() {
                    let episode = episode.expect("episode");
                    assert_eq!(episode.meta.index, k, "numbered from 0");
                    seeds.push(episode.meta.seed);
                    k += 1;
                }
                assert_eq!(k, sharded.len());
                let range = shard.range(total as usize);
                assert_eq!(decoded.load(Ordering::Relaxed), range.len() as u64);
                assert_eq!(skipped.load(Ordering::Relaxed), range.start as u64);
            }
            assert_eq!(seeds, (0..total).collect::<Vec<_>>(), "{total} in {count}");
        }
        let source = numbers(10, serde_json::Value::Null);
        let shard = Shard { index: 2, count: 3 };
        let mut sharded = Sharded::new(Box::new(source), shard).expect("a shard");
        assert!(
            sharded.info().collection.is_none(),
            "another tool's: nothing recorded"
        );
        let seeds: Vec<u64> = std::iter::from_fn(|| sharded.next())
            .map(|e| e.expect("episode").meta.seed)
            .collect();
        assert_eq!(seeds, [6, 7, 8, 9]);
    }

    #[test]
    fn an_empty_shard_and_the_shard_of_a_shard_are_refused() {
        let empty = Sharded::new(
            Box::new(numbers(2, json!({}))),
            Shard { index: 0, count: 3 },
        );
        assert!(
            empty
                .err()
                .is_some_and(|e| e.to_string().contains("no episode"))
        );
        let part = numbers(4, json!({"shard": "1/2"}));
        let nested = Sharded::new(Box::new(part), Shard { index: 0, count: 2 });
        assert!(
            nested
                .err()
                .is_some_and(|e| e.to_string().contains("itself shard 1/2"))
        );
    }
}
