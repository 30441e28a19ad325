//! Progress bars (one per task and one overall) and the final summary table of `collect`; the
//! per-task trial bars of `eval`.
//! Bars draw on stderr and hide themselves when stderr is not a terminal.

use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use surgvla::collect::run::{CollectProgress, CollectReport, Slot, SlotOutcome};
use surgvla::task::TaskId;

pub(crate) struct Bars {
    multi: MultiProgress,
    overall: ProgressBar,
    tasks: Vec<(TaskId, ProgressBar)>,
    /// Gives freed frame memory back as episodes are written.
    trimmer: crate::memory::Trimmer,
}

impl Bars {
    pub(crate) fn new(tasks: &[TaskId]) -> Self {
        let multi = MultiProgress::new();
        let style = |template: &str| {
            ProgressStyle::with_template(template)
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> ")
        };
        let overall = multi.add(ProgressBar::new(0));
        overall.set_style(style(
            "{prefix:>24} [{bar:30}] {pos}/{len} episodes  {msg}  {elapsed_precise} eta {eta}",
        ));
        overall.set_prefix("all tasks");
        let tasks = tasks
            .iter()
            .map(|&task| {
                let bar = multi.add(ProgressBar::new(0));
                bar.set_style(style("{prefix:>24} [{bar:30}] {pos}/{len}  {msg}"));
                bar.set_prefix(format!("{} {}", task.code(), task.name()));
                (task, bar)
            })
            .collect();
        Bars {
            multi,
            overall,
            tasks,
            trimmer: crate::memory::Trimmer::default(),
        }
    }

    /// Removes the bars (before the summary is printed).
    pub(crate) fn clear(&self) {
        for (_, bar) in &self.tasks {
            bar.finish_and_clear();
        }
        self.overall.finish_and_clear();
        let _ = self.multi.clear();
    }
}

/// One bar of `total` episodes, labelled `what`.
pub(crate) fn episode_bar(total: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template(
            "{prefix:>12} [{bar:30}] {pos}/{len} episodes  {elapsed_precise} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_prefix(what.to_string());
    bar
}

/// A spinner saying `what` is under way (work of unknown length).
pub(crate) fn spinner(what: &str) -> ProgressBar {
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg}  {elapsed_precise}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.set_message(what.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

/// One bar of trials per task (`eval`).
pub(crate) struct TrialBars {
    multi: MultiProgress,
    tasks: Vec<(TaskId, ProgressBar)>,
}

impl TrialBars {
    pub(crate) fn new(tasks: &[TaskId], trials: u32) -> Self {
        let multi = MultiProgress::new();
        let style =
            ProgressStyle::with_template("{prefix:>30} [{bar:30}] {pos}/{len} trials  {elapsed}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> ");
        let tasks = tasks
            .iter()
            .map(|&task| {
                let bar = multi.add(ProgressBar::new(u64::from(trials)));
                bar.set_style(style.clone());
                bar.set_prefix(format!("{} {}", task.code(), task.name()));
                (task, bar)
            })
            .collect();
        TrialBars { multi, tasks }
    }

    /// `done` trials of `task` finished.
    pub(crate) fn set(&self, task: TaskId, done: u32) {
        if let Some((_, bar)) = self.tasks.iter().find(|(t, _)| *t == task) {
            bar.set_position(u64::from(done));
        }
    }

    /// Removes the bars (before the table is printed).
    pub(crate) fn clear(&self) {
        for (_, bar) in &self.tasks {
            bar.finish_and_clear();
        }
        let _ = self.multi.clear();
    }
}

impl CollectProgress for Bars {
    fn start(&mut self, slots: &[Slot], already_written: usize) {
        self.overall.set_length(slots.len() as u64);
        for (task, bar) in &self.tasks {
            bar.set_length(slots.iter().filter(|s| s.task == *task).count() as u64);
        }
        if already_written > 0 {
            self.overall
                .set_message(format!("recounting {already_written} written episodes"));
        }
    }

    fn slot_done(&mut self, outcome: &SlotOutcome) {
        self.overall.inc(1);
        let elapsed = self.overall.elapsed().as_secs_f64().max(1e-9);
        self.overall.set_message(format!(
            "{:.0} episodes/s",
            self.overall.position() as f64 / elapsed
        ));
        if let Some((_, bar)) = self.tasks.iter().find(|(t, _)| *t == outcome.slot.task) {
            bar.inc(1);
            if !outcome.failures.is_empty() {
                bar.set_message(format!("last retry: {}", outcome.failures[0].reason));
            }
        }
        self.trimmer.after_episodes(self.overall.position());
    }
}

/// Prints the per-task table and the time shares.
pub(crate) fn print_summary(report: &CollectReport) -> std::io::Result<()> {
    say!(
        "{:<5} {:<24} {:>8} {:>7} {:>8} {:>7} {:>7} {:>8}",
        "task",
        "name",
        "episodes",
        "frames",
        "attempts",
        "expert",
        "seconds",
        "frames/s"
    );
    for task in &report.tasks {
        let (secs, fps) = report
            .timing
            .tasks
            .get(&task.code)
            .copied()
            .unwrap_or_default();
        say!(
            "{:<5} {:<24} {:>8} {:>7} {:>8} {:>6.1}% {:>7.1} {:>8.0}",
            task.code,
            task.name,
            task.episodes,
            task.frames,
            task.attempts,
            task.expert_success_rate * 100.0,
            secs,
            fps
        );
    }
    let t = &report.timing;
    let attempts: u64 = report.tasks.iter().map(|t| t.attempts).sum();
    let successes: u64 = report.tasks.iter().map(|t| t.expert_successes).sum();
    say!(
        "{:<5} {:<24} {:>8} {:>7} {:>8} {:>6.1}% {:>7.1} {:>8.0}",
        "all",
        "",
        report.episodes,
        report.frames,
        attempts,
        successes as f64 * 100.0 / attempts.max(1) as f64,
        t.wall_secs,
        t.frames_per_sec
    );
    say!(
        "CPU time ({} threads): physics {:.1} s, rendering {:.1} s, image encoding {:.1} s, statistics {:.1} s, tables and files {:.1} s, final metadata {:.1} s",
        report.threads,
        t.physics_cpu_secs,
        t.render_cpu_secs,
        t.encode_cpu_secs,
        t.stats_cpu_secs,
        t.write_cpu_secs,
        t.finish_cpu_secs
    );
    Ok(())
}

/// Prints the experts' figures per task (for `surgvla experts`).
pub(crate) fn print_expert_table(report: &CollectReport) -> std::io::Result<()> {
    say!(
        "{:<5} {:<24} {:>8} {:>8} {:>8} {:>7} {:>7}",
        "task",
        "name",
        "episodes",
        "attempts",
        "expert",
        "replay",
        "steps"
    );
    for task in &report.tasks {
        say!(
            "{:<5} {:<24} {:>8} {:>8} {:>7.1}% {:>7} {:>7.1}",
            task.code,
            task.name,
            task.episodes,
            task.attempts,
            task.expert_success_rate * 100.0,
            task.replay_failures,
            task.frames as f64 / task.episodes.max(1) as f64
        );
    }
    say!(
        "expert = attempts whose expert run succeeded; replay = of those, replays that failed; \
         steps = mean episode length. {:.1} s wall, physics {:.1} CPU-s on {} threads",
        report.timing.wall_secs,
        report.timing.physics_cpu_secs,
        report.threads
    );
    Ok(())
}
