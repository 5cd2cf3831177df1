#include <mitsuba/core/fresolver.h>
#include <mitsuba/core/properties.h>
#include <mitsuba/core/string.h>
#include <mitsuba/core/transform.h>
#include <mitsuba/render/volume.h>

#include <nanovdb_drjit/backend_buffer.h>
#include <nanovdb_drjit/io.h>
#include <nanovdb_drjit/pnanovdb.h>

#include <cstdlib>
#include <cstring>
#include <memory>
#include <vector>

NAMESPACE_BEGIN(mitsuba)

/**!

.. _volume-nanovdbvolume:

NanoVDB sparse volume (:monosp:`nanovdbvolume`)
-----------------------------------------------

.. pluginparameters::

 * - filename
   - |string|
   - Path of the NanoVDB file (``.nvdb``) to load. Files written by NanoVDB
     32.3 to 32.9 (OpenVDB 10 to 13) are read, uncompressed or with the ZIP
     or BLOSC codec, including files with several grids or segments and raw
     grid buffers.

 * - grid
   - |string|
   - Which grid of the file to use: its name, or its index in the file
     (``"0"``, ``"1"``, ...) when no grid has that name. Only that grid's
     bytes are read. (Default: the first float grid of the file)

 * - filter_type
   - |string|
   - ``trilinear``: interpolate between voxel centres, as NanoVDB's own
     trilinear sampler does; ``nearest``: the value of the voxel that
     contains the point. (Default: ``trilinear``)

 * - use_grid_transform
   - |bool|
   - If ``false``, the volume's local unit cube :math:`[0, 1]^3` spans the
     grid's active voxels exactly as ``gridvolume`` spans a dense array of the
     same box, so the two plugins render the same image under the same
     ``to_world``. If ``true``, local space is the grid's own world space
     (its index-to-world map from the file), so the volume lines up with
     other VDB tools. (Default: ``false``)

 * - invalid_values
   - |string|
   - What to do with NaN, infinite and negative voxel or tile values:
     ``error``: refuse a grid with NaN or infinite values, naming the first
     offending voxel (negative values load, with a warning);
     ``clamp``: replace NaN by 0, +Inf by the largest finite value of the
     grid, -Inf and negative values by 0, with a warning that counts them.
     (Default: ``error``)

 * - to_world
   - |transform|
   - Transformation applied to the volume's local space. (Default: identity)

This plugin renders sparse volumes stored as NanoVDB grids directly, without
a dense conversion: a cloud that needs hundreds of megabytes as a dense
``gridvolume`` stays at the size of its ``.nvdb`` file, in CPU and GPU memory
alike. It works in every variant (``scalar_*``, ``llvm_ad_*``, ``cuda_ad_*``;
RGB, monochrome, spectral and polarized), where it behaves like a
single-channel ``gridvolume``.

Lookups traverse the NanoVDB tree (root, upper, lower and leaf nodes) with a
Dr.Jit translation of PNanoVDB. Values outside the active voxels are whatever
the tree stores there -- normally the grid's background value (VDB
semantics). Consequently, ``trilinear`` interpolation in the outer half voxel
of the active box blends towards the background, where ``gridvolume`` clamps
to the edge voxel.

Coordinates, with ``use_grid_transform=false``: if the grid's active voxels
span the inclusive index box :math:`[m, M]` and :math:`d = M - m + 1`, the
local point :math:`u \in [0, 1]^3` reads voxel :math:`\lfloor m + u d
\rfloor` (``nearest``) or interpolates at the index position :math:`m + u d
- 0.5` (``trilinear``). Positions are computed relative to :math:`m` in
floating point, and the integer :math:`m` is added last, so grids far from
the origin keep full precision.

The file is validated once when it is loaded (every node offset of the tree
must point inside it), so lookups can trust it. ``max()`` is the maximum of
every value that a lookup can return (background, tiles and all leaf values,
active or not), a true upper bound for the ``heterogeneous`` medium's
majorant; trilinear results are clamped to it, because rounded interpolation
weights can overshoot the largest corner value by a few ulps. Grids containing
NaN or infinite values are rejected unless ``invalid_values="clamp"``. Only float
grids are supported; other grid types fail with a message that names them.

.. tabs::
    .. code-tab:: xml

        <medium type="heterogeneous">
            <volume type="nanovdbvolume" name="sigma_t">
                <string name="filename" value="cloud.nvdb"/>
                <string name="grid" value="density"/>
            </volume>
        </medium>

    .. code-tab:: python

        'type': 'heterogeneous',
        'sigma_t': {
            'type': 'nanovdbvolume',
            'filename': 'cloud.nvdb',
            'grid': 'density'
        }
*/

