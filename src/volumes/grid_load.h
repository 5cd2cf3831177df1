/*
    src/volumes/grid_load.h -- what nanovdbvolume's load does: the selected
    grid(s) of a file or of memory, decoded once by the loader
    (nanovdb_loader::prepare_grid) into one exact-size host block, which the
    backend then owns (the sampler: sampler_setup.h). Only the selected
    grid's bytes are read; no host copy is kept, and none is made on LLVM.

      nvdb_file()   a .nvdb file's grid, or the 6-channel pair "X[0:3]",
                    "X[3:6]" (nanovdb_loader::select_grids); a level set
                    with level_set="fog" is made a fog volume by the .vdb
                    reader process, as vdb2nvdb makes one
      vdb_file()    a .vdb file's grid, converted in memory by the reader
                    process (nanovdb_loader/vdb_import.h): no file is written
      built()       a volume from memory (memory_source.h): its grid(s) built
                    by the loader (nanovdb_loader/build.h), then loaded
      memory()      a grid in memory: built, or a .vdb's converted one

    The plugin (grid_nanovdb.cpp) keeps its properties and the Volume
    interface, and holds one GridLoad: the settings a load takes from the
    properties, and what it learnt (GridFacts, the .vdb import, an index
    grid's update state: index_updates.h).
*/

#pragma once

#include <mitsuba/core/logger.h>
#include <mitsuba/core/vector.h>
#include <mitsuba/render/srgb.h>

#include <nanovdb_drjit/sampler.h>
#include <nanovdb_loader/active_tiles.h>
#include <nanovdb_loader/build.h>
#include <nanovdb_loader/load.h>
#include <nanovdb_loader/vdb_import.h>

#include "index_updates.h"
#include "sampler_setup.h"

#include <cstdlib>
#include <cstring>
#include <memory>
#include <optional>
#include <string>
#include <vector>

