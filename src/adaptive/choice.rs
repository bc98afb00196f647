//! A choice between ways of doing the same work for one mesh — a wide query tree or the binary one,
//! packets or single rays, a BVH or a grid — decided from what each way measured, through the planner's
//! one core ([`rank::choose`](super::rank::choose)): the same margin, the same hysteresis.
//!
//! Each option's cost per frame is modelled as `overhead + per_unit · units`: `overhead` the seconds it
//! adds to keeping the mesh current (a wide tree's collapse and refit, a grid's rebuild), `per_unit` the
//! seconds per unit of work it serves (a ray). Both are learned as [`Estimate`]s while the option is in
//! use. An option not measured yet is predicted from a measured one through the priors' ratio (its
//! overhead, where known from elsewhere, as [`expect_overhead`](Choice::expect_overhead) gives it), with
//! a 25% spread, and tried when it pays for itself — the planner's exploration rule (issue 19): its
//! saving per frame over the option in use, optimistic by one spread (what is unknown may be better
//! than assumed), times the horizon (the frames seen so far: a scene that ran `n` frames is expected to
//! run about `n` more) exceeds the price of its tries (their predicted cost over the option in use) by
//! one spread of the option in use's frames. Tries under way go on, up to three frames until its spread
//! is measured, while it still looks cheaper optimistic by a spread (three tries per option at most,
//! also where a tried frame measured nothing); a frame with no work (`units` = 0) tries nothing.
//!
//! Which option is cheaper is a question about means, so the margin is `z` standard deviations of the
//! difference of the two options' *means* (each at least the machine's pooled relative noise over the
//! square root of its samples) and at least [`MIN_GAIN`] (15%, half again the profile rule's
//! [`SWITCH_MARGIN`](crate::grid::choice::SWITCH_MARGIN)) of the cost in use. An earlier margin of
//! one *frame's* spread kept an option in use forever when its frames' costs were spiky — a periodic
//! rebuild, a loaded machine's stalls — however much cheaper the other measured on average: in the
//! report's `planned-options` the grid, charged a BVH rebuild every third frame (soup) or 10–20 ms
//! stalls (explosion, teapot in stadium), was kept 891 of 900 frames at 1.2–1.7× lauterbach-0.4's time
//! (issue 12; `tests/options.rs` scripts that case).
//!
//! An option measured cheaper than the one in use by more than [`MIN_GAIN`], but on too few samples to
//! pass the margin, is used again until its mean decides one way or the other (`challenger`).
//!
//! An estimate goes stale: one measured only in its tries, while the scene was as it was then, says
//! nothing of the scene as it is later (the report's explosion: the BVH measured in frames 1–4 while
//! the explosion was compact, the grid's frames drifting from 5.8 to 8.9 ms by frame 150, the BVH
//! never measured again — issue 12). With [`retry_stale`](Choice::retry_stale) an option whose
//! estimate is stale — the option in use has drifted by more than [`MIN_GAIN`] and by more than `z`
//! spreads of its frames since the other was last measured, and [`RETRY_GAP`] frames have passed, doubled after each re-try that kept the choice
//! — is tried again as if never measured: its per-unit estimate starts afresh (its overhead with its
//! next sample), up to three frames, the first frame's sample deciding whether the others are worth
//! it. A stationary scene never drifts, so it never pays a re-try; a drifting one that keeps its
//! choice pays a number of re-tries logarithmic in its frames.
//!
//! Hysteresis, in numbers: with costs that jitter around equal ones (±10% in `tests/options.rs`), the
//! option in use changes at most twice per other option — to a try and back — since a mean re-estimated
//! every frame does not drift 15% below a measured one (at 5% it did in that test, at 10% once in
//! `tests/policy.rs`).

use super::Estimate;
use super::rank::{Candidate, choose};
use crate::grid::{ChoiceReason, StructureChoice, StructureKind};

/// Relative spread of a prediction made from a prior.
const PRIOR_SPREAD: f64 = 0.25;

/// Smallest saving, relative to the option in use, for which a measured option replaces it: jitter of
/// the mean in use (re-estimated every frame) never buys a change smaller than this.
const MIN_GAIN: f64 = 0.15;

/// Frames an option is tried for at most before only measurements decide: until its spread is
/// measured rather than assumed (the [`Estimate`]'s three samples), since one frame's prior spread of
/// 25% would keep even a 30% cheaper option from beating the margin.
const TRIES: u32 = 3;

