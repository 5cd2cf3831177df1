// The value policy (src/loader/values.cpp): where the first NaN / Inf /
// negative value sits, sanitize_values, and apply_value_policy.

#include <doctest/doctest.h>

#include "fixtures.h"

// Values: scan_values() and sanitize_values() (NaN / Inf / negative policy support)
// =====================================================================================

namespace {

/// OpenVDB grid with one chosen value at one level, converted by NanoVDB.
/// level 4: the background; 3: a root tile; 2: an upper-node tile; 1: a
/// lower-node tile; 0: a voxel. Plus an ordinary voxel (5, 5, 5) = 1.
Handle one_value_grid(int level, const openvdb::Coord &ijk, float value) {
    openvdb::initialize();
    auto g = openvdb::FloatGrid::create(level == 4 ? value : 0.f);
    g->setName("one_value");
    g->tree().setValueOn(openvdb::Coord(5, 5, 5), 1.0f);
    if (level >= 1 && level <= 3) g->tree().addTile(level, ijk, value, true);
    if (level == 0) g->tree().setValueOn(ijk, value);
    return nanovdb::openToNanoVDB(*g, nanovdb::StatsMode::Disable);
}

struct Counts { uint64_t nan = 0, posinf = 0, neginf = 0, negative = 0, all = 0; };

/// The same counts through NanoVDB's own node structs (every value a lookup
/// can return, see brute_force()).
Counts brute_counts(const nanovdb::FloatGrid &grid) {
    Counts c;
    auto add = [&](float v) {
        ++c.all;
        if (std::isnan(v)) ++c.nan;
        else if (v == std::numeric_limits<float>::infinity()) ++c.posinf;
        else if (v == -std::numeric_limits<float>::infinity()) ++c.neginf;
        else if (v < 0.f) ++c.negative;
    };
    const auto &tree = grid.tree();
    const auto &root = tree.root();
    add(root.background());
    for (uint32_t i = 0; i < root.tileCount(); ++i)
        if (!root.data()->tile(i)->isChild()) add(root.data()->tile(i)->value);
    const auto *upper = tree.getFirstNode<2>();
    for (uint32_t i = 0; i < tree.nodeCount(2); ++i)
        for (uint32_t n = 0; n < 32768; ++n)
            if (!upper[i].data()->isChild(n)) add(upper[i].data()->getValue(n));
    const auto *lower = tree.getFirstNode<1>();
    for (uint32_t i = 0; i < tree.nodeCount(1); ++i)
        for (uint32_t n = 0; n < 4096; ++n)
            if (!lower[i].data()->isChild(n)) add(lower[i].data()->getValue(n));
    const auto *leaf = tree.getFirstNode<0>();
    for (uint32_t i = 0; i < tree.nodeCount(0); ++i)
        for (uint32_t n = 0; n < 512; ++n) add(leaf[i].getValue(n));
    return c;
}

void check_counts(const nio::ValueScan &s, const nanovdb::FloatGrid &grid) {
    const Counts c = brute_counts(grid);
    CHECK(s.value_count == c.all);
    CHECK(s.nan_count == c.nan);
    CHECK(s.posinf_count == c.posinf);
    CHECK(s.neginf_count == c.neginf);
    CHECK(s.negative_count == c.negative);
    CHECK(s.has_nan == (c.nan > 0));
    CHECK(s.has_inf == (c.posinf + c.neginf > 0));
    CHECK(s.has_negative == (c.negative > 0));
}

std::array<int32_t, 3> xyz(const nio::ValueLocation &l) { return { l.ijk[0], l.ijk[1], l.ijk[2] }; }

} // namespace

