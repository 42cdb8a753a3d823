//! Progress of a long run: a live bar on a terminal, plain periodic log lines otherwise.
//!
//! On a terminal (stderr) a [`Progress`] draws an indicatif bar: env steps done / total, env
//! steps/s, SAC updates/s, the last evaluation return and the ETA. Anywhere else (CI, a log
//! file, `--quiet`) it logs one `tracing::info!` line every [`LINE_INTERVAL`] instead, with the
//! same figures, so logs stay readable and grep-able.
//!
//! All bars live in one process-wide [`indicatif::MultiProgress`], so several runs in one
//! process (the learning benchmark's seeds on parallel threads) stack their bars instead of
//! overwriting each other. Whoever writes log lines to stderr while a bar may be drawn must do
//! it inside [`suspend`] (the `mbpo` command's log writer does), or the bar and the line mix.

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::LazyLock;
use std::time::{Duration, Instant};

/// Interval of the plain progress lines.
pub const LINE_INTERVAL: Duration = Duration::from_secs(10);

/// How often a bar's figures (rates, message) are recomputed.
const BAR_REFRESH: Duration = Duration::from_secs(1);

static BARS: LazyLock<MultiProgress> =
    LazyLock::new(|| MultiProgress::with_draw_target(ProgressDrawTarget::stderr_with_hz(10)));

/// Bars currently drawn (so [`suspend`] costs nothing when there are none).
static ACTIVE: AtomicUsize = AtomicUsize::new(0);

/// Run `f`, which writes to stderr, with every progress bar of the process cleared first and
/// redrawn after, so a log line lands above the bars instead of inside one.
pub fn suspend<R>(f: impl FnOnce() -> R) -> R {
    if ACTIVE.load(Ordering::Acquire) == 0 {
        f()
    } else {
        BARS.suspend(f)
    }
}

/// How a [`Progress`] shows itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Display {
    /// A live bar on stderr; where indicatif would not draw one (stderr not a terminal, `TERM`
    /// unset or `dumb`), plain lines every [`LINE_INTERVAL`] instead, never nothing.
    Bar,
    /// A `tracing::info!` line every `every`.
    Lines {
        /// Interval between lines.
        every: Duration,
    },
}

impl Display {
    /// A bar when stderr is a terminal, else a line every [`LINE_INTERVAL`].
    pub fn auto() -> Self {
        if std::io::stderr().is_terminal() {
            Display::Bar
        } else {
            Display::lines()
        }
    }

    /// What `self` comes to in this process: a `Bar` only if indicatif would draw it.
    fn resolve(self) -> Self {
        match self {
            Display::Bar if BARS.is_hidden() => Display::lines(),
            d => d,
        }
    }

    /// Plain lines every [`LINE_INTERVAL`] (e.g. for `--quiet`).
    pub fn lines() -> Self {
        Display::Lines {
            every: LINE_INTERVAL,
        }
    }
}

/// Progress of one run towards `total` env steps.
#[derive(Debug)]
pub struct Progress {
    bar: Option<ProgressBar>,
    label: String,
    total: u64,
    started: Instant,
    every: Duration,
    last_emit: Instant,
    /// Start of the current rate window: (time, env steps, updates); set by the first update,
    /// so a resumed run's earlier steps do not count as done in its first second.
    window: Option<(Instant, u64, u64)>,
    /// (env steps/s, updates/s) over the last finished window.
    rates: Option<(f64, f64)>,
    /// (time, env steps) where the ETA's mean rate starts: the first update, moved to where
    /// SAC updates began if there were none yet (a random warm-up runs many times faster than
    /// learning). A mean, because MBPO's rate swings between SAC updates and model trainings:
    /// a 10 s window during a training would put the ETA at hours, the next one at minutes.
    origin: Option<(Instant, u64)>,
    /// Whether SAC updates have begun (then `origin` stays where it is).
    learning: bool,
    /// (time, env steps) of the previous update: where learning began when this one is the
    /// first with SAC updates.
    previous: Option<(Instant, u64)>,
    /// (seconds, env steps) since `origin`, as of the last finished window.
    since_origin: Option<(f64, u64)>,
    steps: u64,
    updates: u64,
    eval: Option<f64>,
    model_version: Option<u64>,
    /// Where the actors are, in a multi-host run (`hosts: head 1, gpu-box 2`).
    hosts: Option<String>,
    /// What holds the run up now, e.g. a model training under way and who waits for it.
    activity: Option<String>,
    /// What the second counter counts (`updates`: SAC updates; MPC runs count `plans`).
    units: &'static str,
    finished: bool,
}

