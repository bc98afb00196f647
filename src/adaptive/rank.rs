//! The planner's one rule for every choice: options with a predicted cost and the spread of that
//! prediction, ranked so that noise does not flip a decision.

/// One option the planner can take (a build, a structure, a ray-processing mode, …) with its predicted
/// seconds over the planning interval and the standard deviation of that prediction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate<T> {
    /// The option.
    pub option: T,
    /// Predicted seconds.
    pub cost_s: f64,
    /// Standard deviation of the prediction, in seconds.
    pub spread_s: f64,
}

/// Whether `saving_s` seconds pay for `cost_s` seconds with confidence: the saving must exceed the cost by
/// `z` standard deviations of their difference (`spread_s`). The planner's margin for every "act now?"
/// decision (rebuild, explore).
pub fn pays(saving_s: f64, cost_s: f64, spread_s: f64, z: f64) -> bool {
    saving_s - cost_s > z * spread_s.max(0.0)
}

/// The option to take: the cheapest predicted, except that `current` (the option in use) is kept unless
/// the cheapest beats it by more than `z` standard deviations of the difference of their predictions
/// (`√(σ_a² + σ_b²)`, independent errors). That is the hysteresis rule: a choice changes only when the
/// data says the other option is better beyond its noise, so measurements jittering around equal costs
/// never flip it. `None` for no candidates. O(candidates), no allocation (the candidates are iterated
/// twice).
pub fn choose<T: Copy + PartialEq>(
    candidates: impl Iterator<Item = Candidate<T>> + Clone,
    current: Option<T>,
    z: f64,
) -> Option<T> {
    let best = candidates
        .clone()
        .min_by(|a, b| a.cost_s.total_cmp(&b.cost_s))?;
    let kept = current.and_then(|c| candidates.clone().find(|k| k.option == c));
    Some(match kept {
        Some(k) if !pays(k.cost_s, best.cost_s, k.spread_s.hypot(best.spread_s), z) => k.option,
        _ => best.option,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(option: u8, cost_s: f64, spread_s: f64) -> Candidate<u8> {
        Candidate {
            option,
            cost_s,
            spread_s,
        }
    }

    #[test]
    fn the_current_option_stays_within_the_noise() {
        let both = [c(0, 1.0, 0.1), c(1, 0.8, 0.1)];
        // 0.2 s apart, σ of the difference 0.141: beyond 1σ, within 2σ.
        assert_eq!(choose(both.into_iter(), Some(0), 2.0), Some(0));
        assert_eq!(choose(both.into_iter(), Some(0), 1.0), Some(1));
        assert_eq!(choose(both.into_iter(), None, 2.0), Some(1));
        assert_eq!(
            choose([c(0, 1.0, 0.0)].into_iter().take(0), Some(0), 2.0),
            None
        );
        // An option no longer offered is not kept.
        assert_eq!(choose(both.into_iter(), Some(7), 2.0), Some(1));
    }
}
