/*
    src/integrators/loop_bounds.h -- volpathlocal's loop bounds: every loop
    ends, whatever the input

    Each loop stops a lane after more iterations than a valid ray can take,
    and counts it; render() warns, and to_string() and traverse()
    ("loop_bound_trips") show the counts. A trip means a bug or an input
    outside what the integrator supports; the lane then ends as if it had
    left the medium (or the path had been absorbed), so the image is finite
    but biased there. The bounds:
     - path, shadow ray: kMaxStalls iterations in a row in which the path
       neither scattered nor moved (every valid iteration does one of the
       two, or ends the path), or kMaxLoopSteps in all (bound_loop() here);
     - walk: a flight's steps beyond twice the cell faces its segment can
       cross (tracking.h, begin_flight);
     - delta, ratio tracking: tentative collisions beyond the Poisson tail of
       the global majorant's optical depth (tracking.h, begin_flight).
    Each sets its bit of a lane's `tripped` mask; LoopTrips counts the bits.
*/

#pragma once

#include <mitsuba/core/logger.h>
#include <drjit/jit.h>
#include <nanovdb_mitsuba/frozen.h>

#include <atomic>
#include <mutex>
#include <string>
#include <vector>

NAMESPACE_BEGIN(mitsuba)

/// The loops whose iterations are bounded, as bits of a `tripped` mask
enum LoopBound : uint32_t { PathLoop = 0, ShadowLoop, WalkLoop, DeltaLoop, RatioLoop,
                            LoopCount };

/// The lanes each loop bound stopped, counted over renders
template <typename Float> class LoopTrips {
public:
    using UInt32 = dr::uint32_array_t<Float>;
    using Mask = dr::mask_t<Float>;
    static constexpr const char *kLoopNames[LoopCount] = { "path", "shadow ray", "walk",
                                                           "delta tracking", "ratio tracking" };
    static constexpr uint32_t kMaxStalls = 16;
    static constexpr uint32_t kMaxLoopSteps = 1u << 24;

    LoopTrips() {
        if constexpr (dr::is_jit_v<Float>)
            jit_counts = dr::zeros<UInt32>(LoopCount);
    }

    /// One iteration of the path or shadow loop done: `progress` where it
    /// scattered or moved
    static void bound_loop(LoopBound loop, const Mask &progress, Mask &active, UInt32 &stalls,
                           UInt32 &steps, UInt32 &tripped) {
        stalls = dr::select(progress, 0u, stalls + 1u);
        steps += 1u;
        Mask trip = active && (stalls >= kMaxStalls || steps >= kMaxLoopSteps);
        dr::masked(tripped, trip) |= (1u << loop);
        active &= !trip;
    }

    /// Adds a sample's trips (bits of `tripped`) to the counters
    void record(const UInt32 &tripped, const Mask &active) const {
        if constexpr (dr::is_jit_v<Float>) {
            for (uint32_t i = 0; i < LoopCount; ++i)
                dr::scatter_reduce(ReduceOp::Add, jit_counts, UInt32(1), UInt32(i),
                                   active && (tripped & (1u << i)) != 0u);
        } else {
            for (uint32_t i = 0; i < LoopCount; ++i)
                if (active && (tripped & (1u << i)))
                    m_scalar_counts[i].fetch_add(1, std::memory_order_relaxed);
        }
    }

    /// Whether reading the counters evaluates nothing (no pending render,
    /// and not inside a frozen function's recording)
    bool ready() const {
        if constexpr (dr::is_jit_v<Float>) {
            if (recording_frozen_function<Float>())
                return false;
            VarState state = jit_var_state(jit_counts.index());
            return state == VarState::Evaluated || state == VarState::Literal;
        } else {
            return true;
        }
    }

    /// The counts, per loop
    std::vector<uint32_t> counts() const {
        std::vector<uint32_t> out(LoopCount);
        if constexpr (dr::is_jit_v<Float>) {
            UInt32 trips = jit_counts;
            dr::eval(trips);
            dr::store(out.data(), trips);
        } else {
            for (uint32_t i = 0; i < LoopCount; ++i)
                out[i] = m_scalar_counts[i].load();
        }
        return out;
    }

    /// "path: 0, shadow ray: 0, ..." (to_string())
    std::string list() const {
        std::vector<uint32_t> trips = counts();
        std::string out;
        for (uint32_t i = 0; i < LoopCount; ++i)
            out += tfm::format("%s%s: %u", i ? ", " : "", kLoopNames[i], trips[i]);
        return out;
    }

    /// After a render: warns about the trips since the last report
    void report() const {
        std::vector<uint32_t> trips = counts();
        std::lock_guard<std::mutex> guard(m_mutex);
        for (uint32_t i = 0; i < LoopCount; ++i) {
            uint32_t fresh = trips[i] - m_reported[i];
            if (fresh)
                Log(Warn, "volpathlocal: the %s loop's bound stopped %u lanes in this render "
                          "(%u in all): a bug or an unsupported input; please report it with "
                          "the scene", kLoopNames[i], fresh, trips[i]);
            m_reported[i] = trips[i];
        }
    }

    mutable UInt32 jit_counts; ///< per LoopBound (JIT); the integrator traverses it

private:
    mutable std::atomic<uint32_t> m_scalar_counts[LoopCount] = {}; ///< (scalar)
    mutable uint32_t m_reported[LoopCount] = {};
    mutable std::mutex m_mutex;
};

NAMESPACE_END(mitsuba)
