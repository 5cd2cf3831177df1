/*
    src/volumes/memory_source.h -- nanovdbvolume's values from memory: what
    gridvolume accepts besides a file (a VolumeGrid object as "grid", a dense
    tensor as "data"), and voxels given one by one ("values" with "coords"),
    read from the plugin's Properties into the loader's build inputs
    (nanovdb_loader/build.h), which make a NanoVDB grid of them.

    Dense sources keep their whole box as the volume's box (as gridvolume
    spans its array), whatever part of it is active; a voxel list spans its
    active voxels, as a file does.
*/

#pragma once

#include <cstring>
#include <filesystem>
#include <fstream>

#include <mitsuba/core/properties.h>
#include <mitsuba/render/volumegrid.h>

#include <nanovdb_loader/build.h>
#include <nanovdb_loader/majorants.h>

#include <cstring>
#include <optional>
#include <string>
#include <vector>

NAMESPACE_BEGIN(mitsuba)

template <typename Float, typename Spectrum> struct MemorySource {
    MI_IMPORT_TYPES(VolumeGrid)
    using TensorXi = dr::Tensor<DynamicBuffer<Int32>>;

    std::string label;                  ///< names the source in messages
    std::vector<float> values;          ///< host copies (a VolumeGrid's are read in place)
    std::vector<int32_t> coords;
    nanovdb_loader::DenseValues dense;
    nanovdb_loader::SparseValues sparse;
    bool is_dense = false;
    /// 6 channels (SGGX's S): two Vec3f grids, channels 0-2 and 3-5, each
    /// from its own copy of those channels
    bool six_channels = false;
    std::vector<float> halves[2];
    std::optional<ScalarAffineTransform4f> bbox_transform; ///< a VolumeGrid's bbox -> unit cube
    ref<VolumeGrid> grid;               ///< keeps a VolumeGrid's values alive

    /**
     * A .vol's declared size against the file, before VolumeGrid allocates
     * it: the header (\"VOL\", version 3, encoding 1 = float32, x, y, z,
     * channels, a box of 6 floats: 48 bytes) declares x*y*z*channels
     * floats, which must be the rest of the file. A damaged header can
     * declare 10^12 voxels in a 100-byte file.
     */
    static void check_vol_header(const std::string &vol_path) {
        std::ifstream is(vol_path, std::ios::binary);
        unsigned char h[48];
        if (!is.read(reinterpret_cast<char *>(h), 48) || h[0] != 'V' || h[1] != 'O' ||
            h[2] != 'L')
            return; // (VolumeGrid says what is wrong with it)
        int32_t v[5];
        std::memcpy(v, h + 4, sizeof v);
        if (v[0] != 1)
            return;
        std::error_code ec;
        const uint64_t file = (uint64_t) std::filesystem::file_size(vol_path, ec);
        uint64_t values = 1;
        bool overflow = false;
        for (int k = 1; k < 5; ++k) {
            if (v[k] <= 0)
                Throw("nanovdbvolume: \"%s\": damaged .vol header: a size of %d", vol_path, v[k]);
            overflow |= values > UINT64_MAX / 4 / (uint64_t) v[k];
            values *= (uint64_t) v[k];
        }
        if (overflow || ec || values * 4 != file - 48)
            Throw("nanovdbvolume: \"%s\": damaged .vol: its header declares %d x %d x %d "
                  "voxels of %d channels (%s bytes of values); the file holds %llu",
                  vol_path, v[1], v[2], v[3], v[4],
                  overflow ? std::string("more than 2^64") : std::to_string(values * 4),
                  (unsigned long long) (file - 48));
    }

    /// A gridvolume file (.vol: dense, Mitsuba's own format), read by
    /// Mitsuba's VolumeGrid
    MemorySource(const std::string &vol_path) {
        check_vol_header(vol_path);
        try {
            grid = new VolumeGrid(fs::path(vol_path));
        } catch (const std::exception &e) {
            Throw("nanovdbvolume: \"%s\": not a readable .vol file: %s", vol_path, e.what());
        }
        set_volume_grid(vol_path);
    }

    /// Reads the source; `grid_object`: "grid" is a VolumeGrid
    MemorySource(const Properties &props, bool grid_object) {
        if (grid_object) {
            ref<Object> other = props.get<ref<Object>>("grid");
            grid = dynamic_cast<VolumeGrid *>(other.get());
            if (!grid)
                Throw("nanovdbvolume: the \"grid\" property must be a grid name (string) or a "
                      "VolumeGrid object, got %s", other ? other->to_string() : "null");
            ScalarVector3u size = grid->size();
            set_volume_grid(tfm::format("grid: a VolumeGrid of %u x %u x %u voxels, %zu channels",
                                        size.x(), size.y(), size.z(), grid->channel_count()));
        } else if (props.has_property("data")) {
            const TensorXf &t = props.get_any<TensorXf>("data");
            if (t.ndim() != 3 && t.ndim() != 4)
                Throw("nanovdbvolume: \"data\" must be a tensor of shape (z, y, x) or "
                      "(z, y, x, channels), as gridvolume's; it has %zu dimensions", t.ndim());
            if (t.ndim() == 4 && t.shape(3) != 1 && t.shape(3) != 3 && t.shape(3) != 6)
                Throw("nanovdbvolume: \"data\" has %zu channels; 1, 3 or 6 are supported (as "
                      "for gridvolume)", t.shape(3));
            uint32_t channels = t.ndim() == 4 ? (uint32_t) t.shape(3) : 1;
            label = tfm::format("data: a %zu x %zu x %zu tensor, %u channels", t.shape(2),
                                t.shape(1), t.shape(0), channels);
            values = host_copy<float>(t.array());
            set_dense(values.data(),
                      { (uint32_t) t.shape(2), (uint32_t) t.shape(1), (uint32_t) t.shape(0) },
                      channels);
        } else {
            if (!props.has_property("values") || !props.has_property("coords"))
                Throw("nanovdbvolume: voxels one by one need both \"values\" (a TensorXf of "
                      "shape (n,) or (n, 3)) and \"coords\" (a TensorXi of shape (n, 3))");
            for (const char *name : { "values", "coords" })
                if (props.type(name) != Properties::Type::Any)
                    Throw("nanovdbvolume: \"%s\" must be a tensor (TensorXf values, TensorXi "
                          "coords); it arrived as a %s property (Mitsuba's dictionary parser "
                          "turns an array of 3 numbers into a vector: give at least two voxels)",
                          name, props.type(name) == Properties::Type::Vector ? "vector" : "non-tensor");
            const TensorXf &v = props.get_any<TensorXf>("values");
            const TensorXi &c = props.get_any<TensorXi>("coords");
            if (c.ndim() != 2 || c.shape(1) != 3)
                Throw("nanovdbvolume: \"coords\" must be a TensorXi of shape (n, 3): one index "
                      "coordinate (x, y, z) per voxel");
            size_t n = c.shape(0);
            uint32_t channels = v.ndim() == 2 ? (uint32_t) v.shape(1) : 1;
            if (v.ndim() < 1 || v.ndim() > 2 || v.shape(0) != n)
                Throw("nanovdbvolume: \"values\" must be a TensorXf of shape (n,) or (n, "
                      "channels) with n = %zu, as many as \"coords\" has rows", n);
            label = tfm::format("values: %zu voxels, %u channels", n, channels);
            values = host_copy<float>(v.array());
            coords = host_copy<int32_t>(c.array());
            sparse.coords = coords.data();
            sparse.values = values.data();
            sparse.count = n;
            sparse.channels = channels;
            if (channels == 6)
                split_six(values.data(), n);
        }
    }

    /// Builds the grid (`half` 1: channels 3-5 of a 6-channel source); for
    /// a dense source also returns its box
    std::pair<nanovdb_loader::BuiltGrid, std::optional<nanovdb_loader::IndexBox>>
    build(const nanovdb_loader::BuildOptions &options, int half = 0) const {
        if (!is_dense) {
            nanovdb_loader::SparseValues sv = sparse;
            if (six_channels) {
                sv.values = halves[half].data();
                sv.channels = 3;
            }
            return { nanovdb_loader::build_grid(label, sv, options), std::nullopt };
        }
        nanovdb_loader::IndexBox box;
        for (int k = 0; k < 3; ++k) {
            box.lo[k] = 0;
            box.hi[k] = int32_t(dense.size[k]) - 1;
        }
        nanovdb_loader::DenseValues dv = dense;
        if (six_channels) {
            dv.values = halves[half].data();
            dv.channels = 3;
        }
        return { nanovdb_loader::build_grid(label, dv, options), box };
    }

private:
    void set_volume_grid(const std::string &label_) {
        label = label_;
        ScalarVector3u size = grid->size();
        uint32_t channels = (uint32_t) grid->channel_count();
        if (channels != 1 && channels != 3 && channels != 6)
            Throw("nanovdbvolume: \"%s\": %u channels; 1, 3 or 6 are supported (as for "
                  "gridvolume)", label, channels);
        set_dense(grid->data(), { size.x(), size.y(), size.z() }, channels);
        bbox_transform = grid->bbox_transform();
    }

    void set_dense(const float *ptr, std::array<uint32_t, 3> size, uint32_t channels) {
        is_dense = true;
        dense.values = ptr;
        for (int k = 0; k < 3; ++k)
            dense.size[k] = size[k];
        dense.channels = channels;
        if (channels == 6)
            split_six(ptr, uint64_t(size[0]) * size[1] * size[2]);
    }

    void split_six(const float *ptr, uint64_t count) {
        six_channels = true;
        for (int h = 0; h < 2; ++h) {
            halves[h].resize(size_t(count) * 3);
            for (uint64_t i = 0; i < count; ++i)
                for (int c = 0; c < 3; ++c)
                    halves[h][size_t(i * 3 + c)] = ptr[i * 6 + 3 * h + c];
        }
    }

    /// A JIT array's values on the host (one transfer), or a copy of a
    /// scalar variant's buffer
    template <typename T, typename Array> static std::vector<T> host_copy(const Array &a) {
        std::vector<T> out(dr::width(a));
        if (out.empty())
            return out;
        if constexpr (dr::is_jit_v<Array>) {
            auto detached = dr::detach(a);
            dr::eval(detached);
            dr::store(out.data(), detached);
        } else {
            std::memcpy(out.data(), a.data(), out.size() * sizeof(T));
        }
        return out;
    }
};

NAMESPACE_END(mitsuba)
