// nanovdb_loader/load.h -- the one decode path from a file entry to a grid
// that the traversal can read:
//
//   read_grid (container.h) -> validate_grid (validation.h)
//   -> apply_value_policy (values.h) -> plan_readers (reader_policy.h)
//
// and, for a renderer, the one call that also prepares its bounds:
//
//   prepare_grid: decode -> max_in_box (+ per channel) -> node_majorants
//   -> mean_bound (majorants.h) -> spectral rewrite (spectral.h)
//
// The plugin runs it into the memory the backend will own, the fuzzer into a
// guarded buffer; both get the same validated grid and the same reader plan.
#pragma once

#include <nanovdb_loader/container.h>
#include <nanovdb_loader/index_grid.h>
#include <nanovdb_loader/majorants.h>
#include <nanovdb_loader/reader_policy.h>
#include <nanovdb_loader/spectral.h>
#include <nanovdb_loader/validation.h>
#include <nanovdb_loader/values.h>
#include <nanovdb_drjit/layout.h>

#include <array>
#include <optional>
#include <string>
#include <vector>

namespace nanovdb_loader {

struct DecodedGrid {
    ValidatedGrid grid;                ///< a view of the caller's buffer
    ReaderPlan plan;
    std::vector<std::string> warnings; ///< from the value policy, to be shown
    /// Index grids: the values grid.index_values() points into (owned here:
    /// a moved DecodedGrid keeps them where they are), and where they came from
    std::vector<float> index_values;
    std::string index_note;
    uint64_t grid_bytes = 0;           ///< of the grid in the buffer (an index
                                       ///  grid's tree, without blind data)
};

/// Decodes `entry` of the file `path` into `dst` (capacity `dst_bytes` >=
/// entry.grid_size; the rest is zeroed), validates it once, applies the
/// value policy and plans the readers. An index grid's values come from its
/// blind data (`blind`), which is then dropped from the grid
/// (take_blind_values). Throws Error naming the file.
DecodedGrid decode_grid(const std::string &path, const GridEntry &entry, void *dst,
                        uint64_t dst_bytes, InvalidValues policy,
                        const BlindSelection &blind = {});

/// The same for the grid `name` in memory (build.h's buffer), copied into
/// `dst`: `label` names its source in errors, as a path would
DecodedGrid decode_grid_bytes(const std::string &label, const std::string &name,
                              const void *src, uint64_t src_bytes, void *dst,
                              uint64_t dst_bytes, InvalidValues policy,
                              const BlindSelection &blind = {});

/// A decoded scalar grid made into an index grid (make_index_grid), written
/// over it into `dst` (capacity `dst_bytes`; an index grid is smaller than
/// its grid unless the grid has no leaves: 32 bytes more), validated with its
/// values. An index grid is returned as it is.
DecodedGrid to_index_grid(DecodedGrid grid, void *dst, uint64_t dst_bytes, InvalidValues policy);

/// Where prepare_grid() takes a grid from: a file's entry (decode_grid) or
/// a grid in memory (decode_grid_bytes)
struct GridSource {
    std::string path;                  ///< the file, or the label naming the source in errors
    const GridEntry *entry = nullptr;  ///< a file's grid; null: `bytes`
    std::string name;                  ///< bytes: the grid's name in messages
    const void *bytes = nullptr;
    uint64_t size = 0;

    static GridSource file(const std::string &path, const GridEntry &entry) {
        return { path, &entry, entry.name, nullptr, 0 };
    }
    static GridSource memory(const std::string &label, const std::string &name,
                             const void *bytes, uint64_t size) {
        return { label, nullptr, name, bytes, size };
    }
};

struct PrepareOptions {
    InvalidValues invalid_values = InvalidValues::Error;
    /// The volume's index box (inclusive); none: the grid's active box
    std::optional<IndexBox> volume_box;
    /// Lookups reach this many voxels around the box (0: nearest, or
    /// clamped to the box; 1: trilinear; 2: tricubic): lookup_box()
    int ring = 0;
    /// The ring of the node majorants: the voxels a lookup at a point of a
    /// node may read beyond it (1, 2 for tricubic): node_majorants()
    int majorant_ring = 1;
    /// Vec3f grids of a spectral variant: colours into coefficients (others
    /// ignore it)
    std::optional<SpectralConversion> spectral;
    /// Make a scalar grid an index grid of its active values (to_index_grid):
    /// the differentiable form of a volume
    bool index_grid = false;
    /// Index grids from files: the blind channel holding their values
    BlindSelection blind;
};

/// Whether `grid`'s values are 3-vectors: a Vec3f grid, or an index grid of
/// three floats a value
inline bool vec3_values(const ValidatedGrid &grid) {
    return grid.summary().grid_type == nanovdb_drjit::layout::GRID_TYPE_VEC3F ||
           grid.index_values().channels == 3;
}

/// A decoded grid and what a renderer needs to bound its lookups
struct PreparedGrid : DecodedGrid {
    explicit PreparedGrid(DecodedGrid decoded) : DecodedGrid(std::move(decoded)) {}

    IndexBox box{};          ///< lookup_box(): the coordinates lookups read
    /// 1, or SpectralConversion::factor where the colours were converted:
    /// what bounds the converted values from the colours' bounds
    float spectral_factor = 1.f;
    float max = 0.f;         ///< max_in_box(box) x spectral_factor: max()
    /// max_in_box_per_channel(box) of the colours (not scaled); a scalar
    /// grid's max_in_box three times
    std::array<float, 3> max3{};
    float grid_max = 0.f;    ///< ValueStats::max x spectral_factor
    /// Of the stored values (the colours): the plugin scales them by
    /// spectral_factor, and by 1 + 2^-20 for rounding, into its MajorantGrid
    NodeMajorants majorants;
    /// mean_bound(majorants, box, clamp = max / spectral_factor), as it
    /// returns it: of the stored values (x spectral_factor for the plugin's)
    double mean_bound = 0.0;
    SpectralScales scales;   ///< where the colours were converted
};

/// decode_grid / decode_grid_bytes into `dst` (to_index_grid with
/// options.index_grid), then the bounds (max of the lookup box, per channel,
/// per node, their mean) and, last, the spectral rewrite. Throws Error
/// naming the source.
PreparedGrid prepare_grid(const GridSource &source, void *dst, uint64_t dst_bytes,
                          const PrepareOptions &options);

/// The bounds of prepare_grid() (box, max, per node, mean) for a decoded
/// grid: what an index grid's values need again after they change
PreparedGrid prepare_bounds(DecodedGrid decoded, const PrepareOptions &options);

/// An index grid whose values changed (an optimizer's step): the tree at
/// `tree` (made by prepare_grid, `tree_bytes` bytes) validated again with
/// `values` (the caller's, kept where they are: the result does not own
/// them; the tree is only read), the value policy applied to them, the reader plan, then
/// prepare_bounds(). `path` and `name` name the volume in errors.
PreparedGrid rebound_index_grid(const std::string &path, const std::string &name,
                                const void *tree, uint64_t tree_bytes, IndexValues values,
                                const PrepareOptions &options);

} // namespace nanovdb_loader
