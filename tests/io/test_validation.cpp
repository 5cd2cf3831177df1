// Validation (src/loader/validation.cpp): validate_grid's summary and
// value statistics against NanoVDB's C++ API, and its refusals of hostile
// buffers.

#include <doctest/doctest.h>

#include "fixtures.h"
#include <typed_grids.h>

#include <nanovdb_loader/values.h>

#include <cstdio>

TEST_CASE("validate_grid on NanoVDB-made float grids") {
    // Built once for all subcases (doctest re-runs this body for each)
    static const Handle sphere = fog_sphere(), torus = ls_torus(), tiles = tile_grid(),
                        nans = nan_inf_grid(), empty = empty_grid();

    SUBCASE("fog sphere") {
        const auto *grid = sphere.grid<float>();
        REQUIRE(grid);
        const auto info = validate_handle(sphere, "sphere");
        check_info_against_nanovdb(info, *grid);
        CHECK(info.summary().name == "density");
        CHECK(info.summary().grid_class == uint32_t(nanovdb::GridClass::FogVolume));
        CHECK(!info.summary().empty);
        // NanoVDB 32.4's createFogVolumeSphere keeps the level set's
        // background (half width 3 x voxel size 0.5) in the root: a lookup
        // far outside returns 1.5, above every voxel value (0..1). This is
        // why value_max must include the background.
        CHECK(info.summary().background == 1.5f);
        CHECK(info.values().min == 0.0f);
        CHECK(info.values().max == 1.5f);
        CHECK(info.summary().voxel_size[0] == 0.5);
        CHECK(info.summary().map_vec[0] == 0.25);
    }
    SUBCASE("level-set torus") {
        const auto info = validate_handle(torus, "torus");
        check_info_against_nanovdb(info, *torus.grid<float>());
        CHECK(info.summary().background == 3.0f); // half width 3 x voxel size 1
        CHECK(info.values().max == 3.0f);
        CHECK(info.values().min == -3.0f);
    }
    SUBCASE("tiles at every level (OpenVDB)") {
        const auto *grid = tiles.grid<float>();
        REQUIRE(grid);
        const auto info = validate_handle(tiles, "tiles");
        check_info_against_nanovdb(info, *grid);
        CHECK(info.values().max == 100.0f); // the root tile
        CHECK(info.values().min == -50.0f); // the inactive upper tile
        CHECK(info.summary().background == 0.5f);
        CHECK(info.summary().bbox_min[0] == -4096);
        CHECK(info.summary().voxel_size[1] == 0.25);
        // The grid really has a tile at each level.
        const auto &root = grid->tree().root();
        bool root_tile = false;
        for (uint32_t i = 0; i < root.tileCount(); ++i)
            root_tile |= !root.data()->tile(i)->isChild();
        CHECK(root_tile);
    }
    SUBCASE("NaN and Inf values, no statistics") {
        const auto info = validate_handle(nans, "nans");
        check_info_against_nanovdb(info, *nans.grid<float>());
        CHECK(info.values().nan_count == 2);
        CHECK(info.values().inf_count() == 2);
        CHECK(info.values().min == -std::numeric_limits<float>::infinity());
        CHECK(info.values().max == std::numeric_limits<float>::infinity());
    }
    SUBCASE("empty grid") {
        const auto info = validate_handle(empty, "empty");
        check_info_against_nanovdb(info, *empty.grid<float>());
        CHECK(info.summary().empty);
        CHECK(info.summary().node_count[0] == 0);
        CHECK(info.summary().node_count[2] == 0);
        CHECK(info.values().min == 1.5f);
        CHECK(info.values().max == 1.5f);
    }
    SUBCASE("buffer larger than the grid: only the first grid is used") {
        Bytes b = handle_bytes(sphere);
        const Bytes t = handle_bytes(torus);
        b.insert(b.end(), t.begin(), t.end());
        const auto info = nio::validate_grid("two", b.data(), b.size());
        check_info_against_nanovdb(info, *sphere.grid<float>());
    }
}