/// A sample above this many times its estimate's mean (once the mean rests on [`TRIES`] samples) is
/// taken for a stall of the machine — a descheduled thread, a page fault storm — and learned as this
/// many times the mean. On a loaded 2-core machine stalls of 10–20 ms hit one frame in four of 0.5 ms
/// ones (issue 12); a cost that is really that spiky (a rebuild every twentieth frame) is understated,
/// the price of not letting the machine's stalls decide.
const STALL: f64 = 4.0;

/// Frames after an option was last measured before a stale estimate of it is re-tried
/// ([`Choice::retry_stale`]), doubled after each re-try that kept the choice: about the frames the
/// option in use's mean takes to forget the past (an [`Estimate`] weighs the last nine or so samples),
/// so that a drift is the scene's, not one noisy frame's.
const RETRY_GAP: u32 = 10;

/// `x`, or [`STALL`] times the mean of `e` where it is larger and the mean rests on [`TRIES`] samples.
fn unstalled(e: &Estimate, x: f64) -> f64 {
    match e.mean() {
        Some(m) if e.samples() >= TRIES => x.min(STALL * m),
        _ => x,
    }
}

/// One option of a [`Choice`] and what it measured.
#[derive(Clone, Debug)]
struct Arm<T> {
    option: T,
    /// Prior cost per unit and prior overhead, each relative to the other options' priors.
    prior: (f64, f64),
    per_unit: Estimate,
    overhead: Estimate,
    /// Frames the option was tried in (at most [`TRIES`]).
    tries: u32,
    /// The means (per unit, overhead) of the option in use, taken at the first [`Choice::decide`]
    /// after this option was last measured at which they are sure (see `Choice::settle`): what its
    /// estimate is compared against. `None` until then.
    basis: Option<(f64, f64)>,
    /// The [`Choice::decide`] count at this option's last measurement.
    measured_at: u32,
    /// Frames after `measured_at` before a stale re-try ([`RETRY_GAP`], doubled by each re-try).
    gap: u32,
    /// Whether the next per-unit and the next overhead sample start their estimates afresh (a try of
    /// an option measured long ago).
    fresh: (bool, bool),
    /// Seconds of overhead predicted from outside while none is measured ([`Choice::expect_overhead`]).
    expected: Option<f64>,
}

impl<T> Arm<T> {
    /// This option's learned means, overhead 0 while unmeasured; `None` before a per-unit sample.
    fn means(&self) -> Option<(f64, f64)> {
        Some((self.per_unit.mean()?, self.overhead.mean().unwrap_or(0.0)))
    }
}

/// The planner of one per-mesh choice among a few options (see the module docs). Keep one per mesh and
/// choice; a few arithmetic operations per [`decide`](Self::decide), no allocation after
/// [`new`](Self::new).
#[derive(Clone, Debug)]
pub struct Choice<T> {
    arms: Vec<Arm<T>>,
    /// The option chosen on measurements: what hysteresis keeps.
    settled: T,
    /// The option in use this frame: `settled`, or an option being tried.
    current: T,
    explored: bool,
    /// Whether stale estimates are re-tried ([`retry_stale`](Self::retry_stale)).
    retry: bool,
    /// [`decide`](Self::decide) calls so far.
    frame: u32,
    /// Stale re-tries started so far.
    retries: u32,
    /// Standard deviations of margin before the option in use is changed
    /// ([`DEFAULT_Z`](super::DEFAULT_Z)).
    pub z: f64,
}

impl<T: Copy + PartialEq> Choice<T> {
    /// A choice among `options`, each with its prior cost per unit and prior overhead relative to the
    /// others' (our numbers, replaced by measurements at once); the first is the one in use until
    /// something is measured. `None` for no options.
    pub fn new(options: &[(T, f64, f64)]) -> Option<Self> {
        let current = options.first()?.0;
        Some(Choice {
            arms: (options.iter())
                .map(|&(option, per_unit, overhead)| Arm {
                    option,
                    prior: (per_unit, overhead),
                    per_unit: Estimate::default(),
                    overhead: Estimate::default(),
                    tries: 0,
                    basis: None,
                    measured_at: 0,
                    gap: RETRY_GAP,
                    fresh: (false, false),
                    expected: None,
                })
                .collect(),
            settled: current,
            current,
            explored: false,
            retry: false,
            frame: 0,
            retries: 0,
            z: super::DEFAULT_Z,
        })
    }