TEST_CASE("scan_values: counts, and the coordinate of the first offending value") {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    const float inf = std::numeric_limits<float>::infinity();

    SUBCASE("voxels: NaN, +Inf, -Inf (GridBuilder grid)") {
        const Handle h = nan_inf_grid();
        const auto s = scan("nans", h.data(), h.size());
        check_counts(s, *h.grid<float>());
        CHECK(s.nan_count == 2);
        CHECK(s.posinf_count == 1);
        CHECK(s.neginf_count == 1);
        CHECK(s.negative_count == 0);
        REQUIRE(s.has_nan);
        CHECK(s.first_nan.level == 0);
        CHECK(xyz(s.first_nan) == std::array<int32_t, 3>{ 0, 0, 0 });
        CHECK(s.first_nan.reachable);
        REQUIRE(s.has_inf);
        CHECK(xyz(s.first_inf) == std::array<int32_t, 3>{ 2, 0, 0 });
        CHECK(s.finite_max == 4.0f);
        // The byte really holds the value
        float v;
        std::memcpy(&v, reinterpret_cast<const uint8_t *>(h.data()) + s.first_inf.byte, 4);
        CHECK(v == inf);
        CHECK(nio::describe_location(s.first_nan) == "voxel (0, 0, 0)");
        CHECK(nio::describe_invalid_values(s) ==
              "2 NaN (first: voxel (0, 0, 0)), 1 +Inf and 1 -Inf values "
              "(first infinite: voxel (2, 0, 0))");
        // Agrees with validate_grid's counts
        const auto info = validate_handle(h, "nans");
        CHECK(info.values().nan_count == s.nan_count);
        CHECK(info.values().inf_count() == s.posinf_count + s.neginf_count);
    }
    SUBCASE("a NaN at every level, negative coordinates: the lookup's coordinate") {
        struct Case { int level; openvdb::Coord ijk; std::array<int32_t, 3> expect; const char *text; };
        const Case cases[] = {
            { 0, openvdb::Coord(-1, -9, -4097), { -1, -9, -4097 }, "voxel (-1, -9, -4097)" },
            { 1, openvdb::Coord(-9, 130, 7), { -16, 128, 0 },
              "lower-node tile (8^3 voxels) at (-16, 128, 0)" },
            { 2, openvdb::Coord(-300, 5, -5), { -384, 0, -128 },
              "upper-node tile (128^3 voxels) at (-384, 0, -128)" },
            { 3, openvdb::Coord(-5000, 10, 4096), { -8192, 0, 4096 },
              "root tile (4096^3 voxels) at (-8192, 0, 4096)" },
            { 4, openvdb::Coord(0, 0, 0), { 0, 0, 0 }, "background" },
        };
        for (const Case &c : cases) {
            INFO("level " << c.level);
            const Handle h = one_value_grid(c.level, c.ijk, nan);
            const auto s = scan("one", h.data(), h.size());
            check_counts(s, *h.grid<float>());
            REQUIRE(s.has_nan);
            CHECK(s.first_nan.level == uint32_t(c.level));
            CHECK(xyz(s.first_nan) == c.expect);
            CHECK(nio::describe_location(s.first_nan) == c.text);
            // NanoVDB's own accessor reads the NaN at the reported coordinate
            if (c.level < 4) {
                auto acc = h.grid<float>()->getAccessor();
                CHECK(std::isnan(acc.getValue(nanovdb::Coord(c.expect[0], c.expect[1], c.expect[2]))));
            }
        }
    }
    SUBCASE("negatives: an inactive upper tile comes before the leaves") {
        const Handle h = tile_grid();
        const auto s = scan("tiles", h.data(), h.size());
        check_counts(s, *h.grid<float>());
        CHECK(s.nan_count == 0);
        CHECK(!s.has_inf);
        REQUIRE(s.has_negative);
        CHECK(s.negative_count == 2); // the -50 upper tile and the -2 voxel
        CHECK(s.first_negative.level == 2);
        CHECK(xyz(s.first_negative) == std::array<int32_t, 3>{ 0, 0, 128 });
        CHECK(s.finite_max == 100.0f);
    }
    SUBCASE("a level set's values are negative inside: counted, not an error") {
        const Handle h = ls_torus();
        const auto s = scan("torus", h.data(), h.size());
        check_counts(s, *h.grid<float>());
        CHECK(s.negative_count > 0);
        CHECK(s.first_negative.level == 0);
    }
    SUBCASE("clean grid; empty grid with a NaN background") {
        const Handle sphere = fog_sphere();
        const auto s = scan("sphere", sphere.data(), sphere.size());
        check_counts(s, *sphere.grid<float>());
        CHECK(!s.has_nan);
        CHECK(!s.has_inf);
        CHECK(!s.has_negative);
        nanovdb::GridBuilder<float> builder(nan, nanovdb::GridClass::FogVolume);
        const Handle e = builder.getHandle(1.0, nanovdb::Vec3d(0), "empty_nan");
        const auto se = scan("empty", e.data(), e.size());
        CHECK(se.value_count == 1);
        CHECK(se.nan_count == 1);
        CHECK(se.first_nan.level == 4);
        CHECK(se.finite_max == -inf);
    }
    SUBCASE("a node no root tile reaches: scanned, flagged unreachable") {
        // Turn the root tile that leads to the sphere's only upper node into a
        // value tile: the upper node (and everything below) is unreachable.
        const Handle sphere = fog_sphere();
        Bytes b = handle_bytes(sphere);
        const auto &grid = *sphere.grid<float>();
        const auto &root = grid.tree().root();
        REQUIRE(grid.tree().nodeCount(2) >= 1);
        const uint64_t leaf0 = offset_in(grid, grid.tree().getFirstNode<0>());
        poke<float>(b, leaf0 + 96 + 4 * 17, nan); // a NaN in the first leaf
        const auto before = scan("b", b.data(), b.size());
        REQUIRE(before.has_nan);
        CHECK(before.first_nan.reachable);
        for (uint32_t i = 0; i < root.tileCount(); ++i)
            poke<int64_t>(b, offset_in(grid, root.data()->tile(i)) + 8, 0);
        const auto after = scan("b", b.data(), b.size());
        REQUIRE(after.has_nan);
        CHECK(!after.first_nan.reachable);
        CHECK(xyz(after.first_nan) == xyz(before.first_nan));
        CHECK(nio::describe_location(after.first_nan).find("no root tile reaches") !=
              std::string::npos);
    }
    SUBCASE("invalid buffers: the validator's errors") {
        const Handle sphere = fog_sphere();
        Bytes b = handle_bytes(sphere);
        poke<uint64_t>(b, 672 + 24, b.size()); // root offset outside
        CHECK_IO_ERROR(scan("bad", b.data(), b.size()), "bad", "root node offset");
        CHECK_IO_ERROR(sanitize("bad", b.data(), b.size()), "bad", "root node offset");
    }
}

