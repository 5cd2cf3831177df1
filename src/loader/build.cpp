// src/loader/build.cpp -- build_grid() (see build.h): NanoVDB's GridBuilder
// fed from the caller's values.

#include <nanovdb_loader/build.h>
#include <nanovdb_loader/container.h>

#include <nanovdb/util/GridBuilder.h>

#include <cmath>
#include <cstring>
#include <type_traits>

namespace nanovdb_loader {
namespace {

[[noreturn]] void fail(const std::string &label, const std::string &what) {
    throw Error("\"" + label + "\": " + what);
}

void check_channels(const std::string &label, uint32_t channels) {
    if (channels != 1 && channels != 3)
        fail(label, std::to_string(channels) + " channels per voxel: a NanoVDB grid holds "
                    "1 (float) or 3 (Vec3f)");
}

/// Whether every channel of v lies within the threshold of the background
/// (NaN never does: it stays, for the value policy to see)
bool near_background(const float *v, uint32_t channels, const BuildOptions &o) {
    for (uint32_t c = 0; c < channels; ++c)
        if (!(std::fabs(v[c] - o.background) <= o.threshold))
            return false;
    return true;
}

template <typename Value> Value make_value(const float *v) {
    if constexpr (std::is_same_v<Value, float>)
        return v[0];
    else
        return Value(v[0], v[1], v[2]);
}

/// The value type of a GridBuilder
template <typename Builder> struct builder_value;
template <typename Value> struct builder_value<nanovdb::GridBuilder<Value>> {
    using type = Value;
};

template <typename Value> Value background_of(const BuildOptions &o) {
    const float bg[3] = { o.background, o.background, o.background };
    return make_value<Value>(bg);
}

template <typename Value, typename Fill>
BuiltGrid finish(const std::string &label, const BuildOptions &o, Fill &&fill) {
    nanovdb::GridBuilder<Value> builder(background_of<Value>(o));
    fill(builder);
    nanovdb::GridHandle<nanovdb::HostBuffer> handle;
    try {
        handle = builder.getHandle(1.0, nanovdb::Vec3d(0.0), o.name);
    } catch (const std::exception &e) {
        fail(label, std::string("building the grid failed: ") + e.what());
    }
    BuiltGrid out;
    out.bytes.resize(handle.size());
    std::memcpy(out.bytes.data(), handle.data(), handle.size());
    out.active = handle.grid<Value>()->activeVoxelCount();
    return out;
}

} // namespace

BuiltGrid build_grid(const std::string &label, const DenseValues &d, const BuildOptions &o) {
    check_channels(label, d.channels);
    for (int k = 0; k < 3; ++k)
        if (d.size[k] == 0 || d.size[k] > (1u << 31) - 1)
            fail(label, "a dense box of " + std::to_string(d.size[0]) + " x " +
                            std::to_string(d.size[1]) + " x " + std::to_string(d.size[2]) +
                            " voxels: every side must hold 1 to 2^31 - 1 voxels");
    if (!(o.threshold >= 0.f))
        fail(label, "the threshold must be >= 0");
    const uint64_t nx = d.size[0], ny = d.size[1];
    auto at = [&](int32_t x, int32_t y, int32_t z) {
        return d.values + ((uint64_t(z) * ny + uint64_t(y)) * nx + uint64_t(x)) * d.channels;
    };
    auto fill = [&](auto &builder) {
        using Value = typename builder_value<std::decay_t<decltype(builder)>>::type;
        const nanovdb::CoordBBox box(nanovdb::Coord(0),
                                     nanovdb::Coord(int32_t(d.size[0]) - 1,
                                                    int32_t(d.size[1]) - 1,
                                                    int32_t(d.size[2]) - 1));
        const Value bg = background_of<Value>(o);
        builder([&](const nanovdb::Coord &ijk) -> Value {
            const float *v = at(ijk[0], ijk[1], ijk[2]);
            return near_background(v, d.channels, o) ? bg : make_value<Value>(v);
        }, box);
    };
    BuiltGrid out = d.channels == 1 ? finish<float>(label, o, fill)
                                    : finish<nanovdb::Vec3f>(label, o, fill);
    const uint64_t total = uint64_t(d.size[0]) * d.size[1] * d.size[2];
    for (uint64_t i = 0; i < total; ++i) {
        const float *v = d.values + i * d.channels;
        bool exact = true;
        for (uint32_t c = 0; c < d.channels; ++c)
            exact &= v[c] == o.background;
        out.left_out += !exact && near_background(v, d.channels, o);
    }
    return out;
}

BuiltGrid build_grid(const std::string &label, const SparseValues &s, const BuildOptions &o) {
    check_channels(label, s.channels);
    if (!(o.threshold >= 0.f))
        fail(label, "the threshold must be >= 0");
    uint64_t left_out = 0;
    auto fill = [&](auto &builder) {
        using Value = typename builder_value<std::decay_t<decltype(builder)>>::type;
        auto acc = builder.getAccessor();
        for (uint64_t i = 0; i < s.count; ++i) {
            const float *v = s.values + i * s.channels;
            if (near_background(v, s.channels, o)) {
                ++left_out;
                continue;
            }
            const int32_t *c = s.coords + 3 * i;
            acc.setValue(nanovdb::Coord(c[0], c[1], c[2]), make_value<Value>(v));
        }
    };
    BuiltGrid out = s.channels == 1 ? finish<float>(label, o, fill)
                                    : finish<nanovdb::Vec3f>(label, o, fill);
    out.left_out = left_out;
    return out;
}

} // namespace nanovdb_loader
