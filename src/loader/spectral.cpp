// src/loader/spectral.cpp -- to_spectral_coefficients() (see spectral.h).

#include <nanovdb_loader/spectral.h>

#include "tree_view.h"
#include "value_rewriter.h"

#include <cstring>

namespace nanovdb_loader {

using namespace detail;

SpectralScales to_spectral_coefficients(ValidatedGrid &grid, const SpectralConversion &conversion) {
    uint8_t *buf = ValueRewriter::coefficients(grid);
    const TreeView view(grid);
    // The colour at byte `at` becomes coefficients; returns its scale
    auto convert = [&](uint64_t at) {
        float rgb[3], coeff[3];
        std::memcpy(rgb, buf + at, 12);
        const float scale = conversion.convert(rgb, coeff);
        std::memcpy(buf + at, coeff, 12);
        return scale;
    };
    const uint64_t leaves = view.node_count(0);
    SpectralScales s;
    s.tiles_begin = uint32_t(leaves * layout::LEAF_TABLE_COUNT);
    s.background = s.tiles_begin + view.tile_count();
    s.values.assign(size_t(s.background) + 1, 0.f);
    s.leaf_begin_word = uint32_t(grid.summary().node_begin[0] / 4);
    s.tile_begin_word = uint32_t(view.tile(0) / 4);
    for (uint64_t n = 0; n < leaves; ++n)
        for (uint32_t v = 0; v < layout::LEAF_TABLE_COUNT; ++v)
            s.values[size_t(n * layout::LEAF_TABLE_COUNT + v)] =
                convert(view.node(0, n) + view.level(0).table_off + 12 * uint64_t(v));
    // Internal tiles keep their scale in the entry's fourth word
    view.for_each_tile_value([&](uint64_t at, int level, uint32_t) {
        if (level == 1 || level == 2) {
            const float scale = convert(at);
            std::memcpy(buf + at + 12, &scale, 4);
        }
    });
    // Every root tile (the value of one with a child is never read)
    for (uint32_t t = 0; t < view.tile_count(); ++t)
        s.values[s.tiles_begin + t] = convert(view.tile_value(t));
    s.values[s.background] = convert(view.background());
    return s;
}

} // namespace nanovdb_loader