TEST_CASE("sanitize_values replaces NaN, Inf and negatives in place") {
    const float inf = std::numeric_limits<float>::infinity();
    SUBCASE("NaN -> 0, +Inf -> largest finite value, -Inf -> 0") {
        const Handle h = nan_inf_grid();
        Aligned a(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        const auto r = sanitize("nans", a.data(), a.size);
        CHECK(r.nan == 2);
        CHECK(r.posinf == 1);
        CHECK(r.neginf == 1);
        CHECK(r.negative == 0);
        CHECK(r.total() == 4);
        const auto info = nio::validate_grid("nans", a.data(), a.size);
        CHECK(info.values().nan_count == 0);
        CHECK(info.values().inf_count() == 0);
        CHECK(info.values().max == 4.0f);
        CHECK(info.values().min == 0.0f);
        // Read back with NanoVDB's accessor
        const auto *g = reinterpret_cast<const nanovdb::FloatGrid *>(a.data());
        auto acc = g->getAccessor();
        CHECK(acc.getValue(nanovdb::Coord(0, 0, 0)) == 0.0f);
        CHECK(acc.getValue(nanovdb::Coord(1, 0, 0)) == 0.0f);
        CHECK(acc.getValue(nanovdb::Coord(2, 0, 0)) == 4.0f);
        CHECK(acc.getValue(nanovdb::Coord(3, 0, 0)) == 4.0f);
        CHECK(acc.getValue(nanovdb::Coord(300, 0, 0)) == 0.0f);
        // Only those 4 values changed
        Bytes before = handle_bytes(h), after = a.bytes();
        size_t changed_words = 0;
        for (size_t i = 0; i < before.size(); i += 4)
            changed_words += std::memcmp(&before[i], &after[i], 4) != 0;
        CHECK(changed_words == 4);
        // Idempotent
        CHECK(sanitize("nans", a.data(), a.size).total() == 0);
    }
    SUBCASE("negatives: clamped to 0, or kept (then -Inf -> the lowest finite value)") {
        const Handle h = one_value_grid(2, openvdb::Coord(-300, 5, -5), -inf);
        Aligned a(h.size()), k(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        std::memcpy(k.data(), h.data(), h.size());
        const Handle t = tile_grid();
        Aligned ta(t.size());
        std::memcpy(ta.data(), t.data(), t.size());
        const auto rt = sanitize("tiles", ta.data(), ta.size);
        CHECK(rt.negative == 2);
        const auto it = nio::validate_grid("tiles", ta.data(), ta.size);
        CHECK(it.values().min == 0.0f);
        CHECK(it.values().max == 100.0f);
        CHECK(scan("tiles", ta.data(), ta.size).negative_count == 0);

        nio::SanitizeOptions keep;
        keep.clamp_negative = false;
        Aligned tk(t.size());
        std::memcpy(tk.data(), t.data(), t.size());
        CHECK(sanitize("tiles", tk.data(), tk.size, keep).total() == 0);
        CHECK(tk.bytes() == handle_bytes(t));

        const auto r = sanitize("neg", k.data(), k.size, keep);
        CHECK(r.neginf == 1);
        const auto *g = reinterpret_cast<const nanovdb::FloatGrid *>(k.data());
        CHECK(g->getAccessor().getValue(nanovdb::Coord(-300, 5, -5)) == 0.0f); // lowest finite: 0
        CHECK(sanitize("neg", a.data(), a.size).neginf == 1);
        CHECK(reinterpret_cast<const nanovdb::FloatGrid *>(a.data())
                  ->getAccessor().getValue(nanovdb::Coord(-300, 5, -5)) == 0.0f);
    }
    SUBCASE("only invalid values: +Inf -> 0") {
        nanovdb::GridBuilder<float> builder(std::numeric_limits<float>::quiet_NaN(),
                                            nanovdb::GridClass::FogVolume);
        builder.setStats(nanovdb::StatsMode::Disable);
        auto acc = builder.getAccessor();
        for (int i = 0; i < 8; ++i)
            for (int j = 0; j < 8; ++j)
                for (int k = 0; k < 8; ++k) acc.setValue(nanovdb::Coord(i, j, k), inf);
        const Handle h = builder.getHandle(1.0, nanovdb::Vec3d(0), "all_inf");
        Aligned a(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        sanitize("allinf", a.data(), a.size);
        const auto info = nio::validate_grid("allinf", a.data(), a.size);
        CHECK(info.values().min == 0.0f);
        CHECK(info.values().max == 0.0f);
    }
}

// =====================================================================================

TEST_CASE("sanitize_values keeps the grid's statistics true; apply_value_policy") {
    SUBCASE("after sanitizing, the statistics equal a fresh validation's") {
        const Handle h = tile_grid(); // negatives: -50 (upper tile), -2 (voxel)
        Aligned a(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        nio::ValidatedGrid grid = nio::validate_grid("tiles", a.data(), a.size);
        CHECK(grid.values().negative_count == 2);
        nio::sanitize_values(grid);
        const nio::ValidatedGrid fresh = nio::validate_grid("tiles", a.data(), a.size);
        const nio::ValueStats &x = grid.values(), &y = fresh.values();
        CHECK(x.min == y.min);
        CHECK(x.max == y.max);
        CHECK(x.finite_min == y.finite_min);
        CHECK(x.finite_max == y.finite_max);
        CHECK(x.value_count == y.value_count);
        CHECK(x.negative_count == 0);
        CHECK(y.negative_count == 0);
        CHECK(x.first_negative == nio::ValueStats::NONE);
    }
    SUBCASE("a read-only grid cannot be sanitized") {
        const Handle h = nan_inf_grid();
        nio::ValidatedGrid grid = nio::validate_grid("ro", static_cast<const void *>(h.data()),
                                                           h.size());
        CHECK_IO_ERROR(nio::sanitize_values(grid), "ro", "read-only");
    }
    SUBCASE("error: NaN/Inf refused, naming file, grid and the first voxel") {
        const Handle h = nan_inf_grid();
        Aligned a(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        nio::ValidatedGrid grid = nio::validate_grid("f.nvdb", a.data(), a.size);
        CHECK_IO_ERROR(nio::apply_value_policy(grid, "nan_inf", nio::InvalidValues::Error),
                       "f.nvdb", "grid \"nan_inf\"", "2 NaN (first: voxel (0, 0, 0))",
                       "1 +Inf and 1 -Inf", "invalid_values=\"clamp\"");
        CHECK(a.bytes() == handle_bytes(h)); // nothing written
    }
    SUBCASE("error: negatives load with a warning that locates the first") {
        const Handle h = tile_grid();
        Aligned a(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        nio::ValidatedGrid grid = nio::validate_grid("t.nvdb", a.data(), a.size);
        const auto warnings = nio::apply_value_policy(grid, "tiles", nio::InvalidValues::Error);
        REQUIRE(warnings.size() == 1);
        check_message(warnings[0], "t.nvdb",
                      { "grid \"tiles\"", "2 negative values", "upper-node tile (128^3 voxels) at (0, 0, 128)" });
        CHECK(a.bytes() == handle_bytes(h));
    }
    SUBCASE("clamp: replaced and counted; a clean grid costs nothing") {
        const Handle h = nan_inf_grid();
        Aligned a(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        nio::ValidatedGrid grid = nio::validate_grid("c.nvdb", a.data(), a.size);
        const auto warnings = nio::apply_value_policy(grid, "nan_inf", nio::InvalidValues::Clamp);
        REQUIRE(warnings.size() == 1);
        check_message(warnings[0], "c.nvdb", { "replaced 2 NaN by 0", "1 +Inf", "1 -Inf and 0 negative" });
        CHECK(grid.values().all_finite());
        CHECK(grid.values().max == 4.0f);
        CHECK(nio::apply_value_policy(grid, "nan_inf", nio::InvalidValues::Error).empty());
    }
}
