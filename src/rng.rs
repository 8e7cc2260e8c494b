//! The crate's deterministic random numbers: small seedable generators and an integer hash, so a
//! run is reproducible bit for bit from its seeds and no module hand-rolls its own.
//!
//! Three generators are kept, each where it was first used, because changing a site's generator
//! would change its sequence and so the outputs:
//! * [`WyRand`]: fast, for the hot sampling loop of robust PnP (and its shuffle).
//! * [`SplitMix64`]: pair sampling in the scale/shift alignment and the consistency tests, and
//!   the splitmix64 finaliser [`mix64`] as a hash (synthetic scenes, verifier cell subsampling).
//! * [`Lcg64`]: Knuth's MMIX linear congruential generator, which spreads the candidate pairs of
//!   the robust affine depth fit (`geometry::affine_fit`) and makes test data.
//!
//! None of them is cryptographic; all are statistically fine for sampling.

/// The golden-ratio increment of splitmix64 (also used as a seed spreader).
pub const GOLDEN_GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// wyrand: a 64-bit generator with one add and one 128-bit multiply per draw.
pub struct WyRand {
    state: u64,
}

impl WyRand {
    pub fn new(seed: u64) -> Self {
        // Spread the seed so nearby seeds give unrelated streams.
        let mut s = Self { state: seed ^ GOLDEN_GAMMA };
        s.next_u64();
        s
    }

    #[inline(always)]
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0xa076_1d64_78bd_642f);
        let t = (self.state as u128).wrapping_mul((self.state ^ 0xe703_7ed1_a0b4_28db) as u128);
        ((t >> 64) as u64) ^ (t as u64)
    }

    /// Uniform in `0..n` (`n > 0`), Lemire's multiply-shift (bias < n/2⁶⁴).
    #[inline(always)]
    pub fn below(&mut self, n: usize) -> usize {
        ((self.next_u64() as u128 * n as u128) >> 64) as usize
    }

    /// Fisher–Yates shuffle.
    pub fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            let j = self.below(i + 1);
            v.swap(i, j);
        }
    }
}

/// The splitmix64 finaliser: a well-mixed 64-bit hash of an integer.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// splitmix64 (Steele, Lea & Flood 2014): the state steps by [`GOLDEN_GAMMA`], the output is
/// its [`mix64`]. The first draw of `SplitMix64(x)` is `splitmix64_hash(x)`.
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(GOLDEN_GAMMA);
        mix64(self.0)
    }

    /// Uniform in [0, 1) with 53 bits.
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        unit_f64(self.next_u64())
    }

    /// In `0..n` by scaling [`Self::next_f64`] (0 for `n = 0`).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_f64() * n as f64) as usize % n.max(1)
    }
}

/// One splitmix64 step from `x`: a hash of an integer (`SplitMix64(x).next_u64()`).
#[inline]
pub fn splitmix64_hash(x: u64) -> u64 {
    mix64(x.wrapping_add(GOLDEN_GAMMA))
}

/// Knuth's MMIX linear congruential generator, `s ← 6364136223846793005·s + 1442695040888963407`.
/// Its low bits are weak: use the high ones ([`Self::next_high31`], [`Self::next_f64`]).
pub struct Lcg64(pub u64);

impl Lcg64 {
    /// The next state.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        self.0
    }

    /// The top 31 bits of the next state.
    #[inline]
    pub fn next_high31(&mut self) -> usize {
        (self.next_u64() >> 33) as usize
    }

    /// Uniform in [0, 1) with 53 bits.
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        unit_f64(self.next_u64())
    }
}

/// The top 53 bits of `bits` as a float in [0, 1).
#[inline]
fn unit_f64(bits: u64) -> f64 {
    (bits >> 11) as f64 / (1u64 << 53) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix64_matches_the_reference_sequence() {
        // The first outputs of splitmix64 seeded with 0 (Vigna's reference implementation).
        let mut g = SplitMix64(0);
        assert_eq!(g.next_u64(), 0xe220_a839_7b1d_cdaf);
        assert_eq!(g.next_u64(), 0x6e78_9e6a_a1b9_65f4);
        assert_eq!(splitmix64_hash(0), 0xe220_a839_7b1d_cdaf);
    }

    #[test]
    fn lcg_is_knuths_mmix() {
        let mut g = Lcg64(1);
        assert_eq!(g.next_u64(), 6364136223846793005u64.wrapping_add(1442695040888963407));
    }

    #[test]
    fn draws_stay_in_range_and_shuffle_permutes() {
        let mut w = WyRand::new(7);
        let mut s = SplitMix64(7);
        for n in 1..50 {
            assert!(w.below(n) < n);
            assert!(s.below(n) < n);
        }
        assert_eq!(s.below(0), 0);
        let mut v: Vec<u32> = (0..100).collect();
        w.shuffle(&mut v);
        assert_ne!(v, (0..100).collect::<Vec<_>>());
        v.sort_unstable();
        assert_eq!(v, (0..100).collect::<Vec<_>>());
    }

    #[test]
    fn seeds_give_different_streams() {
        let a: Vec<u64> = (0..4).scan(WyRand::new(1), |g, _| Some(g.next_u64())).collect();
        let b: Vec<u64> = (0..4).scan(WyRand::new(2), |g, _| Some(g.next_u64())).collect();
        assert_ne!(a, b);
    }
}
