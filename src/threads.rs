//! Worker threads, made one way for every command: [`pool`] builds a rayon pool of `threads`
//! workers (0: one per core) whose failure is one error type, [`NoThreads`], that each layer
//! wraps in its own.

/// The worker threads could not be started.
#[derive(Debug, thiserror::Error)]
#[error("starting {threads} worker threads")]
pub struct NoThreads {
    /// The threads asked for (0: one per core).
    pub threads: usize,
    #[source]
    pub source: rayon::ThreadPoolBuildError,
}

/// A pool of `threads` workers (0: one per core).
pub fn pool(threads: usize) -> Result<rayon::ThreadPool, NoThreads> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|source| NoThreads { threads, source })
}
