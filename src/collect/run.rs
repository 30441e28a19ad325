//! A whole collection: the list of episode slots, sharding, parallel verified recording, and
//! streaming to an exporter in episode order.
//!
//! The job list is `episodes_per_task` *slots* per task, in task order. Slot `k` of a task tries
//! attempt seeds ([`attempt_seed`]) in order until one passes both the expert's success check
//! and the replay of its dataset actions; failed attempts are counted, not saved. What a slot
//! holds is a function of (seed, task, k) alone, so:
//! - output is identical for any thread count (slots are recorded in parallel, written in
//!   order);
//! - `--shard I/N` takes the I-th of N contiguous ranges of slots, and the shards in order hold
//!   exactly the episodes of the unsharded run;
//! - a resumed run skips the slots already written and recounts their attempts without
//!   rendering, so its report matches an uninterrupted run's.

use crate::collect::record::{attempt_seed, render_replay_with, run_expert, verify_replay};
use crate::collect::report::Tally;
pub use crate::collect::report::{CollectReport, TaskReport, Timing};
pub use crate::collect::slot::{
    BadOptions, BadShard, CollectOptions, Failure, FailureStage, MAX_THREADS_PER_CORE, Shard, Slot,
    SlotOutcome, cores,
};
use crate::episode::Episode;
use crate::episode::FeatureSet;
use crate::export::DatasetInfo;
use crate::export::collection::{Collection, RecordedShard, RunRecord};
use crate::export::{DetachedEncoder, Encoded, EpisodeSink, ExportError, Summary};
use crate::policy::{ExpertLibrary, PlanError};
use crate::task::TaskId;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Instant;