template <typename Float, typename Spectrum>
class NanoVDBVolume final : public Volume<Float, Spectrum> {
public:
    MI_IMPORT_BASE(Volume, update_bbox, m_to_local, m_bbox, m_channel_count)
    MI_IMPORT_TYPES()

    /// The tree as 32-bit words: a JIT array, or a plain host allocation
    using Buffer = std::conditional_t<dr::is_jit_v<Float>, UInt32,
                                      std::unique_ptr<uint32_t[], void (*)(void *)>>;

    NanoVDBVolume(const Properties &props)
        : Base(props), m_buffer(make_empty_buffer()) {
        std::string_view filter = props.get<std::string_view>("filter_type", "trilinear");
        if (filter == "nearest")
            m_nearest = true;
        else if (filter == "trilinear")
            m_nearest = false;
        else
            Throw("Invalid filter type \"%s\", must be one of: \"nearest\" or "
                  "\"trilinear\"!", filter);

        m_use_grid_transform = props.get<bool>("use_grid_transform", false);

        std::string_view invalid = props.get<std::string_view>("invalid_values", "error");
        if (invalid == "clamp")
            m_clamp_invalid = true;
        else if (invalid != "error")
            Throw("Invalid value \"%s\" for invalid_values, must be one of: \"error\" or "
                  "\"clamp\"!", invalid);

        fs::path file_path =
            file_resolver()->resolve(props.get<std::string_view>("filename"));
        m_filename = file_path.string();
        std::string selector(props.get<std::string_view>("grid", ""));

        namespace io = nanovdb_drjit::io;
        io::FloatGridInfo info;
        try {
            std::vector<io::GridEntry> grids = io::list_grids(m_filename);
            const io::GridEntry &entry = io::select_grid(m_filename, grids, selector);
            info = load(entry);
        } catch (const io::Error &e) {
            Throw("nanovdbvolume: %s", e.what());
        }

        m_grid_name = info.name;
        m_background = info.background;
        m_max = info.value_max;
        m_max_opaque = dr::opaque<Float>(m_max);

        // Active index box [min, max] (inclusive). An empty grid reads as the
        // single voxel at the origin, i.e. its background everywhere.
        ScalarVector3i bmin(info.bbox_min[0], info.bbox_min[1], info.bbox_min[2]),
                       bmax(info.bbox_max[0], info.bbox_max[1], info.bbox_max[2]);
        if (info.empty) {
            bmin = ScalarVector3i(0);
            bmax = ScalarVector3i(0);
        }
        m_min_scalar = bmin;
        // Extent as 64-bit arithmetic: max - min + 1 overflows int32 for boxes
        // spanning more than 2^31 voxels.
        for (int k = 0; k < 3; ++k) {
            int64_t extent = int64_t(bmax[k]) - int64_t(bmin[k]) + 1;
            if (extent > std::numeric_limits<int32_t>::max())
                Throw("nanovdbvolume: \"%s\": grid \"%s\" spans %lld voxels along "
                      "axis %d, more than a Mitsuba volume resolution can hold.",
                      m_filename, m_grid_name, (long long) extent, k);
            m_resolution[k] = (int32_t) extent;
        }

        // Per-file values reach kernels as opaque variables, so that loading
        // another file does not recompile them.
        m_root = dr::opaque<UInt32>(info.root_word);
        for (int k = 0; k < 3; ++k) {
            m_min[k]  = dr::opaque<Int32>(bmin[k]);
            m_dims[k] = dr::opaque<Float>((ScalarFloat) m_resolution[k]);
        }

        if (m_use_grid_transform)
            setup_grid_transform(info);

        m_channel_count = 1;
        Log(Debug, "Loaded \"%s\" grid \"%s\": index box [%s, %s], %llu bytes, max %f",
            m_filename, m_grid_name, bmin, bmax, (unsigned long long) m_buffer_bytes, m_max);
    }

    // =====================================================================
    //  Volume interface
    // =====================================================================

