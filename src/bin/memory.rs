//! How the process allocates: few glibc malloc arenas, trimmed every 64 episodes of a
//! conversion.
//!
//! glibc gives each thread that allocates while another holds a lock an arena of its own (up to
//! 8 per core). Freed holes in many arenas stay resident, so peak RSS crept up with the number
//! of episodes (BENCHMARKS.md, "Peak memory"); one arena reuses them. `collect` gets one arena
//! per worker and one for the writer: its workers allocate and free every frame's buffers
//! while encoding, and on one arena they waited on its lock (13 % of the CPU of a 3,000-episode
//! run, BENCHMARKS.md, issue 27), with peak RSS still flat in episodes. Other commands keep
//! one. `MALLOC_ARENA_MAX` in the environment still wins when set.

/// The arenas `collect` on `threads` worker threads gets (0: one per core).
pub(crate) fn collect_arenas(threads: usize) -> usize {
    let workers = if threads == 0 {
        surgvla::collect::slot::cores()
    } else {
        threads
    };
    workers + 1
}

/// Limits glibc's malloc to `arenas` arenas, unless `MALLOC_ARENA_MAX` says otherwise.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
pub(crate) fn limit_arenas(arenas: usize) {
    /// glibc's `M_ARENA_MAX` parameter of `mallopt` (malloc.h).
    const M_ARENA_MAX: i32 = -8;
    unsafe extern "C" {
        fn mallopt(param: i32, value: i32) -> i32;
    }
    if std::env::var_os("MALLOC_ARENA_MAX").is_some() {
        return;
    }
    // SAFETY: mallopt takes two integers and only changes the allocator's tuning; it is called
    // before any other thread exists. A refusal (return 0) leaves glibc's default, which is
    // correct, only larger.
    unsafe {
        mallopt(
            M_ARENA_MAX,
            i32::try_from(arenas.max(1)).unwrap_or(i32::MAX),
        );
    }
}

/// Other platforms keep their allocator's defaults.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn limit_arenas(_arenas: usize) {}

/// Hands the free pages inside glibc's heaps back to the system every [`Trimmer::EPISODES`]
/// episodes (of a conversion, or of a collection's writing). A long conversion frees frame buffers of many sizes between small allocations
/// that live on; the holes stay resident, and without this peak RSS crept up with the number
/// of episodes converted (BENCHMARKS.md, "convert's memory"). Per batch it cost seconds of
/// system time; every 64 episodes it costs nothing measurable.
#[derive(Default)]
pub(crate) struct Trimmer {
    last: u64,
}

impl Trimmer {
    const EPISODES: u64 = 64;

    pub(crate) fn after_episodes(&mut self, done: u64) {
        if done >= self.last + Self::EPISODES {
            self.last = done;
            trim();
        }
    }
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
fn trim() {
    unsafe extern "C" {
        fn malloc_trim(pad: usize) -> i32;
    }
    // SAFETY: malloc_trim takes a size and only returns free memory to the system; it is safe
    // to call from any thread at any time.
    unsafe {
        malloc_trim(0);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn trim() {}
