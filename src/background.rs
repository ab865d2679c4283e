//! Work that runs behind the show: fits, refits and pattern writing while the camera captures,
//! a climb or a training while a film plays. It runs on threads of their own at a lower
//! scheduling priority ([`LOWER_BY`] nice values lower), so that when the machine's cores are
//! all busy the threads that keep time (the camera's reader, the display, the playback loop,
//! the virtual rig's camera) go first and the work behind them takes what is left. On an idle
//! machine the priority changes nothing: the work runs as fast as it would anyway.
//!
//! Without this, on a machine of few cores a fit behind the captures held the capture loop's
//! reader back: frames came late, the measured latency grew by the lag, and every capture
//! waited for it (docs/bench/sets.md, 2026-12-02).

/// How far the threads behind the show sit below the thread that starts them, in nice values
/// (Linux: −20 highest, 19 lowest, 0 the default; never past 19). At 10 below, a busy thread
/// of them gets about a tenth of a core that a busy thread above shares with it (the kernel's
/// weights 110 against 1024 for nice 10 against 0). Relative, so a service started at a
/// nice value of its own keeps its work behind it, never above.
pub const LOWER_BY: i32 = 10;

/// The lowest priority there is (the highest nice value).
const LOWEST: i32 = 19;

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
    let nice = (current_nice() + LOWER_BY).min(LOWEST);
    let built = rayon::ThreadPoolBuilder::new()
        .num_threads(std::thread::available_parallelism().map_or(2, |n| n.get()))
        .thread_name(|i| format!("compend behind {i}"))
        .start_handler(move |_| set_this_thread(nice))
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

/// Sets the calling thread's (not its process's) nice value to `nice`; a refusal is logged
/// and the thread keeps its priority (it only ever costs time, never a result).
fn set_this_thread(nice: i32) {
    // SAFETY: gettid and setpriority take and return plain integers; on Linux, PRIO_PROCESS
    // with a thread ID sets that one thread's nice value.
    let (tid, rc) = unsafe {
        let tid = libc::gettid();
        (
            tid,
            libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, nice),
        )
    };
    if rc != 0 {
        tracing::debug!(
            "thread {tid} behind the show keeps its priority: setpriority({nice}) failed: {}",
            std::io::Error::last_os_error()
        );
    }
}

/// The calling thread's nice value.
fn current_nice() -> i32 {
    // SAFETY: as in set_this_thread; for one's own thread getpriority cannot fail, and its
    // result is the nice value itself (−1 included).
    unsafe { libc::getpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn work_behind_the_show_runs_at_the_lower_priority_and_returns_its_result() {
        // The work's threads sit LOWER_BY below the thread that starts them, never past the
        // lowest priority.
        let mine = current_nice();
        let behind = run(current_nice);
        assert_eq!(
            behind,
            (mine + LOWER_BY).min(LOWEST),
            "own thread at {mine}"
        );
        // Rayon work inside runs on the same threads, at the same priority.
        use rayon::prelude::*;
        let inner: Vec<i32> = run(|| (0..64).into_par_iter().map(|_| current_nice()).collect());
        assert!(inner.iter().all(|&n| n == behind), "{inner:?}");
        assert_eq!(run(|| 6 * 7), 42);
        // Calls nest, and one call's work may wait for another's.
        let (tx, rx) = std::sync::mpsc::channel();
        let waited = std::thread::spawn(move || run(move || rx.recv().expect("sent")));
        let sent = run(move || run(move || tx.send(7)));
        assert!(sent.is_ok());
        assert_eq!(waited.join().expect("no panic"), 7);
    }
}