/// What stops a collection.
#[derive(Debug, thiserror::Error)]
pub enum CollectError {
    #[error(transparent)]
    Plan(#[from] PlanError),
    #[error(transparent)]
    Export(#[from] ExportError),
    #[error(transparent)]
    Options(#[from] BadOptions),
    #[error(
        "{task} episode {k}: no verified episode in {attempts} attempts; last failure: {reason}"
    )]
    Exhausted {
        task: TaskId,
        k: u64,
        attempts: u32,
        reason: String,
    },
    #[error(transparent)]
    Threads(#[from] crate::threads::NoThreads),
}

impl crate::error::HasKind for CollectError {
    /// Whose mistake it is (see [`crate::error::ErrorKind`]).
    fn kind(&self) -> crate::error::ErrorKind {
        match self {
            CollectError::Plan(e) => e.kind(),
            CollectError::Export(e) => e.kind(),
            CollectError::Options(_) => crate::error::ErrorKind::Usage,
            _ => crate::error::ErrorKind::Failed,
        }
    }

    /// Whether the disk filled up while writing.
    fn is_disk_full(&self) -> bool {
        matches!(self, CollectError::Export(e) if e.is_disk_full())
    }
}

/// Fills a slot: attempts in order until one verifies or `max_attempts` have failed
/// (`verified` says which). With `render` false the episode is not rendered (counting only; the
/// verdicts are the same).
pub fn collect_slot(
    slot: Slot,
    index: u64,
    options: &CollectOptions,
    library: &ExpertLibrary,
    render: bool,
) -> Result<SlotOutcome, CollectError> {
    collect_slot_encoded(slot, index, options, library, render, None).map(|(outcome, _)| outcome)
}

/// [`collect_slot`] that also encodes the verified episode for a sink with `encoder`: frame
/// by frame while it is rendered when the encoder can ([`DetachedEncoder::frames`]; each
/// frame's buffers are then drawn into again and the episode keeps no pixels), else whole.
pub fn collect_slot_encoded(
    slot: Slot,
    index: u64,
    options: &CollectOptions,
    library: &ExpertLibrary,
    render: bool,
    encoder: Option<&dyn DetachedEncoder>,
) -> Result<(SlotOutcome, Option<Encoded>), CollectError> {
    let plan = library.plan(slot.task)?;
    let record = &options.record;
    let max_steps = record.max_steps.unwrap_or_else(|| slot.task.step_limit());
    let mut outcome = SlotOutcome::empty(slot);
    for attempt in 0..options.max_attempts.max(1) {
        let seed = attempt_seed(options.seed, slot.task, slot.k, attempt);
        let instance = match slot.task.instance(seed, &record.task) {
            Ok(instance) => instance,
            Err(error) => {
                // Not the expert's failure: the scene could not be drawn; try the next seed.
                outcome.failures.push(Failure {
                    slot,
                    attempt,
                    seed,
                    stage: FailureStage::Spawn,
                    reason: error.problem,
                });
                continue;
            }
        };
        outcome.attempts += 1;
        let expert = run_expert(&instance, plan, max_steps, record.gripper)?;
        outcome.physics_secs += expert.physics_secs;
        let fail = |stage, reason: String| Failure {
            slot,
            attempt,
            seed,
            stage,
            reason,
        };
        if !expert.verdict.success {
            outcome
                .failures
                .push(fail(FailureStage::Expert, expert.verdict.reason.clone()));
            continue;
        }
        let mut frames = encoder.and_then(|e| e.frames(expert.actions.len()));
        let verdict = if render {
            let recorded = render_replay_with(
                &instance,
                &expert.actions,
                index,
                outcome.attempts,
                record,
                |step| match frames.as_mut() {
                    Some(frames) => frames.push(step),
                    None => Ok(Vec::new()),
                },
            )?;
            outcome.physics_secs += recorded.physics_secs;
            outcome.render_secs += recorded.render_secs;
            outcome.episode = Some(recorded.episode);
            recorded.verdict
        } else {
            verify_replay(&instance, &expert.actions, record.gripper)
        };
        if verdict.success {
            outcome.frames = expert.actions.len() as u64;
            outcome.verified = true;
            let encoded = match (encoder, &outcome.episode) {
                (Some(encoder), Some(episode)) => Some(match frames {
                    Some(frames) => frames.finish(episode)?,
                    None => encoder.encode(episode)?,
                }),
                _ => None,
            };
            return Ok((outcome, encoded));
        }
        outcome.episode = None;
        outcome
            .failures
            .push(fail(FailureStage::Replay, verdict.reason));
    }
    Ok((outcome, None))
}

impl SlotOutcome {
    /// A slot before its first attempt.
    fn empty(slot: Slot) -> Self {
        SlotOutcome {
            slot,
            verified: false,
            episode: None,
            frames: 0,
            attempts: 0,
            failures: Vec::new(),
            physics_secs: 0.0,
            render_secs: 0.0,
        }
    }

    /// The error of a slot whose every attempt failed, if this one did.
    pub fn exhausted(&self) -> Option<CollectError> {
        (!self.verified).then(|| CollectError::Exhausted {
            task: self.slot.task,
            k: self.slot.k,
            attempts: self.attempts,
            reason: self
                .failures
                .last()
                .map_or_else(String::new, |f| f.reason.clone()),
        })
    }
}

/// Receives progress (the command line draws bars from it).
pub trait CollectProgress {
    /// Before any work: this shard's slots, and how many of them are already written.
    fn start(&mut self, _slots: &[Slot], _already_written: usize) {}
    /// After a slot's episode is written (or recounted, for already written slots).
    fn slot_done(&mut self, _outcome: &SlotOutcome) {}
}

/// No progress output.
pub struct Silent;

impl CollectProgress for Silent {}

/// The worker pool of a run and its size.
fn worker_pool(options: &CollectOptions) -> Result<(rayon::ThreadPool, usize), CollectError> {
    options.check()?;
    let threads = if options.threads == 0 {
        cores()
    } else {
        options.threads
    };
    let pool = crate::threads::pool(threads)?;
    Ok((pool, threads))
}

/// What a run's slots are recorded with: its options, the experts, and the worker pool with its
/// size.
#[derive(Clone, Copy)]
struct Workers<'a> {
    options: &'a CollectOptions,
    library: &'a ExpertLibrary,
    pool: &'a rayon::ThreadPool,
    threads: usize,
}

/// Fills `slots` (the `first`-th onward) without rendering, reporting each to `tally` and
/// `progress` in order; with `strict`, a slot whose every attempt failed is an error.
fn count_slots(
    strict: bool,
    (slots, first): (&[Slot], usize),
    workers: Workers<'_>,
    tally: &mut Tally,
    progress: &mut dyn CollectProgress,
) -> Result<(), CollectError> {
    let Workers {
        options,
        library,
        pool,
        ..
    } = workers;
    for (c, chunk) in slots.chunks(64).enumerate() {
        let start = first + c * 64;
        let outcomes: Vec<Result<SlotOutcome, CollectError>> = pool.install(|| {
            chunk
                .par_iter()
                .enumerate()
                .map(|(i, slot)| collect_slot(*slot, (start + i) as u64, options, library, false))
                .collect()
        });
        for outcome in outcomes {
            let outcome = outcome?;
            if let (true, Some(error)) = (strict, outcome.exhausted()) {
                return Err(error);
            }
            tally.add(&outcome, 0.0);
            progress.slot_done(&outcome);
        }
    }
    Ok(())
}

/// Runs every slot's attempts as [`collect`] would (expert, replay check) without rendering or
/// writing: the experts' success rates for a set of options. The report's dataset is empty.
pub fn measure_experts(
    options: &CollectOptions,
    library: &ExpertLibrary,
    progress: &mut dyn CollectProgress,
) -> Result<CollectReport, CollectError> {
    let started = Instant::now();
    let slots = options.slots();
    let (pool, threads) = worker_pool(options)?;
    progress.start(&slots, 0);
    let mut tally = Tally::new(options);
    let workers = Workers {
        options,
        library,
        pool: &pool,
        threads,
    };
    count_slots(false, (&slots, 0), workers, &mut tally, progress)?;
    let range = options.shard.range(options.all_slots().len());
    let wall_secs = started.elapsed().as_secs_f64();
    Ok(tally.finish(
        options,
        Summary::default(),
        threads,
        0,
        [range.start, range.end],
        Timing {
            wall_secs,
            ..Timing::default()
        },
    ))
}

/// Writes consecutive recorded episodes to `sink`: what its pipelined side's encoder made of
/// each when every one was encoded, else the episodes in a batch on `pool`.
fn write_ready(
    sink: &mut (dyn EpisodeSink + Send),
    pool: &rayon::ThreadPool,
    episodes: Vec<(Episode, Option<Encoded>)>,
) -> Result<(), CollectError> {
    let all_encoded = episodes.iter().all(|(_, encoded)| encoded.is_some());
    match sink.pipelined() {
        Some(pipelined) if all_encoded => {
            let encoded = episodes
                .into_iter()
                .filter_map(|(episode, encoded)| Some((episode, encoded?)))
                .collect();
            pipelined.sink.write_encoded(encoded)?;
        }
        _ => {
            let episodes: Vec<Episode> = episodes.into_iter().map(|(e, _)| e).collect();
            pool.install(|| sink.write_batch(&episodes))?;
        }
    }
    Ok(())
}

/// Records `slots` (the `first`-th onward) on `pool` and writes their episodes to `sink` in
/// slot order, reporting each to `tally` and `progress`.
///
/// A stream, not batches: each worker takes the next slot as soon as it is free, and the calling
/// thread hands each episode to the sink the moment every episode before it is written (the
/// sink's encoding runs as jobs on the same pool, between recordings). At most
/// [`episodes_in_flight`] episodes are recorded ahead of the writer, so memory stays flat; no
/// core waits for the slowest episode of a batch.
fn record_and_write(
    (slots, first): (&[Slot], usize),
    workers: Workers<'_>,
    sink: &mut (dyn EpisodeSink + Send),
    tally: &mut Tally,
    progress: &mut dyn CollectProgress,
) -> Result<(), CollectError> {
    let (options, library) = (workers.options, workers.library);
    let (pool, threads) = (workers.pool, workers.threads);
    let window = episodes_in_flight(threads);
    let stop = AtomicBool::new(false);
    // With a detached encoder, a worker encodes the episode it recorded and this thread only
    // appends; without one, the sink's batches run on the pool.
    let encoder = sink.pipelined().map(|pipelined| pipelined.encoder);
    let (done, arrivals) = mpsc::channel::<(usize, Arrival)>();
    pool.in_place_scope(|scope| {
        let record = |i: usize| {
            let reply = Reply {
                slot: i,
                done: Some(done.clone()),
            };
            let stop = &stop;
            let encoder = encoder.clone();
            scope.spawn(move |_| {
                // After a failure the remaining slots are not recorded.
                if stop.load(Ordering::Relaxed) {
                    return;
                }
                let arrival = collect_slot_encoded(
                    slots[i],
                    (first + i) as u64,
                    options,
                    library,
                    true,
                    encoder.as_deref(),
                );
                reply.send(arrival);
            });
        };
        let result = (|| {
            let mut spawned = 0;
            let mut written = 0;
            let mut arrived: BTreeMap<usize, Arrival> = BTreeMap::new();
            let mut last_write = Instant::now();
            while written < slots.len() {
                while spawned < slots.len() && spawned < written + window {
                    record(spawned);
                    spawned += 1;
                }
                // The episodes ready in slot order from `written` on (at least one).
                while !arrived.contains_key(&written) {
                    let (i, arrival) = arrivals.recv().map_err(|_| {
                        CollectError::Export(ExportError::Internal(
                            "a recording job ended without a result".into(),
                        ))
                    })?;
                    arrived.insert(i, arrival);
                }
                let mut ready = Vec::new();
                let mut episodes = Vec::new();
                while ready.len() < threads.max(1) {
                    let Some(arrival) = arrived.remove(&(written + ready.len())) else {
                        break;
                    };
                    let (mut outcome, encoded) = arrival?;
                    if let Some(error) = outcome.exhausted() {
                        return Err(error);
                    }
                    if let Some(episode) = outcome.episode.take() {
                        episodes.push((episode, encoded));
                    }
                    ready.push(outcome);
                }
                write_ready(sink, pool, episodes)?;
                // The time since the last write goes to these episodes' tasks, shared by frames.
                let secs = last_write.elapsed().as_secs_f64();
                last_write = Instant::now();
                let frames: u64 = ready.iter().map(|o| o.frames).sum();
                for outcome in &ready {
                    tally.add(outcome, secs * outcome.frames as f64 / frames.max(1) as f64);
                    progress.slot_done(outcome);
                }
                written += ready.len();
            }
            Ok(())
        })();
        if result.is_err() {
            stop.store(true, Ordering::Relaxed);
        }
        result
    })
}

/// What a recording job has made of slot `slot`, or why it has not.
type Arrival = Result<(SlotOutcome, Option<Encoded>), CollectError>;

/// A recording job's way back to the writer: its result, or, should the job end without one
/// (a panic), an error, so the writer never waits for a slot that will not come.
struct Reply {
    slot: usize,
    done: Option<mpsc::Sender<(usize, Arrival)>>,
}

impl Reply {
    fn send(mut self, arrival: Arrival) {
        if let Some(done) = self.done.take() {
            // The receiver outlives every job (the writer returns only after the scope), so a
            // failed send means the run already stopped: nothing to report.
            let _ = done.send((self.slot, arrival));
        }
    }
}

impl Drop for Reply {
    fn drop(&mut self) {
        if let Some(done) = self.done.take() {
            let _ = done.send((
                self.slot,
                Err(CollectError::Export(ExportError::Internal(
                    "a recording job ended without a result".into(),
                ))),
            ));
        }
    }
}

/// Episodes recorded ahead of the writer at most: enough that a worker never waits on a long
/// episode before it (two per thread), few enough that memory stays flat (each holds its
/// frames' pixels, about 20 MB for 55 frames of RGB, depth and mask at 224 x 224).
pub fn episodes_in_flight(threads: usize) -> usize {
    threads.max(1) * 4 + 2
}

/// What `--randomize-appearance` draws from, stated so that train/test separation is: each
/// dimension's training range (`surgvla eval`'s suites evaluate outside them).
fn appearance_ranges() -> serde_json::Value {
    let mut ranges = serde_json::Map::new();
    for (name, range) in crate::assets::Appearance::TRAINING_RANGES {
        ranges.insert(name.into(), serde_json::json!(range));
    }
    ranges.insert("held_out_by".into(), "suites/dimensions-v1.json".into());
    ranges.into()
}

/// What a collection's dataset is: its features, the camera, the robot and the collection
/// options, with the experts' plans (`library`; custom plans are named with their checksums).
pub fn dataset_info(
    options: &CollectOptions,
    features: FeatureSet,
    library: &ExpertLibrary,
) -> DatasetInfo {
    let record = &options.record;
    let custom = library.is_custom();
    let run = RunRecord {
        seed: options.seed,
        tasks: options.tasks.iter().map(|t| t.code().to_string()).collect(),
        episodes_per_task: options.episodes_per_task,
        shard: RecordedShard::Part(options.shard),
        gripper_encoding: record.gripper,
        distractors: record.task.distractors,
        instructions: record.task.instruction.name().into(),
        spawn_scale: record.task.spawn_scale,
        randomize_appearance: record.randomize_appearance,
        appearance_ranges: record.randomize_appearance.then(appearance_ranges),
        policies: if custom { "custom" } else { "builtin" }.into(),
        success_rules: crate::task::success::RULE_SET.into(),
        custom_plans: custom.then(|| {
            (library.custom_plans().into_iter())
                .map(|(task, crc)| (task.to_string(), crc))
                .collect()
        }),
    };
    crate::view::dataset_info(&record.camera, features, Collection::of(&run))
}

/// The collection's report inside the dataset folder.
pub const REPORT: &str = "collect_report.json";

/// Runs the collection into `sink`, starting at the sink's next episode (after a resume, the
/// episodes before it are already in the sink; they are recounted for the report, not rendered
/// or written). Finishes the sink, with the report ([`REPORT`]) as its last file.
pub fn collect(
    options: &CollectOptions,
    library: &ExpertLibrary,
    sink: &mut (dyn EpisodeSink + Send),
    progress: &mut dyn CollectProgress,
) -> Result<CollectReport, CollectError> {
    let started = Instant::now();
    let slots = options.slots();
    let (pool, threads) = worker_pool(options)?;
    let resume_at = (sink.next_episode_index() as usize).min(slots.len());
    progress.start(&slots, resume_at);
    let mut report = Tally::new(options);
    // Recount what an interrupted run already wrote (physics only).
    let written = &slots[..resume_at];
    let workers = Workers {
        options,
        library,
        pool: &pool,
        threads,
    };
    count_slots(true, (written, 0), workers, &mut report, progress)?;
    record_and_write(
        (&slots[resume_at..], resume_at),
        workers,
        sink,
        &mut report,
        progress,
    )?;
    let sink_timing = sink.timing();
    let finish_started = Instant::now();
    let all = options.all_slots().len();
    let range = options.shard.range(all);
    // The report is written into the dataset folder as the sink's last file, before the
    // dataset is marked complete: an interrupted finish resumes, and never loses the report.
    let mut tally = Some(report);
    let mut made = None;
    let mut sidecar = |summary: &Summary| -> Result<Vec<(String, Vec<u8>)>, ExportError> {
        let tally = tally
            .take()
            .ok_or_else(|| ExportError::Internal("the report was made twice".into()))?;
        let finish_secs = finish_started.elapsed().as_secs_f64();
        let report = tally.finish(
            options,
            summary.clone(),
            threads,
            resume_at,
            [range.start, range.end],
            Timing {
                wall_secs: started.elapsed().as_secs_f64(),
                encode_cpu_secs: sink_timing.encode_secs,
                stats_cpu_secs: sink_timing.stats_secs,
                write_cpu_secs: sink_timing.write_secs,
                finish_cpu_secs: finish_secs,
                ..Timing::default()
            },
        );
        let bytes = serde_json::to_vec_pretty(&report).map_err(|source| ExportError::Json {
            path: REPORT.into(),
            source,
        })?;
        made = Some(report);
        Ok(vec![(REPORT.to_string(), bytes)])
    };
    sink.finish_with(Some(&mut sidecar))?;
    made.ok_or_else(|| CollectError::Export(ExportError::Internal("no report was made".into())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_partition_the_slots_in_order() {
        for total in [0usize, 1, 7, 800] {
            for count in 1..6u32 {
                let mut covered = Vec::new();
                for index in 0..count {
                    covered.extend(Shard { index, count }.range(total));
                }
                assert_eq!(covered, (0..total).collect::<Vec<_>>());
            }
        }
        assert_eq!("2/4".parse::<Shard>(), Ok(Shard { index: 2, count: 4 }));
        for bad in ["4/4", "1", "a/2", "0/0", "-1/3"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    #[test]
    fn attempt_seeds_depend_only_on_the_slot() {
        let a = attempt_seed(5, TaskId::GauzePick, 3, 0);
        assert_eq!(
            a,
            crate::collect::record::episode_seed(5, TaskId::GauzePick, 3)
        );
        assert_ne!(a, attempt_seed(5, TaskId::GauzePick, 3, 1));
        assert_ne!(a, attempt_seed(5, TaskId::GauzePick, 4, 0));
        assert_ne!(a, attempt_seed(5, TaskId::NeedlePick, 3, 0));
    }
}
