//! How the process allocates: one glibc malloc arena, trimmed every 64 episodes of a conversion.
//!
//! glibc gives each thread that allocates while another holds a lock an arena of its own (up to
//! 8 per core). The recording workers allocate each frame's buffers (~400 KB) in their arenas
//! and the writer frees them batch after batch; freed holes in several arenas stay resident, so
//! peak RSS crept up with the number of episodes (BENCHMARKS.md, "Peak memory"). One arena
//! reuses those holes: peak RSS measured lower and flat in episodes, at the same speed on 2
//! cores (the small allocations, most of them, go through glibc's per-thread cache without the
//! arena's lock). `MALLOC_ARENA_MAX` in the environment still wins when set.

/// Limits glibc's malloc to one arena, unless `MALLOC_ARENA_MAX` says otherwise.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
pub fn one_arena() {
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
        mallopt(M_ARENA_MAX, 1);
    }
}

/// Other platforms keep their allocator's defaults.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn one_arena() {}

/// Hands the free pages inside glibc's heap back to the system every [`Trimmer::EPISODES`]
/// episodes. A long conversion frees frame buffers of many sizes between small allocations
/// that live on; the holes stay resident, and without this peak RSS crept up with the number
/// of episodes converted (BENCHMARKS.md, "convert's memory"). Per batch it cost seconds of
/// system time; every 64 episodes it costs nothing measurable.
#[derive(Default)]
pub struct Trimmer {
    last: u64,
}

impl Trimmer {
    const EPISODES: u64 = 64;

    pub fn after_episodes(&mut self, done: u64) {
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