    UnpolarizedSpectrum eval(const Interaction3f &it, Mask active) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (dr::none_or<false>(active))
            return dr::zeros<UnpolarizedSpectrum>();
        return UnpolarizedSpectrum(lookup(it, active));
    }

    Float eval_1(const Interaction3f &it, Mask active = true) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (dr::none_or<false>(active))
            return dr::zeros<Float>();
        return lookup(it, active);
    }

    void eval_n(const Interaction3f &it, Float *out, Mask active = true) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        out[0] = lookup(it, active);
    }

    Vector3f eval_3(const Interaction3f &, Mask = true) const override {
        Throw("eval_3(): the nanovdbvolume \"%s\" (grid \"%s\") holds a single "
              "channel, not a 3D vector", m_filename, m_grid_name);
    }

    dr::Array<Float, 6> eval_6(const Interaction3f &, Mask = true) const override {
        Throw("eval_6(): the nanovdbvolume \"%s\" (grid \"%s\") holds a single "
              "channel, not 6", m_filename, m_grid_name);
    }

    ScalarFloat max() const override { return m_max; }

    void max_per_channel(ScalarFloat *out) const override { out[0] = m_max; }

    ScalarVector3i resolution() const override { return m_resolution; }

    std::string to_string() const override {
        std::ostringstream oss;
        oss << "NanoVDBVolume[" << std::endl
            << "  filename = \"" << m_filename << "\"," << std::endl
            << "  grid = \"" << m_grid_name << "\"," << std::endl
            << "  filter_type = " << (m_nearest ? "nearest" : "trilinear") << "," << std::endl
            << "  use_grid_transform = " << m_use_grid_transform << "," << std::endl
            << "  to_local = " << string::indent(m_to_local, 13) << "," << std::endl
            << "  bbox = " << string::indent(m_bbox) << "," << std::endl
            << "  index_min = " << m_min_scalar << "," << std::endl
            << "  dimensions = " << m_resolution << "," << std::endl
            << "  background = " << m_background << "," << std::endl
            << "  max = " << m_max << "," << std::endl
            << "  bytes = " << m_buffer_bytes << "," << std::endl
            << "  backend_bytes = " << m_backend_bytes << "," << std::endl
            << "  reader = " << (m_root_indexed ? "root index" : "root search")
            << (m_compact_offsets ? ", 32-bit child offsets" : ", 64-bit child offsets")
            << std::endl
            << "]";
        return oss.str();
    }

    MI_DECLARE_CLASS(NanoVDBVolume)

