// The host's view of the tree (src/loader/tree_view.h) against NanoVDB's own
// node structs: find() against NanoVDB's probes and its accessor, node
// indices, entries and their origins; and a later root tile that repeats a
// key, which lookups never reach.

#include <doctest/doctest.h>

#include "fixtures.h"
#include "grids.h"

#include "../../src/loader/tree_view.h"

#include <nanovdb_drjit/fast_readers.h>
#include <nanovdb_drjit/pnanovdb.h>
#include <nanovdb_loader/reader_policy.h>

namespace nd = nanovdb_loader::detail;

namespace {

uint32_t float_bits(float v) {
    uint32_t b;
    std::memcpy(&b, &v, 4);
    return b;
}

} // namespace

TEST_CASE("TreeView: find() reaches the nodes NanoVDB's probes reach") {
    // Built once for all subcases (doctest re-runs this body for each)
    static const Handle sphere = fog_sphere(), torus = ls_torus(), tiles = tile_grid();
    const std::pair<const char *, const Handle *> cases[] = {
        { "fog sphere", &sphere }, { "level-set torus", &torus }, { "tiles at every level", &tiles } };
    for (const auto &[name, h] : cases) {
        SUBCASE(name) {
            const auto &grid = *h->grid<float>();
            const nio::ValidatedGrid v = validate_handle(*h, name);
            const nd::TreeView view(v);
            const auto &root = grid.tree().root();
            auto acc = grid.getAccessor();
            size_t nodes_found = 0, values_found = 0, mismatches = 0;
            for (const auto &c : nvdb_test::query_coords(grid, 20000, 11)) {
                const nanovdb::Coord ijk(c[0], c[1], c[2]);
                const auto *upper = root.probeChild(ijk);
                const auto *lower = upper ? upper->probeChild(ijk) : nullptr;
                const auto *leaf = lower ? lower->probeChild(ijk) : nullptr;
                const uint64_t want[3] = { leaf ? offset_in(grid, leaf) : 0,
                                           lower ? offset_in(grid, lower) : 0,
                                           upper ? offset_in(grid, upper) : 0 };
                for (int level = 0; level < 3; ++level) {
                    const nd::TreeView::Found f = view.find(level, c.data());
                    // Where there is no node, the value that covers ijk is
                    // what a lookup returns
                    const bool ok =
                        f.node == want[level] &&
                        (f.node != 0 || float_bits(nd::load<float>(v.data() + f.value)) ==
                                            float_bits(acc.getValue(ijk)));
                    ++(f.node ? nodes_found : values_found);
                    if (!ok && ++mismatches <= 5) {
                        INFO("ijk " << c[0] << " " << c[1] << " " << c[2] << " level " << level);
                        CHECK(f.node == want[level]);
                        CHECK(f.node != 0);
                    }
                }
            }
            CHECK(mismatches == 0);
            CHECK(nodes_found > 0);
            CHECK(values_found > 0);
        }
    }
}

TEST_CASE("TreeView: nodes, entries and their origins") {
    static const Handle tiles = tile_grid();
    const auto &grid = *tiles.grid<float>();
    const nio::ValidatedGrid v = validate_handle(tiles, "tiles");
    const nd::TreeView view(v);
    const auto &tree = grid.tree();
    CHECK(view.node(0, 1) == offset_in(grid, tree.getFirstNode<0>() + 1));
    CHECK(view.node(1, 0) == offset_in(grid, tree.getFirstNode<1>()));
    CHECK(view.node(2, 1) == offset_in(grid, tree.getFirstNode<2>() + 1));
    for (int level = 0; level < 3; ++level)
        for (uint64_t n = 0; n < view.node_count(level); ++n)
            CHECK(view.node_index(level, view.node(level, n)) == n);
    // Every child of the first upper node: child bit, entry, child and
    // origin as NanoVDB's node says
    const auto *upper = tree.getFirstNode<2>();
    const uint64_t up = view.node(2, 0);
    const int32_t o[3] = { upper->origin()[0], upper->origin()[1], upper->origin()[2] };
    size_t children = 0;
    for (uint32_t e = 0; e < 32768; ++e) {
        CHECK(view.child_bit(2, up, e) == upper->childMask().isOn(e));
        CHECK(view.entry(2, up, e) == offset_in(grid, &upper->data()->mTable[e]));
        int32_t eo[3];
        view.entry_origin(2, o, e, eo);
        CHECK(view.entry_of(2, eo) == e);
        if (!upper->childMask().isOn(e))
            continue;
        ++children;
        const auto *lower = upper->data()->getChild(e);
        CHECK(view.child(2, up, e) == offset_in(grid, lower));
        CHECK(eo[0] == lower->origin()[0]);
        CHECK(eo[1] == lower->origin()[1]);
        CHECK(eo[2] == lower->origin()[2]);
    }
    CHECK(children > 0);
}

TEST_CASE("TreeView: a later root tile that repeats a key is one lookups never reach") {
    namespace ndr = nanovdb_drjit;
    const Handle tiles = tile_grid();
    const auto &grid = *tiles.grid<float>();
    const auto &root = grid.tree().root();
    REQUIRE(root.tileCount() >= 3);
    Bytes b = handle_bytes(tiles);
    const uint64_t key0 = offset_in(grid, root.data()->tile(0)),
                   key1 = offset_in(grid, root.data()->tile(1));
    poke<uint64_t>(b, key1, peek<uint64_t>(b, key0)); // tile 1 gets tile 0's key
    const nio::ValidatedGrid v = nio::validate_grid("repeated", b.data(), b.size());
    const nd::TreeView view(v);
    std::vector<uint32_t> reached;
    for (uint32_t t = 0; t < root.tileCount(); ++t)
        if (t != 1)
            reached.push_back(t);
    CHECK(view.tiles() == reached);
    int32_t o[3];
    view.tile_origin(1, o);
    uint32_t t = 99;
    CHECK(view.tile_of(o, t));
    CHECK(t == 0);
    // The planned readers (the root index) and PNanoVDB's search agree: tile 0
    const nio::ReaderPlan plan = nio::plan_readers(v);
    CHECK(plan.root_indexed);
    const uint32_t *words = reinterpret_cast<const uint32_t *>(b.data());
    const ndr::Coord<uint32_t> ijk(o[0], o[1], o[2]);
    uint32_t address[2];
    int i = 0;
    for (const nio::ReaderPlan &p : { plan, plan.faithful() })
        address[i++] = ndr::Reader<uint32_t>::from_plan(p).apply(
            words, [&](const auto &buf, const auto &r) {
                return ndr::root_get_value_address(buf, r, ijk, true);
            });
    CHECK(address[0] == address[1]);
    // ... and read what the grid held there before tile 1 took the key
    CHECK(float_bits(nd::load<float>(b.data() + uint64_t(address[0]) * 4)) ==
          float_bits(grid.getAccessor().getValue(nanovdb::Coord(o[0], o[1], o[2]))));
}