// =====================================================================================
TEST_CASE("validate_grid rejects hostile buffers") {
    static const Handle sphere = fog_sphere();
    static const Handle tiles = tile_grid();
    const auto &grid = *sphere.grid<float>();
    const auto &tree = grid.tree();
    const auto &root = tree.root();
    static const Bytes good = handle_bytes(sphere);
    const std::string p = "hostile.nvdb";
    REQUIRE(tree.nodeCount(0) > 0);
    REQUIRE(tree.nodeCount(1) > 0);
    REQUIRE(tree.nodeCount(2) > 0);
    const uint64_t tree_off = offset_in(grid, &tree);
    const uint64_t root_off = offset_in(grid, &root);
    const uint64_t upper0 = offset_in(grid, tree.getFirstNode<2>());
    const uint64_t lower0 = offset_in(grid, tree.getFirstNode<1>());
    const uint64_t leaf0 = offset_in(grid, tree.getFirstNode<0>());
    CHECK(tree_off == 672);

    auto validate = [&](const Bytes &b) { return nio::validate_grid(p, b.data(), b.size()); };
    CHECK_NOTHROW(validate(good));

    SUBCASE("too small") {
        Bytes b(good.begin(), good.begin() + 700);
        CHECK_IO_ERROR(validate(b), p, "700 bytes", "too small");
        CHECK_IO_ERROR(nio::validate_grid(p, static_cast<const void *>(nullptr), 0), p, "too small");
    }
    SUBCASE("16 GiB or more") {
        // Rejected from the size alone, before any byte is read.
        CHECK_IO_ERROR(nio::validate_grid(p, good.data(), uint64_t(1) << 34), p, "16 GiB");
    }
    SUBCASE("wrong magic") {
        Bytes b = good;
        std::memcpy(b.data(), "NotAGrid", 8);
        CHECK_IO_ERROR(validate(b), p, "not a NanoVDB grid", "NotAGrid");
        std::memcpy(b.data(), "NanoVDB2", 8); // a file magic, not a grid magic
        CHECK_IO_ERROR(validate(b), p, "NanoVDB2");
    }
    SUBCASE("byte-swapped magic") {
        Bytes b = good;
        std::reverse(b.begin(), b.begin() + 8);
        CHECK_IO_ERROR(validate(b), p, "byte-swapped");
    }
    SUBCASE("version 31 and 33") {
        Bytes b = good;
        poke<uint32_t>(b, 16, packed_version(31, 0, 0));
        CHECK_IO_ERROR(validate(b), p, "31.0.0", "major version 32");
        poke<uint32_t>(b, 16, packed_version(33, 1, 2));
        CHECK_IO_ERROR(validate(b), p, "33.1.2");
    }
    SUBCASE("a type without a reader") {
        Bytes b = good;
        poke<uint32_t>(b, 636, 2);
        CHECK_IO_ERROR(validate(b), p, "double", "not supported",
                       "supported types: float, Half, Fp4, Fp8, Fp16, FpN, Vec3f, OnIndex");
        poke<uint32_t>(b, 636, 19);
        CHECK_IO_ERROR(validate(b), p, "Index", "not supported");
        poke<uint32_t>(b, 636, 4000);
        CHECK_IO_ERROR(validate(b), p, "unknown (4000)", "not supported");
    }
    SUBCASE("mGridSize larger than the buffer") {
        Bytes b = good;
        poke<uint64_t>(b, 32, good.size() + 32);
        CHECK_IO_ERROR(validate(b), p, "mGridSize", std::to_string(good.size() + 32));
        poke<uint64_t>(b, 32, 100);
        CHECK_IO_ERROR(validate(b), p, "mGridSize", "smaller");
    }
    SUBCASE("root offset outside the buffer") {
        Bytes b = good;
        poke<uint64_t>(b, tree_off + 24, good.size());
        CHECK_IO_ERROR(validate(b), p, "root node offset", "outside");
        poke<uint64_t>(b, tree_off + 24, ~uint64_t(0));
        CHECK_IO_ERROR(validate(b), p, "root node offset", "outside");
    }
    SUBCASE("misaligned root and node arrays") {
        Bytes b = good;
        poke<uint64_t>(b, tree_off + 24, root_off - tree_off + 8);
        CHECK_IO_ERROR(validate(b), p, "root node", "not 32-byte aligned");
        b = good;
        poke<uint64_t>(b, tree_off + 8, lower0 - tree_off + 4);
        CHECK_IO_ERROR(validate(b), p, "lower node array", "not 32-byte aligned");
    }
    SUBCASE("root table_size absurd") {
        Bytes b = good;
        poke<uint32_t>(b, root_off + 24, 0xffffffffu);
        CHECK_IO_ERROR(validate(b), p, "root tile table", "4294967295");
    }
    SUBCASE("node arrays that do not fit") {
        Bytes b = good;
        poke<uint32_t>(b, tree_off + 32, 0x7fffffffu); // leaf count
        CHECK_IO_ERROR(validate(b), p, "leaf node array", "does not fit");
        b = good;
        poke<uint64_t>(b, tree_off + 16, ~uint64_t(0) - 5); // upper offset
        CHECK_IO_ERROR(validate(b), p, "upper node array", "does not fit");
    }
    SUBCASE("a root tile key that no coordinate has") {
        // PNanoVDB's coord_to_key leaves the top bit of each 21-bit field
        // (20, 41, 62) and bit 63 clear: its search never finds such a tile,
        // while the O(1) root index (by block: those bits dropped) would
        const uint64_t key_at = offset_in(grid, root.data()->tile(0));
        CHECK(key_at == root_off + 64);
        for (int bit : { 20, 41, 62, 63 }) {
            INFO("bit " << bit);
            Bytes b = good;
            const uint64_t key = peek<uint64_t>(good, key_at) | (uint64_t(1) << bit);
            poke<uint64_t>(b, key_at, key);
            char hex[32];
            std::snprintf(hex, sizeof(hex), "0x%016llx", (unsigned long long) key);
            CHECK_IO_ERROR(validate(b), p, "root tile 0", hex, "bit " + std::to_string(bit),
                           "no coordinate has this key");
        }
        Bytes b = good;
        poke<uint64_t>(b, key_at, peek<uint64_t>(good, key_at) | (uint64_t(1) << 20) |
                                      (uint64_t(1) << 63));
        CHECK_IO_ERROR(validate(b), p, "root tile 0", "bits 20 (the top bit of z's field), 63");
    }
    // A root tile with a child.
    uint32_t child_tile = 0;
    while (child_tile < root.tileCount() && !root.data()->tile(child_tile)->isChild()) ++child_tile;
    REQUIRE(child_tile < root.tileCount());
    const uint64_t tile_child = offset_in(grid, root.data()->tile(child_tile)) + 8;
    CHECK(tile_child == root_off + 64 + 32 * child_tile + 8);

    SUBCASE("root tile child outside the buffer") {
        Bytes b = good;
        poke<int64_t>(b, tile_child, int64_t(1) << 40);
        CHECK_IO_ERROR(validate(b), p, "root tile", "outside");
        poke<int64_t>(b, tile_child, std::numeric_limits<int64_t>::min());
        CHECK_IO_ERROR(validate(b), p, "root tile", "outside");
        poke<int64_t>(b, tile_child, -int64_t(root_off) - 8);
        CHECK_IO_ERROR(validate(b), p, "root tile", "outside");
    }
    SUBCASE("root tile child misaligned or outside the upper array") {
        Bytes b = good;
        poke<int64_t>(b, tile_child, peek<int64_t>(good, tile_child) + 32);
        CHECK_IO_ERROR(validate(b), p, "root tile", "misaligned", "upper");
        poke<int64_t>(b, tile_child, int64_t(leaf0) - int64_t(root_off));
        CHECK_IO_ERROR(validate(b), p, "root tile", "outside the upper node array");
    }
    SUBCASE("upper child pointing outside the lower array") {
        const auto *upper = tree.getFirstNode<2>();
        uint32_t n = 0;
        while (n < 32768 && !upper->childMask().isOn(n)) ++n;
        REQUIRE(n < 32768);
        const uint64_t entry = offset_in(grid, &upper->data()->mTable[n]);
        CHECK(entry == upper0 + 8256 + 8 * n);
        Bytes b = good;
        poke<int64_t>(b, entry, int64_t(leaf0) - int64_t(upper0)); // at the leaf array
        CHECK_IO_ERROR(validate(b), p, "upper node 0", "table entry " + std::to_string(n),
                       "outside the lower node array");
        poke<int64_t>(b, entry, int64_t(good.size()));
        CHECK_IO_ERROR(validate(b), p, "upper node 0", "outside");
        poke<int64_t>(b, entry, peek<int64_t>(good, entry) + 4);
        CHECK_IO_ERROR(validate(b), p, "upper node 0", "misaligned");
    }
    SUBCASE("lower child pointing outside the leaf array") {
        const auto *lower = tree.getFirstNode<1>();
        uint32_t n = 0;
        while (n < 4096 && !lower->childMask().isOn(n)) ++n;
        REQUIRE(n < 4096);
        const uint64_t entry = offset_in(grid, &lower->data()->mTable[n]);
        CHECK(entry == lower0 + 1088 + 8 * n);
        Bytes b = good;
        poke<int64_t>(b, entry, 0); // the lower node itself
        CHECK_IO_ERROR(validate(b), p, "lower node 0", "outside the leaf node array");
        poke<int64_t>(b, entry, -int64_t(lower0) - 1);
        CHECK_IO_ERROR(validate(b), p, "lower node 0", "outside");
    }
    SUBCASE("a child bit set in a grid with no nodes below") {
        Bytes b = good;
        poke<uint32_t>(b, tree_off + 32, 0); // pretend there are no leaves
        CHECK_IO_ERROR(validate(b), p, "lower node", "no leaf nodes");
    }
    SUBCASE("tile grid: a root tile value made a child") {
        const auto &tg = *tiles.grid<float>();
        const auto &troot = tg.tree().root();
        uint32_t value_tile = 0;
        while (value_tile < troot.tileCount() && troot.data()->tile(value_tile)->isChild())
            ++value_tile;
        REQUIRE(value_tile < troot.tileCount());
        Bytes b = handle_bytes(tiles);
        poke<int64_t>(b, offset_in(tg, troot.data()->tile(value_tile)) + 8, 64);
        CHECK_IO_ERROR(nio::validate_grid(p, b.data(), b.size()), p,
                       ("root tile " + std::to_string(value_tile)), "upper");
    }
}

