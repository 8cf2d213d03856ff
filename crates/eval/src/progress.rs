//! Progress of the long computations (the evaluation protocols), as data: a computation calls
//! its [`Observer`] with a [`Progress`] at the start and end of each phase and after each step
//! between (a pose, a shape), and the caller decides what to do with it (the `facepose` binary
//! prints it; [`Silent`] drops it). The core itself prints nothing.
//!
//! The contract, for each phase a computation runs: a first call with `done == 0`, then calls
//! with `done` never decreasing, a last call with `done == total`; phases follow each other (a
//! phase is not resumed once the next has started). Calls come a few thousand times per
//! computation at most (one per step, not per face), so an observer may read a clock in each.

/// What a computation is doing; `done` and `total` count the unit of its phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Progress {
    /// The phase.
    pub phase: Phase,
    /// Units of the phase done.
    pub done: usize,
    /// Units of the phase in all.
    pub total: usize,
}

/// A phase of a long computation, with the unit its [`Progress`] counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// The paper's protocol, Table 1, training stage (the mean shape's own views): poses of the
    /// grid.
    PaperTraining,
    /// The paper's protocol, Table 1, testing stage (the test shapes' views): poses of the grid.
    PaperTesting,
    /// The paper's protocol, robustness: (condition, entry) pairs.
    PaperRobustness,
    /// Structure from motion, condition `condition` (0-based) of `conditions`: shapes.
    Sfm {
        /// The condition, 0-based.
        condition: usize,
        /// Conditions in all.
        conditions: usize,
    },
    /// The HPR table over the yaw x pitch grid: poses.
    HprGrid,
}

/// Where a computation reports its [`Progress`]. `Sync`, so that a computation may report from
/// the threads of [`facepose_core::parallel`]; the calls of one computation still follow the contract
/// of the module docs (a parallel one serializes them).
pub trait Observer: Sync {
    /// Takes one report.
    fn observe(&self, progress: Progress);
}

impl<F: Fn(Progress) + Sync> Observer for F {
    fn observe(&self, progress: Progress) {
        self(progress)
    }
}

/// The observer of callers that do not care: drops every report.
#[derive(Debug, Clone, Copy, Default)]
pub struct Silent;

impl Observer for Silent {
    fn observe(&self, _: Progress) {}
}

/// Reports the steps of one phase to an observer: `start` on creation, then `step` per unit of
/// work; the last `step` reports `done == total` (or `finish` does, for a phase whose steps
/// are skipped).
pub(crate) struct PhaseReport<'a> {
    observer: &'a dyn Observer,
    phase: Phase,
    done: usize,
    total: usize,
}

impl<'a> PhaseReport<'a> {
    /// Reports `done == 0` of `total`.
    pub(crate) fn start(observer: &'a dyn Observer, phase: Phase, total: usize) -> Self {
        observer.observe(Progress {
            phase,
            done: 0,
            total,
        });
        PhaseReport {
            observer,
            phase,
            done: 0,
            total,
        }
    }

    /// One more unit done (never past `total`).
    pub(crate) fn step(&mut self) {
        if self.done < self.total {
            self.done += 1;
            self.observer.observe(Progress {
                phase: self.phase,
                done: self.done,
                total: self.total,
            });
        }
    }

    /// Reports `done == total` unless already reported.
    pub(crate) fn finish(self) {
        if self.done < self.total {
            self.observer.observe(Progress {
                phase: self.phase,
                done: self.total,
                total: self.total,
            });
        }
    }
}

/// A recording observer for the tests: every report, in order.
#[cfg(test)]
pub(crate) mod record {
    use super::{Observer, Progress};
    use std::sync::Mutex;

    #[derive(Default)]
    pub struct Recorder(pub Mutex<Vec<Progress>>);

    impl Observer for Recorder {
        fn observe(&self, progress: Progress) {
            self.0.lock().unwrap().push(progress);
        }
    }

    impl Recorder {
        /// Checks the module's contract on what was recorded, and returns the phases in order.
        pub fn phases(&self) -> Vec<super::Phase> {
            let all = self.0.lock().unwrap();
            let mut phases: Vec<super::Phase> = Vec::new();
            let mut last: Option<Progress> = None;
            for p in all.iter() {
                assert!(p.done <= p.total, "{p:?}");
                match last {
                    Some(l) if l.phase == p.phase => {
                        assert!(p.done >= l.done, "{p:?} after {l:?}");
                        assert_eq!(p.total, l.total, "{p:?} after {l:?}");
                    }
                    _ => {
                        if let Some(l) = last {
                            assert_eq!(l.done, l.total, "phase left before its end: {l:?}");
                        }
                        assert_eq!(p.done, 0, "phase started past 0: {p:?}");
                        assert!(!phases.contains(&p.phase), "phase resumed: {p:?}");
                        phases.push(p.phase);
                    }
                }
                last = Some(*p);
            }
            if let Some(l) = last {
                assert_eq!(l.done, l.total, "last phase not finished: {l:?}");
            }
            phases
        }
    }
}

#[cfg(test)]
mod tests {
    use super::record::Recorder;
    use super::*;

    #[test]
    fn a_phase_reports_zero_each_step_and_the_total_once() {
        let r = Recorder::default();
        let mut p = PhaseReport::start(&r, Phase::HprGrid, 3);
        p.step();
        p.step();
        p.finish();
        let done: Vec<usize> = r.0.lock().unwrap().iter().map(|p| p.done).collect();
        assert_eq!(done, [0, 1, 2, 3]);
        let r = Recorder::default();
        let mut p = PhaseReport::start(&r, Phase::HprGrid, 2);
        for _ in 0..5 {
            p.step();
        }
        p.finish();
        let done: Vec<usize> = r.0.lock().unwrap().iter().map(|p| p.done).collect();
        assert_eq!(done, [0, 1, 2]);
        assert_eq!(r.phases(), [Phase::HprGrid]);
    }

    #[test]
    fn closures_observe() {
        let seen = std::sync::atomic::AtomicUsize::new(0);
        let f = |p: Progress| {
            seen.fetch_add(p.done, std::sync::atomic::Ordering::Relaxed);
        };
        let mut p = PhaseReport::start(&f, Phase::PaperTesting, 2);
        p.step();
        p.step();
        assert_eq!(seen.into_inner(), 3);
    }
}
