// src/loader/load.cpp -- decode_grid() and prepare_grid() (see load.h).

#include <nanovdb_loader/load.h>

#include "detail.h"

#include <nanovdb_drjit/layout.h>

#include <cstring>

namespace nanovdb_loader {

namespace {

/// The value policy and reader plan of a validated grid
DecodedGrid planned(ValidatedGrid grid, const std::string &name, uint64_t grid_bytes,
                    InvalidValues policy) {
    DecodedGrid d{ std::move(grid), {}, {}, {}, {}, grid_bytes };
    d.warnings = apply_value_policy(d.grid, name, policy);
    d.plan = plan_readers(d.grid);
    return d;
}

/// Validation, value policy and reader plan of the grid in `dst`, an index
/// grid with `values` when `indexed` (then owned by the result)
DecodedGrid validate_in_place(const std::string &path, const std::string &name, void *dst,
                              uint64_t grid_bytes, InvalidValues policy,
                              IndexGridValues values, bool indexed) {
    // (the vector moves into the result with its floats where `index` points)
    std::vector<float> owned = std::move(values.values);
    const IndexValues index = indexed ? IndexValues{ owned.data(), owned.size() / values.channels,
                                                     values.background, values.channels }
                                      : IndexValues{};
    DecodedGrid d = planned(validate_grid(path, dst, grid_bytes, index), name, grid_bytes, policy);
    d.index_values = std::move(owned);
    d.index_note = std::move(values.note);
    return d;
}

/// What both sources share once the bytes are in `dst`: an index grid's
/// values taken from its blind data first
DecodedGrid decode_in_place(const std::string &path, const std::string &name, void *dst,
                            uint64_t grid_bytes, InvalidValues policy,
                            const BlindSelection &blind) {
    uint8_t *buf = static_cast<uint8_t *>(dst);
    const bool indexed = grid_bytes >= layout::GRID_HEADER_SIZE &&
                         detail::load<uint32_t>(buf + layout::GRID_OFF_GRID_TYPE) ==
                             layout::GRID_TYPE_ONINDEX &&
                         (detail::load<uint64_t>(buf + layout::GRID_OFF_MAGIC) == layout::MAGIC_NUMBER ||
                          detail::load<uint64_t>(buf + layout::GRID_OFF_MAGIC) == layout::MAGIC_GRID);
    IndexGridValues values;
    if (indexed) {
        // (the grid's own size first: take_blind_values reads within it)
        const uint64_t size = detail::load<uint64_t>(buf + layout::GRID_OFF_GRID_SIZE);
        if (size > grid_bytes || size < layout::GRID_HEADER_SIZE)
            validate_grid(path, dst, grid_bytes); // its error names the problem
        values = take_blind_values(path, buf, size, blind, grid_bytes);
    }
    return validate_in_place(path, name, dst, grid_bytes, policy, std::move(values), indexed);
}

void check_capacity(const std::string &path, const std::string &name, void *dst,
                    uint64_t dst_bytes, uint64_t grid_bytes) {
    if (dst_bytes < grid_bytes)
        detail::fail(path, "grid \"" + name + "\": a buffer of " + std::to_string(dst_bytes) +
                               " bytes cannot hold its " + std::to_string(grid_bytes) +
                               " bytes");
    std::memset(static_cast<uint8_t *>(dst) + grid_bytes, 0, size_t(dst_bytes - grid_bytes));
}

} // namespace

DecodedGrid decode_grid(const std::string &path, const GridEntry &entry, void *dst,
                        uint64_t dst_bytes, InvalidValues policy, const BlindSelection &blind) {
    check_capacity(path, entry.name, dst, dst_bytes, entry.grid_size);
    read_grid(path, entry, dst);
    return decode_in_place(path, entry.name, dst, entry.grid_size, policy, blind);
}

DecodedGrid decode_grid_bytes(const std::string &label, const std::string &name,
                              const void *src, uint64_t src_bytes, void *dst,
                              uint64_t dst_bytes, InvalidValues policy,
                              const BlindSelection &blind) {
    check_capacity(label, name, dst, dst_bytes, src_bytes);
    std::memcpy(dst, src, size_t(src_bytes));
    return decode_in_place(label, name, dst, src_bytes, policy, blind);
}

DecodedGrid to_index_grid(DecodedGrid d, void *dst, uint64_t dst_bytes, InvalidValues policy) {
    if (d.grid.is_index_grid())
        return d;
    const std::string path = d.grid.path(), name = d.grid.summary().name;
    MadeIndexGrid made = make_index_grid(d.grid);
    std::vector<std::string> warnings = std::move(d.warnings);
    if (made.inactive_differing)
        warnings.push_back("\"" + path + "\": grid \"" + name + "\": " +
                           std::to_string(made.inactive_differing) +
                           " inactive voxels hold values other than the background; as an index "
                           "grid (differentiable) it keeps the active voxels' values only, and "
                           "reads the background there");
    check_capacity(path, name, dst, dst_bytes, made.bytes.size());
    std::memcpy(dst, made.bytes.data(), made.bytes.size());
    DecodedGrid out = validate_in_place(path, name, dst, made.bytes.size(), policy,
                                        std::move(made.values), true);
    warnings.insert(warnings.end(), out.warnings.begin(), out.warnings.end());
    out.warnings = std::move(warnings);
    return out;
}

PreparedGrid prepare_grid(const GridSource &source, void *dst, uint64_t dst_bytes,
                          const PrepareOptions &options) {
    DecodedGrid d = source.entry ? decode_grid(source.path, *source.entry, dst, dst_bytes,
                                               options.invalid_values, options.blind)
                                 : decode_grid_bytes(source.path, source.name, source.bytes,
                                                     source.size, dst, dst_bytes,
                                                     options.invalid_values, options.blind);
    if (options.index_grid)
        d = to_index_grid(std::move(d), dst, dst_bytes, options.invalid_values);
    return prepare_bounds(std::move(d), options);
}

PreparedGrid rebound_index_grid(const std::string &path, const std::string &name,
                                const void *tree, uint64_t tree_bytes, IndexValues values,
                                const PrepareOptions &options) {
    return prepare_bounds(planned(validate_grid(path, tree, tree_bytes, values), name,
                                  tree_bytes, options.invalid_values),
                          options);
}

PreparedGrid prepare_bounds(DecodedGrid decoded, const PrepareOptions &options) {
    PreparedGrid p(std::move(decoded));
    const bool vec3 = vec3_values(p.grid);
    if (vec3 && options.spectral && p.grid.is_index_grid())
        detail::fail(p.grid.path(), "grid \"" + p.grid.summary().name +
                                        "\": Vec3f values of an index grid are colours, and a "
                                        "spectral variant would turn them into spectral "
                                        "coefficients, which gradients cannot pass through: "
                                        "use an RGB variant, or raw=true to read the three "
                                        "values as they are");
    p.box = options.volume_box ? lookup_box(*options.volume_box, options.ring)
                               : lookup_box(p.grid.summary(), options.ring);
    p.max = max_in_box(p.grid, p.box);
    p.max3 = vec3 ? max_in_box_per_channel(p.grid, p.box) : std::array<float, 3>{ p.max, p.max, p.max };
    p.grid_max = p.grid.values().max;
    p.majorants = node_majorants(p.grid, options.majorant_ring);
    p.mean_bound = mean_bound(p.grid, p.majorants, p.box, p.max);
    if (vec3 && options.spectral) {
        // Last: the bounds above are of the colours. A converted value is
        // scale * S(coefficients), S in [0, 1], scale at most factor x the
        // colour's largest channel: so are its bounds
        p.scales = to_spectral_coefficients(p.grid, *options.spectral);
        p.spectral_factor = options.spectral->factor;
        p.max *= p.spectral_factor;
        p.grid_max *= p.spectral_factor;
    }
    return p;
}

} // namespace nanovdb_loader
