/*
    src/volumes/index_updates.h -- an index grid (differentiable=true) whose
    values changed: params.update() after an optimizer step

    What nanovdbvolume keeps of an index grid at load (its tree's bytes, the
    loader's options, the background), and the two passes an update needs:

      values_changed()   on the backend, without reading the values back:
                         the value policy (clamp: NaN and negatives to 0,
                         +Inf to the largest finite value; error: NaN and
                         infinities refused, negatives warned about) and
                         max(), the values' largest (with the background and
                         a given max_value); the per-node majorants are
                         marked stale
      rebound()          the per-node majorants again. LLVM and CUDA: on the
                         backend (nanovdb_drjit/majorant_rebuild.h, from a
                         plan of the tree made at load), the same table as
                         the host's, with no host round trip; max() stays
                         values_changed()'s. Scalar, and a tree the plan
                         refuses (rebuild_plan.cpp says which): on the host,
                         from the values and the tree in place, through the
                         loader's own passes (rebound_index_grid:
                         validation's value statistics, the value policy,
                         node_majorants, max_in_box, mean_bound); CUDA
                         copies the values there (its tree's copy was kept
                         at load). Only the walk (volpathlocal,
                         prbvolpathlocal) reads these bounds, so the plugin
                         calls this when it next asks for them.
*/

#pragma once

#include <mitsuba/core/logger.h>
#include <nanovdb_mitsuba/frozen.h>

#include <nanovdb_drjit/majorant_rebuild.h>
#include <nanovdb_drjit/sampler.h>
#include <nanovdb_loader/load.h>

#include "sampler_setup.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <optional>
#include <string>
#include <vector>

