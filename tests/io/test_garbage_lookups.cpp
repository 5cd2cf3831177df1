// Validated but garbage buffers: whatever a mutated grid that passes
// validation holds, lookups through the plugin's readers (the loader's reader
// plan, and the faithful PNanoVDB path) never leave the buffer.

#include <doctest/doctest.h>

#include "fixtures.h"
#include "guarded_buffer.h"

#include <optional>
#include <random>

#include <nanovdb_drjit/fast_readers.h>
#include <nanovdb_drjit/pnanovdb.h>
#include <nanovdb_drjit/stencil.h>
#include <nanovdb_loader/reader_policy.h>

TEST_CASE("validated but garbage buffers: lookups never leave the buffer") {
    namespace ndr = nanovdb_drjit;
    const Handle grids[] = { fog_sphere(), tile_grid(), nan_inf_grid() };
    std::mt19937_64 rng(5);
    uint64_t valid = 0, lookups = 0;
    for (const Handle &h : grids) {
        const auto &grid = *h.grid<float>();
        const uint64_t size = h.size();
        nvdb_test::GuardedBuffer g(size);
        std::memcpy(g.data(), h.data(), size);
        const uint64_t words = (size + 3) / 4;
        const uint64_t tree_end = 736;
        for (int m = 0; m < 1500; ++m) {
            // Mutate a few bytes anywhere past the grid header (tree header
            // included); remember them to restore afterwards.
            std::vector<std::pair<uint64_t, uint8_t>> saved;
            const int k = 1 + int(rng() % 8);
            for (int i = 0; i < k; ++i) {
                uint64_t off = 672 + rng() % (size - 672);
                if (rng() % 4 == 0) off = 672 + rng() % (tree_end - 672 + 600); // header, root, tiles
                saved.push_back({ off, g.data()[off] });
                g.data()[off] = uint8_t(rng() % 3 == 0 ? g.data()[off] ^ (1u << (rng() % 8)) : rng());
            }
            std::optional<nio::ValidatedGrid> validated;
            try {
                validated = nio::validate_grid("mutant", g.data(), size);
            } catch (const nio::Error &) {
            }
            if (validated) {
                ++valid;
                const uint32_t *buf = reinterpret_cast<const uint32_t *>(g.data());
                // The plugin's readers for this grid, and PNanoVDB's own algorithm
                const nio::ReaderPlan plan = nio::plan_readers(*validated);
                const auto fast = ndr::Reader<uint32_t>::from_plan(plan),
                           faithful = ndr::Reader<uint32_t>::from_plan(plan.faithful());
                for (int q = 0; q < 64; ++q) {
                    int32_t c[3];
                    for (int a = 0; a < 3; ++a) {
                        const uint64_t r = rng();
                        // near the bbox minimum (INT32_MAX for an empty bbox: wrap)
                        c[a] = (r & 1) ? int32_t(r >> 32)
                                       : int32_t(uint32_t(grid.indexBBox().min()[a]) +
                                                 uint32_t((r >> 8) % 300) - 100u);
                        if (c[a] == INT32_MAX) c[a] = 0;
                    }
                    ndr::Coord<uint32_t> ijk(c[0], c[1], c[2]);
                    for (const auto *reader : { &fast, &faithful }) {
                        reader->apply(buf, [&](const auto &b, const auto &root) {
                            const uint32_t a = ndr::root_get_value_address(b, root, ijk, true);
                            const auto st = ndr::root_get_stencil_addresses(b, root, ijk, true);
                            bool inside = a < words;
                            for (int s = 0; s < 8; ++s) inside &= st[s] < words;
                            if (!inside) {
                                INFO("mutant " << m << " ijk " << c[0] << " " << c[1] << " "
                                               << c[2] << (reader == &fast ? " (plan)" : ""));
                                CHECK(inside);
                            }
                        });
                        ++lookups;
                    }
                }
                (void) nio::scan_values(*validated);
            }
            for (auto it = saved.rbegin(); it != saved.rend(); ++it) g.data()[it->first] = it->second;
        }
    }
    MESSAGE(valid, " of 4500 mutated buffers validated; ", lookups,
            " lookups (1 + 8 addresses each, planned and faithful readers) stayed inside");
    CHECK(valid > 500);
}
