//! The ordered pipeline every pass over datasets' episodes shares: `convert`, every merge and
//! `validate --replay`. [`Episodes`] reads sources in turn (numbered on from 0 for a merge),
//! skipping without decoding those a resumed sink already holds; [`in_order`] hands them to a
//! consumer in batches of one episode per worker thread of the current pool, reading the next
//! batch while the consumer works on this one (reading is partly serial: parquet rows, image
//! decoding), so batches arrive in order and the output is as if episodes went one by one.
//! [`in_order_prepared`] also prepares each episode read on the reading side (`convert` into a
//! sink with a detached encoder encodes there, and the consuming thread only appends).

use crate::episode::Episode;
use crate::export::error::ExportError;
use crate::export::source::EpisodeSource;

/// The episodes of some sources in turn, read in batches.
pub struct Episodes<'a> {
    sources: Vec<&'a mut (dyn EpisodeSource + Send)>,
    /// The source being read.
    current: usize,
    /// Episodes still to skip (a resumed sink holds them).
    skip: u64,
    /// Whether episodes are numbered on across sources (a merge), or keep their index.
    renumber: bool,
    /// Episodes read or skipped so far.
    read: u64,
}

impl<'a> Episodes<'a> {
    /// The episodes of `sources` in turn, each keeping its index (one source: a conversion).
    pub fn of(sources: Vec<&'a mut (dyn EpisodeSource + Send)>) -> Self {
        Episodes {
            sources,
            current: 0,
            skip: 0,
            renumber: false,
            read: 0,
        }
    }

    /// Numbered on from 0 across the sources (a merge).
    pub fn renumbered(mut self) -> Self {
        self.renumber = true;
        self
    }

    /// Without the first `count` episodes, skipped unread where a source can
    /// ([`EpisodeSource::skip_episode`]): those a resumed sink holds.
    pub fn skipping(mut self, count: u64) -> Self {
        self.skip = count;
        self
    }

    /// Up to `size` episodes; empty once every source is read.
    pub fn next_batch(&mut self, size: usize) -> Result<Vec<Episode>, ExportError> {
        let mut batch = Vec::with_capacity(size);
        while batch.len() < size {
            let Some(source) = self.sources.get_mut(self.current) else {
                break;
            };
            if self.skip > 0 {
                match source.skip_episode() {
                    Some(skipped) => {
                        skipped?;
                        self.skip -= 1;
                        self.read += 1;
                    }
                    None => self.current += 1,
                }
                continue;
            }
            match source.next() {
                Some(episode) => {
                    let mut episode = episode?;
                    if self.renumber {
                        episode.meta.index = self.read;
                    }
                    self.read += 1;
                    batch.push(episode);
                }
                None => self.current += 1,
            }
        }
        Ok(batch)
    }
}

/// Every batch of `episodes` into `consume`, in order, on the current thread pool (batches of
/// one episode per thread), the next batch read while `consume` works; `progress` hears the
/// episodes read (or skipped) through each consumed batch. A read error (`read_error` makes it
/// the caller's) stops the pass after the batches before it are consumed.
pub fn in_order<E: Send>(
    episodes: &mut Episodes<'_>,
    read_error: impl Fn(ExportError) -> E,
    consume: &mut (dyn FnMut(Vec<Episode>) -> Result<(), E> + Send),
    progress: &mut (dyn FnMut(u64) + Send),
) -> Result<(), E> {
    let size = rayon::current_num_threads().max(1);
    let read = |episodes: &mut Episodes<'_>| episodes.next_batch(size).map(Ok);
    in_order_read(episodes, read_error, read, consume, progress)
}

/// [`in_order`], each episode read handed to `prepare` on the reading side, the batch's
/// episodes in parallel (a sink's detached encoder: the thread that consumes then only
/// appends, while the next batch is read and encoded). An error of `prepare` stops the pass
/// as a read error does.
pub fn in_order_prepared<T: Send, E: Send>(
    episodes: &mut Episodes<'_>,
    read_error: impl Fn(ExportError) -> E,
    prepare: &(dyn Fn(Episode) -> Result<T, E> + Sync),
    consume: &mut (dyn FnMut(Vec<T>) -> Result<(), E> + Send),
    progress: &mut (dyn FnMut(u64) + Send),
) -> Result<(), E> {
    use rayon::prelude::*;
    let size = rayon::current_num_threads().max(1);
    // (A read error is made the caller's on this thread: `read_error` need not be `Sync`.)
    let read = |episodes: &mut Episodes<'_>| -> Result<Result<Vec<T>, E>, ExportError> {
        let batch = episodes.next_batch(size)?;
        Ok(if batch.len() < 2 {
            batch.into_iter().map(prepare).collect()
        } else {
            batch.into_par_iter().map(prepare).collect()
        })
    };
    in_order_read(episodes, read_error, read, consume, progress)
}