/// A model training under way, as the progress line shows it:
/// `training model v4: epoch 318, holdout mse 0.0025, 10 s`.
pub fn training_note(version: u64, epoch: usize, holdout_mse: f32, seconds: f64) -> String {
    format!(
        "training model v{version}: epoch {epoch}, holdout mse {holdout_mse:.4}, {seconds:.0} s"
    )
}

impl Progress {
    /// Progress of the run `label` (e.g. `mbpo Pendulum-v1 s0`) towards `total` env steps.
    pub fn new(label: impl Into<String>, total: u64, display: Display) -> Self {
        Self::new_at(label.into(), total, display, Instant::now())
    }

    fn new_at(label: String, total: u64, display: Display, now: Instant) -> Self {
        let (bar, every) = match display.resolve() {
            Display::Bar => {
                let bar = BARS.add(ProgressBar::new(total));
                bar.set_style(
                    ProgressStyle::with_template(
                        "{prefix} {elapsed_precise} [{bar:30.cyan/blue}] {pos}/{len} steps | {msg}",
                    )
                    .expect("the template is valid")
                    .progress_chars("=> "),
                );
                bar.set_prefix(label.clone());
                ACTIVE.fetch_add(1, Ordering::AcqRel);
                (Some(bar), BAR_REFRESH)
            }
            Display::Lines { every } => (None, every),
        };
        let p = Self {
            bar,
            label,
            total,
            started: now,
            every,
            last_emit: now,
            window: None,
            rates: None,
            origin: None,
            learning: false,
            previous: None,
            since_origin: None,
            steps: 0,
            updates: 0,
            eval: None,
            model_version: None,
            hosts: None,
            activity: None,
            units: "updates",
            finished: false,
        };
        p.refresh_bar();
        p
    }

    /// Name what the second counter of [`Progress::update`] counts (default `updates`, SAC
    /// updates): its rate is shown as `<units>/s`, and the ETA's mean rate starts where it
    /// first grows (the expensive phase after a fast warm-up).
    pub fn counting(mut self, units: &'static str) -> Self {
        self.units = units;
        self.refresh_bar();
        self
    }

    /// Env steps and SAC updates so far. Cheap enough to call every env step: the bar is
    /// redrawn at most 10 times a second, the figures recomputed once a second, and a plain
    /// line is logged once per interval.
    pub fn update(&mut self, steps: u64, updates: u64) {
        self.update_at(steps, updates, Instant::now());
    }

    fn update_at(&mut self, steps: u64, updates: u64, now: Instant) {
        self.steps = steps;
        self.updates = updates;
        if let Some(bar) = &self.bar {
            bar.set_position(steps);
        }
        if self.origin.is_none() {
            self.origin = Some((now, steps));
        }
        if !self.learning && updates > 0 {
            self.learning = true;
            if let Some(began) = self.previous {
                self.origin = Some(began);
                self.since_origin = None;
            }
        }
        self.previous = Some((now, steps));
        if self.window.is_none() {
            self.window = Some((now, steps, updates));
            if let Some(bar) = &self.bar {
                bar.reset_eta();
            }
            return;
        }
        if now.duration_since(self.last_emit) >= self.every {
            self.last_emit = now;
            self.roll_window(now);
            match &self.bar {
                Some(_) => self.refresh_bar(),
                None => tracing::info!("{}", self.line(now)),
            }
        }
    }

    /// The return of the latest evaluation.
    pub fn set_eval(&mut self, eval_return: f64) {
        if self.eval == Some(eval_return) {
            return;
        }
        self.eval = Some(eval_return);
        self.refresh_bar();
    }

    /// The latest model version (pipeline: weights published by the model trainer).
    pub fn set_model_version(&mut self, version: u64) {
        self.model_version = Some(version);
    }

    /// Where the actors are (a multi-host run), shown last in the status.
    pub fn set_hosts(&mut self, hosts: String) {
        self.hosts = Some(hosts);
    }

    /// What holds the run up now (`None`: nothing worth saying), shown after the rates, e.g.
    /// `training model v4: epoch 12, holdout mse 0.0123, 4 s; the learner waits for it`:
    /// without it a training shows as `0.0 env steps/s`, which reads as a hang.
    pub fn set_activity(&mut self, activity: Option<String>) {
        if self.activity != activity {
            self.activity = activity;
            self.refresh_bar();
        }
    }