private:
    // =====================================================================
    //  Spaces. Local: the unit cube over the active box (default) or the
    //  grid's world space (use_grid_transform). Index: NanoVDB's integer
    //  voxel coordinates, values at integer positions. Kernels compute the
    //  index position *relative to the box minimum* in floating point and add
    //  the integer minimum last.
    // =====================================================================

    /// Value at local point of `it` (nearest or trilinear)
    Float lookup(const Interaction3f &it, Mask active) const {
        MI_MASK_ARGUMENT(active);
        namespace ndr = nanovdb_drjit;

        Vector3f rel;      // index position relative to m_min
        Vector3i base;     // integer cell (relative to m_min)
        if (!m_use_grid_transform) {
            Point3f p = m_to_local * it.p;
            // Same arithmetic as Dr.Jit's texture (gridvolume), so both plugins
            // pick the same voxels and weights.
            if (m_nearest) {
                base = index_floor(p * m_dims);
                return value_at(index_add(base, m_min), active);
            }
            rel = dr::fmadd(p, m_dims, -.5f);
        } else {
            Point4f p = m_index_from_world * Point4f(it.p.x(), it.p.y(), it.p.z(), 1.f);
            rel = Vector3f(p.x(), p.y(), p.z());
            if (m_nearest) {
                base = index_floor(rel + .5f);
                return value_at(index_add(base, m_min), active);
            }
        }

        base = index_floor(rel);
        Vector3f w1 = rel - Vector3f(base),
                 w0 = 1.f - w1;
        Vector3i ijk0 = index_add(base, m_min);

        // The 8 corners in one traversal (see root_get_stencil_addresses),
        // summed in the order and with the weights of Dr.Jit's texture
        ndr::Coord<UInt32> c(ijk0.x(), ijk0.y(), ijk0.z());
        dr::Array<UInt32, 8> address = with_reader([&](const auto &buf, const auto &root) {
            return ndr::root_get_stencil_addresses(buf, root, c, active);
        });
        Float result = 0.f;
        for (uint32_t corner = 0; corner < 8; ++corner) {
            int32_t bit[3] = { (int32_t) (corner & 1), (int32_t) ((corner >> 1) & 1),
                               (int32_t) ((corner >> 2) & 1) };
            Float weight = 1.f;
            for (uint32_t k = 0; k < 3; ++k)
                weight = weight * (bit[k] ? w1[k] : w0[k]);
            result = dr::fmadd(ndr::read_float(buffer(), address[corner], active), weight,
                               result);
        }
        // The rounded weights can sum to slightly more than 1, so the result
        // could exceed the largest corner by a few ulps (measured: 3 ulps on
        // a level set whose values sit at its maximum). The heterogeneous
        // medium needs max() to be a true bound, so clamp.
        return dr::minimum(result, m_max_opaque);
    }

    /**
     * The policy for NaN, infinite and negative values, applied on the host
     * before the grid reaches the backend (see the invalid_values parameter).
     * Scans only grids whose validation already found such values.
     */
    void check_values(void *data, size_t bytes, const std::string &grid,
                      nanovdb_drjit::io::FloatGridInfo &info) {
        namespace io = nanovdb_drjit::io;
        bool non_finite = info.nan_count > 0 || info.inf_count > 0,
             negative = info.value_min < 0.f;
        if (!non_finite && !negative)
            return;
        io::ValueScan scan = io::scan_values(m_filename, data, bytes);
        if (!m_clamp_invalid) {
            if (non_finite)
                Throw("nanovdbvolume: \"%s\": grid \"%s\" contains %s; only finite "
                      "values can be rendered. Set invalid_values=\"clamp\" to replace "
                      "NaN by 0, +Inf by the largest finite value and -Inf and negative "
                      "values by 0.", m_filename, grid, io::describe_invalid_values(scan));
            Log(Warn, "\"%s\": grid \"%s\" contains %llu negative values (first: %s); "
                "a negative density makes no physical sense. Set "
                "invalid_values=\"clamp\" to replace them by 0.", m_filename, grid,
                (unsigned long long) scan.negative_count,
                io::describe_location(scan.first_negative));
            return;
        }
        io::SanitizeResult r = io::sanitize_values(m_filename, data, bytes);
        Log(Warn, "\"%s\": grid \"%s\": replaced %llu NaN by 0, %llu +Inf by the largest "
            "finite value, %llu -Inf and %llu negative values by 0 (invalid_values=clamp).",
            m_filename, grid, (unsigned long long) r.nan, (unsigned long long) r.posinf,
            (unsigned long long) r.neginf, (unsigned long long) r.negative);
        info = io::validate_float_grid(m_filename, data, bytes);
    }

    /**
     * Decides, once per file, which of the translation's readers the kernels
     * use (traced as one code path per file, never as a runtime branch):
     * CompactOffsets where every child offset fits the low word, and an
     * O(1) root tile index where it is small (at most 0.4 % of the grid).
     */
    void prepare_readers(const uint32_t *words, size_t bytes,
                         const nanovdb_drjit::io::FloatGridInfo &info) {
        namespace ndr = nanovdb_drjit;
        m_compact_offsets = ndr::host::has_compact_offsets(words, bytes);
        ndr::host::RootIndex index;
        uint64_t max_entries = std::max<uint64_t>(64, bytes / 1024);
        m_root_indexed = ndr::host::build_root_index(words, info.root_word, max_entries, index);
        if (!m_root_indexed)
            return;
        if (index.table.empty())
            index.table.push_back(0u);
        m_root_table_host = std::move(index.table);
        if constexpr (dr::is_jit_v<Float>)
            m_root_table = dr::load<UInt32>(m_root_table_host.data(), m_root_table_host.size());
        for (int k = 0; k < 3; ++k) {
            m_block_min[k] = dr::opaque<Int32>(index.block_min[k]);
            m_block_dims[k] = dr::opaque<Int32>(index.block_dims[k]);
        }
        if constexpr (dr::is_jit_v<Float>)
            std::vector<uint32_t>().swap(m_root_table_host); // the JIT array holds it now
    }

    /// Calls fn(buffer, root) with the reader chosen by prepare_readers()
    template <typename Fn> decltype(auto) with_reader(Fn &&fn) const {
        namespace ndr = nanovdb_drjit;
        auto with_root = [&](const auto &buf) -> decltype(auto) {
            if (m_root_indexed) {
                if constexpr (dr::is_jit_v<Float>)
                    return fn(buf, ndr::IndexedRootHandle<UInt32, UInt32>{
                                       m_root, m_root_table, m_block_min, m_block_dims });
                else
                    return fn(buf, ndr::IndexedRootHandle<UInt32, const uint32_t *>{
                                       m_root, m_root_table_host.data(), m_block_min,
                                       m_block_dims });
            }
            return fn(buf, ndr::RootHandle<UInt32>{ m_root });
        };
        if (m_compact_offsets)
            return with_root(ndr::CompactOffsets<std::decay_t<decltype(buffer())>>{ buffer() });
        return with_root(buffer());
    }

    /// floor() to int32 for positions relative to the box minimum. Points
    /// absurdly far outside the volume are clamped first (a float beyond the
    /// int32 range has no int32 floor); they read the background either way.
    static Vector3i index_floor(const Vector3f &rel) {
        constexpr float limit = 2147483520.f; // largest float below 2^31
        return dr::floor2int<Vector3i>(dr::clip(rel, -limit, limit));
    }

    /// a + b with int32 wrap-around on every backend (the VDB index space
    /// wraps as PNanoVDB's does; plain C++ int32 overflow is undefined)
    static Vector3i index_add(const Vector3i &a, const Vector3i &b) {
        return dr::reinterpret_array<Vector3i>(dr::reinterpret_array<Vector3u>(a) +
                                               dr::reinterpret_array<Vector3u>(b));
    }

    /// The buffer as the translation reads it: a JIT array or a host pointer
    decltype(auto) buffer() const {
        if constexpr (dr::is_jit_v<Float>)
            return (const UInt32 &) m_buffer;
        else
            return static_cast<const uint32_t *>(m_buffer.get());
    }

    /// Value stored at integer index coordinate `ijk` (PNanoVDB traversal)
    Float value_at(const Vector3i &ijk, Mask active) const {
        namespace ndr = nanovdb_drjit;
        ndr::Coord<UInt32> c(ijk.x(), ijk.y(), ijk.z());
        return with_reader([&](const auto &buf, const auto &root) {
            return ndr::root_get_value(buf, root, c, active);
        });
    }

    /// With use_grid_transform: local space = the grid's world space.
    void setup_grid_transform(const nanovdb_drjit::io::FloatGridInfo &info) {
        // index = inv_mat * (world - vec); relative to the box minimum:
        // rel = inv_mat * world - (inv_mat * vec + min), composed with
        // to_local in double precision and rounded once.
        using Matrix4d = dr::Matrix<double, 4>;
        Matrix4d index_from_grid = dr::identity<Matrix4d>();
        for (int r = 0; r < 3; ++r) {
            double t = 0.0;
            for (int c = 0; c < 3; ++c) {
                index_from_grid(r, c) = info.map_inv[3 * r + c];
                t += info.map_inv[3 * r + c] * info.map_vec[c];
            }
            index_from_grid(r, 3) = -t - (double) m_min_scalar[r];
        }
        Matrix4d to_local = dr::identity<Matrix4d>();
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
                to_local(r, c) = (double) m_to_local.matrix(r, c);
        Matrix4d m = index_from_grid * to_local;

        ScalarMatrix4f mf;
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
                mf(r, c) = (float) m(r, c);
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
                m_index_from_world(r, c) = dr::opaque<Float>(mf(r, c));

        // World-space bounds: the voxels' cells [min - 0.5, max + 0.5] of the
        // index box, mapped by the grid transform and then by to_world.
        ScalarAffineTransform4f to_world = m_to_local.inverse();
        m_bbox = ScalarBoundingBox3f();
        for (int corner = 0; corner < 8; ++corner) {
            double idx[3], world[3];
            for (int k = 0; k < 3; ++k)
                idx[k] = (corner >> k & 1) ? m_min_scalar[k] + m_resolution[k] - 0.5
                                           : m_min_scalar[k] - 0.5;
            for (int r = 0; r < 3; ++r) {
                world[r] = info.map_vec[r];
                for (int c = 0; c < 3; ++c)
                    world[r] += info.map_mat[3 * r + c] * idx[c];
            }
            m_bbox.expand(to_world * ScalarPoint3f((float) world[0], (float) world[1],
                                                   (float) world[2]));
        }
    }

    // =====================================================================
    //  Loading: only the selected grid's bytes, into one exact-size
    //  allocation that the backend owns (include/nanovdb_drjit/
    //  backend_buffer.h). No host copy is kept, and none is made on LLVM.
    // =====================================================================

    static Buffer make_empty_buffer() {
        if constexpr (dr::is_jit_v<Float>)
            return UInt32();
        else
            return Buffer(nullptr, std::free);
    }

    /// Read -> validate -> value policy -> reader set-up, into `words`
    /// (a block of `alloc_bytes`, the grid's bytes zero-padded to 64)
    nanovdb_drjit::io::FloatGridInfo decode(const nanovdb_drjit::io::GridEntry &entry,
                                            uint32_t *words, size_t bytes,
                                            size_t alloc_bytes) {
        namespace io = nanovdb_drjit::io;
        std::memset((uint8_t *) words + bytes, 0, alloc_bytes - bytes);
        io::read_grid(m_filename, entry, words);
        io::FloatGridInfo info = io::validate_float_grid(m_filename, words, bytes);
        check_values(words, bytes, entry.name, info);
        prepare_readers(words, bytes, info);
        return info;
    }

    nanovdb_drjit::io::FloatGridInfo load(const nanovdb_drjit::io::GridEntry &entry) {
        namespace io = nanovdb_drjit::io;
        namespace backend = nanovdb_drjit::backend;
        size_t bytes = (size_t) entry.grid_size,
               alloc_bytes = ((bytes + 63) / 64) * 64, words = alloc_bytes / 4;
        m_buffer_bytes = bytes;

        // One host block: the final buffer on scalar and LLVM variants (LLVM
        // kernels read host memory in place), the staging buffer on CUDA.
        std::unique_ptr<uint32_t[], void (*)(void *)> host(nullptr, std::free);
        void *ptr = nullptr;
        if (posix_memalign(&ptr, 64, alloc_bytes) != 0 || !ptr)
            Throw("nanovdbvolume: \"%s\": cannot allocate %zu bytes for grid \"%s\"",
                  m_filename, bytes, entry.name);
        host.reset((uint32_t *) ptr);
        io::FloatGridInfo info = decode(entry, host.get(), bytes, alloc_bytes);

        if constexpr (!dr::is_jit_v<Float>) {
            m_buffer = std::move(host);
        } else if constexpr (dr::backend_v<Float> == JitBackend::LLVM) {
            m_buffer = UInt32::steal(backend::map_host_words(host.release(), words));
        } else {
            try {
                m_buffer = UInt32::steal(backend::upload_cuda_words(host.get(), words));
            } catch (const std::exception &e) {
                Throw("nanovdbvolume: \"%s\": grid \"%s\" (%zu bytes): %s", m_filename,
                      entry.name, bytes, e.what());
            }
        }
        m_backend_bytes = alloc_bytes;
        return info;
    }

