// nanovdb_loader/spectral.h -- the spectral rewrite of a Vec3f grid: every
// colour becomes the coefficients of a spectrum model and a scale, in place.
//
// Spectral variants of Mitsuba render a colour as scale * S(coefficients),
// with S Mitsuba's sRGB model (srgb_model_fetch / srgb_model_eval): 4
// numbers instead of 3. The coefficients replace the colour in the grid, so
// the tree is not copied, and each scale goes where the grid has room: an
// internal node's table entry is 16 bytes for 12 of value (the scale is its
// fourth word); the others (leaf values, root tiles, the background) into
// one array beside the grid: 4 bytes per leaf voxel, +33 % of the leaf
// bytes (the price of the fourth number, as for Mitsuba's gridvolume).
//
// The loader knows no spectrum model: the caller passes the conversion.
#pragma once

#include <nanovdb_loader/validation.h>

#include <cstdint>
#include <functional>
#include <vector>

namespace nanovdb_loader {

struct SpectralConversion {
    /// Writes the coefficients of `rgb` into `coeff` and returns its scale
    /// (Mitsuba: scale = 2 max(rgb), coefficients of rgb / scale)
    std::function<float(const float rgb[3], float coeff[3])> convert;
    /// A bound of scale / max(rgb) (Mitsuba's: 2): as S <= 1, a converted
    /// value is at most `factor` times its colour's largest channel
    float factor = 2.f;
};

/// The scale of every value outside the internal nodes, in one array
struct SpectralScales {
    /// Leaf values (512 per leaf, leaf array order), then every root tile
    /// (table order, with a child or not), then the background
    std::vector<float> values;
    uint32_t tiles_begin = 0; ///< index of root tile 0's scale (512 x leaves)
    uint32_t background = 0;  ///< index of the background's scale (the last)
    /// Where lookups find a value's index from its address: the word
    /// address of the first leaf, and of the first root tile
    uint32_t leaf_begin_word = 0, tile_begin_word = 0;
};

/// Rewrites every colour of a Vec3f grid (every value validation counts,
/// and the values of root tiles with a child) as coefficients, in place,
/// and returns the scales of those outside the internal nodes. Once per
/// grid, the last thing done to its values (grid.holds_coefficients()
/// afterwards); Error for another type or a read-only grid.
SpectralScales to_spectral_coefficients(ValidatedGrid &grid, const SpectralConversion &conversion);

} // namespace nanovdb_loader
