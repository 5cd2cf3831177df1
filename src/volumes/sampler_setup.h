/*
    src/volumes/sampler_setup.h -- the hand-off from the loader to the
    lookups: a grid that nanovdb_loader::prepare_grid() prepared (host side:
    bytes, reader plan, bounds, node majorants, spectral scales) set into a
    nanovdb_drjit::GridSampler (device side), which then owns the bytes.

    The one place that knows both sides, so that the loader stays free of
    Dr.Jit and the sampler free of the loader. The plugin (grid_nanovdb.cpp)
    and the sampler's tests (tests/test_sampler.cpp) set samplers up through
    it, so the tests check what renders.
*/

#pragma once

#include <nanovdb_drjit/sampler.h>
#include <nanovdb_loader/load.h>
#include <nanovdb_loader/majorants.h>

#include <cstdint>
#include <optional>
#include <utility>

namespace nanovdb_mitsuba {

/// What set_up_sampler made of a prepared grid
struct SamplerSetup {
    float max = 0.f;                  ///< every lookup's bound (max())
    float max3[3] = { 0.f, 0.f, 0.f }; ///< per channel (Vec3f; else max)
    int32_t cell_base[3] = { 0, 0, 0 }; ///< the walk's base: the box minimum
                                        ///  rounded down to a 4096 multiple
    double mean_bound = 0.0;          ///< the mean local bound (spectral
                                      ///  factor applied)
    size_t majorant_bytes = 0, scale_bytes = 0;
};

template <typename Float>
SamplerSetup set_up_bounds(nanovdb_drjit::GridSampler<Float> &s, nanovdb_loader::PreparedGrid &g,
                           bool clamp, const std::optional<nanovdb_loader::IndexBox> &volume_box);

/**
 * Sets `s` up from `g` and takes over `host` (the block prepare_grid wrote
 * into, `word_count` 32-bit words): the reader of the plan, the per-node
 * majorants of the walk, max(), the spectral scales (when the loader made
 * them) and the grid's words. `clamp`: wrap_mode "clamp" (the walk's cells
 * outside the volume's box are bounded by max()); `volume_box`: the volume's
 * box when it is not the grid's active box. The box itself (set_box) is the
 * caller's: it knows the volume's extent. `g.scales` is moved from.
 */
template <typename Float>
SamplerSetup set_up_sampler(nanovdb_drjit::GridSampler<Float> &s, nanovdb_loader::PreparedGrid &g,
                            typename nanovdb_drjit::GridSampler<Float>::HostBlock host,
                            size_t word_count, bool clamp,
                            const std::optional<nanovdb_loader::IndexBox> &volume_box) {
    namespace loader = nanovdb_loader;
    using UInt32 = drjit::uint32_array_t<Float>;
    const bool vec3 = loader::vec3_values(g.grid);
    s.reader = nanovdb_drjit::Reader<UInt32>::from_plan(g.plan);
    SamplerSetup out = set_up_bounds(s, g, clamp, volume_box);
    if (vec3 && !g.scales.values.empty()) {
        out.scale_bytes = g.scales.values.size() * sizeof(float);
        s.set_scales(std::move(g.scales.values), g.scales.tiles_begin, g.scales.leaf_begin_word,
                     g.scales.tile_begin_word);
    }
    if (g.grid.is_index_grid())
        s.set_index_values(g.index_values.data(), g.index_values.size(),
                           g.grid.index_values().background, g.grid.index_values().channels);
    s.set_grid(std::move(host), word_count);
    return out;
}

/**
 * The bounds of `g` in `s`: max() (per channel) and the per-node majorants
 * of the walk; at set-up, and again when an index grid's values change
 * (the plugin's parameters_changed)
 */
template <typename Float>
SamplerSetup set_up_bounds(nanovdb_drjit::GridSampler<Float> &s, nanovdb_loader::PreparedGrid &g,
                           bool clamp, const std::optional<nanovdb_loader::IndexBox> &volume_box) {
    namespace loader = nanovdb_loader;
    using UInt32 = drjit::uint32_array_t<Float>;
    const loader::GridSummary &summary = g.grid.summary();
    const bool vec3 = loader::vec3_values(g.grid);
    SamplerSetup out;
    out.max = g.max;
    for (int k = 0; k < 3; ++k)
        out.max3[k] = vec3 ? g.max3[k] : g.max;

    // Per-node bounds for majorant tracking, raised by 2^-20 for the few ulps
    // by which rounded trilinear weights can overshoot
    for (int k = 0; k < 3; ++k)
        out.cell_base[k] = summary.empty ? 0 : int32_t(uint32_t(summary.bbox_min[k]) & ~4095u);
    s.majorants = nanovdb_drjit::MajorantGrid<UInt32>::make(
        g.majorants.layout, g.majorants.values, nanovdb_drjit::MAJORANT_SCALE * g.spectral_factor, out.max,
        out.cell_base);
    s.majorants.set_root_tiles(g.majorants.tile_origins, out.cell_base, summary.bbox_min,
                               summary.bbox_max);
    if (clamp) { // (walk cells outside the box: see MajorantGrid)
        const loader::IndexBox vb = volume_box ? *volume_box : loader::lookup_box(summary, false);
        int32_t lo[3], hi[3];
        for (int k = 0; k < 3; ++k) { // int32 wrap-around, as the index space
            lo[k] = int32_t(uint32_t(vb.lo[k]) - uint32_t(out.cell_base[k]));
            hi[k] = int32_t(uint32_t(vb.hi[k]) - uint32_t(out.cell_base[k]));
        }
        s.majorants.set_clamp_box(lo, hi, out.max);
    }
    out.majorant_bytes = (size_t) g.majorants.bytes();
    out.mean_bound = g.spectral_factor * g.mean_bound;
    s.set_bounds(out.max, out.max3);
    return out;
}

} // namespace nanovdb_mitsuba
