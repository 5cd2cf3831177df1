/*
    src/volumes/volume_properties.h -- nanovdbvolume's properties, read and
    checked in one place (the doc block in grid_nanovdb.cpp lists them):
    where the values come from (a file, or memory: memory_source.h), the
    filter, the wrap mode, the placement switches, and what the load takes
    (grid_load.h's LoadSettings). Every refusal names the volume's file or
    source. The constructor then loads the grid and places it.
*/

#pragma once

#include <mitsuba/core/fresolver.h>
#include <mitsuba/core/logger.h>
#include <mitsuba/core/properties.h>

#include <nanovdb_loader/build.h>
#include <nanovdb_loader/vdb_import.h>

#include "grid_load.h"
#include "memory_source.h"

#include <cmath>
#include <cstdio>
#include <optional>
#include <string>
#include <string_view>

namespace mitsuba::nvdb {

/// filter_type: what a lookup reads
enum class Filter : uint32_t { Nearest, Trilinear, StochasticTrilinear, StochasticTricubic };
constexpr const char *FILTER_NAMES[] = { "nearest", "trilinear", "stochastic_trilinear",
                                         "stochastic_tricubic" };

/// The properties, read
struct VolumeProperties {
    std::string filename;             ///< the resolved file, or the memory source's label
    bool grid_object = false;         ///< "grid" is a VolumeGrid (not a file's grid name)
    bool vol_file = false;            ///< a gridvolume .vol file: dense, made sparse at load
    std::string selector;             ///< a file's grid ("": the first), or the pair "X"
    Filter filter = Filter::Trilinear;
    bool clamp = false;               ///< wrap_mode "clamp" (else "tree")
    bool use_grid_transform = false, use_grid_bbox = false;
    bool count_lookups = false;
    nanovdb_loader::BuildOptions build; ///< values from memory: background, threshold
    std::optional<float> max_value;   ///< a bound given by the user
    LoadSettings load;                ///< what the load takes (grid_load.h)
};

/// Whether `path` starts as a gridvolume file does ("VOL", version 3)
inline bool is_vol_file(const std::string &path) {
    FILE *f = std::fopen(path.c_str(), "rb");
    if (!f)
        return false; // (the loader reports a missing file)
    unsigned char magic[4] = { 0, 0, 0, 0 };
    size_t n = std::fread(magic, 1, 4, f);
    std::fclose(f);
    return n == 4 && magic[0] == 'V' && magic[1] == 'O' && magic[2] == 'L' && magic[3] == 3;
}

/**
 * Reads and checks nanovdbvolume's properties. A volume from memory (a
 * VolumeGrid, a tensor, a voxel list or a .vol file) is read into `memory`
 * here, first, so that every later message names its source.
 */
template <typename Float, typename Spectrum>
VolumeProperties read_volume_properties(const Properties &props,
                                        std::optional<MemorySource<Float, Spectrum>> &memory) {
    VolumeProperties p;
    p.grid_object = props.has_property("grid") && props.type("grid") == Properties::Type::Object;
    const int sources = int(props.has_property("filename")) + int(p.grid_object) +
                        int(props.has_property("data")) +
                        int(props.has_property("values") || props.has_property("coords"));
    if (sources != 1)
        Throw("nanovdbvolume: give exactly one of \"filename\" (a .nvdb file), \"grid\" "
              "(a VolumeGrid), \"data\" (a dense tensor) or \"values\" with \"coords\" "
              "(voxels one by one); %d were given", sources);
    if (props.has_property("filename")) {
        p.filename = file_resolver()->resolve(props.get<std::string_view>("filename")).string();
        p.vol_file = is_vol_file(p.filename);
        if (p.vol_file) {
            if (props.has_property("grid"))
                Throw("nanovdbvolume: \"%s\": a .vol file holds one volume: no \"grid\" to "
                      "choose", p.filename);
            memory.emplace(p.filename);
        }
    } else {
        memory.emplace(props, p.grid_object);
        p.filename = memory->label;
    }
    const std::string &name = p.filename;

    std::string_view filter = props.get<std::string_view>("filter_type", "trilinear");
    for (size_t f = 0; f < std::size(FILTER_NAMES); ++f)
        if (filter == FILTER_NAMES[f])
            p.filter = Filter(f);
    if (filter != FILTER_NAMES[(size_t) p.filter])
        Throw("nanovdbvolume: \"%s\": invalid filter_type \"%s\", must be one of: "
              "\"nearest\", \"trilinear\", \"stochastic_trilinear\" or "
              "\"stochastic_tricubic\"", name, filter);

    std::string_view rebuild = props.get<std::string_view>("majorant_rebuild", "backend");
    if (rebuild == "host")
        p.load.rebuild_on_backend = false;
    else if (rebuild != "backend")
        Throw("nanovdbvolume: \"%s\": invalid value \"%s\" for majorant_rebuild, must be "
              "one of: \"backend\" or \"host\"", name, rebuild);

    std::string_view invalid = props.get<std::string_view>("invalid_values", "error");
    if (invalid == "clamp")
        p.load.invalid_values = nanovdb_loader::InvalidValues::Clamp;
    else if (invalid != "error")
        Throw("nanovdbvolume: \"%s\": invalid value \"%s\" for invalid_values, must be "
              "one of: \"error\" or \"clamp\"", name, invalid);

    // Outside the box: the tree's own values (VDB semantics; the default
    // for files and voxel lists) or the edge voxels (gridvolume's
    // convention, and its default: the default for dense data)
    const bool dense_source = p.grid_object || props.has_property("data") || p.vol_file;
    std::string_view wrap = props.get<std::string_view>("wrap_mode", dense_source ? "clamp" : "tree");
    if (wrap == "clamp")
        p.clamp = true;
    else if (wrap == "repeat" || wrap == "mirror")
        Throw("nanovdbvolume: \"%s\": wrap_mode \"%s\" is not supported: a sparse grid has "
              "no period to repeat or mirror; use \"clamp\" (the edge voxels, gridvolume's "
              "default) or \"tree\" (the tree's own values)", name, wrap);
    else if (wrap != "tree")
        Throw("nanovdbvolume: \"%s\": invalid wrap_mode \"%s\", must be one of: \"tree\" "
              "or \"clamp\"", name, wrap);

    p.use_grid_transform = props.get<bool>("use_grid_transform", false);
    p.use_grid_bbox = props.get<bool>("use_grid_bbox", false);
    if (p.use_grid_bbox && p.use_grid_transform)
        Throw("nanovdbvolume: \"%s\": use_grid_bbox and use_grid_transform both place the "
              "volume by the grid's own coordinates; set one of them", name);
    if (p.use_grid_bbox && (props.has_property("data") || props.has_property("values")))
        Throw("nanovdbvolume: \"%s\": use_grid_bbox needs a bounding box, which a file or a "
              "VolumeGrid has and a tensor does not (as for gridvolume)", name);
    // gridvolume's hardware textures (CUDA): nothing to switch here, the
    // tree is traversed on every backend
    if (props.has_property("accel"))
        Log(Debug, "nanovdbvolume: \"%s\": accel=%s has no effect (no texture units: the "
                   "tree is traversed)", name, props.get<bool>("accel"));
    p.load.raw = props.get<bool>("raw", false);
    p.count_lookups = props.get<bool>("count_lookups", false);
    // Differentiable values: the grid becomes an index grid (its tree)
    // and one Float array of its active values, exposed as "data"
    p.load.differentiable = props.get<bool>("differentiable", false);
    p.load.blind.channel = std::string(props.get<std::string_view>("blind_channel", ""));
    p.load.blind.component = (uint32_t) props.get<uint32_t>("blind_component", 0);
    // level_set: what a file's level set becomes. The default keeps what
    // each kind of file gave before: vdb2nvdb's fog for a .vdb, the
    // stored distances for a .nvdb (vdb2nvdb fogs the level sets it
    // writes unless --keep-level-sets: a .nvdb level set was kept so)
    const bool vdb_file = !memory && nanovdb_loader::is_vdb_path(p.filename);
    std::string_view level_set = props.get<std::string_view>("level_set",
                                                             vdb_file ? "fog" : "distance");
    if (level_set == "fog")
        p.load.level_set_fog = true;
    else if (level_set != "distance")
        Throw("nanovdbvolume: \"%s\": invalid level_set \"%s\", must be one of: \"fog\" "
              "or \"distance\"", name, level_set);
    if (memory && props.has_property("level_set"))
        Throw("nanovdbvolume: \"%s\": level_set applies to the level sets of .nvdb and "
              ".vdb files; this volume comes from %s, which holds none", name,
              p.vol_file ? "a .vol file" : "memory");

    if (memory) {
        p.build.background = props.get<float>("background", 0.f);
        p.build.threshold = props.get<float>("threshold", 0.f);
        if (!std::isfinite(p.build.background))
            Throw("nanovdbvolume: \"%s\": background must be finite, got %f", name,
                  p.build.background);
        if (!(p.build.threshold >= 0.f))
            Throw("nanovdbvolume: \"%s\": threshold must be >= 0, got %f", name,
                  p.build.threshold);
    } else if (!p.grid_object) {
        p.selector = std::string(props.get<std::string_view>("grid", ""));
    }
    if (props.has_property("max_value"))
        p.max_value = props.get<float>("max_value");

    // What the load takes from these properties; a filter's reach: a
    // tricubic stencil reaches 1.5 voxels, a ring of 2
    p.load.filename = p.filename;
    p.load.clamp = p.clamp;
    p.load.reach = p.filter == Filter::Nearest              ? 0
                   : p.filter == Filter::StochasticTricubic ? 2
                                                            : 1;
    return p;
}

} // namespace mitsuba::nvdb
