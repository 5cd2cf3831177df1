// Index grids (nanovdb_loader/index_grid.h): a float grid made an index grid
// holds its active values in the documented order, with the tree NanoVDB's
// accessor walks; hostile index grids and blind channels are refused with
// errors that name the file and the problem; the value policy rewrites an
// index grid's values.

#include <doctest/doctest.h>

#include "fixtures.h"

#include <nanovdb_drjit/layout.h>
#include <nanovdb_loader/index_grid.h>
#include <nanovdb_loader/load.h>

#include <cstring>
#include <limits>
#include <vector>

namespace {

using nanovdb_drjit::layout::GRID_TYPE_ONINDEX;

/// A made index grid, validated with its values (the values stay here)
struct Made {
    nio::MadeIndexGrid made;
    Bytes bytes;
    nio::IndexValues index() {
        return { made.values.values.data(), made.values.values.size() / made.values.channels,
                 made.values.background, made.values.channels };
    }
};

Made make(const Handle &h, const std::string &label) {
    const nio::ValidatedGrid v = validate_handle(h, label);
    Made m{ nio::make_index_grid(v), {} };
    m.bytes = Bytes(m.made.bytes.begin(), m.made.bytes.end());
    return m;
}

/// The value index of voxel ijk, by PNanoVDB 32.6's rules read straight off
/// the made grid's bytes with NanoVDB's own accessor for the tree walk (the
/// node layout below the leaves is the float grid's)
uint64_t leaf_index_of(const uint8_t *leaf, uint32_t n) {
    uint64_t mask, first, prefix;
    std::memcpy(&mask, leaf + 16 + 8 * (n >> 6), 8);
    std::memcpy(&first, leaf + 80, 8);
    std::memcpy(&prefix, leaf + 88, 8);
    if (!((mask >> (n & 63)) & 1u))
        return 0;
    uint64_t sum = uint64_t(__builtin_popcountll(mask & ((uint64_t(1) << (n & 63)) - 1)));
    if (n >> 6)
        sum += (prefix >> (9 * ((n >> 6) - 1))) & 511u;
    return first + sum;
}

} // namespace

TEST_CASE("make_index_grid: the active values, in the documented order") {
    static const Handle sphere = fog_sphere(), tiles = tile_grid();
    SUBCASE("fog sphere: each leaf's active voxels, leaf by leaf") {
        Made m = make(sphere, "sphere");
        const auto *grid = sphere.grid<float>();
        const auto &tree = grid->tree();
        // NanoVDB's fog sphere keeps the level set's background (1.5) while
        // its inactive voxels and tiles hold 0: the tiles keep their value
        // (an index each, before the voxels), the inactive voxels read 1.5
        // tiles, counted with NanoVDB's node structs: root tiles without
        // child, then upper and lower entries without child, active or not
        // the background
        const float bg = grid->tree().background();
        std::vector<float> tile_want;
        const auto *root = tree.root().data();
        for (uint32_t t = 0; t < root->mTableSize; ++t) {
            const auto *tile = root->tile(t);
            if (!tile->isChild() && (tile->state || tile->value != bg))
                tile_want.push_back(tile->value);
        }
        auto internal = [&](const auto *first, uint32_t count, uint32_t entries) {
            for (uint32_t i = 0; i < count; ++i) {
                const auto *d = (first + i)->data();
                for (uint32_t e = 0; e < entries; ++e)
                    if (!d->mChildMask.isOn(e) && (d->mValueMask.isOn(e) || d->mTable[e].value != bg))
                        tile_want.push_back(d->mTable[e].value);
            }
        };
        internal(tree.getFirstNode<2>(), tree.nodeCount(2), 32768);
        internal(tree.getFirstNode<1>(), tree.nodeCount(1), 4096);
        const uint64_t tile_values = tile_want.size();
        CHECK(tile_values > 0);
        CHECK(m.made.inactive_differing > 0);
        REQUIRE(m.made.values.values.size() >= tile_values);
        CHECK(std::equal(tile_want.begin(), tile_want.end(), m.made.values.values.begin()));
        // leaf i of the made grid: 96 bytes at the leaf array; its voxels'
        // indices run on from the previous leaf's, n ascending
        const nio::ValidatedGrid v = nio::validate_grid("made", m.bytes.data(), m.bytes.size(),
                                                        m.index());
        CHECK(v.summary().grid_type == GRID_TYPE_ONINDEX);
        CHECK(v.summary().node_count[0] == tree.nodeCount(0));
        CHECK(v.values().max == doctest::Approx(1.5f)); // the background counts, as for the grid
        uint64_t next = tile_values + 1, checked = 0;
        for (uint32_t i = 0; i < tree.nodeCount(0); ++i) {
            const auto *leaf = tree.getFirstNode<0>() + i;
            const uint8_t *ours = m.bytes.data() + v.summary().node_begin[0] + 96 * uint64_t(i);
            for (uint32_t n = 0; n < 512; ++n) {
                const uint64_t idx = leaf_index_of(ours, n);
                if (!leaf->isActive(n)) {
                    CHECK(idx == 0);
                    continue;
                }
                CHECK(idx == next);
                CHECK(m.made.values.values[idx - 1] == leaf->getValue(n));
                ++next;
                ++checked;
            }
        }
        CHECK(next - 1 == m.made.values.values.size());
        CHECK(checked > 0);
    }
    SUBCASE("tiles: root, upper and lower tiles first, active or valued") {
        Made m = make(tiles, "tiles");
        // tile_grid: an active root tile (100), an inactive upper tile (-50,
        // not the background 0.5: it keeps its value), an active lower tile (7),
        // then the three voxels
        const std::vector<float> &vals = m.made.values.values;
        REQUIRE(vals.size() == 6);
        CHECK(vals[0] == 100.f);
        CHECK(vals[1] == -50.f);
        CHECK(vals[2] == 7.f);
        CHECK(m.made.values.background[0] == 0.5f);
        const nio::ValidatedGrid v = nio::validate_grid("made", m.bytes.data(), m.bytes.size(),
                                                        m.index());
        CHECK(v.values().max == 100.f);
        CHECK(v.values().min == -50.f);
        CHECK(v.values().negative_count > 0);
    }
}

