// src/loader/load.cpp -- decode_grid() and prepare_grid() (see load.h).

#include <nanovdb_loader/load.h>

#include "detail.h"

#include <cstring>

namespace nanovdb_loader {

namespace {

/// What both sources share once the bytes are in `dst`
DecodedGrid decode_in_place(const std::string &path, const std::string &name, void *dst,
                            uint64_t grid_bytes, InvalidValues policy) {
    DecodedGrid d{ validate_grid(path, dst, grid_bytes), {}, {} };
    d.warnings = apply_value_policy(d.grid, name, policy);
    d.plan = plan_readers(d.grid);
    return d;
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
                        uint64_t dst_bytes, InvalidValues policy) {
    check_capacity(path, entry.name, dst, dst_bytes, entry.grid_size);
    read_grid(path, entry, dst);
    return decode_in_place(path, entry.name, dst, entry.grid_size, policy);
}

DecodedGrid decode_grid_bytes(const std::string &label, const std::string &name,
                              const void *src, uint64_t src_bytes, void *dst,
                              uint64_t dst_bytes, InvalidValues policy) {
    check_capacity(label, name, dst, dst_bytes, src_bytes);
    std::memcpy(dst, src, size_t(src_bytes));
    return decode_in_place(label, name, dst, src_bytes, policy);
}

PreparedGrid prepare_grid(const GridSource &source, void *dst, uint64_t dst_bytes,
                          const PrepareOptions &options) {
    PreparedGrid p(source.entry ? decode_grid(source.path, *source.entry, dst, dst_bytes,
                                              options.invalid_values)
                                : decode_grid_bytes(source.path, source.name, source.bytes,
                                                    source.size, dst, dst_bytes,
                                                    options.invalid_values));
    const bool vec3 = p.grid.summary().grid_type == layout::GRID_TYPE_VEC3F;
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
