//! What a SIGINT/SIGTERM does to a run: one decision, tested over every case.

/// What the coordinator knows when a SIGINT/SIGTERM arrives.
#[derive(Debug, Clone, Copy)]
pub struct RunState {
    /// The checkpoint barrier under way, if any: whether the run stops after it.
    pub barrier: Option<bool>,
    /// Every process sent its Done record.
    pub all_done: bool,
    /// Every actor sent its Done record.
    pub actors_done: bool,
    /// An earlier signal chose [`OnSignal::Finish`].
    pub finishing: bool,
}

/// What a SIGINT/SIGTERM does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OnSignal {
    /// Write a checkpoint, then stop (resumable with `--resume`).
    CheckpointAndStop,
    /// A periodic checkpoint is under way: stop after it.
    StopAfterBarrier,
    /// Every actor is done: what is left -- the learner's last updates, the last evaluations,
    /// the last step's checkpoint -- is short. Finish the run instead (it can still be
    /// extended with `--resume RUN --steps N`).
    Finish,
    /// A second signal, or nothing left to do: stop at once, without a checkpoint.
    StopNow,
}

/// What a SIGINT/SIGTERM does in the state `run`.
pub fn on_signal(run: RunState) -> OnSignal {
    match run.barrier {
        _ if run.finishing => OnSignal::StopNow,
        // A periodic barrier at the last step resumes the run, which then finishes.
        Some(false) | None if run.actors_done && !run.all_done => OnSignal::Finish,
        Some(false) => OnSignal::StopAfterBarrier,
        None if !run.all_done => OnSignal::CheckpointAndStop,
        Some(true) | None => OnSignal::StopNow,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(barrier: Option<bool>, actors_done: bool, all_done: bool) -> RunState {
        RunState {
            barrier,
            all_done,
            actors_done,
            finishing: false,
        }
    }

    #[test]
    fn a_signal_checkpoints_unless_the_actors_are_done_then_the_run_finishes() {
        use OnSignal::*;
        let cases = [
            // (barrier under way, actors done, all done) -> first signal
            (None, false, false, CheckpointAndStop),
            (Some(false), false, false, StopAfterBarrier),
            (Some(true), false, false, StopNow),
            (None, true, false, Finish),
            (Some(false), true, false, Finish),
            (None, true, true, StopNow),
            (Some(false), true, true, StopAfterBarrier),
        ];
        for (barrier, actors_done, all_done, want) in cases {
            let run = state(barrier, actors_done, all_done);
            assert_eq!(on_signal(run), want, "{run:?}");
        }
        // A second signal while finishing stops at once.
        let finishing = RunState {
            finishing: true,
            ..state(None, true, false)
        };
        assert_eq!(on_signal(finishing), StopNow);
    }
}