    /// This choice, re-trying stale estimates (see the module docs): for a choice whose options'
    /// costs drift apart as a scene changes (a BVH against a grid over an explosion). Costs nothing
    /// while the option in use's cost holds within 15% of what it was when the others were
    /// measured; a re-try costs up to three frames of the other option.
    pub fn retry_stale(self) -> Self {
        Choice {
            retry: true,
            ..self
        }
    }

    /// Stale re-tries started so far ([`retry_stale`](Self::retry_stale)).
    pub fn retries(&self) -> u32 {
        self.retries
    }

    /// Predicts `option`'s overhead per frame at `seconds` while it has measured none, in place of the
    /// priors' ratio to a measured option's overhead: for an overhead known from elsewhere (a grid's
    /// rebuild, from the grid build's seconds per triangle learned on any mesh). The ratio says nothing
    /// where the measured overhead is not the same work: a BVH only refitted, or not updated at all
    /// (rigid motion), predicts a per-frame grid rebuild at twice its own near-nothing. Ignored unless
    /// finite and not negative; call it before each [`decide`](Self::decide) whose frames differ. O(1).
    pub fn expect_overhead(&mut self, option: T, seconds: f64) {
        if seconds.is_finite()
            && seconds >= 0.0
            && let Some(arm) = self.arm_mut(option)
        {
            arm.expected = Some(seconds);
        }
    }

    /// The option in use.
    pub fn current(&self) -> T {
        self.current
    }

    /// The option chosen on measurements, which a try returns to unless it wins.
    pub fn settled(&self) -> T {
        self.settled
    }

    /// Whether the last [`decide`](Self::decide) picked an option that had not been measured (a try).
    pub fn explored(&self) -> bool {
        self.explored
    }

    /// Learns a frame of `option`: `units` of work served in `seconds` (ignored unless `units` > 0, the
    /// time is finite and not negative, and `option` is one of the choice's; a sample above four
    /// times the mean is clipped, taken for a stall of the machine).
    pub fn served(&mut self, option: T, units: f64, seconds: f64) {
        if units > 0.0
            && seconds.is_finite()
            && seconds >= 0.0
            && let Some(arm) = self.arm_mut(option)
        {
            if std::mem::take(&mut arm.fresh.0) {
                arm.per_unit = Estimate::default();
            }
            arm.per_unit.add(unstalled(&arm.per_unit, seconds / units));
            self.measured(option);
        }
    }

    /// Learns a frame of `option`'s overhead: the seconds it added to keeping the mesh current (a sample
    /// above four times the mean clipped, taken for a stall of the machine).
    pub fn kept(&mut self, option: T, seconds: f64) {
        if seconds.is_finite()
            && seconds >= 0.0
            && let Some(arm) = self.arm_mut(option)
        {
            if std::mem::take(&mut arm.fresh.1) {
                arm.overhead = Estimate::default();
            }
            arm.overhead.add(unstalled(&arm.overhead, seconds));
            self.measured(option);
        }
    }

    /// Notes that `option` was measured this frame: its estimate's basis is to be taken afresh.
    fn measured(&mut self, option: T) {
        let frame = self.frame;
        if let Some(arm) = self.arm_mut(option) {
            arm.basis = None;
            arm.measured_at = frame;
        }
    }

