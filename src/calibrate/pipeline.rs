//! Captures in a pipeline: what is to be shown next is prepared on one thread (reading and
//! placing a pattern, compensating a closed-loop image) and what was captured is stored on
//! another (PNG encoding, the manifest), while the calling thread only shows and captures.
//! A camera does not wait: every millisecond spent between two captures is a millisecond on the
//! calibration's clock, so only showing and capturing stay on the capture's path.
//!
//! Order and failure: items are prepared, captured and stored in order. The first error stops
//! the pipeline; everything captured before it is still stored (a later run resumes from it),
//! and that error is returned.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;

use crate::error::{Error, Result};

/// Items prepared ahead of the capture, and captures waiting to be stored: a bound on the
/// memory the pipeline holds (a few camera and projector images).
const AHEAD: usize = 3;

/// Runs `shoot` on items `0..n` in order on the calling thread, each prepared by `prepare` on a
/// helper thread up to [`AHEAD`] items ahead, its result handed to `store` on another helper
/// thread. Returns the first error of any of them.
pub fn run<T, R>(
    n: usize,
    prepare: impl Fn(usize) -> Result<T> + Sync,
    mut shoot: impl FnMut(usize, T) -> Result<R>,
    store: impl FnMut(usize, R) -> Result<()> + Send,
) -> Result<()>
where
    T: Send,
    R: Send,
{
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        let (prepared_tx, prepared) = mpsc::sync_channel::<(usize, Result<T>)>(AHEAD);
        let (taken, taken_rx) = mpsc::sync_channel::<(usize, R)>(AHEAD);
        let stop = &stop;
        let prepare = &prepare;
        let preparer = s.spawn(move || {
            for i in 0..n {
                if stop.load(Ordering::Relaxed) {
                    return;
                }
                let item = prepare(i);
                let failed = item.is_err();
                if prepared_tx.send((i, item)).is_err() || failed {
                    return;
                }
            }
        });
        let storer = s.spawn(move || -> Result<()> {
            let mut store = store;
            for (i, r) in taken_rx {
                if let Err(e) = store(i, r) {
                    stop.store(true, Ordering::Relaxed);
                    return Err(e);
                }
            }
            Ok(())
        });
        let mut result = Ok(());
        for (i, item) in prepared.iter() {
            if stop.load(Ordering::Relaxed) {
                break;
            }
            let shot = item.and_then(|t| shoot(i, t));
            match shot {
                Ok(r) => {
                    if taken.send((i, r)).is_err() {
                        break;
                    }
                }
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        stop.store(true, Ordering::Relaxed);
        drop(prepared);
        drop(taken);
        let stored = storer
            .join()
            .unwrap_or_else(|_| Err(Error::Failed("the capture store thread panicked".into())));
        if preparer.join().is_err() && result.is_ok() {
            result = Err(Error::Failed(
                "the thread preparing the projected images panicked".into(),
            ));
        }
        // A capture's error first (what stopped the pipeline), then the store's.
        result.and(stored)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    #[test]
    fn every_item_is_prepared_shot_and_stored_in_order() {
        let stored = Mutex::new(Vec::new());
        let mut shot = Vec::new();
        run(
            10,
            |i| Ok(i * 2),
            |i, t| {
                shot.push(i);
                Ok(t + 1)
            },
            |i, r| {
                stored.lock().unwrap().push((i, r));
                Ok(())
            },
        )
        .unwrap();
        assert_eq!(shot, (0..10).collect::<Vec<_>>());
        let want: Vec<_> = (0..10).map(|i| (i, i * 2 + 1)).collect();
        assert_eq!(*stored.lock().unwrap(), want);
    }

    /// A capture that fails stops the pipeline; what was captured before it is stored and the
    /// capture's error is returned.
    #[test]
    fn a_failed_capture_stops_after_storing_what_came_before() {
        let stored = Mutex::new(Vec::new());
        let e = run(
            10,
            Ok,
            |i, t| {
                if i == 4 {
                    Err(Error::Failed("camera gone".into()))
                } else {
                    Ok(t)
                }
            },
            |i, _| {
                stored.lock().unwrap().push(i);
                Ok(())
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("camera gone"), "{e}");
        assert_eq!(*stored.lock().unwrap(), vec![0, 1, 2, 3]);
    }

    /// A store that fails (disk full) stops the captures soon after, with its error.
    #[test]
    fn a_failed_store_stops_the_captures() {
        let mut shot = 0;
        let e = run(
            100,
            Ok,
            |_, t| {
                shot += 1;
                std::thread::sleep(std::time::Duration::from_millis(2));
                Ok(t)
            },
            |i, _| {
                if i == 2 {
                    Err(Error::Failed("no space left".into()))
                } else {
                    Ok(())
                }
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("no space"), "{e}");
        assert!(
            shot < 100,
            "captures went on after the store failed: {shot}"
        );
    }

    /// A preparation that fails (a corrupt pattern file) is returned as it is.
    #[test]
    fn a_failed_preparation_is_returned() {
        let e = run(
            5,
            |i| {
                if i == 1 {
                    Err(Error::Input("pattern 2: not a PNG".into()))
                } else {
                    Ok(i)
                }
            },
            |_, t| Ok(t),
            |_, _| Ok(()),
        )
        .unwrap_err();
        assert!(e.to_string().contains("not a PNG"), "{e}");
    }
}
