// nanovdb_loader/load.h -- the one decode path from a file entry to a grid
// that the traversal can read:
//
//   read_grid (container.h) -> validate_grid (validation.h)
//   -> apply_value_policy (values.h) -> plan_readers (reader_policy.h)
//
// The plugin runs it into the memory the backend will own, the fuzzer into a
// guarded buffer; both get the same validated grid and the same reader plan.
#pragma once

#include <nanovdb_loader/container.h>
#include <nanovdb_loader/reader_policy.h>
#include <nanovdb_loader/validation.h>
#include <nanovdb_loader/values.h>

#include <string>
#include <vector>

namespace nanovdb_loader {

struct DecodedGrid {
    ValidatedGrid grid;                ///< a view of the caller's buffer
    ReaderPlan plan;
    std::vector<std::string> warnings; ///< from the value policy, to be shown
};

/// Decodes `entry` of the file `path` into `dst` (capacity `dst_bytes` >=
/// entry.grid_size; the rest is zeroed), validates it once, applies the
/// value policy and plans the readers. Throws Error naming the file.
DecodedGrid decode_grid(const std::string &path, const GridEntry &entry, void *dst,
                        uint64_t dst_bytes, InvalidValues policy);

/// The same for the grid `name` in memory (build.h's buffer), copied into
/// `dst`: `label` names its source in errors, as a path would
DecodedGrid decode_grid_bytes(const std::string &label, const std::string &name,
                              const void *src, uint64_t src_bytes, void *dst,
                              uint64_t dst_bytes, InvalidValues policy);

} // namespace nanovdb_loader