/// The pass both share: each batch `read` makes consumed while the next one is read.
fn in_order_read<T: Send, E: Send>(
    episodes: &mut Episodes<'_>,
    read_error: impl Fn(ExportError) -> E,
    read: impl Fn(&mut Episodes<'_>) -> Result<Result<Vec<T>, E>, ExportError> + Sync,
    consume: &mut (dyn FnMut(Vec<T>) -> Result<(), E> + Send),
    progress: &mut (dyn FnMut(u64) + Send),
) -> Result<(), E> {
    let mut next = read(episodes).map_err(&read_error)??;
    while !next.is_empty() {
        let batch = std::mem::take(&mut next);
        let read_through = episodes.read;
        let (consumed, read) = rayon::join(|| consume(batch), || read(episodes));
        consumed?;
        progress(read_through);
        next = read.map_err(&read_error)??;
    }
    progress(episodes.read);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::info::DatasetInfo;

    /// `count` episodes numbered from `first`, failing at `fail_at` when given; counts what
    /// was decoded.
    struct Numbers {
        info: DatasetInfo,
        next: u64,
        end: u64,
        fail_at: Option<u64>,
        decoded: u64,
    }

    fn numbers(first: u64, count: u64, fail_at: Option<u64>) -> Numbers {
        let info = DatasetInfo::from_surgvla_json(&serde_json::Value::Null, 5, "r", Vec::new());
        Numbers {
            info,
            next: first,
            end: first + count,
            fail_at,
            decoded: 0,
        }
    }

    impl Iterator for Numbers {
        type Item = Result<Episode, ExportError>;

        fn next(&mut self) -> Option<Self::Item> {
            (self.next < self.end).then(|| {
                self.next += 1;
                if Some(self.next - 1) == self.fail_at {
                    return Err(ExportError::Internal("broken".into()));
                }
                self.decoded += 1;
                Ok(crate::episode::empty_episode(
                    self.next - 1,
                    100 + self.next - 1,
                ))
            })
        }
    }

    impl EpisodeSource for Numbers {
        fn info(&self) -> &DatasetInfo {
            &self.info
        }

        fn len(&self) -> u64 {
            self.end - self.next
        }

        fn skip_episode(&mut self) -> Option<Result<(), ExportError>> {
            (self.next < self.end).then(|| {
                self.next += 1;
                Ok(())
            })
        }
    }

    fn pass(episodes: &mut Episodes<'_>, threads: usize) -> (Vec<(u64, u64)>, Vec<u64>) {
        let pool = crate::threads::pool(threads).expect("pool");
        let (mut seen, mut heard) = (Vec::new(), Vec::new());
        pool.install(|| {
            in_order(
                episodes,
                |e| e,
                &mut |batch| {
                    seen.extend(batch.iter().map(|e| (e.meta.index, e.meta.seed)));
                    Ok(())
                },
                &mut |read| heard.push(read),
            )
        })
        .expect("a pass");
        (seen, heard)
    }

    #[test]
    fn sources_in_turn_renumbered_past_the_skipped_in_order() {
        for threads in 1..=3 {
            let (mut a, mut b) = (numbers(0, 3, None), numbers(0, 4, None));
            let mut episodes = Episodes::of(vec![&mut a, &mut b]).renumbered().skipping(2);
            let (seen, heard) = pass(&mut episodes, threads);
            let indices: Vec<u64> = seen.iter().map(|s| s.0).collect();
            let seeds: Vec<u64> = seen.iter().map(|s| s.1).collect();
            assert_eq!(indices, [2, 3, 4, 5, 6], "{threads} threads");
            assert_eq!(seeds, [102, 100, 101, 102, 103]);
            assert_eq!(heard.last(), Some(&7));
            assert!(heard.windows(2).all(|w| w[0] <= w[1]), "{heard:?}");
            assert_eq!(a.decoded, 1, "the skipped are not decoded");
        }
    }

    #[test]
    fn a_conversion_keeps_indices_and_a_read_error_stops_after_the_batches_before() {
        let mut source = numbers(0, 5, None);
        let (seen, _) = pass(&mut Episodes::of(vec![&mut source]), 2);
        assert_eq!(
            seen.iter().map(|s| s.0).collect::<Vec<_>>(),
            [0, 1, 2, 3, 4]
        );
        let mut broken = numbers(0, 9, Some(5));
        let pool = crate::threads::pool(2).expect("pool");
        let mut consumed = Vec::new();
        let result = pool.install(|| {
            in_order(
                &mut Episodes::of(vec![&mut broken]),
                |e| e.to_string(),
                &mut |batch| {
                    consumed.extend(batch.iter().map(|e| e.meta.index));
                    Ok(())
                },
                &mut |_| {},
            )
        });
        assert!(result.expect_err("broken").contains("broken"));
        assert_eq!(consumed, [0, 1, 2, 3], "the batches before the error");
    }

    #[test]
    fn prepared_episodes_arrive_in_order_and_a_prepare_error_stops_after_the_batches_before() {
        for threads in 1..=3 {
            let pool = crate::threads::pool(threads).expect("pool");
            let mut source = numbers(0, 9, None);
            let (mut consumed, mut heard) = (Vec::new(), Vec::new());
            let result = pool.install(|| {
                in_order_prepared(
                    &mut Episodes::of(vec![&mut source]),
                    |e| e.to_string(),
                    &|episode| match episode.meta.index {
                        7 => Err("unpreparable 7".to_string()),
                        i => Ok(i * 10),
                    },
                    &mut |batch| {
                        consumed.extend(batch);
                        Ok(())
                    },
                    &mut |read| heard.push(read),
                )
            });
            assert_eq!(
                result,
                Err("unpreparable 7".to_string()),
                "{threads} threads"
            );
            let before = 7 - 7 % threads as u64;
            let expected: Vec<u64> = (0..before).map(|i| i * 10).collect();
            assert_eq!(consumed, expected, "{threads} threads");
            assert_eq!(heard.last().copied().unwrap_or(0), before);
        }
    }
}
