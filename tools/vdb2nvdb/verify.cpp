// The written file against OpenVDB. See verify.h.

#include "verify.h"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <type_traits>
#include <vector>

#include <nanovdb/util/GridValidator.h>

#include <nanovdb_convert/format.h>
#include "testdata/seeded.h"

namespace vdb2nvdb {

using nvdb_testdata::Rng;
using openvdb::Coord;
using openvdb::CoordBBox;
using openvdb::FloatGrid;

namespace {

uint32_t float_bits(float v) {
    uint32_t u;
    std::memcpy(&u, &v, 4);
    return u;
}

template <typename BuildT> constexpr Quantize quantize_of() {
    if constexpr (std::is_same_v<BuildT, nanovdb::Fp4>) return Quantize::Fp4;
    else if constexpr (std::is_same_v<BuildT, nanovdb::Fp8>) return Quantize::Fp8;
    else if constexpr (std::is_same_v<BuildT, nanovdb::Fp16>) return Quantize::Fp16;
    else if constexpr (std::is_same_v<BuildT, nanovdb::FpN>) return Quantize::FpN;
    else return Quantize::Float;
}

/// NanoVDB's default FpN tolerance (OpenToNanoVDB::compression), or the user's
float fpn_tolerance(const FloatGrid &g, const Options &opts) {
    if (opts.tolerance >= 0.f)
        return opts.tolerance;
    if (g.getGridClass() == openvdb::GRID_LEVEL_SET)
        return 0.1f * float(g.voxelSize()[0]);
    if (g.getGridClass() == openvdb::GRID_FOG_VOLUME)
        return 0.01f;
    return 0.f;
}

struct Verifier {
    const FloatGrid &vdb;
    const std::string &name;
    const Options &opts;
    uint64_t mismatches = 0;

    void fail(const std::string &msg) {
        ++mismatches;
        if (mismatches <= 10) {
            std::fflush(stdout);
            std::fprintf(stderr, "vdb2nvdb: verify: grid %s: %s\n", dq(name).c_str(), msg.c_str());
        }
    }

