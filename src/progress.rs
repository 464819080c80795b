//! Progress reporting for long work, decoupled from any terminal UI: the library reports
//! phases and counts; the binary shows them as progress bars.

/// Receives progress of long-running work. Implementations must be cheap and thread-safe:
/// `advance` is called from worker threads.
pub trait Progress: Sync {
    /// A new phase with `total` units of work (0 when unknown).
    fn begin(&self, _phase: &str, _total: u64) {}
    /// `n` more units done in the current phase.
    fn advance(&self, _n: u64) {}
    /// `done` units of the current phase are finished (reports may arrive out of order from
    /// worker threads; implementations keep the largest).
    fn reached(&self, _done: u64) {}
    /// The current phase is over.
    fn end(&self) {}
}

/// Ignores all progress (tests, library users who don't care).
pub struct NoProgress;

impl Progress for NoProgress {}
