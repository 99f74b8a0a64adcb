//! What the wire does to frames: drops, corrupted bytes, latency and jitter (delivery order is
//! kept, like a serial line). Decisions come from a seeded generator, so a run is reproducible.

use std::time::Duration;

/// SplitMix64: small, fast, and good enough to decide faults.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The wire's current behaviour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Noise {
    pub corrupt_byte_rate: f64,
    pub drop_rate: f64,
    pub latency: Duration,
    pub jitter: Duration,
}

/// Apply the noise to one frame: `None` if dropped, else how many bytes were corrupted.
pub fn mangle(rng: &mut Rng, noise: &Noise, bytes: &mut [u8]) -> Option<usize> {
    if noise.drop_rate > 0.0 && rng.unit() < noise.drop_rate {
        return None;
    }
    let mut n = 0;
    if noise.corrupt_byte_rate > 0.0 {
        for b in bytes.iter_mut() {
            if rng.unit() < noise.corrupt_byte_rate {
                *b ^= (rng.next_u64() % 255 + 1) as u8;
                n += 1;
            }
        }
    }
    Some(n)
}

/// The one-way delay of the next frame.
pub fn delay(rng: &mut Rng, noise: &Noise) -> Duration {
    noise.latency + noise.jitter.mul_f64(rng.unit())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corruption_rate_is_close_to_the_setting_and_reproducible() {
        let noise = Noise {
            corrupt_byte_rate: 0.01,
            drop_rate: 0.0,
            latency: Duration::ZERO,
            jitter: Duration::ZERO,
        };
        let run = |seed| {
            let mut rng = Rng::new(seed);
            let mut buf = vec![0u8; 100_000];
            mangle(&mut rng, &noise, &mut buf).unwrap()
        };
        let n = run(7);
        assert!((800..1200).contains(&n), "{n}");
        assert_eq!(n, run(7));
    }
}