    /// The predicted seconds of a frame of `option` with `units` of work, and the spread of that
    /// prediction; the bool says whether it rests on measurements of the option itself. `None` while no
    /// option measured its per-unit cost, or for an option not of this choice.
    pub fn predict(&self, option: T, units: f64) -> Option<(Candidate<T>, bool)> {
        let arm = self.arm(option)?;
        // An overhead not measured yet (a try's first frame, which pays a switch's catch-up and teaches
        // no overhead) is predicted through the priors' ratio too: taken for 0, it made a structure
        // whose queries alone came near the one in use worth two more tries (the report's cloth tried
        // the grid three frames at 1.8 times a BVH frame; issue 12).
        let overhead = (arm.overhead.mean())
            .or(arm.expected)
            .or_else(|| {
                (self.arms.iter()).find_map(|a| Some(a.overhead.mean()? * arm.prior.1 / a.prior.1))
            })
            .unwrap_or(0.0);
        if let Some(per_unit) = arm.per_unit.mean() {
            // What is predicted is one frame: its spread is one frame's plus the mean's own (a margin of
            // the mean's spread alone would let an option in use, re-estimated every frame, drift past
            // one measured a while ago by chance, given enough frames).
            let spread = (arm.per_unit.spread() * units)
                .hypot(arm.per_unit.mean_spread() * units)
                .hypot(arm.overhead.spread());
            return Some((
                Candidate {
                    option,
                    cost_s: overhead + per_unit * units,
                    spread_s: spread,
                },
                true,
            ));
        }
        let (from, per_unit) = (self.arms.iter()).find_map(|a| Some((a, a.per_unit.mean()?)))?;
        let cost = per_unit * units * arm.prior.0 / from.prior.0 + overhead;
        Some((
            Candidate {
                option,
                cost_s: cost,
                spread_s: PRIOR_SPREAD * cost,
            },
            false,
        ))
    }

    /// The option settled on, trying nothing, for a frame in which a choice this one lies under tries an
    /// option: a structure being tried is measured with its wide-tree and packet options as settled, not
    /// with one of theirs being tried too, whose cost would be charged to the structure (issue 12). O(1).
    pub fn hold(&mut self) -> T {
        self.current = self.settled;
        self.explored = false;
        self.current
    }

    /// The option to use for a frame with `units` of work: among the measured options the cheapest
    /// predicted, the one chosen before kept unless another beats it by `z` standard deviations of the
    /// difference of their means and by 15%; or an
    /// option measured fewer than three times whose optimistic prediction beats that (tried: once
    /// measured, it is chosen only if it beats the kept one by the margin like any other).
    pub fn decide(&mut self, units: f64) -> T {
        self.frame = self.frame.saturating_add(1);
        // Timing noise is the machine's, not an option's: every measured option's mean carries at least
        // the largest relative spread any option measured over three samples or more (an option tried
        // three times can have measured almost none by chance, and would then win on a lucky mean), over
        // the square root of the samples its mean rests on.
        let noise = (self.arms.iter())
            .filter(|a| a.per_unit.samples() >= TRIES)
            .filter_map(|a| Some(a.per_unit.spread() / a.per_unit.mean()?))
            .filter(|r| r.is_finite())
            .fold(0.0, f64::max);
        let candidates = (self.arms.iter()).filter_map(|a| {
            let (c, true) = self.predict(a.option, units)? else {
                return None;
            };
            let pooled = noise * c.cost_s / a.per_unit.effective_samples().max(1.0).sqrt();
            let mean = (a.per_unit.mean_spread() * units).hypot(a.overhead.mean_spread());
            Some(Candidate {
                spread_s: mean.max(pooled),
                ..c
            })
        });
        let best = choose(candidates, Some(self.settled), self.z).unwrap_or(self.settled);
        let measured = |o| match self.predict(o, units) {
            Some((c, true)) => Some(c.cost_s),
            _ => None,
        };
        let mut chosen = match (measured(best), measured(self.settled)) {
            (Some(b), Some(s)) if b > s * (1.0 - MIN_GAIN) => self.settled,
            _ => best,
        };
        // A challenger whose mean is as sure as it will get and still cheaper by MIN_GAIN has won: on
        // frames as noisy as a loaded machine's, a margin of z spreads of means resting on nine samples
        // each may never pass.
        if let Some(c) = self.challenger(chosen, units)
            && self.arm(c).is_some_and(|a| a.per_unit.saturated())
        {
            chosen = c;
        }
        self.settle(chosen);
        let stale = self.stale(units);
        if let Some(arm) = stale.and_then(|s| self.arm_mut(s)) {
            // Tried as if never measured (see below): the first frame's sample alone predicts it, and
            // decides whether the other two tries are worth it.
            arm.tries = 0;
            arm.gap = arm.gap.saturating_mul(2);
            self.retries += 1;
        }
        let kept = self.predict(chosen, units).map(|c| c.0);
        let tried = stale
            .or_else(|| {
                (self.arms.iter())
                    .filter(|a| {
                        a.option != chosen && a.per_unit.samples() < TRIES && a.tries < TRIES
                    })
                    .find_map(|a| {
                        let (c, _) = self.predict(a.option, units)?;
                        let kept = kept?;
                        // Tries under way go on while the option still looks cheaper, optimistic by
                        // a spread: their price was weighed when they began.
                        let go_on = a.tries > 0 && c.cost_s - c.spread_s < kept.cost_s;
                        let worth = go_on || self.worth_trying(&c, &kept, TRIES - a.tries);
                        (units > 0.0 && worth).then_some(a.option)
                    })
            })
            .or_else(|| self.challenger(chosen, units));
        self.explored = tried.is_some();
        let (frame, retry) = (self.frame, self.retry);
        if let Some(arm) = tried.and_then(|t| self.arm_mut(t)) {
            arm.tries = (arm.tries + 1).min(TRIES);
            // With `retry_stale`, a try of an option last measured [`RETRY_GAP`] frames ago or more
            // measures it afresh: blended into samples of the scene as it was, a new one would move
            // its mean by a fifth of the change.
            if retry && arm.per_unit.mean().is_some() && frame - arm.measured_at >= RETRY_GAP {
                arm.fresh = (true, true);
            }
        }
        self.current = tried.unwrap_or(chosen);
        self.current
    }

