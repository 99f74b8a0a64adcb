//! Reconnect delays: doubling from `initial_ms`, capped at `max_ms`. Pure, so the link's retry
//! schedule is a tested function of the attempt number, not of a timer's history.

/// The delay before reconnect attempt `attempt` (0 = the first retry after a failure).
pub fn reconnect_delay_ms(attempt: u32, initial_ms: u64, max_ms: u64) -> u64 {
    let initial = initial_ms.min(max_ms);
    let factor = 1u64.checked_shl(attempt.min(63)).unwrap_or(u64::MAX);
    initial.saturating_mul(factor).min(max_ms)
}

#[cfg(test)]
mod tests {
    use super::reconnect_delay_ms as d;

    #[test]
    fn doubles_then_caps() {
        let got: Vec<u64> = (0..8).map(|a| d(a, 50, 500)).collect();
        assert_eq!(got, [50, 100, 200, 400, 500, 500, 500, 500]);
        assert_eq!(d(u32::MAX, 50, 500), 500);
        assert_eq!(d(3, 900, 500), 500);
        assert_eq!(d(5, 0, 500), 0);
    }
}
