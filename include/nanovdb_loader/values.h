// nanovdb_loader/values.h -- the value policy: NaN, infinities, negatives.
//
// Validation (validation.h) has already counted every value a lookup can
// return and remembered where the first NaN, infinite and negative value sit.
// This module turns that into what a renderer needs:
//  * apply_value_policy(): refuse, warn about or repair a grid, following the
//    plugin's invalid_values setting, with messages that name the file, the
//    grid and the first offending voxel;
//  * locate_value() / scan_values(): the index coordinate of a value, found
//    by walking the tree from the root tiles' keys (never from the nodes'
//    stored bounding boxes, which lookups do not read): a voxel for a leaf
//    value; for a tile, the first (minimum) voxel of the 8^3 (lower), 128^3
//    (upper) or 4096^3 (root) block it covers. A node reached by no root tile
//    gets the origin stored in its own bbox (rounded down to the node size)
//    and is flagged unreachable;
//  * sanitize_values(): replaces invalid values in place, in one pass that
//    also brings the grid's ValueStats up to date.
#pragma once

#include <nanovdb_loader/validation.h>

#include <cstdint>
#include <string>
#include <vector>

namespace nanovdb_loader {

/// Where a value sits: its level (PNanoVDB's codes) and index coordinate.
struct ValueLocation {
    /// 0 leaf voxel, 1 lower-node tile (8^3 voxels), 2 upper-node tile
    /// (128^3), 3 root tile (4096^3), 4 the background (no coordinate).
    uint32_t level = 4;
    int32_t  ijk[3] = { 0, 0, 0 }; ///< voxel, or the tile's minimum voxel
    uint64_t byte = 0;             ///< byte offset of the value in the grid buffer
                                   ///< (quantized leaves: of their code table)
    bool     reachable = true;     ///< false: in a node that no root tile reaches
};

/// The location of a value that ValueStats counts, from its key (e.g.
/// ValueStats::first_nan: a byte offset, or a leaf value key). O(internal nodes).
ValueLocation locate_value(const ValidatedGrid &grid, uint64_t key);

/// "voxel (1, -2, 3)", "lower-node tile (8^3 voxels) at (8, 0, 0)",
/// "upper-node tile (128^3 voxels) at ...", "root tile (4096^3 voxels) at
/// ...", "background"; unreachable nodes add ", in a node no root tile reaches".
std::string describe_location(const ValueLocation &l);

/// The grid's ValueStats with the first offending values located
struct ValueScan {
    uint64_t value_count = 0;    ///< values examined (validation.h, "Which values")
    uint64_t nan_count = 0;      ///< NaN (any payload, either sign)
    uint64_t posinf_count = 0;   ///< +Inf
    uint64_t neginf_count = 0;   ///< -Inf
    uint64_t negative_count = 0; ///< finite and < 0 (-0.0 is not negative; -Inf is not counted here)
    bool has_nan = false, has_inf = false, has_negative = false;
    ValueLocation first_nan, first_inf, first_negative; ///< valid where has_*
    /// Largest finite value (-Inf if there is none): what sanitize_values()
    /// puts in place of +Inf.
    float finite_max = 0.f;
};

/// Locates the first NaN, infinite and negative values that validation
/// found. Reads no value: O(internal nodes).
ValueScan scan_values(const ValidatedGrid &grid);

/// "3 NaN (first: voxel (1, 2, 3)), 1 +Inf and 0 -Inf values (first
/// infinite: background)": the part of a load error that scan_values() fills.
std::string describe_invalid_values(const ValueScan &s);

/// What sanitize_values() does with each kind of value.
struct SanitizeOptions {
    /// Replace finite negative values (and -Inf) by 0. Without it, negatives
    /// are kept and -Inf becomes the lowest finite value of the grid.
    bool clamp_negative = true;
};

/// Counts of the replacements made by sanitize_values().
struct SanitizeResult {
    uint64_t nan = 0, posinf = 0, neginf = 0, negative = 0;
    uint64_t total() const { return nan + posinf + neginf + negative; }
};

/// Replaces invalid values in place (every value validation counts):
///   NaN       -> 0 (no medium: the neutral density);
///   +Inf      -> the largest finite value of the grid (0 if there is none).
///                Not FLT_MAX: the medium's majorant is scale * max(), and a
///                majorant near FLT_MAX makes delta tracking take steps of
///                1e-38 (it never leaves the volume) or overflows to Inf;
///   -Inf      -> 0 with clamp_negative, else the lowest finite value;
///   negative  -> 0 with clamp_negative (a density cannot be negative; a
///                negative majorant breaks tracking), else kept.
/// Half values are written back as halves. A quantized leaf (Fp4/8/16/FpN)
/// holding an invalid value is encoded again, at its code width, from its
/// repaired values: minimum, quantum = (max - min) / (2^bits - 1), codes
/// rounded to nearest; its other values move by at most quantum / 2.
/// One pass; grid.values() describes the new values afterwards (as decoded).
SanitizeResult sanitize_values(ValidatedGrid &grid, const SanitizeOptions &options = {});

/// The plugin's invalid_values setting
enum class InvalidValues {
    Error, ///< refuse NaN and infinite values; warn about negative ones
    Clamp  ///< sanitize_values() with clamp_negative, and warn
};

/// Applies the policy to a grid named `grid_name` in messages: throws Error
/// (naming the file, the grid and the first offending value) or returns the
/// warnings to show (none for a clean grid, which costs nothing here).
std::vector<std::string> apply_value_policy(ValidatedGrid &grid, const std::string &grid_name,
                                            InvalidValues policy);

} // namespace nanovdb_loader
