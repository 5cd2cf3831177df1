// Majorants (src/loader/majorants.cpp): max_in_box() against NanoVDB's own
// accessor, which reads every coordinate of the box (the independent
// reference), and lookup_box().

#include <doctest/doctest.h>

#include "fixtures.h"

#include <nanovdb_loader/majorants.h>

#include <climits>
#include <random>

namespace {

/// The largest value NanoVDB's accessor returns over the box (NaN skipped)
float brute_max(const nanovdb::FloatGrid &grid, const nio::IndexBox &b) {
    auto acc = grid.getAccessor();
    float m = -std::numeric_limits<float>::infinity();
    for (int64_t i = b.lo[0]; i <= b.hi[0]; ++i)
        for (int64_t j = b.lo[1]; j <= b.hi[1]; ++j)
            for (int64_t k = b.lo[2]; k <= b.hi[2]; ++k) {
                const float v = acc.getValue(nanovdb::Coord(int32_t(i), int32_t(j), int32_t(k)));
                if (!std::isnan(v))
                    m = std::max(m, v);
            }
    return m;
}

nio::IndexBox box(int32_t x0, int32_t y0, int32_t z0, int32_t x1, int32_t y1, int32_t z1) {
    return { { x0, y0, z0 }, { x1, y1, z1 } };
}

/// Random boxes (sides 1..48) around `centre`, spread by `spread`
std::vector<nio::IndexBox> random_boxes(const std::array<int32_t, 3> &centre, int32_t spread,
                                        int count, uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::vector<nio::IndexBox> out;
    for (int n = 0; n < count; ++n) {
        nio::IndexBox b;
        for (int a = 0; a < 3; ++a) {
            b.lo[a] = centre[a] + int32_t(rng() % uint64_t(2 * spread + 1)) - spread;
            b.hi[a] = b.lo[a] + int32_t(rng() % 48);
        }
        out.push_back(b);
    }
    return out;
}

} // namespace

TEST_CASE("max_in_box equals the largest value NanoVDB's accessor reads in the box") {
    // Built once for all subcases (doctest re-runs this body for each)
    static const Handle sphere = fog_sphere(), torus = ls_torus(), tiles = tile_grid();
    struct Case { const char *name; const Handle *h; std::array<int32_t, 3> centre; int32_t spread; };
    const Case cases[] = {
        { "fog sphere", &sphere, { 2, 4, 6 }, 40 },
        { "level-set torus", &torus, { 0, 0, 0 }, 45 },
        { "tiles at every level", &tiles, { 0, 0, 128 }, 200 },
        { "tiles: root tile edge", &tiles, { -4096, 0, 0 }, 30 },
        { "tiles: lower tile edge", &tiles, { 8, 0, 0 }, 12 },
        { "tiles: far voxel", &tiles, { 5000, -300, 20 }, 24 },
    };
    for (const Case &c : cases) {
        SUBCASE(c.name) {
            const auto &grid = *c.h->grid<float>();
            const nio::ValidatedGrid v = validate_handle(*c.h, c.name);
            std::vector<nio::IndexBox> boxes = random_boxes(c.centre, c.spread, 60, 7);
            // The lookup boxes of both filters, where small enough to read whole
            for (bool trilinear : { false, true }) {
                const nio::IndexBox b = nio::lookup_box(v.summary(), trilinear);
                uint64_t n = 1;
                for (int a = 0; a < 3; ++a) n *= uint64_t(int64_t(b.hi[a]) - b.lo[a] + 1);
                if (n <= (uint64_t(1) << 22))
                    boxes.push_back(b);
            }
            size_t mismatches = 0;
            for (const nio::IndexBox &b : boxes) {
                const float got = nio::max_in_box(v, b), want = brute_max(grid, b);
                if (got != want && ++mismatches <= 5) {
                    INFO("box [" << b.lo[0] << " " << b.lo[1] << " " << b.lo[2] << "] - ["
                                 << b.hi[0] << " " << b.hi[1] << " " << b.hi[2] << "]");
                    CHECK(got == want);
                }
            }
            MESSAGE(std::string(c.name), ": ", boxes.size(), " boxes, ", mismatches, " mismatches");
            CHECK(mismatches == 0);
        }
    }
}

TEST_CASE("max_in_box: tight where the grid's maximum is not") {
    SUBCASE("a fog volume with its level set's background: the background only where the "
            "box leaves the tree") {
        // Voxels of 1 in a 16^3 box inside one leaf-aligned region, background 3
        openvdb::initialize();
        auto g = openvdb::FloatGrid::create(3.0f);
        g->tree().fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(15)), 1.0f, true);
        const Handle h = nanovdb::openToNanoVDB(*g);
        const nio::ValidatedGrid v = validate_handle(h, "fog");
        CHECK(v.values().max == 3.0f);
        CHECK(nio::max_in_box(v, nio::lookup_box(v.summary(), false)) == 1.0f); // nearest
        // The trilinear ring (-1 and 16) reaches voxels the tree stores as
        // inactive background values, 3
        CHECK(nio::max_in_box(v, nio::lookup_box(v.summary(), true)) == 3.0f);
        CHECK(brute_max(*h.grid<float>(), nio::lookup_box(v.summary(), true)) == 3.0f);
        // Far from every tile: the background alone
        CHECK(nio::max_in_box(v, box(100000, 0, 0, 100001, 1, 1)) == 3.0f);
        // Inside the voxels only
        CHECK(nio::max_in_box(v, box(3, 3, 3, 12, 12, 12)) == 1.0f);
    }
    SUBCASE("after sanitize_values the leaf maxima follow the new values") {
        const Handle h = nan_inf_grid();
        Aligned a(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        nio::ValidatedGrid v = nio::validate_grid("nans", a.data(), a.size);
        const nio::IndexBox b = box(-8, -8, -8, 8, 8, 8); // the +Inf voxel (2, 0, 0)
        CHECK(nio::max_in_box(v, b) == std::numeric_limits<float>::infinity());
        nio::sanitize_values(v);
        CHECK(nio::max_in_box(v, b) == 4.0f); // +Inf became the largest finite value
        CHECK(nio::max_in_box(v, box(0, 0, 0, 7, 7, 7)) == 4.0f); // whole leaf: leaf_max()
    }
}

TEST_CASE("lookup_box: the active box, grown by the trilinear ring, saturated at the int32 ends") {
    nio::GridSummary s;
    s.empty = false;
    for (int a = 0; a < 3; ++a) { s.bbox_min[a] = -5; s.bbox_max[a] = 9; }
    s.bbox_min[1] = INT32_MIN;
    s.bbox_max[2] = INT32_MAX;
    nio::IndexBox n = nio::lookup_box(s, false), t = nio::lookup_box(s, true);
    CHECK(n.lo[0] == -5); CHECK(n.hi[0] == 9);
    CHECK(t.lo[0] == -6); CHECK(t.hi[0] == 10);
    CHECK(t.lo[1] == INT32_MIN); CHECK(t.hi[1] == INT32_MAX); // the ring wraps: whole axis
    CHECK(t.lo[2] == INT32_MIN); CHECK(t.hi[2] == INT32_MAX);
    s.empty = true;
    n = nio::lookup_box(s, false);
    t = nio::lookup_box(s, true);
    for (int a = 0; a < 3; ++a) {
        CHECK(n.lo[a] == 0); CHECK(n.hi[a] == 0);
        CHECK(t.lo[a] == -1); CHECK(t.hi[a] == 1);
    }
}