// In Mitsuba's namespace, as the plugin: its Log and Throw
namespace mitsuba::nvdb {

/// The bounds of an index grid's values, after an update
struct IndexBounds {
    float max = 0.f;                   ///< lookups' bound (max())
    float max3[3] = { 0.f, 0.f, 0.f }; ///< per channel (Vec3f)
    float grid_max = 0.f;              ///< the largest stored value (rebound() only)
    float majorant_ratio = 1.f;        ///< mean local bound / max() (the last computed)
};

template <typename Float> struct IndexUpdates {
    using Sampler = nanovdb_drjit::GridSampler<Float>;

    // Kept at load (the plugin's load())
    size_t tree_bytes = 0;                               ///< 0: not an index grid
    nanovdb_loader::PrepareOptions options;              ///< to bound it again
    std::optional<nanovdb_loader::IndexBox> volume_box;
    std::vector<uint8_t> tree_host;                      ///< CUDA: the tree's copy
    std::array<float, 3> background{};                   ///< index 0's value (per channel)
    float max_value_given = 0.f;                         ///< max_value, kept after updates
    bool stale = false;                                  ///< values changed since rebound()
    bool ratio_stale = false;                            ///< majorant_ratio() not yet of the last rebound()
    /// The JIT variable of the values last bounded (held by the sampler
    /// since, so no other variable has its index), and their bounds: an
    /// update that hands back the same variable (dr.enable_grad() alone
    /// gives it a new AD index, and Mitsuba then calls parameters_changed)
    /// changes nothing, and bounds nothing again
    uint32_t bounded_index = 0;
    IndexBounds bounded;
    /// LLVM, CUDA: the rebuild on the backend (invalid: on the host), and
    /// the factor of its value slots (MajorantGrid::make's)
    struct NoRebuild {
        bool valid() const { return false; }
    };
    using Detached = drjit::detached_t<Float>;
    std::conditional_t<drjit::is_jit_v<Float>, nanovdb_drjit::MajorantRebuild<Detached>, NoRebuild>
        rebuild;
    float rebuild_factor = 1.f;
    nanovdb_loader::IndexBox mean_box{}; ///< the box of the mean bound (the load's)

    bool active() const { return tree_bytes != 0; }

    /// Backend rebuilds that replayed the first one's kernels (kernel_replay.h)
    uint32_t rebuild_replays() const {
        if constexpr (drjit::is_jit_v<Float>)
            return rebuild.replay().replays();
        else
            return 0;
    }

    /// The tree in host memory: the sampler's block itself (scalar, LLVM:
    /// the backend reads it in place), or the copy kept for CUDA
    const uint8_t *tree(const Sampler &s) const {
        if constexpr (drjit::is_cuda_v<Float>)
            return tree_host.data();
        else if constexpr (drjit::is_jit_v<Float>)
            return (const uint8_t *) drjit::detach(s.grid).data();
        else
            return (const uint8_t *) s.grid.get();
    }

    /// The JIT index of the sampler's values (0: not a JIT array)
    static uint32_t values_index(const Sampler &s) {
        if constexpr (drjit::is_jit_v<Float>)
            return drjit::detach(s.index_values).index();
        else
            return 0;
    }

    /// Records the values as bounded, with their max() (the load's)
    void remember(const Sampler &s, float max, const float max3[3]) {
        bounded_index = values_index(s);
        bounded.max = max;
        for (int k = 0; k < 3; ++k)
            bounded.max3[k] = max3[k];
    }

    /// Updates and rebuilds read numbers back on the host (max(), the mean
    /// bound), which the recording of a frozen function (dr.freeze) cannot
    /// replay: refused while one records, saying what to do instead
    static void refuse_while_recording(const std::string &filename) {
        if (mitsuba::recording_frozen_function<Float>())
            Throw("nanovdbvolume: \"%s\": \"data\" was updated inside a frozen function "
                  "(dr.freeze), or the function reaches the volume other than through "
                  "its arguments: the volume's bounds are computed from the new values "
                  "when params.update() is called and when the function is called. Call "
                  "params.update() before the frozen function, and pass it the scene (or "
                  "the volume)", filename);
    }

    /// The values changed: the value policy and max() on the backend (see
    /// above); sets the sampler's bounds and returns them. `filename`: for
    /// errors. The same variable as last time (see bounded_index): nothing
    IndexBounds values_changed(Sampler &s, const std::string &filename) {
        namespace dr = drjit;
        if (bounded_index != 0 && values_index(s) == bounded_index)
            return bounded;
        refuse_while_recording(filename);
        auto &values = s.index_values;
        const uint32_t channels = s.index_channels;
        float largest[3] = { background[0], background[1], background[2] };
        if constexpr (dr::is_jit_v<Float>) {
            if (options.invalid_values == nanovdb_loader::InvalidValues::Clamp) {
                Float v = values;
                v = dr::select(dr::isnan(v) | (v < 0.f), 0.f, v);
                Float finite_max = dr::max(dr::select(dr::isinf(v), 0.f, v));
                values = dr::select(dr::isinf(v), finite_max, v);
            }
            if (dr::width(values) > 0) {
                auto detached = dr::detach(values);
                using D = decltype(detached);
                D bad = dr::select(dr::isnan(detached) | dr::isinf(detached), 1.f, 0.f),
                  negative = dr::select(detached < 0.f, 1.f, 0.f);
                // each channel's largest (3 channels: values interleaved)
                dr::Array<D, 3> top;
                if (channels == 3) {
                    dr::Array<D, 3> v3 = dr::unravel<dr::Array<D, 3>>(detached);
                    for (int k = 0; k < 3; ++k)
                        top[k] = dr::max(v3[k]);
                } else {
                    top = dr::Array<D, 3>(dr::max(detached));
                }
                dr::Array<D, 5> r(top[0], top[1], top[2], dr::sum(bad), dr::sum(negative));
                dr::eval(r);
                // (the read waits for the backend's queue: the render and
                // backward pass before it, on LLVM, finish here)
                float host[5];
                for (int k = 0; k < 5; ++k)
                    host[k] = r[k].entry(0);
                if (host[3] > 0.f)
                    Throw("nanovdbvolume: \"%s\": after an update of \"data\": %.0f values are "
                          "NaN or infinite; only finite values can be rendered. Set "
                          "invalid_values=\"clamp\" to replace NaN by 0 and +Inf by the "
                          "largest finite value", filename, host[3]);
                if (host[4] > 0.f)
                    Log(Warn, "nanovdbvolume: \"%s\": after an update of \"data\": %.0f "
                              "negative values (invalid_values=\"clamp\" replaces them by 0)",
                        filename, host[4]);
                for (int k = 0; k < 3; ++k)
                    largest[k] = std::max(largest[k], host[k]);
            }
        } else {
            for (size_t i = 0; i < values.size(); ++i) {
                float &x = values[i];
                if (options.invalid_values == nanovdb_loader::InvalidValues::Clamp && !(x >= 0.f))
                    x = 0.f;
                if (!std::isfinite(x))
                    Throw("nanovdbvolume: \"%s\": after an update of \"data\": a value is "
                          "NaN or infinite", filename);
                float &l = largest[channels == 3 ? i % 3 : 0];
                l = std::max(l, x);
            }
            if (channels != 3)
                largest[1] = largest[2] = largest[0];
        }
        IndexBounds b;
        b.grid_max = std::max({ largest[0], largest[1], largest[2] });
        b.max = std::max({ b.grid_max, max_value_given });
        for (int k = 0; k < 3; ++k)
            b.max3[k] = std::max(largest[k], max_value_given);
        s.set_bounds(b.max, b.max3);
        stale = true;
        remember(s, b.max, b.max3);
        return b;
    }

    /// The mean local bound / max() of the table rebound() last built on
    /// the backend: the walk's choice between local and global majorants
    /// reads it on the host (one number back), so it is computed when asked,
    /// not with the table: a frozen step's replays never ask. Inside a
    /// recording (dr.freeze), which may not read back, the last one computed
    /// (the recording's choice holds for its replays anyway)
    float majorant_ratio(const Sampler &s) {
        namespace dr = drjit;
        if constexpr (dr::is_jit_v<Float>) {
            if (ratio_stale && !mitsuba::recording_frozen_function<Float>()) {
                typename decltype(rebuild)::Box box;
                for (int a = 0; a < 3; ++a) {
                    box.lo[a] = mean_box.lo[a];
                    box.hi[a] = mean_box.hi[a];
                }
                box.clamp = bounded.max;
                const dr::float64_array_t<Detached> mean =
                    rebuild.mean(dr::detach<false>(s.majorants.table), dr::detach<false>(s.index_values),
                                 s.index_channels, background.data(), rebuild_factor, box);
                bounded.majorant_ratio = bounded.max > 0.f ? float(mean.entry(0) / bounded.max) : 1.f;
                ratio_stale = false;
            }
        }
        return bounded.majorant_ratio;
    }

    /// The per-node majorants and max_in_box() again (see above); sets the
    /// sampler's bounds and returns them (the backend's: its majorant_ratio
    /// when majorant_ratio() is asked)
    IndexBounds rebound(Sampler &s, bool clamp, const std::string &filename,
                        const std::string &grid_name) {
        namespace dr = drjit;
        namespace loader = nanovdb_loader;
        auto t0 = std::chrono::steady_clock::now();
        auto &values = s.index_values;
        if constexpr (dr::is_jit_v<Float>) {
            if (rebuild.valid()) {
                // (a walk may first ask inside a loop it traces symbolically:
                // the rebuild reads nothing of it, and evaluates as outside)
                dr::scoped_set_flag symbolic(JitFlag::SymbolicScope, false);
                dr::scoped_disable_symbolic<Detached> unmasked;
                using UInt32 = dr::uint32_array_t<Detached>;
                auto &m = s.majorants;
                m.table = rebuild.table(dr::detach<false>(s.grid), dr::detach<false>(values),
                                        s.index_channels, background.data(), rebuild_factor);
                m.background = dr::reinterpret_array<Detached>(dr::gather<UInt32>(
                    dr::detach<false>(m.table), dr::opaque<UInt32>(rebuild.background_slot())));
                m.clamp = dr::opaque<Detached>(bounded.max); // (values_changed()'s max())
                if (m.clamp_to_box)
                    m.outside = m.clamp;
                stale = false;
                ratio_stale = true; // (majorant_ratio(), when asked)
                // The rebuild's arrays, freed, stay in Dr.Jit's allocator
                // cache. The next rebuild, the same kernels replayed, reuses
                // them; the step between does not. LLVM hands them back
                // (and with them what the step left there) where they are
                // large. Measured (bench/step_memory.py, cloudfield_1600,
                // 114.6 M values): the step's peak 4.03 GB -> 3.57 GB (the
                // host's rebuild: 3.87 GB). Kept where they are small:
                // handed back, the next rebuild and step fault their pages
                // in again (before a frozen step: cloudfield's rebuild
                // 3.1-3.3 -> 3.6-5.2 ms, the cloud's 3.9 -> 8.6 ms), at the
                // cost of a higher peak (the smoke's fit: 43-45 -> 62 MB
                // above the loaded level; PERF_LOG §48). CUDA (not
                // measured): left to Dr.Jit's cache.
                if constexpr (dr::is_llvm_v<Float>)
                    if (rebuild.scratch_bytes() > (size_t(64) << 20))
                        jit_flush_malloc_cache();
                // (the host's part: a replay's kernels run on after it)
                Log(Debug, "nanovdbvolume: \"%s\": per-node majorants of the updated values "
                           "on the backend, %.2f ms on the host (%s, scratch about %.0f MB)", filename,
                    std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                        .count(),
                    rebuild.replay().replayed() ? "replayed" : "traced",
                    rebuild.scratch_bytes() / 1048576.0);
                return bounded;
            }
        }
        size_t count;
        const float *host_values;
        std::vector<float> copy;
        if constexpr (dr::is_jit_v<Float>) {
            dr::eval(values);
            dr::sync_thread();
            count = dr::width(values);
            if constexpr (dr::is_cuda_v<Float>) {
                copy.resize(count);
                dr::store(copy.data(), dr::detach(values));
                host_values = copy.data();
            } else {
                host_values = dr::detach(values).data();
            }
        } else {
            count = values.size();
            host_values = values.data();
        }
        IndexBounds b;
        try {
            loader::PreparedGrid g = loader::rebound_index_grid(
                filename, grid_name, tree(s), tree_bytes,
                loader::IndexValues{ const_cast<float *>(host_values),
                                     count / s.index_channels, background, s.index_channels },
                options);
            for (const std::string &warning : g.warnings)
                Log(Warn, "%s", warning);
            // A max_value above the values stays (gridvolume keeps it too)
            g.max = std::max(g.max, max_value_given);
            nanovdb_mitsuba::SamplerSetup set =
                nanovdb_mitsuba::set_up_bounds(s, g, clamp, volume_box);
            b.max = set.max;
            for (int k = 0; k < 3; ++k)
                b.max3[k] = set.max3[k];
            b.grid_max = g.grid_max;
            b.majorant_ratio = b.max > 0.f ? float(set.mean_bound / b.max) : 1.f;
            bounded.majorant_ratio = b.majorant_ratio; // (majorant_ratio()'s)
            stale = false;
        } catch (const loader::Error &e) {
            Throw("nanovdbvolume: after an update of \"data\": %s", e.what());
        }
        Log(Debug, "nanovdbvolume: \"%s\": per-node majorants of the updated values in %.1f ms",
            filename, std::chrono::duration<double, std::milli>(
                          std::chrono::steady_clock::now() - t0).count());
        return b;
    }
};

} // namespace mitsuba::nvdb
