//! The one median of the workspace, and the one "mean of the last evaluations": benchmarks,
//! learning summaries over seeds and the README tables all report them, so they must agree on
//! what they are.

/// How many evaluations "the mean of the last evaluations" averages, wherever a learning curve is
/// summarised (`mbpo bench learning`'s results file at each budget, `mbpo plot`'s tables): one
/// evaluation swings widely (HalfCheetah: 5161 at 19k, 696 at 20k) and a collapse shows in the
/// mean of several. Ten, as issue 23's "no collapse" goal counts them (the last ten evaluations
/// to 50k: 41k-50k at one every 1000 steps).
pub const RECENT_EVALUATIONS: usize = 10;

/// The median of `values`: the middle value for an odd count, the mean of the two middle
/// values for an even count (the textbook and numpy convention); `None` for no values.
///
/// Sorts `values` in place (`f64::total_cmp`, so an infinity sorts as a number: a median over
/// "never" counted as `+∞` is `+∞` once half the values are). A NaN sorts last.
pub fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(values[n / 2]),
        _ => Some((values[n / 2 - 1] + values[n / 2]) / 2.0),
    }
}

#[cfg(test)]
mod tests {
    use super::median;

    #[test]
    fn odd_counts_take_the_middle_value_and_even_counts_the_mean_of_the_two() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median(&mut [7.0]), Some(7.0));
        assert_eq!(median(&mut []), None);
    }

    #[test]
    fn infinities_count_as_values() {
        let inf = f64::INFINITY;
        assert_eq!(median(&mut [inf, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [inf, 1.0, inf]), Some(inf));
        assert_eq!(median(&mut [inf, 1.0, inf, 2.0]), Some(inf));
    }
}
