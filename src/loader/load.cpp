// src/loader/load.cpp -- decode_grid() (see load.h).

#include <nanovdb_loader/load.h>

#include "detail.h"

#include <cstring>

namespace nanovdb_loader {

DecodedGrid decode_grid(const std::string &path, const GridEntry &entry, void *dst,
                        uint64_t dst_bytes, InvalidValues policy) {
    if (dst_bytes < entry.grid_size)
        detail::fail(path, "grid \"" + entry.name + "\": a buffer of " +
                               std::to_string(dst_bytes) + " bytes cannot hold its " +
                               std::to_string(entry.grid_size) + " bytes");
    std::memset(static_cast<uint8_t *>(dst) + entry.grid_size, 0,
                size_t(dst_bytes - entry.grid_size));
    read_grid(path, entry, dst);
    DecodedGrid d{ validate_grid(path, dst, entry.grid_size), {}, {} };
    d.warnings = apply_value_policy(d.grid, entry.name, policy);
    d.plan = plan_readers(d.grid);
    return d;
}

} // namespace nanovdb_loader
