// prepare_grid (src/loader/load.cpp): from a file and from memory, the same
// grid, plan and bounds as the separate calls it replaces (decode_grid,
// lookup_box, max_in_box, max_in_box_per_channel, node_majorants,
// mean_bound), and a spectral rewrite byte for byte the plugin's own
// (to_spectral_coefficients in grid_nanovdb.cpp before prepare_grid,
// rewritten here with a stand-in for Mitsuba's srgb_model_fetch).

#include <doctest/doctest.h>

#include "fixtures.h"
#include "typed_grids.h"

#include <nanovdb_drjit/layout.h>
#include <nanovdb_loader/load.h>

#include <climits>
#include <optional>

namespace {

namespace L = nanovdb_drjit::layout;

/// A grid to prepare: its bytes and a file holding them
struct Source {
    std::string name;
    Bytes bytes;
    std::string path; ///< written by NanoVDB's writer
};

Source source(const std::string &name, const Handle &h) {
    Source s{ name, handle_bytes(h), tmp_path("prepare_" + name + ".nvdb") };
    nanovdb::io::writeGrid(s.path, h);
    return s;
}

bool same_bits(float a, float b) { return std::memcmp(&a, &b, 4) == 0; }

/// A stand-in for srgb_model_fetch: any fixed map of [0, 1]^3 will do
void fake_fetch(const float norm[3], float coeff[3]) {
    coeff[0] = norm[0] * 3.f - 1.f;
    coeff[1] = norm[1] + norm[2];
    coeff[2] = 0.25f * norm[2] - norm[0];
}

/// The plugin's conversion of a colour (scale = 2 max(rgb), coefficients of
/// rgb / scale), with the stand-in
float convert(const float rgb[3], float coeff[3]) {
    const float scale = std::max(rgb[0], std::max(rgb[1], rgb[2])) * 2.f;
    const float norm[3] = { rgb[0] / std::max(1e-8f, scale), rgb[1] / std::max(1e-8f, scale),
                            rgb[2] / std::max(1e-8f, scale) };
    fake_fetch(norm, coeff);
    return scale;
}

/// The plugin's to_spectral_coefficients before prepare_grid, redone
/// through NanoVDB's own node structs on the grid at `buf`: every leaf
/// value, every internal tile (its scale in the entry's fourth word), every
/// root tile, the background
struct OldSpectral {
    std::vector<float> scales; ///< leaf values, root tiles, background
    uint32_t tiles_begin, leaf_begin_word, tile_begin_word;
};
OldSpectral old_spectral(uint8_t *buf) {
    auto &grid = *reinterpret_cast<nanovdb::NanoGrid<nanovdb::Vec3f> *>(buf);
    auto &tree = grid.tree();
    auto rewrite = [](nanovdb::Vec3f &colour) {
        const float rgb[3] = { colour[0], colour[1], colour[2] };
        float coeff[3];
        const float scale = convert(rgb, coeff);
        colour = nanovdb::Vec3f(coeff[0], coeff[1], coeff[2]);
        return scale;
    };
    auto tiles = [&](auto *node, uint32_t count) {
        for (uint32_t n = 0; n < count; ++n)
            for (uint32_t e = 0; e < node[n].childMask().bitCount(); ++e) {
                if (node[n].childMask().isOn(e))
                    continue;
                auto &entry = node[n].data()->mTable[e];
                const float scale = rewrite(entry.value);
                std::memcpy(reinterpret_cast<uint8_t *>(&entry) + 12, &scale, 4);
            }
    };
    OldSpectral old;
    auto *leaf = tree.getFirstNode<0>();
    for (uint32_t n = 0; n < tree.nodeCount(0); ++n)
        for (uint32_t v = 0; v < 512; ++v)
            old.scales.push_back(rewrite(leaf[n].data()->mValues[v]));
    tiles(tree.getFirstNode<2>(), tree.nodeCount(2));
    tiles(tree.getFirstNode<1>(), tree.nodeCount(1));
    auto &root = tree.root();
    for (uint32_t t = 0; t < root.tileCount(); ++t)
        old.scales.push_back(rewrite(root.data()->tile(t)->value));
    old.scales.push_back(rewrite(root.data()->mBackground));
    old.tiles_begin = tree.nodeCount(0) * 512;
    auto word = [&](const void *p) { return uint32_t((static_cast<const uint8_t *>(p) - buf) / 4); };
    old.leaf_begin_word = word(leaf);
    old.tile_begin_word = word(root.data()->tile(0));
    return old;
}

/// The separate calls, as the plugin made them before prepare_grid
struct Separate {
    Aligned buf;
    std::optional<nio::DecodedGrid> d;
    nio::IndexBox box;
    float max, grid_max;
    std::array<float, 3> max3;
    nio::NodeMajorants majorants;
    double mean;
};

void separate(const Source &src, const std::optional<nio::IndexBox> &volume_box, bool ring,
              Separate &s) {
    s.d.emplace(nio::decode_grid_bytes("sep", src.name, src.bytes.data(), src.bytes.size(),
                                       s.buf.data(), s.buf.size, nio::InvalidValues::Error));
    const nio::ValidatedGrid &g = s.d->grid;
    s.box = volume_box ? nio::lookup_box(*volume_box, ring) : nio::lookup_box(g.summary(), ring);
    s.max = nio::max_in_box(g, s.box);
    s.max3 = g.summary().grid_type == L::GRID_TYPE_VEC3F
                 ? nio::max_in_box_per_channel(g, s.box)
                 : std::array<float, 3>{ s.max, s.max, s.max };
    s.grid_max = g.values().max;
    s.majorants = nio::node_majorants(g);
    s.mean = nio::mean_bound(g, s.majorants, s.box, s.max);
}

void check_same(const nio::PreparedGrid &p, const Separate &s, float factor) {
    for (int a = 0; a < 3; ++a) {
        CHECK(p.box.lo[a] == s.box.lo[a]);
        CHECK(p.box.hi[a] == s.box.hi[a]);
        CHECK(same_bits(p.max3[a], s.max3[a]));
    }
    CHECK(p.spectral_factor == factor);
    CHECK(same_bits(p.max, s.max * factor));
    CHECK(same_bits(p.grid_max, s.grid_max * factor));
    CHECK(p.mean_bound == s.mean);
    CHECK(p.majorants.layout.size == s.majorants.layout.size);
    REQUIRE(p.majorants.values.size() == s.majorants.values.size());
    CHECK(std::memcmp(p.majorants.values.data(), s.majorants.values.data(),
                      s.majorants.bytes()) == 0);
    CHECK(p.plan.root_indexed == s.d->plan.root_indexed);
    CHECK(p.plan.root_table == s.d->plan.root_table);
    CHECK(p.warnings.size() == s.d->warnings.size()); // (each names its own source)
}

std::vector<Source> sources() {
    std::vector<Source> out;
    out.push_back(source("sphere", fog_sphere()));
    out.push_back(source("torus", ls_torus()));
    out.push_back(source("tiles", tile_grid()));
    for (const char *name : { "lower_tiles", "root_tiles_negative", "noisy_cloud" })
        out.push_back(source(std::string(name) + "_vec3f",
                             nvdb_test::make_typed_grid(name, "vec3f").handle));
    out.push_back(source("noisy_cloud_fp8", nvdb_test::make_typed_grid("noisy_cloud", "fp8").handle));
    return out;
}

} // namespace