    /// Whether `tries` more frames of an option predicted at `c` pay against the option in use, predicted
    /// at `kept` from its measurements (the planner's exploration rule, as for builds: issue 19): the
    /// saving per frame, optimistic by one spread of the prediction (what is unknown may be better than
    /// assumed), over the horizon — the frames seen so far: a scene that ran `n` frames is expected to
    /// run about `n` more — must exceed what the tries are predicted to cost over the option in use by
    /// one spread of its frames. Without the price a grid predicted at 1.2 × a BVH's seconds per ray was
    /// tried at 20k triangles where each tried frame cost 18 BVH frames (the report's rigid, issue 12).
    fn worth_trying(&self, c: &Candidate<T>, kept: &Candidate<T>, tries: u32) -> bool {
        let horizon = f64::from(self.frame);
        let saving = kept.cost_s - (c.cost_s - c.spread_s);
        let price = f64::from(tries) * (c.cost_s - kept.cost_s);
        saving * horizon > price.max(0.0) + kept.spread_s
    }

    /// Makes `chosen` the option settled on. A change restarts the re-try gaps of both options and
    /// the other options' bases; every option measured since the last frame takes the means of the
    /// option in use as its basis, once those include an overhead and rest on as many samples as they
    /// will (a mean of three noisy frames is easily 10% off, and a basis that far off is a drift).
    fn settle(&mut self, chosen: T) {
        if chosen != self.settled {
            let before = self.settled;
            for arm in &mut self.arms {
                arm.basis = None;
                if arm.option == chosen || arm.option == before {
                    arm.gap = RETRY_GAP;
                }
            }
            self.settled = chosen;
        }
        let Some(basis) = (self.arm(chosen))
            .filter(|a| a.per_unit.saturated() && a.overhead.mean().is_some())
            .and_then(Arm::means)
        else {
            return;
        };
        for arm in &mut self.arms {
            if arm.option != chosen && arm.basis.is_none() && arm.per_unit.mean().is_some() {
                arm.basis = Some(basis);
            }
        }
    }

    /// With [`retry_stale`](Self::retry_stale), the option to re-try for a frame of `units` because its
    /// estimate is stale: measured at least [`gap`](Arm::gap) frames ago, while the option settled on
    /// cost what it costs now by more than [`MIN_GAIN`] and by more than `z` of its frames' spreads
    /// (up or down: a scene that grows or shrinks moves the options apart), and the drift large enough to have closed the gap: its stale cost over
    /// the settled option's then below the square of the drift (as if the two had moved apart by as
    /// much as the one in use moved). The cheapest such option predicted, if any.
    fn stale(&self, units: f64) -> Option<T> {
        if !self.retry || units <= 0.0 {
            return None;
        }
        let (per_unit, overhead) = self.arm(self.settled)?.means()?;
        let now = overhead + per_unit * units;
        // One frame's spread of the option in use: a drift within z of it is the machine's noise (a
        // loaded machine's frames move its mean by more than MIN_GAIN), not the scene's.
        let noise = self.z * self.predict(self.settled, units)?.0.spread_s;
        (self.arms.iter())
            .filter(|a| a.option != self.settled)
            .filter(|a| self.frame - a.measured_at >= a.gap)
            .filter_map(|a| {
                let (per_unit, overhead) = a.basis?;
                let then = overhead + per_unit * units;
                let drift = (now / then).max(then / now);
                if !drift.is_finite() {
                    return None;
                }
                let (cost, _) = self.predict(a.option, units)?;
                let drifted = drift > 1.0 + MIN_GAIN && (now - then).abs() > noise;
                (drifted && cost.cost_s < then * drift * drift).then_some(cost)
            })
            .min_by(|a, b| a.cost_s.total_cmp(&b.cost_s))
            .map(|c| c.option)
    }

