//! Deterministic random numbers, the one copy of each generator the engine uses:
//! * [`SplitMix64`] on the host: parameter initialisation, batch and random-pose
//!   draws, the sample jitter's seed, and the tests' random data;
//! * [`pcg_hash`], [`rand_u32`] and [`unit_f32`]: the CPU mirror of
//!   `kernels/common/hash.wgsl`, the stateless hash the kernels draw with (occupancy
//!   grid queries, sample jitter, random backgrounds).
//!
//! Invariants: no state outside the generator value, no dependency, the same sequence
//! on every platform; the mirror functions are bit-identical to the WGSL (u32
//! wrapping arithmetic, 24-bit floats), which the sampler's and renderer's reference
//! tests rely on.

/// SplitMix64 (Steele, Lea and Flood 2014): a small, well-mixed 64-bit generator.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

/// The golden-ratio increment of SplitMix64.
const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

impl SplitMix64 {
    /// The generator whose state is `seed`.
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    /// The generator whose state is `seed ^ GOLDEN`, so that small seeds (0, 1, a
    /// step count) do not start from a nearly empty state: the batch and pose draws.
    pub fn mixed(seed: u64) -> Self {
        SplitMix64(seed ^ GOLDEN)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(GOLDEN);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// The high 32 bits of the next word.
    pub fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }

    /// Uniform in `0..n` (Lemire's multiply-shift; `n = 0` gives 0).
    pub fn below(&mut self, n: u64) -> u64 {
        ((self.next_u64() as u128 * n as u128) >> 64) as u64
    }

    /// Uniform in `[-r, r)`, 53 bits.
    pub fn uniform(&mut self, r: f64) -> f64 {
        ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * r
    }

    /// Uniform in `[0, 1)`, 24 bits.
    pub fn unit_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in `[lo, hi)`.
    pub fn range_f32(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit_f32()
    }
}

/// PCG hash (Jarzynski and Olano, "Hash Functions for GPU Rendering", 2020), as
/// `pcg_hash` in `kernels/common/hash.wgsl`.
pub fn pcg_hash(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// Random word number `k` of item `index` under `seed`, as `rand_u32` in
/// `kernels/common/hash.wgsl`.
pub fn rand_u32(seed: u32, index: u32, k: u32) -> u32 {
    pcg_hash(pcg_hash(pcg_hash(seed).wrapping_add(index)).wrapping_add(k))
}

/// Uniform float in `[0, 1)` from the 24 high bits of a random word, as `unit_f32` in
/// `kernels/common/hash.wgsl`.
pub fn unit_f32(bits: u32) -> f32 {
    (bits >> 8) as f32 * (1.0 / 16_777_216.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix64_matches_the_reference_sequence() {
        // Reference values of SplitMix64 from state 0 (Vigna's splitmix64.c).
        let mut r = SplitMix64::new(0);
        assert_eq!(r.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(r.next_u64(), 0x6E78_9E6A_A1B9_65F4);
        assert_eq!(r.next_u64(), 0x06C4_5D18_8009_454F);
    }

    #[test]
    fn draws_stay_in_their_ranges_and_cover_them() {
        let mut r = SplitMix64::mixed(7);
        let mut seen = [false; 10];
        for _ in 0..2000 {
            let b = r.below(10);
            assert!(b < 10);
            seen[b as usize] = true;
            let u = r.uniform(2.5);
            assert!((-2.5..2.5).contains(&u));
            let f = r.range_f32(-1.0, 3.0);
            assert!((-1.0..3.0).contains(&f));
        }
        assert!(seen.iter().all(|&s| s), "below(10) missed a value: {seen:?}");
        assert_eq!(r.below(0), 0);
    }

    #[test]
    fn pcg_hash_matches_published_values() {
        // The paper's formula evaluated independently (Python, arbitrary precision mod 2^32).
        assert_eq!(pcg_hash(0), 129_708_002);
        assert_eq!(pcg_hash(1), 2_831_084_092);
        assert!((0.0..1.0).contains(&unit_f32(u32::MAX)));
        assert_eq!(unit_f32(255), 0.0);
    }
}