// In Mitsuba's namespace, as the plugin: its Log and Throw
namespace mitsuba::nvdb {

/// What the plugin reports of a loaded grid
struct GridFacts {
    std::string name;
    uint32_t grid_type = 0, grid_class = 0;
    float max = 0.f, grid_max = 0.f;   ///< lookups' bound; the largest stored value
    float max3[3] = { 0.f, 0.f, 0.f }; ///< per channel (Vec3f)
    size_t grid_bytes = 0, backend_bytes = 0, majorant_bytes = 0, scale_bytes = 0;
    size_t value_bytes = 0;            ///< an index grid's values
    float majorant_ratio = 1.f;        ///< mean local bound / max()
};

/// What a load takes from the plugin's properties
struct LoadSettings {
    std::string filename;              ///< the file, or the memory source's label
    int reach = 1;                     ///< voxels the filter's stencil reaches beyond its
                                       ///< cell: nearest 0, trilinear 1, tricubic 2
    bool clamp = false;                ///< wrap_mode "clamp": lookups clamped to the box
    nanovdb_loader::InvalidValues invalid_values = nanovdb_loader::InvalidValues::Error;
    bool differentiable = false;       ///< make the grid an index grid ("data")
    bool rebuild_on_backend = true;    ///< majorant_rebuild: "backend" (true) or "host"
    bool raw = false;                  ///< Vec3f: no spectral conversion
    bool level_set_fog = false;        ///< level_set: "fog" (true) or "distance"
    nanovdb_loader::BlindSelection blind; ///< a file's index grid: its values' channel
};

/// A .vdb file's grid, converted at load (vdb_file()): for traverse() and to_string()
struct VdbImport {
    bool imported = false;
    uint32_t source_class = 0; ///< OpenVDB's GridClass of the grid in the file
    double convert_seconds = 0;
    double reader_seconds = 0, reader_peak_mb = 0; ///< the reader process's
};

template <typename Float, typename Spectrum> struct GridLoad {
    using Sampler = nanovdb_drjit::GridSampler<Float>;
    using HostBlock = typename Sampler::HostBlock;
    using GridSummary = nanovdb_loader::GridSummary;
    using IndexBox = nanovdb_loader::IndexBox;
    static constexpr uint32_t kLevelSet = 1; // NanoVDB's GridClass::LevelSet

    LoadSettings settings;
    GridFacts facts, second_facts;     ///< the grid (channels 0-2 of 6); channels 3-5
    VdbImport vdb;
    bool fogged = false;               ///< a level set of the file, made a fog volume
    uint32_t grid_index = 0xffffffffu; ///< in the file's grids (memory sources: none)
    int32_t cell_base[3] = { 0, 0, 0 }; ///< the walk's base (multiple of 4096)
    IndexUpdates<Float> index;         ///< an index grid's (differentiable=true)
    std::vector<nanovdb_loader::ActiveTile> tiles; ///< the grid's active tiles

    /// A .vdb file's grid `selector`, converted in memory as vdb2nvdb
    /// converts it: only that grid is read, and no file is written
    GridSummary vdb_file(const std::string &selector, Sampler &s) {
        nanovdb_loader::VdbGrid g;
        try {
            g = nanovdb_loader::import_vdb_grid(settings.filename, selector,
                                                settings.level_set_fog);
        } catch (const nanovdb_loader::Error &e) {
            Throw("nanovdbvolume: %s", e.what());
        }
        vdb.imported = true;
        vdb.source_class = g.source_class;
        fogged = g.fogged;
        vdb.convert_seconds = g.convert_seconds;
        vdb.reader_seconds = g.reader_seconds;
        vdb.reader_peak_mb = double(g.reader_peak_bytes) / double(1 << 20);
        grid_index = g.index;
        Log(Debug, "nanovdbvolume: \"%s\": grid \"%s\" read in %.3f s, converted in %.3f s%s "
            "by nanovdb-vdb-reader (%.3f s, peak %.1f MB)", settings.filename, g.name,
            g.read_seconds, g.convert_seconds,
            g.fogged ? " (a level set, made a fog volume)" : "", g.reader_seconds,
            vdb.reader_peak_mb);
        return memory(g.name, g.data.get(), g.size, std::nullopt, s, facts, false);
    }

    /// A .nvdb file's grid `selector`, or, where a grid X is asked for and
    /// the file holds "X[0:3]" and "X[3:6]", that pair: 6 channels, the
    /// second into `second`
    GridSummary nvdb_file(const std::string &selector, Sampler &s,
                          std::unique_ptr<Sampler> &second) {
        namespace loader = nanovdb_loader;
        try {
            std::vector<loader::GridEntry> grids = loader::list_grids(settings.filename);
            loader::GridChoice choice = loader::select_grids(settings.filename, grids, selector);
            const loader::GridEntry *a = choice.first, *b = choice.second;
            grid_index = uint32_t(a - grids.data());
            if (!b && a->grid_class == kLevelSet && settings.level_set_fog)
                return level_set_as_fog(*a, s);
            GridSummary summary = entry(*a, s, facts, b != nullptr);
            if (b) {
                second = std::make_unique<Sampler>();
                GridSummary s2 = entry(*b, *second, second_facts, true);
                check_same_box(summary, s2, a->name, b->name);
                facts.name = choice.name;
            }
            return summary;
        } catch (const loader::Error &e) {
            Throw("nanovdbvolume: %s", e.what());
        }
    }

    /// A grid in memory: built by the plugin (memory_source.h), or a .vdb's
    /// converted grid; `box`: the volume's box if it is not the active one;
    /// `six`: one of the two grids of a 6-channel volume
    GridSummary memory(const std::string &name, const uint8_t *bytes, size_t size,
                       const std::optional<IndexBox> &box, Sampler &s, GridFacts &f, bool six) {
        try {
            f.name = name;
            return load(nanovdb_loader::GridSource::memory(settings.filename, name, bytes, size),
                        size, box, s, f, six);
        } catch (const nanovdb_loader::Error &e) {
            Throw("nanovdbvolume: %s", e.what());
        }
    }

    /// A volume from memory (memory_source.h): its grid built by the loader
    /// (nanovdb_loader/build.h) and loaded, and for 6 channels the second
    /// grid into `second`; `box` becomes the volume's box where it is not
    /// the active one (a dense source's whole box)
    template <typename Source>
    GridSummary built(const Source &source, const nanovdb_loader::BuildOptions &options,
                      Sampler &s, std::unique_ptr<Sampler> &second,
                      std::optional<IndexBox> &box) {
        GridSummary summary;
        const bool six = source.six_channels;
        for (int half = 0; half < (six ? 2 : 1); ++half) {
            auto [grid, dense_box] = source.build(options, half);
            box = dense_box;
            if (grid.left_out)
                Log(Info, "nanovdbvolume: \"%s\": %llu voxels within threshold = %f of the "
                          "background left out", settings.filename,
                    (unsigned long long) grid.left_out, options.threshold);
            if (half == 0) {
                summary = memory(options.name, grid.bytes.data(), grid.bytes.size(), box, s,
                                 facts, six);
            } else {
                second = std::make_unique<Sampler>();
                memory(options.name, grid.bytes.data(), grid.bytes.size(), box, *second,
                       second_facts, six);
            }
        }
        return summary;
    }

private:
    /**
     * A .nvdb file's level set with level_set="fog": made a fog volume as
     * vdb2nvdb makes one, by the .vdb reader process (the conversion is
     * OpenVDB's sdfToFogVolume, and the plugin does not link OpenVDB), then
     * loaded as the grid it sends back. Only this grid is read.
     */
    GridSummary level_set_as_fog(const nanovdb_loader::GridEntry &e, Sampler &s) {
        nanovdb_loader::VdbGrid g =
            nanovdb_loader::import_nvdb_level_set_as_fog(settings.filename, grid_index, e.name);
        fogged = true;
        Log(Debug, "nanovdbvolume: \"%s\": level set \"%s\" made a fog volume by "
            "nanovdb-vdb-reader in %.3f s (peak %.1f MB)", settings.filename, g.name,
            g.reader_seconds, double(g.reader_peak_bytes) / double(1 << 20));
        return memory(e.name, g.data.get(), g.size, std::nullopt, s, facts, false);
    }

    GridSummary entry(const nanovdb_loader::GridEntry &e, Sampler &s, GridFacts &f, bool six) {
        f.name = e.name;
        return load(nanovdb_loader::GridSource::file(settings.filename, e), e.grid_size,
                    std::nullopt, s, f, six);
    }

    /// The two grids of a 6-channel volume must share their active box
    void check_same_box(const GridSummary &a, const GridSummary &b, const std::string &name_a,
                        const std::string &name_b) const {
        for (int k = 0; k < 3; ++k)
            if (a.bbox_min[k] != b.bbox_min[k] || a.bbox_max[k] != b.bbox_max[k] ||
                a.empty != b.empty)
                Throw("nanovdbvolume: \"%s\": the grids \"%s\" and \"%s\" of a 6-channel "
                      "volume have different active boxes", settings.filename, name_a, name_b);
    }

    /// One host block for `bytes` of grid, padded to 64 bytes: the final
    /// buffer on scalar and LLVM variants (LLVM kernels read host memory in
    /// place), the staging buffer on CUDA
    HostBlock allocate(uint64_t bytes, GridFacts &f) const {
        f.grid_bytes = (size_t) bytes;
        f.backend_bytes = ((f.grid_bytes + 63) / 64) * 64;
        HostBlock host(nullptr, std::free);
        void *ptr = nullptr;
        if (posix_memalign(&ptr, 64, f.backend_bytes) != 0 || !ptr)
            Throw("nanovdbvolume: \"%s\": cannot allocate %zu bytes for grid \"%s\"",
                  settings.filename, f.grid_bytes, f.name);
        host.reset((uint32_t *) ptr);
        return host;
    }

    /**
     * The loader's one call (nanovdb_loader::prepare_grid: decode, validate,
     * value policy, reader plan, max(), per-node majorants, their mean, and
     * for spectral Vec3f grids the colours as coefficients) into one host
     * block, then the hand-off to the backend, into sampler `s`.
     * `volume_box`: the volume's box if it is not the active one; `six`: one
     * of the two grids of a 6-channel volume (never converted into spectra).
     */
    GridSummary load(const nanovdb_loader::GridSource &source, uint64_t bytes,
                     const std::optional<IndexBox> &volume_box, Sampler &s, GridFacts &f,
                     bool six) {
        namespace loader = nanovdb_loader;
        HostBlock host = allocate(bytes + (settings.differentiable ? 64 : 0), f);
        loader::PrepareOptions options;
        options.invalid_values = settings.invalid_values;
        options.volume_box = volume_box;
        // max(): what lookups inside the volume can return (its box, and the
        // ring the filter's stencils reach unless they clamp to the box),
        // not every value the grid stores; the sampler clamps lookups to it
        options.ring = settings.clamp ? 0 : settings.reach;
        options.majorant_ring = std::max(settings.reach, 1);
        // Spectral variants turn colours into sRGB-model coefficients and a
        // scale, as gridvolume does (unless raw; never for 6 channels): a
        // spectrum is scale * S(coefficients), S in [0, 1], scale = 2 max(rgb)
        if (is_spectral_v<Spectrum> && !settings.raw && !six)
            options.spectral = loader::SpectralConversion{
                [](const float rgb[3], float coeff[3]) {
                    Color<float, 3> color(rgb[0], rgb[1], rgb[2]);
                    float scale = dr::max(color) * 2.f;
                    dr::Array<float, 3> c = srgb_model_fetch(color / dr::maximum(1e-8f, scale));
                    for (int k = 0; k < 3; ++k)
                        coeff[k] = c[k];
                    return scale;
                },
                2.f };
        options.index_grid = settings.differentiable && !six;
        options.blind = settings.blind;
        loader::PreparedGrid g = loader::prepare_grid(source, host.get(), f.backend_bytes,
                                                      options);
        for (const std::string &warning : g.warnings)
            Log(Warn, "%s", warning);
        // Its active tiles (few, usually none), for an emission sampler
        // (nanovdb_mitsuba/grid_units.h); read while the view is valid
        if (!six)
            tiles = loader::active_tiles(g.grid);
        if (g.grid.is_index_grid()) {
            // The rebuild of its majorants on the backend after updates
            // (index_updates.h): a plan of the tree, read here, while the
            // bytes g.grid views are still those below
            if constexpr (dr::is_jit_v<Float>) {
                std::string why;
                std::optional<nanovdb_drjit::MajorantRebuildPlan> plan;
                if (settings.rebuild_on_backend)
                    plan = loader::majorant_rebuild_plan(g.grid, options.majorant_ring, &why);
                if (plan) {
                    index.rebuild = decltype(index.rebuild)(*plan);
                    index.rebuild_factor = nanovdb_drjit::MAJORANT_SCALE * g.spectral_factor;
                    index.mean_box = g.box;
                } else if (settings.rebuild_on_backend) {
                    Log(Info, "nanovdbvolume: \"%s\": the per-node majorants of updated values "
                              "are rebuilt on the host (%s)", settings.filename, why);
                }
            }
            // The index grid's tree is smaller than the grid it was made
            // from, or than the file's grid with its blind data: a block of
            // its size, so that the backend holds the tree and the values once
            HostBlock fitted = allocate(g.grid_bytes, f);
            std::memcpy(fitted.get(), host.get(), g.grid_bytes);
            std::memset((uint8_t *) fitted.get() + g.grid_bytes, 0,
                        f.backend_bytes - g.grid_bytes);
            host = std::move(fitted);
            Log(Info, "nanovdbvolume: \"%s\": grid \"%s\" as an index grid: %s, %zu bytes of "
                      "tree and %zu of values%s", settings.filename, g.grid.summary().name,
                g.index_note, g.grid_bytes, g.index_values.size() * sizeof(float),
                dr::is_jit_v<Float> ? " (differentiable: \"data\")" : "");
            // what an update needs to bound the values again (index_updates.h)
            index.options = options;
            index.volume_box = volume_box;
            // (the tree stays on the device: a host copy for a rebuild on the host)
            if (dr::is_cuda_v<Float> && !index.rebuild.valid())
                index.tree_host.assign((const uint8_t *) host.get(),
                                       (const uint8_t *) host.get() + g.grid_bytes);
            index.tree_bytes = g.grid_bytes;
            index.background = g.grid.index_values().background;
            f.value_bytes = g.index_values.size() * sizeof(float);
        }
        const GridSummary &summary = g.grid.summary();
        f.grid_type = summary.grid_type;
        f.grid_class = summary.grid_class;
        f.name = summary.name; // the grid's own name (GridData)
        f.grid_max = g.grid_max;
        // The hand-off to the backend (sampler_setup.h): the sampler owns the
        // block from here on
        nanovdb_mitsuba::SamplerSetup set;
        try {
            set = nanovdb_mitsuba::set_up_sampler(s, g, std::move(host), f.backend_bytes / 4,
                                                  settings.clamp, volume_box);
        } catch (const std::exception &e) {
            Throw("nanovdbvolume: \"%s\": grid \"%s\" (%zu bytes): %s", settings.filename,
                  f.name, f.grid_bytes, e.what());
        }
        f.max = set.max;
        for (int k = 0; k < 3; ++k) {
            f.max3[k] = set.max3[k];
            cell_base[k] = set.cell_base[k];
        }
        f.majorant_bytes = set.majorant_bytes;
        f.scale_bytes = set.scale_bytes;
        f.majorant_ratio = f.max > 0.f ? float(set.mean_bound / f.max) : 1.f;
        return summary;
    }
};

} // namespace mitsuba::nvdb
