//! Work that runs behind the show: fits, refits and pattern writing while the camera captures,
//! a climb or a training while a film plays. It runs on threads of their own at a lower
//! scheduling priority ([`NICE`]), so that when the machine's cores are all busy the threads
//! that keep time (the camera's reader, the display, the playback loop, the virtual rig's
//! camera) go first and the work behind them takes what is left. On an idle machine the
//! priority changes nothing: the work runs as fast as it would anyway.
//!
//! Without this, on a machine of few cores a fit behind the captures held the capture loop's
//! reader back: frames came late, the measured latency grew by the lag, and every capture
//! waited for it (docs/bench/sets.md, 2026-12-02).

/// The nice value of the threads behind the show (Linux: −20 highest, 19 lowest, 0 the
/// default). At 10 a busy thread of it gets about a tenth of a core that a busy thread at 0
/// shares with it (the kernel's weights 110 against 1024).
pub const NICE: i32 = 10;

/// Runs `work` on threads behind the show and returns what it returns; the calling thread
/// waits. Rayon work inside it (`par_iter` and the like) runs on the same threads, and threads
/// it starts inherit their priority.
///
/// Each call has threads of its own (as many as the machine has cores), not a pool shared by
/// every call: work behind the show waits on other such work (a fit joins the geometry fitted
/// ahead), and in a shared pool a thread blocked in one call could have taken up the other
/// call's work beneath it and never return. Where the threads cannot be had (the system
/// refuses threads), `work` runs on the calling thread at its own priority, with a warning.
pub fn run<T: Send>(work: impl FnOnce() -> T + Send) -> T {
    let built = rayon::ThreadPoolBuilder::new()
        .num_threads(std::thread::available_parallelism().map_or(2, |n| n.get()))
        .thread_name(|i| format!("compend behind {i}"))
        .start_handler(|_| lower_this_thread())
        .build();
    match built {
        Ok(pool) => pool.install(work),
        Err(e) => {
            tracing::warn!(
                "the threads for work behind the show did not start ({e}); it runs at the \
                 priority of the camera and the display"
            );
            work()
        }
    }
}

/// The priority of threads of [`run`] (what the kernel reports for one of them), for tests
/// and logs.
pub fn priority() -> i32 {
    run(current_nice)
}

/// Lowers the calling thread (not its process) to [`NICE`]; a refusal is logged and the
/// thread keeps its priority (it only ever costs time, never a result).
fn lower_this_thread() {
    // SAFETY: gettid and setpriority take and return plain integers; on Linux, PRIO_PROCESS
    // with a thread ID sets that one thread's nice value.
    let (tid, rc) = unsafe {
        let tid = libc::gettid();
        (
            tid,
            libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, NICE),
        )
    };
    if rc != 0 {
        tracing::debug!(
            "thread {tid} behind the show keeps its priority: setpriority({NICE}) failed: {}",
            std::io::Error::last_os_error()
        );
    }
}

/// The calling thread's nice value.
fn current_nice() -> i32 {
    // SAFETY: as in lower_this_thread; for one's own thread getpriority cannot fail, and its
    // result is the nice value itself (−1 included).
    unsafe { libc::getpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn work_behind_the_show_runs_at_the_lower_priority_and_returns_its_result() {
        // The test's own thread is at the process's priority; the work's threads below it
        // (unless this process already runs at or past NICE, where nothing can be lowered).
        let mine = current_nice();
        let behind = run(current_nice);
        assert_eq!(priority(), behind);
        if mine < NICE {
            assert_eq!(behind, NICE, "own thread at {mine}");
        }
        // Rayon work inside runs on the same threads, at the same priority.
        use rayon::prelude::*;
        let inner: Vec<i32> = run(|| (0..64).into_par_iter().map(|_| current_nice()).collect());
        assert!(inner.iter().all(|&n| n == behind), "{inner:?}");
        assert_eq!(run(|| 6 * 7), 42);
        // Calls nest and wait on each other without holding each other up: the outer call's
        // threads are its own.
        let (tx, rx) = std::sync::mpsc::channel();
        let waited = std::thread::spawn(move || run(move || rx.recv().expect("sent")));
        let sent = run(move || run(move || tx.send(7)));
        assert!(sent.is_ok());
        assert_eq!(waited.join().expect("no panic"), 7);
    }
}