    /// Show `note` as what holds the run up (as [`Self::set_activity`]) and, without a
    /// terminal, log the line when one is due: a training inside one env step can take
    /// minutes, and without this the log would fall silent meanwhile.
    pub fn hold_up(&mut self, note: String) {
        self.set_activity(Some(note));
        self.update(self.steps, self.updates);
    }

    /// Close the rate window ending at `now` (if it is long enough to mean something).
    fn roll_window(&mut self, now: Instant) {
        let Some((t0, s0, u0)) = self.window else {
            return;
        };
        let dt = now.duration_since(t0).as_secs_f64();
        if dt >= 0.5 {
            self.rates = Some((
                self.steps.saturating_sub(s0) as f64 / dt,
                self.updates.saturating_sub(u0) as f64 / dt,
            ));
            self.window = Some((now, self.steps, self.updates));
            if let Some((start, s_start)) = self.origin {
                let elapsed = now.duration_since(start).as_secs_f64();
                self.since_origin = Some((elapsed, self.steps.saturating_sub(s_start)));
            }
        }
    }

    /// Seconds left at the mean rate since the first update.
    fn eta_seconds(&self) -> Option<f64> {
        let (seconds, steps) = self.since_origin?;
        (steps > 0).then(|| self.total.saturating_sub(self.steps) as f64 * seconds / steps as f64)
    }

    /// Rates, evaluation and model version, e.g.
    /// `12.3 env steps/s | 246 updates/s | eval -150.2 | model v3`.
    pub fn status(&self) -> String {
        let mut parts = Vec::with_capacity(4);
        match self.rates {
            Some((sps, ups)) => {
                parts.push(format!("{sps:.1} env steps/s"));
                parts.push(format!("{ups:.0} {}/s", self.units));
            }
            None => parts.push("- env steps/s".into()),
        }
        parts.push(match self.eval {
            Some(r) => format!("eval {r:.1}"),
            None => "eval -".into(),
        });
        if let Some(v) = self.model_version {
            parts.push(format!("model v{v}"));
        }
        if let Some(activity) = &self.activity {
            parts.push(activity.clone());
        }
        if let Some(hosts) = &self.hosts {
            parts.push(hosts.clone());
        }
        parts.join(" | ")
    }

    /// `ETA 123 s`, or `ETA ?` before a rate is known.
    fn eta(&self) -> String {
        match self.eta_seconds() {
            Some(s) => format!("ETA {s:.0} s"),
            None => "ETA ?".into(),
        }
    }

    /// The plain progress line at `now`.
    fn line(&self, now: Instant) -> String {
        format!(
            "{}: [{:.0} s] step {}/{} ({:.0} %) | {} | {}",
            self.label,
            now.duration_since(self.started).as_secs_f64(),
            self.steps,
            self.total,
            100.0 * self.steps as f64 / self.total.max(1) as f64,
            self.status(),
            self.eta()
        )
    }

    fn refresh_bar(&self) {
        if let Some(bar) = &self.bar {
            // The bar's own `{eta}` would follow the last seconds' rate: ours is the mean.
            bar.set_message(format!("{} | {}", self.status(), self.eta()));
        }
    }

