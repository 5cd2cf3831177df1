// src/loader/value_rewriter.h -- the one writer of a ValidatedGrid's values
// (a friend of the class). Internal to the loader: sanitize_values()
// (values.cpp) repairs values and brings their statistics up to date;
// to_spectral_coefficients() (spectral.cpp) turns Vec3f colours into
// sRGB-model coefficients, the last step of a load.
#pragma once

#include <nanovdb_loader/validation.h>

#include "detail.h"

#include <utility>
#include <vector>

namespace nanovdb_loader {

struct ValueRewriter {
    /// The buffer, for writing values that stay values (sanitize_values);
    /// Error if it was validated as read-only or holds coefficients
    static uint8_t *data(ValidatedGrid &grid) {
        writable(grid);
        return grid.m_data;
    }
    /// Index grids: the background's value, channel k (not in the values array)
    static void set_index_background(ValidatedGrid &grid, uint32_t k, float background) {
        grid.m_index.background[k] = background;
    }
    static void set_values(ValidatedGrid &grid, const ValueStats &stats,
                           std::vector<float> leaf_min, std::vector<float> leaf_max) {
        grid.m_values = stats;
        grid.m_leaf_min = std::move(leaf_min);
        grid.m_leaf_max = std::move(leaf_max);
    }

    /// The buffer, for rewriting every colour of a Vec3f grid as spectral
    /// coefficients (once): afterwards grid.holds_coefficients(), and its
    /// statistics still describe the colours
    static uint8_t *coefficients(ValidatedGrid &grid) {
        writable(grid);
        if (grid.summary().grid_type != layout::GRID_TYPE_VEC3F)
            detail::fail(grid.m_path, "internal error: a spectral rewrite of a grid of type " +
                                          grid_type_name(grid.summary().grid_type) +
                                          " (only Vec3f colours have one)");
        grid.m_coefficients = true;
        return grid.m_data;
    }

private:
    static void writable(const ValidatedGrid &grid) {
        if (!grid.m_writable)
            detail::fail(grid.m_path, "internal error: values rewritten in a grid "
                                      "validated from a read-only buffer");
        if (grid.m_coefficients)
            detail::fail(grid.m_path, "internal error: values rewritten in a grid that "
                                      "already holds spectral coefficients");
    }
};

} // namespace nanovdb_loader
