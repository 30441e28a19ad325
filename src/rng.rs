//! A small, stable, seedable random number generator (SplitMix64).
//!
//! Every output of surgvla is a pure function of (config, seed), across crate upgrades too, so
//! the generator is ours rather than a dependency whose stream may change between versions.

/// SplitMix64: fast, statistically sound for simulation spawns, and splittable by seed mixing.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        SplitMix64 { state: seed }
    }

    /// A generator for the named stream of a seed (e.g. one per episode and purpose), so that
    /// adding draws to one stream never shifts another.
    pub fn stream(seed: u64, stream: &str) -> Self {
        let mut hash = 0xcbf2_9ce4_8422_2325u64;
        for byte in stream.bytes() {
            hash ^= u64::from(byte);
            hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
        }
        let mut mixer = SplitMix64::new(seed ^ hash);
        SplitMix64::new(mixer.next_u64())
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [low, high).
    pub fn uniform(&mut self, low: f64, high: f64) -> f64 {
        low + (high - low) * self.next_f64()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_stream_and_streams_differ() {
        let a: Vec<u64> = (0..4)
            .map({
                let mut r = SplitMix64::stream(7, "spawn");
                move |_| r.next_u64()
            })
            .collect();
        let b: Vec<u64> = (0..4)
            .map({
                let mut r = SplitMix64::stream(7, "spawn");
                move |_| r.next_u64()
            })
            .collect();
        let c = SplitMix64::stream(7, "expert").next_u64();
        assert_eq!(a, b);
        assert_ne!(a[0], c);
    }

    #[test]
    fn uniform_stays_in_range_and_spreads() {
        let mut rng = SplitMix64::new(1);
        let draws: Vec<f64> = (0..1000).map(|_| rng.uniform(-2.0, 3.0)).collect();
        assert!(draws.iter().all(|v| (-2.0..3.0).contains(v)));
        let mean = draws.iter().sum::<f64>() / draws.len() as f64;
        assert!((mean - 0.5).abs() < 0.2, "mean {mean}");
    }
}