// =====================================================================================

TEST_CASE("validate_grid: node arrays must not overlap; children at the right level") {
    static const Handle sphere = fog_sphere();
    const auto &grid = *sphere.grid<float>();
    const auto &tree = grid.tree();
    static const Bytes good = handle_bytes(sphere);
    const std::string p = "overlap.nvdb";
    const uint64_t tree_off = 672;
    const uint64_t root_off = offset_in(grid, &tree.root());
    const uint64_t upper0 = offset_in(grid, tree.getFirstNode<2>());
    const uint64_t lower0 = offset_in(grid, tree.getFirstNode<1>());
    auto validate = [&](const Bytes &b) { return nio::validate_grid(p, b.data(), b.size()); };

    SUBCASE("the leaf array overlapping the root") {
        Bytes b = good;
        poke<uint64_t>(b, tree_off + 0, root_off - tree_off);
        CHECK_IO_ERROR(validate(b), p, "leaf node array", "overlaps the root node");
    }
    SUBCASE("the lower array overlapping the upper array") {
        Bytes b = good;
        poke<uint64_t>(b, tree_off + 8, upper0 - tree_off + 32);
        CHECK_IO_ERROR(validate(b), p, "lower node array", "overlaps the upper node array");
    }
    SUBCASE("a node array inside the grid header") {
        Bytes b = good;
        poke<uint64_t>(b, tree_off + 16, 0); // upper array at the tree itself
        CHECK_IO_ERROR(validate(b), p, "upper node array", "overlaps the grid and tree header");
    }
    SUBCASE("a root table long enough to run into the upper array") {
        Bytes b = good;
        const uint32_t tiles = uint32_t((upper0 - root_off - 64) / 32) + 1;
        poke<uint32_t>(b, root_off + 24, tiles);
        CHECK_IO_ERROR(validate(b), p, "upper node array", "overlaps the root node and its tile table");
    }
    SUBCASE("child offsets at the parent itself, backwards, or at the wrong level") {
        const auto *upper = tree.getFirstNode<2>();
        uint32_t n = 0;
        while (n < 32768 && !upper->childMask().isOn(n)) ++n;
        REQUIRE(n < 32768);
        const uint64_t entry = upper0 + 8256 + 8 * n;
        Bytes b = good;
        poke<int64_t>(b, entry, 0); // the upper node itself
        CHECK_IO_ERROR(validate(b), p, "upper node 0", "outside the lower node array");
        poke<int64_t>(b, entry, int64_t(root_off) - int64_t(upper0)); // backwards, at the root
        CHECK_IO_ERROR(validate(b), p, "upper node 0", "outside the lower node array");
        // A root tile pointing at a lower node (one level too deep)
        uint32_t t = 0;
        const auto &root = tree.root();
        while (!root.data()->tile(t)->isChild()) ++t;
        Bytes c = good;
        poke<int64_t>(c, offset_in(grid, root.data()->tile(t)) + 8, int64_t(lower0) - int64_t(root_off));
        CHECK_IO_ERROR(validate(c), p, "root tile", "outside the upper node array");
    }
    SUBCASE("every file of shared/data and every NanoVDB-made grid still validates") {
        for (const Handle *h : { &sphere }) CHECK_NOTHROW(validate_handle(*h, "ok"));
        const Handle t = tile_grid(), e = empty_grid(), l = ls_torus();
        CHECK_NOTHROW(validate_handle(t, "t"));
        CHECK_NOTHROW(validate_handle(e, "e"));
        CHECK_NOTHROW(validate_handle(l, "l"));
    }
}