    template <typename BuildT>
    bool run(const nanovdb::NanoGrid<BuildT> &nano) {
        const Quantize q = quantize_of<BuildT>();
        std::string err = nanovdb::GridValidator<BuildT>::check(nano, /*detailed=*/true);
        if (!err.empty()) {
            fail("the written grid does not validate (NanoVDB GridValidator): " + err);
            return false;
        }
        // Whole-grid properties
        const std::string want_name = name.substr(0, nanovdb::GridData::MaxNameSize - 1);
        if (want_name != nano.shortGridName())
            fail("name " + dq(nano.shortGridName()) + " instead of " + dq(want_name));
        if (float_bits(nano.tree().background()) != float_bits(vdb.background()))
            fail("background " + fmt_float(nano.tree().background()) + " instead of " +
                 fmt_float(vdb.background()));
        if (nano.activeVoxelCount() != vdb.activeVoxelCount())
            fail("active voxel count " + fmt_count(nano.activeVoxelCount()) + " instead of " +
                 fmt_count(vdb.activeVoxelCount()));
        const CoordBBox vbox = vdb.evalActiveVoxelBoundingBox();
        const auto &nb = nano.indexBBox();
        const bool nano_empty = nano.isEmpty() || nb.min()[0] > nb.max()[0];
        if (vbox.empty() != nano_empty ||
            (!vbox.empty() && (Coord(nb.min()[0], nb.min()[1], nb.min()[2]) != vbox.min() ||
                               Coord(nb.max()[0], nb.max()[1], nb.max()[2]) != vbox.max())))
            fail("active index bbox differs from OpenVDB's " +
                 (vbox.empty() ? std::string("(empty)")
                               : "[" + fmt_coord(vbox.min()) + ", " + fmt_coord(vbox.max()) + "]"));
        const bool want_fog = vdb.getGridClass() == openvdb::GRID_FOG_VOLUME;
        const bool want_ls = vdb.getGridClass() == openvdb::GRID_LEVEL_SET;
        if ((want_fog && nano.gridClass() != nanovdb::GridClass::FogVolume) ||
            (want_ls && nano.gridClass() != nanovdb::GridClass::LevelSet))
            fail("grid class differs from OpenVDB's " + class_name(vdb.getGridClass()));
        {
            // index -> world at the corners of a box: the same affine map
            CoordBBox b = vbox.empty() ? CoordBBox(Coord(0), Coord(1)) : vbox;
            for (int c = 0; c < 8; ++c) {
                openvdb::Vec3d p((c & 1) ? b.max().x() : b.min().x(),
                                 (c & 2) ? b.max().y() : b.min().y(),
                                 (c & 4) ? b.max().z() : b.min().z());
                openvdb::Vec3d w = vdb.transform().indexToWorld(p);
                nanovdb::Vec3d n = nano.indexToWorld(nanovdb::Vec3d(p[0], p[1], p[2]));
                for (int k = 0; k < 3; ++k)
                    if (std::fabs(w[k] - n[k]) > 1e-9 * (1.0 + std::fabs(w[k]))) {
                        fail("index-to-world map differs at index " + fmt_coord(Coord(p[0], p[1], p[2])));
                        c = 8;
                        break;
                    }
            }
        }

        // Sample regions with active values: leaves and active tiles
        std::vector<const FloatGrid::TreeType::LeafNodeType *> leaves;
        leaves.reserve(vdb.tree().leafCount());
        for (auto it = vdb.tree().cbeginLeaf(); it; ++it)
            if (!it->isEmpty())
                leaves.push_back(it.getLeaf());
        std::vector<CoordBBox> tiles;
        {
            auto it = vdb.tree().cbeginValueOn();
            it.setMaxDepth(FloatGrid::TreeType::ValueOnCIter::LEAF_DEPTH - 1);
            for (; it; ++it)
                if (!it.isVoxelValue())
                    tiles.push_back(it.getBoundingBox());
        }
        const uint64_t regions = leaves.size() + tiles.size();

        const float tol = q == Quantize::FpN ? fpn_tolerance(vdb, opts) : 0.f;
        auto vacc = vdb.getConstAccessor();
        auto nacc = nano.getAccessor();
        // Largest error a quantized value may have: half a quantization step
        // of its leaf (NanoVDB rounds to the nearest code without dithering),
        // the FpN tolerance, and float rounding of code * quantum + minimum.
        auto bound = [&](const Coord &c) -> double {
            if (q == Quantize::Float)
                return 0.0;
            const auto *leaf = vacc.probeConstLeaf(c);
            if (!leaf)
                return 0.0; // tiles and the background are stored as floats
            float lo = std::numeric_limits<float>::max(), hi = -lo;
            for (openvdb::Index i = 0; i < 512; ++i) {
                lo = std::min(lo, leaf->getValue(i));
                hi = std::max(hi, leaf->getValue(i));
            }
            const double range = double(hi) - double(lo);
            const int bits = q == Quantize::Fp4 ? 4 : q == Quantize::Fp8 ? 8 : 16;
            double b = 0.5 * range / double((1u << bits) - 1);
            if (q == Quantize::FpN)
                b = std::max(double(tol), 0.5 * range / 65535.0);
            return b + 8.0 * FLT_EPSILON * (std::max(std::fabs(lo), std::fabs(hi)) + range);
        };

        Rng rng = Rng::stream(opts.seed ^ 0x766462326e766462ull);
        const bool empty = vbox.empty();
        const CoordBBox inner = empty ? CoordBBox(Coord(-8), Coord(8)) : vbox;
        // The box grown by `m` voxels, clamped to int32 (no overflow at the extremes)
        auto grown = [&](int64_t m) {
            int64_t lo[3], hi[3];
            for (int k = 0; k < 3; ++k) {
                lo[k] = std::max<int64_t>(int64_t(inner.min()[k]) - m, INT32_MIN);
                hi[k] = std::min<int64_t>(int64_t(inner.max()[k]) + m, INT32_MAX);
            }
            return CoordBBox(Coord(int32_t(lo[0]), int32_t(lo[1]), int32_t(lo[2])),
                             Coord(int32_t(hi[0]), int32_t(hi[1]), int32_t(hi[2])));
        };
        const CoordBBox near = grown(2), outer = grown(64);
        uint64_t checked = 0;
        double worst = 0.0;
        for (uint64_t s = 0; s < opts.verify; ++s) {
            Coord c;
            const uint64_t kind = s % 3;
            if (kind == 0 && regions > 0) {
                // an active value: a random active voxel of a random leaf, or a tile
                const uint64_t r = rng.below(regions);
                if (r < leaves.size()) {
                    const auto *leaf = leaves[r];
                    const auto &mask = leaf->getValueMask();
                    openvdb::Index n = openvdb::Index(rng.below(512));
                    n = mask.findNextOn(n);
                    if (n >= 512)
                        n = mask.findFirstOn();
                    c = leaf->offsetToGlobalCoord(n);
                } else {
                    const CoordBBox &t = tiles[r - leaves.size()];
                    c = Coord(rng.range(t.min().x(), t.max().x()), rng.range(t.min().y(), t.max().y()),
                              rng.range(t.min().z(), t.max().z()));
                }
            } else if (kind != 2) {
                // anywhere in the active bbox (grown by 2 voxels)
                c = Coord(rng.range(near.min().x(), near.max().x()),
                          rng.range(near.min().y(), near.max().y()),
                          rng.range(near.min().z(), near.max().z()));
            } else if (rng.below(16) == 0) {
                // far away, up to the int32 extremes
                for (int k = 0; k < 3; ++k)
                    c[k] = int32_t(uint32_t(rng.next()));
            } else {
                // outside the active bbox, within 64 voxels of it (a few
                // tries: the box may fill the whole index space)
                for (int tries = 0; tries < 64; ++tries) {
                    c = Coord(rng.range(outer.min().x(), outer.max().x()),
                              rng.range(outer.min().y(), outer.max().y()),
                              rng.range(outer.min().z(), outer.max().z()));
                    if (empty || !inner.isInside(c))
                        break;
                }
            }
            const nanovdb::Coord nc(c.x(), c.y(), c.z());
            const float a = vacc.getValue(c), b = nacc.getValue(nc);
            const bool aon = vacc.isValueOn(c), bon = nacc.isActive(nc);
            bool same;
            double limit = 0.0;
            if (q == Quantize::Float) {
                same = float_bits(a) == float_bits(b);
            } else {
                limit = bound(c);
                const double d = std::fabs(double(a) - double(b));
                same = d <= limit || (std::isnan(a) && std::isnan(b));
                if (same)
                    worst = std::max(worst, d);
            }
            if (!same || aon != bon) {
                std::string msg = "mismatch at " + fmt_coord(c) + ": OpenVDB " + fmt_float(a) +
                                  (aon ? " (active)" : " (inactive)") + ", written file " +
                                  fmt_float(b) + (bon ? " (active)" : " (inactive)");
                if (q != Quantize::Float)
                    msg += ", allowed error " + fmt_float(limit);
                fail(msg);
            }
            ++checked;
        }
        if (mismatches > 10) {
            std::fflush(stdout);
            std::fprintf(stderr, "vdb2nvdb: verify: grid %s: %s mismatches in all\n",
                         dq(name).c_str(), fmt_count(mismatches).c_str());
        }
        if (mismatches == 0 && !opts.quiet) {
            std::string extra = q == Quantize::Float
                                    ? "identical"
                                    : "within the quantization bound (largest error " +
                                          fmt_float(worst) + ")";
            std::printf("verified %s: %s samples (active voxels, in and outside the bbox) %s\n",
                        dq(name).c_str(), fmt_count(checked).c_str(), extra.c_str());
        }
        return mismatches == 0;
    }
};

} // namespace

bool verify_float(const FloatGrid &vdb, const Handle &nano, const std::string &name,
                  const Options &opts) {
    bool ok = false;
    with_grid(nano, name, [&](const auto &grid) {
        Verifier v{ vdb, name, opts };
        ok = v.run(grid);
    });
    return ok;
}

bool verify_vec3(const openvdb::Vec3SGrid &vdb, const nanovdb::NanoGrid<nanovdb::Vec3f> &nano,
                 const std::string &name, const Options &opts) {
    uint64_t mismatches = 0, checked = 0;
    auto fail = [&](const std::string &msg) {
        if (++mismatches <= 10) {
            std::fflush(stdout);
            std::fprintf(stderr, "vdb2nvdb: verify: grid %s: %s\n", dq(name).c_str(), msg.c_str());
        }
    };
    if (nano.activeVoxelCount() != vdb.activeVoxelCount())
        fail("active voxel count " + fmt_count(nano.activeVoxelCount()) + " instead of " +
             fmt_count(vdb.activeVoxelCount()));
    std::vector<const openvdb::Vec3STree::LeafNodeType *> leaves;
    for (auto it = vdb.tree().cbeginLeaf(); it; ++it)
        leaves.push_back(it.getLeaf());
    const CoordBBox vbox = vdb.evalActiveVoxelBoundingBox();
    auto vacc = vdb.getConstAccessor();
    auto nacc = nano.getAccessor();
    Rng rng = Rng::stream(opts.seed ^ 0x766563337665633full);
    for (uint64_t s = 0; s < opts.verify; ++s) {
        Coord c;
        if (s % 2 == 0 && !leaves.empty()) {
            const auto *leaf = leaves[size_t(rng.below(leaves.size()))];
            c = leaf->offsetToGlobalCoord(openvdb::Index(rng.below(512)));
        } else {
            const CoordBBox b = vbox.empty() ? CoordBBox(Coord(-8), Coord(8))
                                             : CoordBBox(vbox.min().offsetBy(-2), vbox.max().offsetBy(2));
            c = Coord(rng.range(b.min().x(), b.max().x()), rng.range(b.min().y(), b.max().y()),
                      rng.range(b.min().z(), b.max().z()));
        }
        const openvdb::Vec3s a = vacc.getValue(c);
        const nanovdb::Vec3f v = nacc.getValue(nanovdb::Coord(c.x(), c.y(), c.z()));
        bool same = vacc.isValueOn(c) == nacc.isActive(nanovdb::Coord(c.x(), c.y(), c.z()));
        for (int k = 0; k < 3; ++k)
            same &= float_bits(a[k]) == float_bits(v[k]);
        if (!same)
            fail("mismatch at " + fmt_coord(c) + ": OpenVDB (" + fmt_float(a[0]) + ", " +
                 fmt_float(a[1]) + ", " + fmt_float(a[2]) + "), written file (" +
                 fmt_float(v[0]) + ", " + fmt_float(v[1]) + ", " + fmt_float(v[2]) + ")");
        ++checked;
    }
    if (mismatches == 0 && !opts.quiet)
        std::printf("verified %s: %s samples (voxels of its leaves, in and around the bbox) "
                    "identical\n", dq(name).c_str(), fmt_count(checked).c_str());
    return mismatches == 0;
}

void print_probes(const FloatGrid &vdb, const Handle &h, const std::string &name,
                  const Options &opts) {
    auto vacc = vdb.getConstAccessor();
    with_grid(h, name, [&](const auto &nano) {
        auto nacc = nano.getAccessor();
        for (const Coord &c : opts.probes) {
            const nanovdb::Coord nc(c.x(), c.y(), c.z());
            std::printf("probe %s %d,%d,%d openvdb %s %s nanovdb %s %s\n", dq(name).c_str(),
                        c.x(), c.y(), c.z(), fmt_float(vacc.getValue(c)).c_str(),
                        vacc.isValueOn(c) ? "on" : "off", fmt_float(nacc.getValue(nc)).c_str(),
                        nacc.isActive(nc) ? "on" : "off");
        }
    });
}

} // namespace vdb2nvdb