    /// Remove the bar (or log the last line). Called by `drop` too, so an error that unwinds
    /// through a run does not leave a half-drawn bar behind.
    pub fn finish(&mut self) {
        if self.finished {
            return;
        }
        self.finished = true;
        match self.bar.take() {
            Some(bar) => {
                bar.finish_and_clear();
                BARS.remove(&bar);
                ACTIVE.fetch_sub(1, Ordering::AcqRel);
            }
            None => {
                let now = Instant::now();
                self.roll_window(now);
                tracing::info!("{}", self.line(now));
            }
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
            BARS.remove(&bar);
            ACTIVE.fetch_sub(1, Ordering::AcqRel);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(every: u64) -> Display {
        Display::Lines {
            every: Duration::from_secs(every),
        }
    }

    #[test]
    fn rates_come_from_the_last_window_and_the_eta_from_the_mean_rate() {
        let t0 = Instant::now();
        let mut p = Progress::new_at("sac P s0".into(), 1000, lines(10), t0);
        assert_eq!(p.status(), "- env steps/s | eval -");
        p.update_at(0, 0, t0);
        // Before the interval nothing is recomputed.
        p.update_at(50, 1000, t0 + Duration::from_secs(5));
        assert_eq!(p.rates, None);
        // 100 steps and 2000 updates in 10 s.
        p.update_at(100, 2000, t0 + Duration::from_secs(10));
        assert_eq!(p.rates, Some((10.0, 200.0)));
        assert_eq!(p.eta_seconds(), Some(90.0));
        p.set_eval(-151.25);
        p.set_model_version(3);
        assert_eq!(
            p.status(),
            "10.0 env steps/s | 200 updates/s | eval -151.2 | model v3"
        );
        assert_eq!(
            p.line(t0 + Duration::from_secs(10)),
            "sac P s0: [10 s] step 100/1000 (10 %) | 10.0 env steps/s | 200 updates/s | eval -151.2 | model v3 | ETA 90 s"
        );
        p.set_hosts("hosts: head 1, w 2".into());
        assert!(p.status().ends_with("model v3 | hosts: head 1, w 2"));
        // The next window only counts its own steps: 400 steps in 20 s. The ETA goes by all
        // 500 steps in 30 s: 500 left take 30 s.
        p.update_at(500, 2000, t0 + Duration::from_secs(30));
        assert_eq!(p.rates, Some((20.0, 0.0)));
        assert_eq!(p.eta_seconds(), Some(30.0));
        // A window without progress (a model training) lengthens the ETA, it does not void it:
        // 500 steps in 50 s, 500 left.
        p.update_at(500, 2000, t0 + Duration::from_secs(50));
        assert_eq!(p.rates, Some((0.0, 0.0)));
        assert_eq!(p.eta_seconds(), Some(50.0));
        // An MPC run counts plans.
        let mut p = p.counting("plans");
        p.update_at(600, 2100, t0 + Duration::from_secs(60));
        assert!(p.status().contains("| 10 plans/s |"), "{}", p.status());
    }

    #[test]
    fn the_eta_starts_counting_when_learning_starts() {
        let t0 = Instant::now();
        let mut p = Progress::new_at("x".into(), 10_000, lines(10), t0);
        // A random warm-up: 5000 steps in 10 s without SAC updates ...
        p.update_at(0, 0, t0);
        p.update_at(5000, 0, t0 + Duration::from_secs(10));
        assert_eq!(p.eta_seconds(), Some(10.0));
        // ... then learning at 10 steps/s: the ETA goes by that alone.
        p.update_at(5001, 20, t0 + Duration::from_secs(11));
        p.update_at(5200, 4000, t0 + Duration::from_secs(30));
        assert_eq!(p.eta_seconds(), Some(480.0));
    }

    #[test]
    fn a_resumed_run_measures_rates_from_its_first_update() {
        let t0 = Instant::now();
        let mut p = Progress::new_at("x".into(), 10_000, lines(10), t0);
        p.update_at(6000, 120_000, t0 + Duration::from_secs(1));
        p.update_at(6100, 122_000, t0 + Duration::from_secs(11));
        assert_eq!(p.rates, Some((10.0, 200.0)));
        assert_eq!(p.eta_seconds(), Some(390.0));
    }

    #[test]
    fn a_stalled_run_has_no_eta() {
        let t0 = Instant::now();
        let mut p = Progress::new_at("x".into(), 10, lines(1), t0);
        p.update_at(0, 0, t0);
        p.update_at(0, 0, t0 + Duration::from_secs(2));
        assert_eq!(p.rates, Some((0.0, 0.0)));
        assert_eq!(p.eta_seconds(), None);
        assert!(p.line(t0).ends_with("ETA ?"), "{}", p.line(t0));
    }

    #[test]
    fn bars_register_and_unregister_for_suspend() {
        // The only unit test of this crate that makes bars, so the count is exact. Under CI
        // stderr is no terminal: then no bar is drawn and the progress falls back to lines.
        let drawn = usize::from(!BARS.is_hidden());
        let before = ACTIVE.load(Ordering::Acquire);
        let mut a = Progress::new("a", 10, Display::Bar);
        assert_eq!(a.bar.is_some(), drawn == 1);
        if drawn == 0 {
            assert_eq!(a.every, LINE_INTERVAL, "a hidden bar becomes plain lines");
        }
        {
            let _b = Progress::new("b", 10, Display::Bar);
            assert_eq!(ACTIVE.load(Ordering::Acquire), before + 2 * drawn);
        }
        assert_eq!(
            ACTIVE.load(Ordering::Acquire),
            before + drawn,
            "drop removes a bar"
        );
        a.update(5, 1);
        assert_eq!(suspend(|| 7), 7);
        a.finish();
        a.finish();
        drop(a);
        assert_eq!(
            ACTIVE.load(Ordering::Acquire),
            before,
            "finish, a second finish and drop remove the bar once"
        );
    }
}