// =====================================================================================
// A buffer that passed validation but holds garbage (mutated tile keys, masks,
// table values, counts...) never makes a lookup leave it. The grid sits at the
// end of a mapping followed by 16 GiB + a page of PROT_NONE address space, all
// that a 32-bit word address can reach: any read past the end faults. Each
// returned address is also checked against the buffer size.
// =====================================================================================


/// The byte offset of a grid's leaf array (the tree's leaf offset + 672)
static uint64_t layout_leaf_begin(const Bytes &b) { return 672 + peek<uint64_t>(b, 672); }

// =====================================================================================
TEST_CASE("typed grids: validation, statistics and hostile quantized leaves") {
    const std::string p = "typed.nvdb";
    auto words_of = [](const nvdb_test::TypedGrid &g) {
        Bytes b(g.bytes);
        std::memcpy(b.data(), g.words.data(), g.bytes);
        return b;
    };
    SUBCASE("every type validates; its statistics are those of its decoded values") {
        for (const char *type : { "fp4", "fp8", "fp16", "fpn", "half", "vec3f" }) {
            INFO("type " << type);
            const nvdb_test::TypedGrid g = nvdb_test::make_typed_grid("noisy_cloud", type);
            Bytes b = words_of(g);
            const auto info = nio::validate_grid(p, b.data(), b.size());
            CHECK(info.summary().grid_type == g.grid_type);
            CHECK(info.summary().node_count[0] == g.float_grid.grid<float>()->tree().nodeCount(0));
            CHECK(info.summary().node_end[0] == g.bytes); // leaves last, to the grid's end
            // max over every value (leaves decoded) = the accessor's largest value
            float expect = -1e30f;
            const auto *fg = g.float_grid.grid<float>();
            auto acc = fg->getAccessor();
            const auto *leaf = fg->tree().getFirstLeaf();
            if (std::string(type) == "vec3f") {
                auto ref = g.reference3();
                for (uint32_t n = 0; n < fg->tree().nodeCount(0); ++n)
                    for (uint32_t v = 0; v < 512; ++v) {
                        float c[3];
                        ref(leaf[n].offsetToGlobalCoord(v), c);
                        expect = std::max(expect, std::max(c[0], std::max(c[1], c[2])));
                    }
            } else {
                auto ref = g.reference();
                for (uint32_t n = 0; n < fg->tree().nodeCount(0); ++n)
                    for (uint32_t v = 0; v < 512; ++v)
                        expect = std::max(expect, ref(leaf[n].offsetToGlobalCoord(v)));
            }
            (void) acc;
            CHECK(info.values().max == expect);
            CHECK(info.values().value_count > 0);
        }
    }
    SUBCASE("FpN: a code width beyond 16 bits") {
        const nvdb_test::TypedGrid g = nvdb_test::make_typed_grid("noisy_cloud", "fpn");
        Bytes b = words_of(g);
        const uint64_t leaf = layout_leaf_begin(b);
        // flags >> 5 = 5: 32-bit codes, which FpN does not have
        b[leaf + 15] = uint8_t((b[leaf + 15] & 0x1f) | (5 << 5));
        CHECK_IO_ERROR(nio::validate_grid(p, b.data(), b.size()), p, "FpN leaf 0",
                       "code width of 32 bits", "1, 2, 4, 8 or 16 bits");
    }
    SUBCASE("FpN: leaves that run past the grid's end") {
        const nvdb_test::TypedGrid g = nvdb_test::make_typed_grid("noisy_cloud", "fpn");
        Bytes b = words_of(g);
        const uint64_t leaf = layout_leaf_begin(b);
        const uint32_t count = peek<uint32_t>(b, 672 + 32);
        // Widen the last leaf to 16 bits: it no longer fits the grid
        uint64_t at = leaf;
        for (uint32_t n = 0; n + 1 < count; ++n)
            at += 96 + (64u << (b[at + 15] >> 5));
        REQUIRE((b[at + 15] >> 5) < 4);
        b[at + 15] = uint8_t((b[at + 15] & 0x1f) | (4 << 5));
        CHECK_IO_ERROR(nio::validate_grid(p, b.data(), b.size()), p,
                       "FpN leaf " + std::to_string(count - 1), "extends past the end");
    }
    SUBCASE("quantized grids truncated: mGridSize beyond the buffer") {
        for (const char *type : { "fp4", "fpn", "half", "vec3f" }) {
            const nvdb_test::TypedGrid g = nvdb_test::make_typed_grid("noisy_cloud", type);
            Bytes b = words_of(g);
            b.resize(b.size() - 100);
            CHECK_IO_ERROR(nio::validate_grid(p, b.data(), b.size()), p, "mGridSize");
        }
    }
    SUBCASE("Fp8: a child offset into the middle of a leaf") {
        const nvdb_test::TypedGrid g = nvdb_test::make_typed_grid("noisy_cloud", "fp8");
        Bytes b = words_of(g);
        // the first lower node's first child entry
        const uint64_t lower = 672 + peek<uint64_t>(b, 672 + 8);
        uint32_t e = 0;
        while (!((peek<uint32_t>(b, lower + 544 + 4 * (e >> 5)) >> (e & 31)) & 1u)) ++e;
        const uint64_t at = lower + 1088 + 8 * uint64_t(e);
        poke<int64_t>(b, at, peek<int64_t>(b, at) + 32);
        CHECK_IO_ERROR(nio::validate_grid(p, b.data(), b.size()), p, "misaligned");
    }
}

