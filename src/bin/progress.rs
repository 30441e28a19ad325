//! Progress bars (one per task and one overall) and the final summary table of `collect`; the
//! per-task trial bars of `eval`.
//! Bars draw on stderr when it is a terminal. When it is not (a log file, a Slurm job), a
//! thread prints a progress line with the rate and the time left every `--progress-interval`
//! seconds instead ([`Lines`]), as cargo and rclone do; `--quiet` silences both.

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How progress is shown: `--quiet` and `--progress-interval`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Shown {
    pub(crate) quiet: bool,
    pub(crate) interval: Duration,
}

static SHOWN: Mutex<Shown> = Mutex::new(Shown {
    quiet: false,
    interval: Duration::from_secs(10),
});

/// Sets how progress is shown for the rest of the command.
pub(crate) fn show(shown: Shown) {
    *SHOWN.lock().unwrap_or_else(|e| e.into_inner()) = shown;
}

fn shown() -> Shown {
    *SHOWN.lock().unwrap_or_else(|e| e.into_inner())
}

/// Hides `multi`'s bars when progress is not to be drawn (`--quiet`).
fn drawn(multi: &MultiProgress) {
    if shown().quiet {
        multi.set_draw_target(ProgressDrawTarget::hidden());
    }
}

/// Progress lines on a stderr that is not a terminal: a thread that reads (done, total) and
/// prints `what: done/total unit (rate/s, N s left)` every interval until the bars finish.
pub(crate) struct Lines;

impl Lines {
    /// Starts the lines for `what`, counted in `unit`, read by `read` ((done, total, finished)),
    /// unless stderr is a terminal or progress is quiet.
    fn start(
        what: String,
        unit: &'static str,
        read: impl Fn() -> (u64, u64, bool) + Send + 'static,
    ) {
        let Shown { quiet, interval } = shown();
        if quiet || std::io::stderr().is_terminal() {
            return;
        }
        std::thread::spawn(move || {
            let started = Instant::now();
            let mut last = started;
            let mut said = None;
            loop {
                std::thread::sleep(Duration::from_millis(50).min(interval));
                let (done, total, finished) = read();
                if finished {
                    return;
                }
                // Once all is counted, the rest (writing, recording failures) says itself.
                if last.elapsed() < interval || (said == Some(done) && done == total) {
                    continue;
                }
                last = Instant::now();
                said = Some(done);
                eprintln!("{}", line(&what, unit, done, total, started.elapsed()));
            }
        });
    }
}

/// One progress line: `what: done/total unit (rate/s, time left)`.
fn line(what: &str, unit: &str, done: u64, total: u64, elapsed: Duration) -> String {
    let secs = elapsed.as_secs_f64().max(1e-9);
    let rate = done as f64 / secs;
    let left = if done == 0 || total == 0 {
        "time left unknown".to_string()
    } else {
        format!(
            "{:.0} s left",
            total.saturating_sub(done) as f64 / rate.max(1e-9)
        )
    };
    let of = if total > 0 {
        format!("{done}/{total}")
    } else {
        done.to_string()
    };
    format!(
        "{what}: {of} {unit} ({rate:.1}/s, {left}, {:.0} s so far)",
        secs
    )
}

/// [`Lines`] for one bar.
fn lines_of(bar: &ProgressBar, what: &str, unit: &'static str) {
    let bar = bar.clone();
    Lines::start(what.to_string(), unit, move || {
        (bar.position(), bar.length().unwrap_or(0), bar.is_finished())
    });
}
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
        drawn(&multi);
        lines_of(&overall, "collecting", "episodes");
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
    if shown().quiet {
        bar.set_draw_target(ProgressDrawTarget::hidden());
    }
    lines_of(&bar, what, "episodes");
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
        let tasks: Vec<(TaskId, ProgressBar)> = tasks
            .iter()
            .map(|&task| {
                let bar = multi.add(ProgressBar::new(u64::from(trials)));
                bar.set_style(style.clone());
                bar.set_prefix(format!("{} {}", task.code(), task.name()));
                (task, bar)
            })
            .collect();
        drawn(&multi);
        let watched: Vec<ProgressBar> = tasks.iter().map(|(_, b)| b.clone()).collect();
        Lines::start("eval".into(), "trials", move || {
            let sum = |f: &dyn Fn(&ProgressBar) -> u64| watched.iter().map(f).sum::<u64>();
            (
                sum(&|b| b.position()),
                sum(&|b| b.length().unwrap_or(0)),
                watched.iter().all(ProgressBar::is_finished),
            )
        });
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

/// Prints the per-task table (80 columns: the longest name, `needle_pick_distractors`, is 23)
/// and the time shares.
pub(crate) fn print_summary(report: &CollectReport) -> std::io::Result<()> {
    say!(
        "{:<5} {:<23} {:>8} {:>7} {:>8} {:>7} {:>7} {:>8}",
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
            "{:<5} {:<23} {:>8} {:>7} {:>8} {:>6.1}% {:>7.1} {:>8.0}",
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
        "{:<5} {:<23} {:>8} {:>7} {:>8} {:>6.1}% {:>7.1} {:>8.0}",
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
        "time per stage, summed over {}: physics {:.1} s, rendering {:.1} s, image encoding {:.1} s, statistics {:.1} s, tables and files {:.1} s, final metadata {:.1} s",
        crate::say::n(report.threads as u64, "thread"),
        t.physics_cpu_secs,
        t.render_cpu_secs,
        t.encode_cpu_secs,
        t.stats_cpu_secs,
        t.write_cpu_secs,
        t.finish_cpu_secs
    );
    if let Some(cpu_secs) = process_cpu_secs() {
        // The stages' times include waits, and a stage that runs threads of its own (the
        // writer's image encoding) is counted on each: they can add up to more than this.
        say!("CPU time of the process: {cpu_secs:.1} s (user and system)");
    }
    Ok(())
}

/// The CPU time (user and system) this process has used so far, seconds, from
/// `/proc/self/stat` (Linux; None elsewhere). Its clock ticks are USER_HZ, 100 a second on
/// every Linux architecture.
fn process_cpu_secs() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    cpu_secs_of_stat(&stat)
}

/// The user and system time of a `/proc/<pid>/stat` line, seconds: fields 14 and 15, counted
/// after the command name (field 2, in parentheses, which may hold spaces).
fn cpu_secs_of_stat(stat: &str) -> Option<f64> {
    let (_, after_name) = stat.rsplit_once(')')?;
    let fields: Vec<&str> = after_name.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i)?.parse::<u64>().ok();
    Some((ticks(11)? + ticks(12)?) as f64 / 100.0)
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
         steps = mean episode length. {:.1} s wall, physics {:.1} CPU-s on {}",
        report.timing.wall_secs,
        report.timing.physics_cpu_secs,
        crate::say::n(report.threads as u64, "thread")
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_time_is_read_after_the_command_name() {
        // A command name with spaces and a parenthesis; utime 250 and stime 50 ticks.
        let stat = "42 (a b) c) S 1 42 42 0 -1 4194560 100 0 0 0 250 50 0 0 20 0 3 0 1 2 3";
        assert_eq!(cpu_secs_of_stat(stat), Some(3.0));
        assert_eq!(cpu_secs_of_stat("42 (x) S 1"), None);
        if cfg!(target_os = "linux") {
            assert!(process_cpu_secs().is_some());
        }
    }
}
