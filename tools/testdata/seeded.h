// Seeded random numbers for test data: splitmix64 (Steele, Lea and Flood,
// "Fast splittable pseudorandom number generators", 2014) and nothing from
// <random>, whose distributions are implementation-defined: the same seed
// gives the same grids and the same samples on every platform.
#pragma once

#include <cstdint>

namespace nvdb_testdata {

/// splitmix64's increment, 2^64 / phi
constexpr uint64_t kGolden = 0x9E3779B97F4A7C15ull;

/// splitmix64's finaliser (Stafford's Mix13): a bijection of 64 bits
constexpr uint64_t mix64(uint64_t z) {
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/// The splitmix64 output that follows the state x
constexpr uint64_t splitmix64(uint64_t x) { return mix64(x + kGolden); }

/// The top 53 bits of h as a double in [0, 1)
constexpr double unit_interval(uint64_t h) { return double(h >> 11) * 0x1.0p-53; }

/// splitmix64 of a counter: the k-th number is splitmix64(start + k * step).
class Rng {
public:
    /// The stream of the test grids' query coordinates (tests/grids.h):
    /// a hashed seed, counted up by 1
    static Rng counter(uint64_t seed) { return Rng(splitmix64(seed ^ 0x6E616E6F76646221ull), 1); }
    /// splitmix64 proper (step kGolden) from a scrambled seed: vdb2nvdb's
    /// verification samples
    static Rng stream(uint64_t seed) { return Rng(seed * kGolden + 0x632BE59BD9B4E019ull, kGolden); }

    uint64_t next() {
        const uint64_t x = m_counter;
        m_counter += m_step;
        return splitmix64(x);
    }
    /// Uniform in [0, n) (0 for n = 0). The modulo bias (< n / 2^64) does not matter here.
    uint64_t below(uint64_t n) { return n ? next() % n : 0; }
    /// Uniform in [lo, hi] (inclusive), hi - lo < 2^63
    int64_t range(int64_t lo, int64_t hi) { return lo + int64_t(below(uint64_t(hi - lo) + 1)); }
    /// Uniform in [0, 1)
    double uniform() { return unit_interval(next()); }

private:
    Rng(uint64_t start, uint64_t step) : m_counter(start), m_step(step) {}
    uint64_t m_counter, m_step;
};

} // namespace nvdb_testdata