TEST_CASE("typed grids: invalid values are found and repaired in their own encoding") {
    const std::string p = "typed_values.nvdb";
    SUBCASE("half: NaN and Inf halves, located at their voxel") {
        nvdb_test::TypedGrid g = nvdb_test::make_typed_grid("noisy_cloud", "half");
        uint8_t *buf = reinterpret_cast<uint8_t *>(g.words.data());
        const uint64_t leaf = 672 + peek<uint64_t>(Bytes(buf, buf + 736), 672);
        std::memcpy(buf + leaf + 96 + 2 * 5, "\x00\x7e", 2);  // NaN at n = 5
        std::memcpy(buf + leaf + 96 + 2 * 9, "\x00\x7c", 2);  // +Inf at n = 9
        auto info = nio::validate_grid(p, static_cast<void *>(buf), g.bytes);
        CHECK(info.values().nan_count == 1);
        CHECK(info.values().posinf_count == 1);
        const nio::ValueScan scan = nio::scan_values(info);
        const auto o = g.float_grid.grid<float>()->tree().getFirstLeaf()->offsetToGlobalCoord(5);
        CHECK(scan.first_nan.level == 0);
        CHECK(scan.first_nan.ijk[0] == o[0]);
        CHECK(scan.first_nan.ijk[1] == o[1]);
        CHECK(scan.first_nan.ijk[2] == o[2]);
        const nio::SanitizeResult r = nio::sanitize_values(info);
        CHECK(r.nan == 1);
        CHECK(r.posinf == 1);
        CHECK(info.values().all_finite());
        // Written back as halves: a fresh validation agrees
        const auto again = nio::validate_grid(p, static_cast<const void *>(buf), g.bytes);
        CHECK(again.values().all_finite());
        CHECK(again.values().max == info.values().max);
    }
    SUBCASE("fp8: a NaN quantum and a negative minimum, re-encoded") {
        nvdb_test::TypedGrid g = nvdb_test::make_typed_grid("noisy_cloud", "fp8");
        uint8_t *buf = reinterpret_cast<uint8_t *>(g.words.data());
        const uint64_t leaf0 = 672 + peek<uint64_t>(Bytes(buf, buf + 736), 672);
        const float nan = std::numeric_limits<float>::quiet_NaN(), neg = -0.5f;
        std::memcpy(buf + leaf0 + 96 - 12, &nan, 4);            // leaf 0: quantum NaN
        std::memcpy(buf + leaf0 + 608 + 96 - 16, &neg, 4);      // leaf 1: minimum -0.5
        auto info = nio::validate_grid(p, static_cast<void *>(buf), g.bytes);
        CHECK(info.values().nan_count > 0);
        CHECK(info.values().negative_count > 0);
        const nio::SanitizeResult r = nio::sanitize_values(info);
        CHECK(r.nan > 0);
        CHECK(r.negative > 0);
        CHECK(info.values().all_finite());
        CHECK(info.values().negative_count == 0);
        CHECK(info.values().min >= 0.f);
        const auto again = nio::validate_grid(p, static_cast<const void *>(buf), g.bytes);
        CHECK(again.values().all_finite());
        CHECK(again.values().negative_count == 0);
        CHECK(again.values().max == info.values().max);
    }
}
