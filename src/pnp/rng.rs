//! A tiny deterministic PRNG (wyrand) for sampling: fast, seedable, no API churn.

pub(crate) struct WyRand {
    state: u64,
}

impl WyRand {
    pub(crate) fn new(seed: u64) -> Self {
        // Spread the seed so nearby seeds give unrelated streams.
        let mut s = Self { state: seed ^ 0x9e37_79b9_7f4a_7c15 };
        s.next_u64();
        s
    }

    #[inline(always)]
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0xa076_1d64_78bd_642f);
        let t = (self.state as u128).wrapping_mul((self.state ^ 0xe703_7ed1_a0b4_28db) as u128);
        ((t >> 64) as u64) ^ (t as u64)
    }

    /// Uniform in `0..n` (`n > 0`), Lemire's multiply-shift (bias < n/2⁶⁴).
    #[inline(always)]
    pub(crate) fn below(&mut self, n: usize) -> usize {
        ((self.next_u64() as u128 * n as u128) >> 64) as usize
    }

    /// Fisher–Yates shuffle.
    pub(crate) fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            let j = self.below(i + 1);
            v.swap(i, j);
        }
    }
}