private:
    Buffer m_buffer;
    UInt32 m_root;             // word address of the root node
    Vector3i m_min;            // active box minimum (opaque on JIT backends)
    Vector3f m_dims;           // active box extent, as float (opaque)
    Matrix4f m_index_from_world; // use_grid_transform: world -> index - min
    Float m_max_opaque;        // max(), the clamp of trilinear results
    UInt32 m_root_table;       // O(1) root tile index (JIT variants)
    std::vector<uint32_t> m_root_table_host; // ... (scalar variants)
    Vector3i m_block_min, m_block_dims;      // ... its box of 4096^3 blocks
    bool m_root_indexed = false;
    bool m_compact_offsets = false;

    ScalarVector3i m_min_scalar;
    ScalarVector3i m_resolution;
    ScalarFloat m_max = 0.f;
    ScalarFloat m_background = 0.f;
    size_t m_buffer_bytes = 0;  // the grid's bytes
    size_t m_backend_bytes = 0; // what the backend holds for it (padded to 64 B)
    bool m_nearest = false;
    bool m_use_grid_transform = false;
    bool m_clamp_invalid = false;
    std::string m_filename, m_grid_name;

    MI_TRAVERSE_CB(Base, m_buffer, m_root, m_min, m_dims, m_index_from_world, m_max_opaque,
                   m_root_table, m_block_min, m_block_dims)
};

MI_EXPORT_PLUGIN(NanoVDBVolume)
NAMESPACE_END(mitsuba)