TEST_CASE("index grids: hostile trees and values are refused, naming the problem") {
    static const Handle sphere = fog_sphere();
    Made m = make(sphere, "sphere");
    const std::string p = "hostile.nvdb";
    const nio::ValidatedGrid v = nio::validate_grid("made", m.bytes.data(), m.bytes.size(), m.index());
    const uint64_t leaf0 = v.summary().node_begin[0];
    SUBCASE("no values for its indices") {
        CHECK_IO_ERROR(nio::validate_grid(p, m.bytes.data(), m.bytes.size()), p, "value index",
                       "but the grid has 0 values");
    }
    SUBCASE("too few values") {
        nio::IndexValues iv = m.index();
        iv.count -= 1;
        CHECK_IO_ERROR(nio::validate_grid(p, m.bytes.data(), m.bytes.size(), iv), p,
                       "last value index", "values (indices 1 to");
    }
    SUBCASE("prefix sums that disagree with the mask") {
        Bytes b = m.bytes;
        // the first leaf with active voxels beyond its first mask word
        uint64_t leaf = leaf0;
        for (uint32_t i = 0; i < v.summary().node_count[0]; ++i, leaf += 96) {
            uint64_t prefix;
            std::memcpy(&prefix, &b[leaf + 88], 8);
            if (prefix != 0)
                break;
        }
        b[leaf + 88] ^= 1;
        CHECK_IO_ERROR(nio::validate_grid(p, b.data(), b.size(), m.index()), p, "has prefix sum",
                       "active voxels there");
    }
    SUBCASE("a leaf whose first index is the background's") {
        Bytes b = m.bytes;
        uint64_t leaf = leaf0;
        std::memset(&b[leaf + 80], 0, 8);
        uint64_t mask = 0;
        for (int w = 0; w < 8; ++w) {
            uint64_t x;
            std::memcpy(&x, &b[leaf + 16 + 8 * w], 8);
            mask |= x;
        }
        if (mask != 0)
            CHECK_IO_ERROR(nio::validate_grid(p, b.data(), b.size(), m.index()), p,
                           "first value index 0");
    }
    SUBCASE("a background index other than 0") {
        Bytes b = m.bytes;
        const uint64_t root = uint64_t(v.summary().root_word) * 4;
        b[root + 32] = 3;
        CHECK_IO_ERROR(nio::validate_grid(p, b.data(), b.size(), m.index()), p,
                       "background's value index is 3");
    }
    SUBCASE("more values than 32-bit indices reach") {
        nio::IndexValues iv = m.index();
        iv.count = uint64_t(1) << 32;
        CHECK_IO_ERROR(nio::validate_grid(p, m.bytes.data(), m.bytes.size(), iv), p,
                       "beyond the lookups' 32-bit indices");
    }
}