    /// Once `chosen` rests on [`TRIES`] samples, a measured option cheaper by more than [`MIN_GAIN`] whose mean still rests on
    /// too few samples to beat it by the margin: used again, frame after frame, until its mean either
    /// passes the margin or rests on as many samples as an estimate keeps (then it is chosen), or rises
    /// within [`MIN_GAIN`] of `chosen`'s (then it stops).
    /// Without this an option measured only in its [`TRIES`] frames was never measured again, and a
    /// margin resting on three samples never closed: the report's explosion kept a grid its BVH had
    /// measured 19% cheaper for all 300 frames (issue 12). Expected cheaper, each such frame costs
    /// nothing on average; costs that only jitter around equal ones never qualify (their means stay
    /// within 15%, see the module docs), so hysteresis is unchanged.
    fn challenger(&self, chosen: T, units: f64) -> Option<T> {
        // The option in use is measured first: until its own spread is, it is what is unsure.
        let kept = match self.predict(chosen, units)? {
            (c, true) if self.arm(chosen)?.per_unit.samples() >= TRIES => c.cost_s,
            _ => return None,
        };
        (self.arms.iter())
            .filter(|a| a.option != chosen && units > 0.0)
            .filter_map(|a| match self.predict(a.option, units)? {
                (c, true) if c.cost_s < kept * (1.0 - MIN_GAIN) => Some(c),
                _ => None,
            })
            .min_by(|a, b| a.cost_s.total_cmp(&b.cost_s))
            .map(|c| c.option)
    }

    fn arm(&self, option: T) -> Option<&Arm<T>> {
        self.arms.iter().find(|a| a.option == option)
    }

    fn arm_mut(&mut self, option: T) -> Option<&mut Arm<T>> {
        self.arms.iter_mut().find(|a| a.option == option)
    }
}

/// The per-mesh choices the ECS plans, with our priors (replaced by measurements at once).
impl Choice<StructureKind> {
    /// A mesh's structure: the BVH in use first, the grid with `rule`'s (the profile rule's,
    /// [`crate::grid::choose_structure`]) prior seconds per ray relative to the BVH's — 1 × where the
    /// rule picked the grid (mixed sizes: fewer steps, each dearer), 2 × where it picked the BVH for
    /// empty space ([`ChoiceReason::Clustered`]: a step per empty cell; never tried, optimistic by its
    /// 25% spread it still costs more), 1.2 × otherwise — and an overhead of 2 × the BVH's (a refit and
    /// a grid rebuild against a refit) until [`expect_overhead`](Self::expect_overhead) predicts it from
    /// the grid frames' learned seconds per triangle. A try must pay for itself over the horizon
    /// (`worth_trying`); stale estimates are re-tried ([`retry_stale`](Self::retry_stale)).
    ///
    /// Why the BVH first, whatever the rule picked: with the 15% hysteresis the structure in use
    /// is kept against one measured up to 15% cheaper, so the first one should be the one that costs
    /// least where the rule is wrong. On time the rule's grid picks were all wrong at 20k triangles on an
    /// idle machine (stop 26: lauterbach-0.4 the best fixed structure on the soup, the explosion and the
    /// teapot in stadium), and the soup, started on the grid, stayed there 162 of 900 frames at 1.05 ×
    /// the BVH's time (issue 12). The rule's profile still decides how soon the grid is tried. Why:
    /// `ecs::planned`.
    pub fn structure(rule: &StructureChoice) -> Self {
        let per_ray = match (rule.structure, rule.reason) {
            (_, ChoiceReason::Clustered(_)) => 2.0,
            (StructureKind::Grid, _) => 1.0,
            _ => 1.2,
        };
        Choice::new(&[
            (StructureKind::Bvh, 1.0, 1.0),
            (StructureKind::Grid, per_ray, 2.0),
        ])
        .expect("two options")
        .retry_stale()
    }
}