TEST_CASE("prepare_grid: the grid and bounds of the separate calls, from a file or memory") {
    static const std::vector<Source> all = sources();
    for (const Source &src : all) {
        SUBCASE(src.name.c_str()) {
            const std::vector<nio::GridEntry> entries = nio::list_grids(src.path);
            REQUIRE(entries.size() == 1);
            const nio::IndexBox some{ { -9, 0, 3 }, { 20, 7, 40 } };
            for (const std::optional<nio::IndexBox> &volume_box :
                 { std::optional<nio::IndexBox>(), std::optional<nio::IndexBox>(some) })
                for (bool ring : { false, true }) {
                    INFO("volume box " << bool(volume_box) << ", ring " << ring);
                    Separate s{ Aligned(src.bytes.size()), {}, {}, 0.f, 0.f, {}, {}, 0.0 };
                    separate(src, volume_box, ring, s);
                    nio::PrepareOptions o;
                    o.volume_box = volume_box;
                    o.ring = ring;
                    Aligned mem(src.bytes.size()), file(src.bytes.size());
                    const nio::PreparedGrid pm = nio::prepare_grid(
                        nio::GridSource::memory("mem", src.name, src.bytes.data(), src.bytes.size()),
                        mem.data(), mem.size, o);
                    const nio::PreparedGrid pf = nio::prepare_grid(
                        nio::GridSource::file(src.path, entries[0]), file.data(), file.size, o);
                    check_same(pm, s, 1.f);
                    check_same(pf, s, 1.f);
                    CHECK(pm.scales.values.empty());
                    CHECK(mem.bytes() == s.buf.bytes());
                    CHECK(file.bytes() == s.buf.bytes());
                    CHECK(!pm.grid.holds_coefficients());
                }
        }
    }
}

TEST_CASE("prepare_grid: the spectral rewrite is the plugin's, byte for byte") {
    static const std::vector<Source> all = sources();
    nio::PrepareOptions o;
    o.ring = true;
    o.spectral = nio::SpectralConversion{ convert, 2.f };
    for (const Source &src : all) {
        SUBCASE(src.name.c_str()) {
            Separate s{ Aligned(src.bytes.size()), {}, {}, 0.f, 0.f, {}, {}, 0.0 };
            separate(src, std::nullopt, true, s);
            Aligned mem(src.bytes.size());
            nio::PreparedGrid p = nio::prepare_grid(
                nio::GridSource::memory("mem", src.name, src.bytes.data(), src.bytes.size()),
                mem.data(), mem.size, o);
            if (s.d->grid.summary().grid_type != L::GRID_TYPE_VEC3F) { // nothing to convert
                check_same(p, s, 1.f);
                CHECK(p.scales.values.empty());
                CHECK(!p.grid.holds_coefficients());
                CHECK(mem.bytes() == s.buf.bytes());
            } else {
                // The bounds are the colours' (x 2 for max and grid_max)
                check_same(p, s, 2.f);
                const OldSpectral old = old_spectral(s.buf.data());
                CHECK(mem.bytes() == s.buf.bytes());
                CHECK(p.scales.values == old.scales);
                CHECK(p.scales.tiles_begin == old.tiles_begin);
                CHECK(p.scales.background == old.scales.size() - 1);
                CHECK(p.scales.leaf_begin_word == old.leaf_begin_word);
                CHECK(p.scales.tile_begin_word == old.tile_begin_word);
                // Converted once; the colours' statistics are kept
                CHECK(p.grid.holds_coefficients());
                CHECK(same_bits(p.grid.values().max, s.d->grid.values().max));
                CHECK_IO_ERROR(nio::to_spectral_coefficients(p.grid, *o.spectral), "mem",
                               "already holds spectral coefficients");
                CHECK_IO_ERROR(nio::sanitize_values(p.grid), "mem",
                               "already holds spectral coefficients");
            }
        }
    }
}