TEST_CASE("index grids: values from blind channels") {
    static const Handle sphere = fog_sphere();
    Made m = make(sphere, "sphere");
    const std::vector<float> &want = m.made.values.values;
    const uint64_t tree = m.bytes.size();
    // Appends one GridBlindMetaData record and its data to the made grid
    auto with_channel = [&](const std::string &name, uint32_t value_size, uint32_t type,
                            const Bytes &data, uint64_t value_count) {
        Bytes b = m.bytes;
        Bytes record(288, 0);
        const int64_t data_offset = 288;
        std::memcpy(&record[0], &data_offset, 8);
        std::memcpy(&record[8], &value_count, 8);
        std::memcpy(&record[16], &value_size, 4);
        std::memcpy(&record[28], &type, 4);
        std::memcpy(&record[32], name.data(), name.size());
        b.insert(b.end(), record.begin(), record.end());
        b.insert(b.end(), data.begin(), data.end());
        while (b.size() % 32)
            b.push_back(0);
        const uint64_t size = b.size();
        const int64_t meta = int64_t(tree);
        const uint32_t count = 1;
        std::memcpy(&b[32], &size, 8);
        std::memcpy(&b[640], &meta, 8);
        std::memcpy(&b[648], &count, 4);
        return b;
    };
    auto floats = [](const std::vector<float> &v) {
        Bytes out(4 * v.size());
        std::memcpy(out.data(), v.data(), out.size());
        return out;
    };
    auto decode = [&](Bytes b, const nio::BlindSelection &sel = {}) {
        Aligned dst(b.size());
        std::memcpy(dst.data(), b.data(), b.size());
        return std::make_pair(nio::decode_grid_bytes("blind.nvdb", "density", b.data(), b.size(),
                                                     dst.data(), b.size(),
                                                     nio::InvalidValues::Error, sel),
                              std::move(dst));
    };
    SUBCASE("NanoVDB's float channel, the background's value first") {
        std::vector<float> v = want;
        v.insert(v.begin(), 0.25f);
        auto [d, dst] = decode(with_channel("density", 4, 1, floats(v), v.size()));
        CHECK(d.index_values == want);
        CHECK(d.grid.index_values().background[0] == 0.25f);
        CHECK(d.grid_bytes == tree); // the blind data dropped
    }
    SUBCASE("fVDB's tensor [N, 2]: a component of each row") {
        Bytes data(8 * 3);
        const int64_t header[3] = { 2, int64_t(want.size()), 2 };
        std::memcpy(data.data(), header, 24);
        std::vector<float> rows;
        for (float x : want) {
            rows.push_back(-x);
            rows.push_back(x);
        }
        const Bytes f = floats(rows);
        data.insert(data.end(), f.begin(), f.end());
        auto [d, dst] = decode(with_channel("fvdb_jdatafloat32", 1, 0, data, data.size()),
                               nio::BlindSelection{ "", 1 });
        CHECK(d.index_values == want);
        CHECK(d.index_note.find("component 1 of 2") != std::string::npos);
        CHECK_IO_ERROR(decode(with_channel("fvdb_jdatafloat32", 1, 0, data, data.size()),
                              nio::BlindSelection{ "", 2 }),
                       "blind.nvdb", "holds 2 float(s) per value; component 2 does not exist");
        Bytes bad = data;
        bad.resize(bad.size() - 4);
        CHECK_IO_ERROR(decode(with_channel("fvdb_jdatafloat32", 1, 0, bad, bad.size())),
                       "blind.nvdb", "not the 24-byte header and the floats of its shape");
    }
    SUBCASE("no blind data, a channel of integers, a record outside the grid") {
        CHECK_IO_ERROR(decode(m.bytes), "blind.nvdb", "has no blind data");
        Bytes ints(4 * want.size(), 0);
        CHECK_IO_ERROR(decode(with_channel("ids", 4, 4, ints, want.size()), { "ids", 0 }),
                       "blind.nvdb", "does not hold floats", "int32");
        CHECK_IO_ERROR(decode(with_channel("density", 4, 1, floats(want), want.size() * 100)),
                       "blind.nvdb", "lies outside");
        CHECK_IO_ERROR(decode(with_channel("density", 4, 1, floats(want), want.size()),
                              { "heat", 0 }),
                       "blind.nvdb", "has no blind channel \"heat\"", "\"density\"");
    }
    SUBCASE("the value policy rewrites the values") {
        std::vector<float> v = want;
        v[3] = std::numeric_limits<float>::quiet_NaN();
        v[5] = -1.f;
        Bytes b = with_channel("density", 4, 1, floats(v), v.size());
        CHECK_IO_ERROR(decode(b), "blind.nvdb", "1 NaN");
        Aligned dst(b.size());
        nio::DecodedGrid d = nio::decode_grid_bytes("blind.nvdb", "density", b.data(), b.size(),
                                                    dst.data(), b.size(), nio::InvalidValues::Clamp);
        CHECK(d.index_values[3] == 0.f);
        CHECK(d.index_values[5] == 0.f);
        CHECK(d.grid.values().nan_count == 0);
    }
}