impl Choice<bool> {
    /// Whether a mesh keeps the wide query tree: on first, as without the planner; 0.7 × the binary
    /// tree's seconds per ray, and the binary tree's maintenance 0.7 × the wide one's (a collapse per
    /// build and a second refit pass).
    pub fn wide() -> Self {
        Choice::new(&[(true, 0.7, 1.0), (false, 1.0, 0.7)]).expect("two options")
    }

    /// Whether packet requests (coherent: camera tiles, rays toward one point) meet a mesh as packets:
    /// on first, as without the planner; 0.8 × single rays' seconds per ray, no overhead either way.
    pub fn packets() -> Self {
        Choice::new(&[(true, 0.8, 1.0), (false, 1.0, 1.0)]).expect("two options")
    }

    /// [`packets`](Self::packets) for batches of *incoherent* rays cut into packets (the report's rays
    /// from random points around a scene to random points inside it): single rays first, packets 1.5 ×
    /// their seconds per ray — they measured 1.4–1.75 × on such rays (docs/BENCHMARKS.md, stop 24),
    /// since most packets fail the common-direction test and pay their lane bookkeeping for nothing.
    /// With that prior packets are never tried (even optimistic by a spread they cost more), so a
    /// structure tried under it is measured ray by ray, as it will answer.
    pub fn incoherent_packets() -> Self {
        Choice::new(&[(false, 1.0, 1.0), (true, 1.5, 1.0)]).expect("two options")
    }

    /// [`packets`](Self::packets) for rays whose single walks are cheap against packets: *sparse* rays
    /// handed over in small coherent batches — the pixels a selective shadow pass marks
    /// ([`HardShadows`](crate::shadows::HardShadows)), a handful along a shadow's edge in each 8 × 8
    /// block, whose parallel rays share a direction but few nodes — and single rays walked several at
    /// a time, interleaved (`TraceWorld::occluded_interleaved`), whose overlapped waits for memory
    /// beat a packet's shared node visits even on a ray per pixel. Single rays first, packets 1.05 ×
    /// their seconds per ray: on the crowd's marked pixels packets measured 4–8% slower per pass than
    /// single rays one by one (`bench shadows`, docs/BENCHMARKS.md stop 46), and 5% (16 × 2,880
    /// triangles) and 19% (64 × 10,880) slower than interleaved single rays (stop 47); on a ray per
    /// pixel 10–12% slower than interleaved single rays (stop 47). Packets are
    /// tried early (up to three frames: their optimistic prediction, less a 25% spread, undercuts
    /// single rays) and kept only if they measure cheaper by the planner's margin.
    pub fn sparse_packets() -> Self {
        Choice::new(&[(false, 1.0, 1.0), (true, 1.05, 1.0)]).expect("two options")
    }

    /// Whether a shadow pass renders its map, and classifies a hard selective pass's pixels, on the GPU
    /// ([`GpuShadowMap`](crate::gpu::GpuShadowMap)) rather than on the CPU's threads, in seconds of both
    /// phases per triangle of the occluders: the CPU first (nothing to try where there is no GPU), the
    /// GPU 0.25 × its seconds per triangle — our guess at a GPU's rasterisation and classification with
    /// the uploads and read-backs they pay, which the first measurements replace (on a software adapter
    /// the GPU measures slower and is dropped).
    pub fn map_on_gpu() -> Self {
        Choice::new(&[(false, 1.0, 1.0), (true, 0.25, 1.0)]).expect("two options")
    }

    /// Whether a mesh's grid bins triangles with the triangle–cell overlap test: off first, as
    /// [`GridOptions`](crate::grid::GridOptions)' default; on, 0.92 × its seconds per ray and 2.4 × its
    /// rebuild (`bench grid --quick`: queries 0–16% faster, builds 2.2–2.6× slower). Tried only while a
    /// rebuild costs under about two fifths of the grid's query time (`0.75 · (0.92 q + 2.4 o) < q + o`):
    /// with few rays per rebuild it is never built.
    pub fn overlap() -> Self {
        Choice::new(&[(false, 1.0, 1.0), (true, 0.92, 2.4)]).expect("two options")
    }
}
