//! The `linear` fit that grows behind a calibration's captures: a thread at a lower priority
//! ([`crate::background`]) that fits the rung on the first sampling pairs as soon as they are
//! stored (the geometry and response curves every later model keeps), then adds each pair as it
//! is stored ([`crate::fit::GrowingFit`]). The fit on the sampling pairs, and after the
//! closed-loop pairs the fit on every pair, are then one solve after the last capture instead of
//! a fit each (docs/bench/calibrate.md, "The linear fit grown behind the captures").

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::thread::JoinHandle;

use crate::dataset::Setup;
use crate::error::{Error, Result};
use crate::fit::{self, GrowingFit, Request};
use crate::model::Model;

/// What the capture side tells the thread.
enum Message {
    /// Training pair `index` (1-based) is on disk, capture and projector image.
    Stored(usize),
    /// The model on every pair stored so far, sent back once they are all added.
    Model(Sender<Result<Model>>),
}

/// How the thread's fit starts.
enum Start {
    /// From a fit of its own of this request on the first `pairs` pairs, once stored.
    Fit { req: Box<Request>, pairs: usize },
    /// From this state (a model fitted on the first pairs).
    Grown(Box<GrowingFit>),
}

/// The thread growing the fit, and the sender that tells it.
pub(super) struct Grower {
    tx: Sender<Message>,
    thread: JoinHandle<Result<GrowingFit>>,
}

impl Grower {
    /// A grower that fits `req` (a `linear` fit; its `geometry_memo` then holds the geometry)
    /// on the setup's first `pairs` training pairs once they are stored, and grows from that
    /// fit. `None` when no thread could start (logged).
    pub(super) fn fit_first(setup: &Setup, req: Request, pairs: usize) -> Option<Self> {
        Self::spawn(
            setup,
            Start::Fit {
                req: Box::new(req),
                pairs,
            },
        )
    }

    /// A grower from `model`, a linear rung fitted on the setup's first pairs, with no pair
    /// added yet (tell it of the stored ones, from the first). `None` for a model that is not a
    /// linear rung, or when no thread could start (logged).
    pub(super) fn from_model(setup: &Setup, model: &Model) -> Option<Self> {
        let fit = GrowingFit::new(model)?;
        Self::spawn(setup, Start::Grown(Box::new(fit)))
    }

    fn spawn(setup: &Setup, start: Start) -> Option<Self> {
        let (tx, rx) = channel();
        let (dir, root) = (
            setup.path().to_path_buf(),
            setup.root().path().to_path_buf(),
        );
        let thread = std::thread::Builder::new()
            .name("growing fit".into())
            .spawn(move || crate::background::run(move || grow((dir, root), start, rx)));
        match thread {
            Ok(thread) => Some(Self { tx, thread }),
            Err(e) => {
                tracing::warn!("could not start the thread that grows the linear fit: {e}");
                None
            }
        }
    }

    /// Tells it that training pair `index` (1-based) is stored. A thread that stopped has
    /// logged why; the model is then asked for in vain and fitted afresh.
    pub(super) fn stored(&self, index: usize) {
        let _ = self.tx.send(Message::Stored(index));
    }

    /// The model on every pair stored so far (waits for the thread to add them).
    pub(super) fn model(&self) -> Result<Model> {
        let (reply, answer) = channel();
        self.tx
            .send(Message::Model(reply))
            .map_err(|_| Error::Failed("the thread growing the fit has stopped".into()))?;
        answer
            .recv()
            .map_err(|_| Error::Failed("the thread growing the fit has stopped".into()))?
    }

    /// The model on every pair, once the thread has added the last: refused unless it holds
    /// exactly `pairs` pairs.
    pub(super) fn finish(self, pairs: usize) -> Result<Model> {
        drop(self.tx);
        let fit = self
            .thread
            .join()
            .map_err(|_| Error::Failed("the thread growing the fit panicked".into()))??;
        if fit.pairs() != pairs {
            return Err(Error::Failed(format!(
                "the grown fit holds {} of the {pairs} pairs",
                fit.pairs()
            )));
        }
        fit.model()
    }
}

/// The thread's work: until the sender is dropped, adds the stored pairs in order (those
/// stored together in one add) and answers the requests for the model after them.
fn grow(
    (dir, root): (PathBuf, PathBuf),
    start: Start,
    rx: Receiver<Message>,
) -> Result<GrowingFit> {
    let setup = Setup::open(&dir, Some(&root))?;
    let (mut fit, first) = match start {
        Start::Fit { req, pairs } => (None, Some((req, pairs))),
        Start::Grown(fit) => (Some(*fit), None),
    };
    let mut stored = BTreeSet::new();
    // The pairs stored from the first, without a gap.
    let mut contiguous = 0;
    let mut failed: Option<String> = None;
    while let Ok(message) = rx.recv() {
        let mut replies = Vec::new();
        for m in std::iter::once(message).chain(rx.try_iter()) {
            match m {
                Message::Stored(i) => {
                    stored.insert(i);
                }
                Message::Model(reply) => replies.push(reply),
            }
        }
        while stored.contains(&(contiguous + 1)) {
            contiguous += 1;
        }
        if failed.is_none()
            && let Err(e) = catch_up(&setup, (&mut fit, &first), contiguous)
        {
            tracing::warn!("growing the linear fit: {e}; it is fitted afresh instead");
            failed = Some(e.to_string());
        }
        for reply in replies {
            let answer = match (&failed, &fit, &first) {
                (Some(why), _, _) => Err(Error::Failed(why.clone())),
                (None, Some(fit), _) => fit.model(),
                (None, None, Some((_, pairs))) => Err(Error::Failed(format!(
                    "{contiguous} of the {pairs} pairs its first fit needs are stored"
                ))),
                (None, None, None) => Err(Error::Failed("nothing to grow from".into())),
            };
            let _ = reply.send(answer);
        }
    }
    match (failed, fit) {
        (None, Some(fit)) => Ok(fit),
        (Some(why), _) => Err(Error::Failed(why)),
        (None, None) => Err(Error::Failed(
            "the pairs its first fit needs were never all stored".into(),
        )),
    }
}

/// Brings the fit up to the first `contiguous` stored pairs: its first fit once the pairs it
/// needs are stored, then the pairs it has not added.
fn catch_up(
    setup: &Setup,
    (fit, first): (&mut Option<GrowingFit>, &Option<(Box<Request>, usize)>),
    contiguous: usize,
) -> Result<()> {
    if fit.is_none()
        && let Some((req, pairs)) = first
        && contiguous >= *pairs
    {
        let (model, _) = fit::fit(setup, req, |_, _, _| {})?;
        tracing::info!(
            "linear fit behind the captures: the first {pairs} pairs fitted in {:.1} s; the \
             rest are added as they are stored",
            model.meta.timings.train_seconds
        );
        *fit = Some(GrowingFit::new(&model).ok_or_else(|| {
            Error::Failed(format!(
                "the fit on the first {pairs} pairs is not a linear rung"
            ))
        })?);
    }
    if let Some(fit) = fit
        && fit.pairs() < contiguous
    {
        fit.add(setup, fit.pairs() + 1..=contiguous)?;
    }
    Ok(())
}
